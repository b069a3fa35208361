"""What workspace tests share: the repository root, the stack environment, the ground truth."""

import json
import os

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
    """Return the simulator's latest ground truth, or None before its first report.

    Keys: ``t_ns`` (monotonic), ``pose`` [x, y, theta], ``v``, ``w``, ``collisions``,
    ``in_contact``. Tests judge the robot's motion on this, never on the odometry under test.
    This is the one place that knows where the simulator publishes its truth.
    """
    try:
        with open(ground_truth_path(runtime_dir), encoding='utf-8') as f:
            return json.load(f)
    except (FileNotFoundError, json.JSONDecodeError):
        return None
