"""Shared pytest fixtures for every m4k test suite (packages and workspace): tests only.

Each test directory's ``conftest.py`` does ``from m4k_testing import *``. This package sits on
top of the layering, beside the tests: it may import any m4k package (its process fixture starts
processes through :class:`m4k_bringup.child.Child`, the one process wrapper), and no runtime
module may import it (test/test_layering.py). What it gives:

* ROS isolation for the whole run: a random ``ROS_DOMAIN_ID`` unless one is set, and
  localhost-only discovery, so test nodes never meet another machine's graph.
* ``m4k_runtime_dir``: a fresh private XDDP runtime directory per test (``M4K_RUNTIME_DIR``).
* ``procs``: starts subprocesses as :class:`~m4k_bringup.child.Child` (a session of their own)
  and stops whatever is left through Child's stop ladder.
* An autouse leak check that fails any test leaving behind a child process, a Python thread
  or a socket file descriptor -- the python-can habit of catching leaks where they happen.
* The ``hardware`` marker for tests that need the real robot (CI runs ``-m 'not hardware'``).
* The ``e2e`` marker for the end-to-end tier: tests that start the stack, its processes or ROS
  nodes. ``make check`` runs ``-m 'not e2e and not hardware'``; ``make test`` runs them all.
* The ``serial`` marker for the tests judged on the simulator's physics in wall-clock time (a
  stop against its line, a drive against its limits, calibrate's fit): ``make test`` runs them
  one after the other, at normal priority, while everything else runs beside them at a lower
  one (tools/run-tests.sh), so two of them never share the machine.
* The ``ros2cli`` marker for tests that need launch/launch_ros/ros2cli (not on PyPI): skipped,
  saying so, where they do not import; the skip policy accepts that skip only there.
* The ``needs_ros_package(name)`` marker for tests that need a ROS package PyPI lacks (e.g.
  robot_state_publisher): skipped, naming it, where the ament index does not have it; the skip
  policy accepts that skip only where the package really is missing.
* The ``needs_root(reason)`` marker: skipped, saying why, when not root -- and the skip policy:
  under the test runner (``M4K_CI=1``) a run fails when a test was skipped that could have run
  here (any skip as root; any skip other than ``needs_root`` otherwise), so a missing
  privilege or feature never hides behind a green summary.
* The hypothesis settings profile, chosen in this one place for every suite by
  ``M4K_HYPOTHESIS_PROFILE``: ``ci`` (the default: derandomized, no example database, fixed
  example counts -- a commit passes or fails the same way every run) or ``fuzz`` (random
  seeds, :data:`FUZZ_FACTOR` times the examples; ``make fuzz`` prints the seed to replay with
  ``--hypothesis-seed``). Tests size themselves with :func:`examples`.
"""

from __future__ import annotations

import dataclasses
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from typing import Any, IO, Iterator, Mapping

import pytest

from m4k_bringup.child import Child, Output, Stopping

__all__ = ['pytest_configure', 'pytest_unconfigure', 'pytest_runtest_setup',
           'pytest_runtest_logreport', 'pytest_collectreport', 'pytest_sessionfinish',
           'leak_check', 'm4k_runtime_dir',
           'procs', 'ProcessGroup', 'child_pids', 'socket_fds', 'examples',
           'HYPOTHESIS_PROFILE_ENV', 'FUZZ_FACTOR']

os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 100)))
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('RCUTILS_LOGGING_BUFFERED_STREAM', '0')
# What the stack keeps between runs (the flight recorder's dumps, the persisted e-stop request
# when no runtime directory is given) goes under XDG_STATE_HOME: a private one per test
# session, removed at its end, so no test writes into the user's ~/.local/state.
# Made in pytest_configure (importing this module makes nothing: a helper that imports it
# outside pytest left a directory behind).
_STATE_HOME: str | None = None

_LEAK_GRACE_S = 3.0

HYPOTHESIS_PROFILE_ENV = 'M4K_HYPOTHESIS_PROFILE'
FUZZ_FACTOR = 20  # ``fuzz`` runs this many times each test's example count
_NEEDS_ROOT = 'needs root: '
_NEEDS_ROS2CLI = 'needs ros2cli/launch (not on PyPI: a full ROS install or the ros-verify env): '
_NEEDS_PKG = 'needs the ROS package (not on PyPI, not in the ament index here): '
_session_skips: list[tuple[str, str]] = []


