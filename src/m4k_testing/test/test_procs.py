"""The process fixture: every test process is an m4k_bringup Child, stopped by its ladder."""

import os
import signal
import subprocess
import sys
import time

import pytest

from m4k_bringup.child import Child
from m4k_testing import ProcessGroup

# Ignores SIGTERM and leaves a grandchild in its process group; prints the grandchild's pid.
STUBBORN = ('import signal, subprocess, sys, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); '
            'g = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"]); '
            'print(g.pid, flush=True); time.sleep(120)')


def _alive(pid: int) -> bool:
    try:
        with open(f'/proc/{pid}/stat') as f:
            return f.read().rsplit(')', 1)[1].split()[0] != 'Z'
    except OSError:
        return False


def _gone(pid: int, wait_s: float = 20.0) -> bool:
    """Tell whether ``pid`` has ended, waiting up to ``wait_s`` (a bound, not a measurement)."""
    end = time.monotonic() + wait_s
    while _alive(pid) and time.monotonic() < end:
        time.sleep(0.05)
    return not _alive(pid)


def test_a_started_process_is_a_child_in_a_session_of_its_own(procs):
    proc = procs.start(['python', '-c', 'import os, sys; print(os.getsid(0)); '
                        'print("err", file=sys.stderr); print(sys.stdin.read() == "")'])
    out, err = proc.communicate(timeout=60)
    assert out.split() == [str(proc.pid), 'True'] and err == 'err\n'   # stdin is /dev/null
    assert proc.args[0] == sys.executable
    (child,) = procs._children.values()
    assert isinstance(child, Child) and child.proc is proc
    assert child.name == os.path.basename(sys.executable)
    assert procs.stop(proc) == 0 and procs._children == {}
    assert procs.stop(proc) == 0                 # stopped already: the same code again


def test_a_process_from_elsewhere_is_not_stopped_by_the_group(procs):
    other = subprocess.Popen([sys.executable, '-c', 'pass'])
    try:
        with pytest.raises(ValueError, match='not started by this process group'):
            procs.stop(other)
    finally:
        other.wait(60)


def test_the_streams_go_where_the_test_says(procs, tmp_path):
    out, err = tmp_path / 'out', tmp_path / 'err'
    with open(out, 'w') as fo, open(err, 'w') as fe:
        proc = procs.start(['python', '-c', 'import sys; print("o"); print("e", file=sys.stderr)'],
                           stdout=fo, stderr=fe)
        assert proc.wait(60) == 0
    assert out.read_text() == 'o\n' and err.read_text() == 'e\n'
    merged = procs.start(['python', '-c', 'import sys; print("o", flush=True); '
                          'print("e", file=sys.stderr)'], stderr=subprocess.STDOUT)
    assert merged.communicate(timeout=60)[0] == 'o\ne\n' and merged.stderr is None
    quiet = procs.start(['python', '-c', 'import sys; print("o"); print("e", file=sys.stderr)'],
                        stdout=subprocess.DEVNULL)
    assert quiet.stdout is None and quiet.communicate(timeout=60)[1] == 'e\n'


def test_stdin_can_be_a_pipe_and_the_environment_is_the_tests(procs):
    proc = procs.start(['python', '-m', 'json.tool'], dict(os.environ, M4K_X='1'),
                       stdin=subprocess.PIPE)
    assert procs._children[proc.pid].name == 'json.tool'
    assert proc.communicate('{"a": 1}', timeout=60)[0].split() == ['{', '"a":', '1', '}']
    env = procs.start(['python', '-c', 'import os; print(os.environ["M4K_X"])'],
                      dict(os.environ, M4K_X='7'))
    assert env.communicate(timeout=60)[0] == '7\n'


def test_stop_ends_a_process_that_ignores_the_signal_and_its_group():
    group = ProcessGroup()
    proc = group.start(['python', '-c', STUBBORN])
    grandchild = int(proc.stdout.readline())
    assert group.stop(proc, signal.SIGTERM, timeout=1.0) == -signal.SIGKILL
    assert not _alive(proc.pid) and proc.stdout.closed
    assert _gone(grandchild)        # the SIGKILL to the group ended it too


def test_stop_all_stops_the_last_started_first_and_reports_each_code():
    group = ProcessGroup()
    first = group.start(['python', '-c', 'import time; time.sleep(120)'])
    second = group.start(['python', '-c', 'raise SystemExit(3)'])
    assert second.wait(60) == 3
    group.stop_all()
    assert first.returncode == -signal.SIGTERM and second.returncode == 3
    assert group._children == {}


def test_binary_pipes_are_refused():
    with pytest.raises(ValueError, match='text'):
        ProcessGroup().start(['true'], text=False)
