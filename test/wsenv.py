"""What workspace tests share: the repository root, the stack environment, the simulator."""

import json
import os
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def stack_env(runtime_dir: str) -> dict[str, str]:
    """Return the environment for stack processes run from the source tree.

    The sources come first on PYTHONPATH (so a test exercises this checkout, not an older
    install), the runtime directory is the test's private one and the configuration is the
    repository's ``config/``.
    """
    env = dict(os.environ)
    src = [os.path.join(ROOT, 'src', p) for p in ('m4k_rt', 'm4k_drivers', 'm4k_bench')]
    env['PYTHONPATH'] = os.pathsep.join(
        src + [x for x in env.get('PYTHONPATH', '').split(os.pathsep) if x])
    env['M4K_RUNTIME_DIR'] = runtime_dir
    env['M4K_CONFIG_DIR'] = os.path.join(ROOT, 'config')
    env['M4K_WORLD_REPORT'] = ground_truth_path(runtime_dir)
    return env


def ground_truth_path(runtime_dir: str) -> str:
    """Return where the simulator of a stack started with :func:`stack_env` reports its truth."""
    return os.path.join(runtime_dir, 'world.json')


def ground_truth(runtime_dir: str) -> dict | None:
    """Return the simulator's ground truth now, or None when no simulator has reported.

    Asks the running ``sim_robot`` over its sim-bus socket (the truth of this instant); when
    none answers (stopped), the last report it wrote. Keys: ``t_ns`` (monotonic), ``pose``
    [x, y, theta], ``v``, ``w``, ``collisions``, ``in_contact``, and ``wheel_speed_left`` /
    ``wheel_speed_right`` (rad/s), ``motor_enabled`` (the amplifier enable), ``motor_volts``.
    Tests judge the robot's motion on this, never on the odometry under test. This is the one
    place that knows where the simulator publishes its truth.
    """
    from m4k_drivers.simbus import read_truth
    try:
        return read_truth(runtime_dir)
    except (OSError, ValueError):
        pass
    try:
        with open(ground_truth_path(runtime_dir), encoding='utf-8') as f:
            return json.load(f)
    except (FileNotFoundError, json.JSONDecodeError):
        return None


def start_sim_robot(procs, env: dict[str, str], runtime_dir: str, *args: str,
                    timeout_s: float = 20.0):
    """Start ``sim_robot`` (a real process) on ``runtime_dir`` and wait until it answers."""
    proc = procs.start(['python', '-m', 'm4k_drivers.sim_robot', '--runtime-dir', runtime_dir,
                        *args], env=env)
    deadline = time.monotonic() + timeout_s
    while ground_truth_live(runtime_dir) is None:
        if proc.poll() is not None:
            raise RuntimeError(f'sim_robot exited with {proc.returncode}: '
                               f'{proc.communicate()[1]}')
        if time.monotonic() > deadline:
            raise TimeoutError(f'sim_robot did not answer within {timeout_s} s')
        time.sleep(0.05)
    return proc


def ground_truth_live(runtime_dir: str) -> dict | None:
    """Return the running simulator's truth, None when none answers (no file fallback)."""
    from m4k_drivers.simbus import read_truth
    try:
        return read_truth(runtime_dir)
    except (OSError, ValueError):
        return None