def _hypothesis_profile() -> str:
    """Register the m4k hypothesis profiles and load the one the environment names."""
    from hypothesis import HealthCheck, settings
    common: dict[str, Any] = {'deadline': None, 'database': None, 'print_blob': True,
              # A loaded 2-core machine makes data generation slow, not wrong.
              'suppress_health_check': [HealthCheck.too_slow]}
    settings.register_profile('ci', derandomize=True, max_examples=100, **common)
    settings.register_profile('fuzz', derandomize=False, max_examples=100 * FUZZ_FACTOR,
                              **common)
    name = os.environ.get(HYPOTHESIS_PROFILE_ENV) or 'ci'
    settings.load_profile(name)  # an unknown name raises InvalidArgument, naming it
    return name


try:
    HYPOTHESIS_PROFILE = _hypothesis_profile()
except ImportError:  # hypothesis is a test requirement; suites without it still run
    HYPOTHESIS_PROFILE = ''


def examples(n: int) -> int:
    """Return a property test's example count: ``n`` under ``ci``, more under ``fuzz``."""
    return n * FUZZ_FACTOR if HYPOTHESIS_PROFILE == 'fuzz' else n


def pytest_configure(config: pytest.Config) -> None:
    """Register the m4k markers; give the session its private state directory."""
    global _STATE_HOME
    if _STATE_HOME is None:
        _STATE_HOME = tempfile.mkdtemp(prefix='m4k-test-state-')
        os.environ['XDG_STATE_HOME'] = _STATE_HOME
    config.addinivalue_line('markers', 'hardware: needs the real M4K hardware; CI skips it')
    config.addinivalue_line(
        'markers', 'e2e: the end-to-end tier (starts the stack, its processes or ROS nodes); '
        'make check deselects it, make test runs it')
    config.addinivalue_line(
        'markers', "serial: judged on the simulator's physics in wall-clock time; make test runs "
        'these one at a time at normal priority, the rest beside them at a lower one')
    config.addinivalue_line(
        'markers', "after_packages: a workspace module make test runs after the packages' "
        'end-to-end tests, in their confined stream (test/conftest.py)')
    config.addinivalue_line(
        'markers', 'whole_machine: a serial test that loads every core on purpose; make test '
        'runs these first, before any confined stack starts (test/conftest.py)')
    config.addinivalue_line(
        'markers', 'ros2cli: needs launch/launch_ros or ros2cli (not on PyPI: a full ROS '
        'install or the ros-verify environment); skipped with the reason elsewhere')
    config.addinivalue_line(
        'markers', 'allow_leaks(kinds): tolerate leftovers of the given kinds '
        "('fds' for in-process DDS transports); state why in the test")
    config.addinivalue_line(
        'markers', 'needs_ros_package(name): skipped, naming it, where the ament index lacks it')
    config.addinivalue_line(
        'markers', 'needs_root(reason): skipped, with the reason, when not run as root')



def ros2cli_available() -> bool:
    """Return True when launch_ros and ros2launch import (a full ROS install, ros-verify)."""
    import importlib.util
    return all(importlib.util.find_spec(m) is not None for m in ('launch_ros', 'ros2launch'))


def ros_package_available(name: str) -> bool:
    """Return True when the ament index knows the ROS package ``name``."""
    try:
        from ament_index_python.packages import get_package_prefix, PackageNotFoundError
    except ImportError:
        return False
    try:
        get_package_prefix(name)
    except PackageNotFoundError:
        return False
    return True


def pytest_runtest_setup(item: pytest.Item) -> None:
    """Skip needs_root tests when not root, ros2cli tests without ros2cli; say why."""
    marker = item.get_closest_marker('needs_root')
    if marker is not None and os.geteuid() != 0:
        pytest.skip(_NEEDS_ROOT + (marker.args[0] if marker.args else 'privileged test'))
    if item.get_closest_marker('ros2cli') is not None and not ros2cli_available():
        pytest.skip(_NEEDS_ROS2CLI + 'launch_ros/ros2launch do not import here')
    for marker in item.iter_markers('needs_ros_package'):
        if not ros_package_available(marker.args[0]):
            pytest.skip(_NEEDS_PKG + marker.args[0])


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    """Remember every skip for the skip policy."""
    if report.skipped and not hasattr(report, 'wasxfail'):
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(
            report.longrepr)
        _session_skips.append((report.nodeid, reason))


