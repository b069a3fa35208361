"""The one stop ladder (m4k_rt.proc.stop_process): signal, escalate, clean the group."""

import os
import signal
import subprocess
import sys
import time

from m4k_rt.proc import stop_process

_IGNORE_TERM = 'import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); ' \
    'print("ready", flush=True); time.sleep(60)'
# A parent that starts a grandchild in the same group, prints its pid, exits on SIGTERM.
_WITH_GRANDCHILD = ('import subprocess, sys, time; '
                    'c = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"]); '
                    'print(c.pid, flush=True); time.sleep(60)')


def _start(code: str) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([sys.executable, '-c', code], stdout=subprocess.PIPE, text=True,
                            start_new_session=True)
    assert proc.stdout is not None
    return proc, proc.stdout.readline().strip()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie (reaped by init later) counts as gone
    with open(f'/proc/{pid}/stat') as f:
        return f.read().split(') ')[1][0] != 'Z'


def test_a_process_that_obeys_sigterm_is_not_killed():
    proc, _ = _start('import time; print("ready", flush=True); time.sleep(60)')
    escalated = []
    assert stop_process(proc, timeout=10, on_escalate=escalated.append) == -signal.SIGTERM
    assert escalated == []
    assert proc.stdout is not None and proc.stdout.closed


def test_a_process_that_ignores_sigterm_is_killed_after_the_timeout():
    proc, _ = _start(_IGNORE_TERM)
    escalated = []
    assert stop_process(proc, timeout=0.3, on_escalate=escalated.append) == -signal.SIGKILL
    assert escalated == [0.3]


def test_a_grandchild_left_in_the_group_is_killed_even_when_only_the_leader_is_signalled():
    proc, line = _start(_WITH_GRANDCHILD)
    grandchild = int(line)
    assert _alive(grandchild)
    assert stop_process(proc, timeout=10, group=False) == -signal.SIGTERM
    deadline = time.monotonic() + 10
    while _alive(grandchild) and time.monotonic() < deadline:
        time.sleep(0.02)
    assert not _alive(grandchild)


def test_stopping_an_ended_process_returns_its_code():
    proc = subprocess.Popen([sys.executable, '-c', 'raise SystemExit(3)'],
                            start_new_session=True)
    proc.wait(30)
    assert stop_process(proc) == 3
