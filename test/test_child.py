"""m4k_bringup.child.Child, the one process wrapper: log capture, exit codes, the stop ladder."""

import os
import signal
import subprocess
import sys
import time

import pytest

from m4k_bringup.child import Child, Launch, Output, Stopping

# Ignores SIGTERM, starts a grandchild in its process group, prints both pids, waits.
STUBBORN = ('import signal, subprocess, sys, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); '
            'g = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"]); '
            'print("pids", g.pid, flush=True); time.sleep(120)')


def _gone(pid: int, wait_s: float = 10.0) -> bool:
    """Tell whether ``pid`` has ended (reaped or a zombie), waiting up to ``wait_s``."""
    end = time.monotonic() + wait_s
    while time.monotonic() < end:
        try:
            with open(f'/proc/{pid}/stat') as f:
                if f.read().rsplit(')', 1)[1].split()[0] == 'Z':
                    return True
        except OSError:
            return True
        time.sleep(0.05)
    return False


def _wait_for(pred, wait_s: float = 20.0) -> bool:
    end = time.monotonic() + wait_s
    while not pred() and time.monotonic() < end:
        time.sleep(0.05)
    return pred()


def test_a_log_file_child_is_headed_appended_and_reports_its_exit_code(tmp_path):
    log = str(tmp_path / 'x.log')
    argv = [sys.executable, '-c', 'import sys; print("out"); print("err", file=sys.stderr); '
            'sys.exit(3)']
    c = Child('x', argv, output=Output(log_path=log)).start()
    assert c.wait(30.0) == 3
    assert not c.alive() and c.returncode == 3
    assert c.stop() == 3 and c.last_rc == 3 and c.proc is None
    assert c.stop() is None                 # stopped already
    again = Child('x', argv, output=Output(log_path=log)).start()   # appended, a second header
    assert again.wait(30.0) == 3 and again.stop() == 3
    text = open(log).read()
    assert text.count('$ ' + ' '.join(argv)) == 2 and text.count('out\n') == 2
    assert text.count('err\n') == 2
    assert c.tail(2)[-1] in ('out', 'err')


def test_a_log_file_child_can_truncate_and_go_without_a_header(tmp_path):
    log = tmp_path / 'x.log'
    log.write_text('old\n')
    c = Child('x', [sys.executable, '-c', 'print("new")'],
              output=Output(log_path=str(log), log_append=False, log_header=False)).start()
    assert c.wait(30.0) == 0
    c.stop()
    assert log.read_text() == 'new\n'


def test_the_stop_ladder_escalates_to_sigkill_and_clears_the_group(tmp_path):
    escalated = []
    c = Child('stubborn', [sys.executable, '-c', STUBBORN],
              output=Output(log_path=str(tmp_path / 's.log')),
              stopping=Stopping(timeout=0.5, on_escalate=escalated.append, must_end=True)).start()
    assert _wait_for(lambda: c.tail()[-1].startswith('pids ')), c.tail()
    grandchild = int(c.tail()[-1].split()[1])
    rc = c.stop()
    assert rc == -signal.SIGKILL and escalated == [0.5]
    assert _gone(grandchild)              # the group sweep after the process ended


# Both install Python's SIGINT handler themselves: started from a non-interactive shell's
# background job the test process (and so every child) inherits SIGINT ignored, and Python
# then leaves it ignored -- the group's SIGINT would reach nobody.
GRANDCHILD = ('import signal, sys, time\n'
              'signal.signal(signal.SIGINT, signal.default_int_handler)\n'
              'try:\n    print("ready", flush=True); time.sleep(120)\n'
              'except KeyboardInterrupt:\n    open(sys.argv[1], "w").write("SIGINT")\n')
PARENT = ('import signal, subprocess, sys\n'
          'signal.signal(signal.SIGINT, signal.default_int_handler)\n'
          'g = subprocess.Popen([sys.executable, "-c", sys.argv[1], sys.argv[2]])\n'
          'try:\n    g.wait()\nexcept KeyboardInterrupt:\n    g.wait()\n')