def pytest_collectreport(report: pytest.CollectReport) -> None:
    """Remember a collection-time skip (module-level ``pytest.skip``, ``importorskip``).

    Such a skip never reaches :func:`pytest_runtest_logreport`: every test of the module
    vanishes at collection, so without this the skip policy never saw it.
    """
    if report.skipped:
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(
            report.longrepr)
        _session_skips.append((report.nodeid, reason))


def forbidden_skips(skips: list[tuple[str, str]], euid: int) -> list[tuple[str, str]]:
    """Return the skips the runner does not accept (pure: the policy itself).

    As root every test can run here, so every skip is refused; otherwise only the
    ``needs_root`` skips are accepted. A ``ros2cli`` skip is accepted only where launch_ros
    and ros2launch really do not import (not on PyPI), a ``needs_ros_package`` skip only where
    the ament index really lacks the package.
    """
    ros2cli = ros2cli_available()

    def accepted(why: str) -> bool:
        why = why.removeprefix('Skipped: ')
        if why.startswith(_NEEDS_ROS2CLI):
            return not ros2cli
        if why.startswith(_NEEDS_PKG):
            return not ros_package_available(why.removeprefix(_NEEDS_PKG).split()[0])
        return euid != 0 and why.startswith(_NEEDS_ROOT)

    return [(node, why) for node, why in skips if not accepted(why)]


def pytest_unconfigure(config: pytest.Config) -> None:
    """Remove the session's private state directory."""
    global _STATE_HOME
    if _STATE_HOME is not None:
        shutil.rmtree(_STATE_HOME, ignore_errors=True)
        _STATE_HOME = None


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """Under the runner (M4K_CI=1), fail the run when a test that could run was skipped."""
    if os.environ.get('M4K_CI') != '1':
        return
    bad = forbidden_skips(_session_skips, os.geteuid())
    if not bad:
        return
    sys.stderr.write('\nm4k skip policy: {} test(s) skipped that can run here (euid {}):\n'
                     .format(len(bad), os.geteuid()))
    for node, why in bad:
        sys.stderr.write('  {}: {}\n'.format(node, why))
    if session.exitstatus == 0:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def child_pids(pid: int | None = None) -> set[int]:
    """Return the pids of live (non-zombie) processes whose parent is ``pid``."""
    pid = os.getpid() if pid is None else pid
    found = set()
    for entry in os.listdir('/proc'):
        if not entry.isdigit():
            continue
        try:
            with open(f'/proc/{entry}/stat', 'rb') as f:
                stat = f.read()
        except OSError:
            continue
        # The command name may contain spaces and parentheses: split after the last ')'.
        fields = stat[stat.rfind(b')') + 2:].split()
        if len(fields) > 1 and int(fields[1]) == pid and fields[0] != b'Z':
            found.add(int(entry))
    return found


def socket_fds() -> set[tuple[int, str]]:
    """Return (fd, target) for every open socket descriptor of this process."""
    out = set()
    for fd in os.listdir('/proc/self/fd'):
        try:
            target = os.readlink(f'/proc/self/fd/{fd}')
        except OSError:
            continue
        if target.startswith('socket:'):
            out.add((int(fd), target))
    return out


def _threads() -> set[tuple[int | None, str]]:
    return {(t.ident, t.name) for t in threading.enumerate() if t.is_alive()}


@pytest.fixture(autouse=True)
def leak_check(request: pytest.FixtureRequest) -> Iterator[None]:
    """Fail the test if it leaves a child process, a thread or a socket behind."""
    marker = request.node.get_closest_marker('allow_leaks')
    allowed = set(marker.args) if marker else set()
    procs0, threads0, fds0 = child_pids(), _threads(), socket_fds()
    yield
    deadline = time.monotonic() + _LEAK_GRACE_S
    while True:
        new_procs = child_pids() - procs0
        new_threads = _threads() - threads0
        new_fds = set() if 'fds' in allowed else socket_fds() - fds0
        if not (new_procs or new_threads or new_fds) or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    problems = []
    if new_procs:
        problems.append(f'child processes left running: {sorted(new_procs)}')
        for pid in new_procs:  # do not let one leak cascade into every later test
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
    if new_threads:
        problems.append(f'threads left running: {sorted(n for _, n in new_threads)}')
    if new_fds:
        problems.append(f'sockets left open: {sorted(new_fds)}')
    if problems:
        pytest.fail('resource leak: ' + '; '.join(problems), pytrace=False)


