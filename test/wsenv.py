"""What workspace tests share: the repository root, the stack environment, the simulator."""

import json
import os
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# The workspace's Python packages, lowest layer first.
PYTHON_PACKAGES = ('m4k_rt', 'm4k_drivers', 'm4k_bridge', 'm4k_bringup', 'm4k_bench')
# The tests' own package (src/m4k_testing): on top, beside the tests; no runtime module uses it.
TEST_PACKAGES = ('m4k_testing',)


def stack_env(runtime_dir: str) -> dict[str, str]:
    """Return the environment for stack processes run from the source tree.

    The sources come first on PYTHONPATH (so a test exercises this checkout, not an older
    install), the runtime directory is the test's private one and the configuration is the
    repository's ``config/``.
    """
    env = dict(os.environ)
    src = [os.path.join(ROOT, 'src', p) for p in PYTHON_PACKAGES]
    env['PYTHONPATH'] = os.pathsep.join(
        src + [x for x in env.get('PYTHONPATH', '').split(os.pathsep) if x])
    env['M4K_RUNTIME_DIR'] = runtime_dir
    env['M4K_CONFIG_DIR'] = os.path.join(ROOT, 'config')
    env['M4K_WORLD_REPORT'] = ground_truth_path(runtime_dir)
    # The flight recorder's default dump directory ($XDG_STATE_HOME/m4k/flight_recorder):
    # beside the test's runtime directory, never in the user's home.
    env['XDG_STATE_HOME'] = state_home(runtime_dir)
    return env


def state_home(runtime_dir: str) -> str:
    """Return the XDG_STATE_HOME of a stack started with :func:`stack_env`."""
    return os.path.join(os.path.dirname(runtime_dir), 'state')


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


class LineWatch:
    """Collect a process's output lines in a thread; let a test wait for lines (event, not time).

    ``timeout`` bounds every wait: generous, a healthy run never comes near it.
    """

    def __init__(self, stream, timeout: float = 60.0) -> None:
        self.lines: list[str] = []
        self.timeout = timeout
        self._cond = threading.Condition()
        self._done = False
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream) -> None:
        for line in stream:
            with self._cond:
                self.lines.append(line)
                self._cond.notify_all()
        with self._cond:
            self._done = True
            self._cond.notify_all()

    def count(self, text: str) -> int:
        """Return how many lines so far contain ``text``."""
        with self._cond:
            return self.count_locked(text)

    def wait_for(self, text: str, n: int = 1) -> None:
        """Wait until ``n`` lines contain ``text``; fail with the output's tail otherwise."""
        with self._cond:
            self._cond.wait_for(lambda: self._done or self.count_locked(text) >= n,
                                self.timeout)
            assert self.count_locked(text) >= n, 'fewer than {} {!r} lines in:\n{}'.format(
                n, text, ''.join(self.lines)[-3000:])

    def count_locked(self, text: str) -> int:
        """Like :meth:`count`, for a caller that holds the lock."""
        return sum(text in ln for ln in self.lines)

    def close(self) -> str:
        """Wait for the stream's end; return the whole output."""
        self._thread.join(self.timeout)
        return ''.join(self.lines)


def check_provenance(doc: dict) -> None:
    """Assert a result file records this checkout's commit and the machine, not its name."""
    import subprocess
    head = subprocess.run(['git', 'rev-parse', 'HEAD'], cwd=ROOT, capture_output=True,
                          text=True, check=True).stdout.strip()
    prov = doc['provenance']
    assert prov['commit'] == head, (prov['commit'], head)
    assert isinstance(prov['dirty'], bool)
    machine = prov['machine']
    assert machine['cpus_online'] >= 1 and machine['kernel'] and 'cpu_model' in machine
    assert 'hostname' not in machine and 'node' not in machine


def config_with(dest: str, overlays: dict[str, dict]) -> str:
    """Return ``dest`` holding the repository's ``config/`` with ``overlays`` merged in.

    ``overlays`` maps a layer's file name (``m4k.yaml``, ``control.yaml``) to the settings
    deep-merged into that file (m4k_rt.config.deep_merge, the stack's one layering), for a
    tool pointed at a config directory (``--config-dir``, ``M4K_CONFIG_DIR``).
    """
    import shutil

    import yaml

    from m4k_rt.config import deep_merge
    src = os.path.join(ROOT, 'config')
    for name in os.listdir(src):
        if os.path.isfile(os.path.join(src, name)):
            shutil.copy(os.path.join(src, name), dest)
    for name, over in overlays.items():
        path = os.path.join(dest, name)
        with open(path, encoding='utf-8') as f:
            doc = yaml.safe_load(f)
        with open(path, 'w', encoding='utf-8') as f:
            yaml.safe_dump(deep_merge(doc, over), f)
    return str(dest)