def test_a_group_stop_signals_the_whole_group(tmp_path):
    mark = tmp_path / 'grandchild-got'
    c = Child('g', [sys.executable, '-c', PARENT, GRANDCHILD, str(mark)],
              output=Output(log_path=str(tmp_path / 'g.log')),
              stopping=Stopping(sig=signal.SIGINT, group=True, timeout=30.0)).start()
    assert _wait_for(lambda: c.tail()[-1] == 'ready'), c.tail()
    assert c.stop() == 0
    assert mark.read_text() == 'SIGINT'


def test_a_console_child_copies_its_lines_and_is_reaped():
    lines: list[str] = []
    c = Child('c', [sys.executable, '-c', 'print("one"); print("two"); raise SystemExit(4)'],
              dict(os.environ), output=Output(on_line=lines.append),
              launch=Launch(supervised=True))
    c.start()
    assert _wait_for(lambda: not c.alive())
    assert c.reap() == 4 and c.last_rc == 4 and c.proc is None and lines == ['one', 'two']
    assert c.started_at > 0 and c.pid > 0


def test_a_child_logs_to_a_file_or_to_a_console_not_both(tmp_path):
    with pytest.raises(ValueError):
        Child('x', ['true'], output=Output(log_path=str(tmp_path / 'x.log'), on_line=print))


def test_a_piped_child_talks_through_its_streams_and_they_are_closed_when_it_stops():
    c = Child('echo', [sys.executable, '-c', 'import sys; line = sys.stdin.readline(); '
                       'print(line.upper(), end=""); print("err", file=sys.stderr)'],
              output=Output(pipes=('stdin', 'stdout', 'stderr'))).start()
    c.proc.stdin.write('hello\n')
    c.proc.stdin.flush()
    assert c.proc.stdout.readline() == 'HELLO\n'
    assert c.proc.stderr.readline() == 'err\n'
    streams = (c.proc.stdin, c.proc.stdout, c.proc.stderr)
    assert c.wait(20.0) == 0
    assert c.stop(5.0) == 0 and c.returncode == 0
    assert all(s.closed for s in streams)


def test_a_child_discards_its_output_to_devnull_and_can_be_pinned():
    cpu = min(os.sched_getaffinity(0))
    c = Child('quiet', [sys.executable, '-c', 'import os, time; print(sorted('
                        'os.sched_getaffinity(0)), flush=True); time.sleep(120)'],
              output=Output(log_path=os.devnull, log_header=False), launch=Launch(cpu=cpu)).start()
    assert os.sched_getaffinity(c.pid) == {cpu}
    assert c.stop(5.0) == -signal.SIGTERM


def test_pipes_name_the_standard_streams_only():
    with pytest.raises(ValueError, match='pipes'):
        Child('x', ['true'], output=Output(pipes=('stdout', 'fd3')))


def test_a_child_writes_to_the_files_its_caller_holds_open_and_leaves_them_open(tmp_path):
    out, err = open(tmp_path / 'out', 'w'), open(tmp_path / 'err', 'w')
    with out, err:
        c = Child('split', [sys.executable, '-c', 'import sys; print("o"); '
                            'print("e", file=sys.stderr)'],
                  output=Output(streams={'stdout': out, 'stderr': err})).start()
        assert c.wait(20.0) == 0 and c.stop(5.0) == 0
        assert not out.closed and not err.closed
    assert (tmp_path / 'out').read_text() == 'o\n' and (tmp_path / 'err').read_text() == 'e\n'
    merged = Child('merged', [sys.executable, '-c', 'import sys; print("o", flush=True); '
                              'print("e", file=sys.stderr)'],
                   output=Output(pipes=('stdout',), streams={'stderr': subprocess.STDOUT})).start()
    assert merged.proc.stdout.read() == 'o\ne\n' and merged.stop(5.0) == 0


@pytest.mark.parametrize('pipes,streams', [
    ((), {'fd3': subprocess.DEVNULL}), (('stdout',), {'stdout': subprocess.DEVNULL}),
    ((), {'stdout': subprocess.STDOUT}), ((), {'stderr': subprocess.PIPE})])
def test_streams_name_the_standard_streams_not_piped_and_stdout_is_not_stderr(pipes, streams):
    with pytest.raises(ValueError, match='streams'):
        Child('x', ['true'], output=Output(pipes=pipes, streams=streams))