@pytest.fixture
def m4k_runtime_dir(tmp_path_factory: pytest.TempPathFactory,
                    monkeypatch: pytest.MonkeyPatch) -> str:
    """Give the test a fresh private XDDP runtime directory (M4K_RUNTIME_DIR)."""
    # Short path: Unix socket paths are limited to 108 bytes.
    path = tmp_path_factory.mktemp('rt', numbered=True) / 'm4k'
    monkeypatch.setenv('M4K_RUNTIME_DIR', str(path))
    return str(path)


class ProcessGroup:
    """Start processes as :class:`~m4k_bringup.child.Child` and make sure every one ends.

    :meth:`start` returns the child's ``subprocess.Popen`` (a test reads its pipes, waits for it,
    signals it); :meth:`stop` and the fixture's teardown stop it through the child's stop ladder
    (the signal to its whole process group, wait, SIGKILL, then SIGKILL whatever is left in the
    group), failing the test if even SIGKILL did not end it.
    """

    def __init__(self) -> None:
        self._children: dict[int, Child] = {}

    def start(self, argv: list[str], env: Mapping[str, str] | None = None, *,
              stdin: int | IO[Any] | None = None, stdout: int | IO[Any] | None = subprocess.PIPE,
              stderr: int | IO[Any] | None = subprocess.PIPE,
              text: bool = True) -> subprocess.Popen:
        """Start ``argv`` (``python`` means this interpreter) in a session of its own.

        ``stdin``, ``stdout`` and ``stderr`` as for ``subprocess.Popen``: ``PIPE`` gives a
        text pipe (the default for the output streams), a file, descriptor, ``DEVNULL`` or
        (stderr) ``STDOUT`` is connected as given and stays the caller's to close, None
        inherits -- except stdin, which reads /dev/null unless given.
        """
        if not text:
            raise ValueError('the pipes of a test process are text pipes')
        if argv and argv[0] == 'python':
            argv = [sys.executable, *argv[1:]]
        given = {'stdin': stdin, 'stdout': stdout, 'stderr': stderr}
        pipes = [name for name, s in given.items() if s == subprocess.PIPE]
        streams = {name: s for name, s in given.items()
                   if s is not None and s != subprocess.PIPE}
        name = argv[2] if argv[1:2] == ['-m'] and len(argv) > 2 else os.path.basename(argv[0])
        child = Child(name, argv, env,
                      output=Output(pipes=pipes, streams=streams),
                      stopping=Stopping(group=True, must_end=True)).start()
        assert child.proc is not None
        self._children[child.pid] = child
        return child.proc

    def stop(self, proc: subprocess.Popen, sig: int = signal.SIGTERM,
             timeout: float = 10.0) -> int:
        """Signal the process's group, wait, escalate to SIGKILL; return the exit code.

        Stopping a process this group has already stopped returns its exit code again (a
        test's ``finally`` may stop what its body stopped).
        """
        child = self._children.pop(proc.pid, None)
        if child is not None:
            return self._stop(child, sig, timeout)
        if proc.returncode is None:
            raise ValueError(f'{proc.args!r} was not started by this process group')
        return proc.returncode

    def stop_all(self) -> None:
        """Stop every process started through this group, the last started first."""
        while self._children:
            self._stop(self._children.pop(next(reversed(self._children))))

    @staticmethod
    def _stop(child: Child, sig: int = signal.SIGTERM, timeout: float = 10.0) -> int:
        child.stopping = dataclasses.replace(child.stopping, sig=sig)
        rc = child.stop(timeout)    # must_end: SIGKILL that did not end it fails the test
        assert rc is not None
        return rc


@pytest.fixture
def procs() -> Iterator[ProcessGroup]:
    """Start subprocesses that are guaranteed to be stopped after the test."""
    group = ProcessGroup()
    try:
        yield group
    finally:
        group.stop_all()
