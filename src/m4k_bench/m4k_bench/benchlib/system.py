"""The machine side of the bench: tools, machine description, stress-ng, process CPU time.

* :func:`ensure_tools` finds cyclictest and stress-ng and, when missing and running as root,
  installs them from the distribution (``apt-get install -y rt-tests stress-ng``); otherwise it
  says exactly what to install.
* :func:`stress` runs stress-ng (a :class:`m4k_bringup.child.Child`) in its own process group
  for one measurement and stops it by that group's id (never by name).
* :func:`machine_info` describes the machine and kernel for the report.
"""

from __future__ import annotations

import contextlib
import os
import platform
import shutil
import subprocess
import sys
import time
from typing import Any, Callable, Iterator

from m4k_bringup.child import Child, Output, Stopping

__all__ = ['DmaLatency', 'STRESS_ARGS', 'TOOL_PACKAGES', 'busy_note', 'ensure_tools',
           'machine_info', 'proc_cpu_seconds', 'start_stress', 'stress']

# tool -> Debian package
TOOL_PACKAGES = {'cyclictest': 'rt-tests', 'stress-ng': 'stress-ng'}

# A CPU worker on every vCPU and one 256 MiB memory worker that keeps its mapping: the paper's
# "CPU and memory" stress, at normal priority. The RT threads (SCHED_FIFO) preempt it inside
# the guest; the baseline (SCHED_OTHER) has to share the CPUs with it. Issue 42: no longer the
# ``--io 1`` sync() worker (each sync is a synchronous flush the hypervisor runs while the
# vCPU waits, which no guest priority preempts), and ``--vm-keep`` (no munmap/mmap churn, so
# no fresh host page faults behind the guest's back): load the CPUs, not the hypervisor.
# docs/design-notes.md §12; benchlib.stressprobe measures the variants side by side.
STRESS_ARGS = ('--cpu', str(os.cpu_count() or 2), '--vm', '1', '--vm-bytes', '256M',
               '--vm-keep')


def ensure_tools(log: Callable[[str], None], install: bool = True) -> dict[str, str | None]:
    """Return tool -> path (None when missing after trying to install it as root)."""
    found = {t: shutil.which(t) for t in TOOL_PACKAGES}
    missing = sorted({TOOL_PACKAGES[t] for t, p in found.items() if p is None})
    if not missing:
        return found
    cmd = ['apt-get', 'install', '-y', *missing]
    if install and os.geteuid() == 0 and shutil.which('apt-get'):
        log('installing {} ({})'.format(', '.join(missing), ' '.join(cmd)))
        env = dict(os.environ, DEBIAN_FRONTEND='noninteractive')
        ok = subprocess.run(cmd, env=env, capture_output=True).returncode == 0
        if not ok:  # a stale package list is the usual reason
            subprocess.run(['apt-get', 'update'], env=env, capture_output=True)
            ok = subprocess.run(cmd, env=env, capture_output=True).returncode == 0
        if not ok:
            log('could not install {}: run "{}" as root'.format(', '.join(missing),
                                                                 ' '.join(cmd)))
        found = {t: shutil.which(t) for t in TOOL_PACKAGES}
    else:
        log('missing {}: install with "sudo apt-get install -y {}" (the bench runs without '
            'them and says what it skipped)'.format(
                ', '.join(t for t, p in found.items() if p is None), ' '.join(missing)))
    return found


def start_stress(binary: str, timeout_s: float, args: tuple[str, ...] = STRESS_ARGS,
                 settle_s: float = 1.0) -> Child:
    """Start ``stress-ng ARGS --timeout T`` (T bounds it even if we die) as a :class:`Child`.

    Its output is discarded; it runs in a process group of its own, and ``stop()`` ends it and
    every worker by that group (SIGTERM, 5 s, SIGKILL), never by name. It is given
    ``settle_s`` to load the machine; a stress-ng that exits at once is a RuntimeError.
    """
    child = Child('stress-ng', [binary, *args, '--timeout', '{}s'.format(int(timeout_s) + 1)],
                  output=Output(log_path=os.devnull, log_header=False),
                  stopping=Stopping(group=True, timeout=5.0)).start()
    time.sleep(settle_s)
    if not child.alive():
        rc = child.stop()
        raise RuntimeError('stress-ng exited at once (code {}): {}'.format(
            rc, ' '.join(child.argv)))
    return child


@contextlib.contextmanager
def stress(binary: str, timeout_s: float, args: tuple[str, ...] = STRESS_ARGS,
           settle_s: float = 1.0) -> Iterator[Child]:
    """Run stress-ng (:func:`start_stress`) for the duration of a ``with`` block."""
    child = start_stress(binary, timeout_s, args, settle_s)
    try:
        yield child
    finally:
        child.stop()


class DmaLatency:
    """Hold ``/dev/cpu_dma_latency`` at 0 µs for a ``with`` block (``held`` says if it worked).

    The bench holds it for the whole run, so every condition -- m4k, the plain-ROS baseline and
    cyclictest alone -- runs with the same CPU idle-state policy (cyclictest and rt_core also
    request 0 µs themselves; the kernel takes the minimum of all requests).
    """

    PATH = '/dev/cpu_dma_latency'

    def __init__(self) -> None:
        """Prepare; nothing is opened yet."""
        self.fd: int | None = None
        self.error: str | None = None

    @property
    def held(self) -> bool:
        """Tell whether the request is in force."""
        return self.fd is not None

    def __enter__(self) -> DmaLatency:
        """Open the device and write a 32-bit 0 (the request lasts while the fd is open)."""
        try:
            fd = os.open(self.PATH, os.O_WRONLY | os.O_CLOEXEC)
        except OSError as exc:
            self.error = '{}: {}'.format(self.PATH, exc.strerror)
            return self
        try:
            os.write(fd, (0).to_bytes(4, sys.byteorder))
        except OSError as exc:
            os.close(fd)
            self.error = '{}: {}'.format(self.PATH, exc.strerror)
            return self
        self.fd = fd
        return self

    def __exit__(self, *exc: object) -> None:
        """Close the fd: the kernel drops the request."""
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None


def proc_cpu_seconds(pid: int) -> float:
    """Return utime + stime of process ``pid`` (all its threads) in seconds."""
    with open(f'/proc/{pid}/stat', 'rb') as f:
        stat = f.read()
    # comm may contain spaces and parentheses: split after the last ')'. Fields 14 and 15
    # (utime, stime) are the 12th and 13th after it.
    fields = stat[stat.rfind(b')') + 2:].split()
    ticks = int(fields[11]) + int(fields[12])
    return ticks / os.sysconf('SC_CLK_TCK')


def _read(path: str) -> str | None:
    try:
        with open(path, encoding='utf-8', errors='replace') as f:
            return f.read().strip()
    except OSError:
        return None


def _cpu_model() -> str | None:
    text = _read('/proc/cpuinfo') or ''
    for line in text.splitlines():
        if line.startswith('model name'):
            return line.split(':', 1)[1].strip()
    return None


def _virt() -> str | None:
    if shutil.which('systemd-detect-virt'):
        p = subprocess.run(['systemd-detect-virt'], capture_output=True, text=True)
        if p.stdout.strip():
            return p.stdout.strip()
    flags = _read('/proc/cpuinfo') or ''
    return 'hypervisor present (cpuinfo flag)' if ' hypervisor' in flags else None


def machine_info() -> dict[str, Any]:
    """Describe the machine and kernel: CPU, memory, preemption model, RT limits, versions."""
    u = platform.uname()
    mem_kb = None
    for line in (_read('/proc/meminfo') or '').splitlines():
        if line.startswith('MemTotal:'):
            mem_kb = int(line.split()[1])
    preempt = _read('/sys/kernel/debug/sched/preempt')
    realtime = _read('/sys/kernel/realtime')
    try:
        affinity = sorted(os.sched_getaffinity(0))
    except OSError:
        affinity = None
    try:
        import numpy
        numpy_version = numpy.__version__
    except ImportError:
        numpy_version = None
    return {
        'hostname': u.node, 'kernel': u.release, 'kernel_version': u.version,
        'machine': u.machine, 'cpu_model': _cpu_model(), 'cpus_online': os.cpu_count(),
        'cpus_allowed': affinity, 'memory_gib': round(mem_kb / 2**20, 1) if mem_kb else None,
        'preempt_rt': realtime == '1' or 'PREEMPT_RT' in u.version,
        'preempt_model': preempt or ('PREEMPT_DYNAMIC' if 'PREEMPT_DYNAMIC' in u.version
                                     else 'PREEMPT' if 'PREEMPT' in u.version else None),
        'sched_rt_runtime_us': _read('/proc/sys/kernel/sched_rt_runtime_us'),
        'clocksource': _read('/sys/devices/system/clocksource/clocksource0/current_clocksource'),
        'virtualization': _virt(), 'loadavg': _read('/proc/loadavg'),
        'python': sys.version.split()[0], 'numpy': numpy_version, 'euid': os.geteuid(),
        'os': (_read('/etc/debian_version') and 'Debian ' + (_read('/etc/debian_version') or ''))
        or platform.platform(),
    }


def busy_note(info: dict[str, Any]) -> str | None:
    """Return a warning when the 1-minute load average already exceeds half the CPUs."""
    try:
        load1 = float(str(info.get('loadavg', '')).split()[0])
    except (IndexError, ValueError):
        return None
    cpus = info.get('cpus_online') or 1
    if load1 <= 0.5 * cpus:
        return None
    return ('the machine was busy before the bench started (1-min load average {:.2f} on {} '
            'CPUs): the "idle" conditions ran next to that other work, so absolute numbers '
            'are worse than on a quiet machine; the ratios compare runs made side by side '
            'under the same background'.format(load1, cpus))
