"""rt_stat: per-task statistics of a running RT core, like /proc/xenomai/sched/stat + slackspot.

Opens the monitor's ``stat`` port (on demand: the ``status`` port belongs to the bridge), reads
one monitor batch (closed by RT_STATUS) and prints a Fig. 5-like table: task, priority,
period, cycles, context switches, the mode-switch analogue, page faults, forbidden calls with
the last call site, overruns, deadline misses and the p99 release latency; then, per device
whose driver host reported them (HOST_DROPS, forwarded by the monitor), the datagrams it served
and the ones it dropped by reason. ``--watch`` refreshes every batch, with statistics
accumulated since rt_stat started.
"""

import argparse
import math
import sys
import time
from typing import Sequence, TextIO

from m4k_bench import recorder
from m4k_rt import channel, protocol, rosargs

__all__ = ['format_stat', 'main', 'read_batch']


def read_batch(ep: channel.NrtXddpEndpoint, rec: recorder.Recorder, timeout: float) -> bool:
    """Feed datagrams into ``rec`` until an RT_STATUS closes a batch; False on timeout."""
    end = time.monotonic() + timeout
    while True:
        left = end - time.monotonic()
        if left <= 0:
            return False
        try:
            data = ep.read(left)
        except TimeoutError:
            return False
        if rec.feed(data) == protocol.Kind.RT_STATUS:
            return True


def format_stat(rec: recorder.Recorder) -> str:
    """Format the Fig. 5-like table and the forbidden-call sites (pure)."""
    head = ('{:<10} {:>4} {:>8} {:>8} {:>7} {:>7} {:>6} {:>6} {:>6} {:>5} {:>5} {:>5} '
            '{:>10}  {}')
    lines = [head.format('TASK', 'PRIO', 'PERIOD', 'CYCLES', 'CSW', 'CSWI', 'MSW*', 'PF',
                         'FORBID', 'OVR', 'MISS', 'ERR', 'LAT99(us)', 'LAST FORBIDDEN SITE')]
    st = rec.rt_status
    for t in sorted(rec.tasks.values(), key=lambda s: (-s.priority, s.name)):
        a = t.analyze()
        h = t.health
        sites = list(t.sites.values())
        last = sites[-1] if sites else None
        site = '{} {}:{} ({}) x{}'.format(last.event, last.file, last.line, last.func,
                                          last.calls) if last else '-'
        lat = a.latency.p99 / 1e3
        lines.append(head.format(
            t.name[:10], t.priority, '{:g}ms'.format(t.period_ns / 1e6), t.cycles, t.nvcsw,
            t.nivcsw, '-' if h is None else h.nvcsw_extra,
            t.minflt + (h.majflt if h else 0), t.forbidden_calls,
            '-' if h is None else h.overruns, '-' if h is None else h.deadline_misses,
            '-' if h is None else h.body_errors,
            '-' if math.isnan(lat) else '{:.1f}'.format(lat), site))
    lines.append('MSW* = voluntary context switches beyond the timer wait (blocked on '
                 'something else, e.g. the GIL or a syscall)')
    if st is not None:
        lines.append('policy {} mem_locked {} degraded {} guard {} ntasks {} cycles_min {}'.format(
            'FIFO' if st.policy == 1 else 'OTHER', st.mem_locked, st.degraded,
            st.guard_active, st.ntasks, st.cycles_min))
    for t in rec.tasks.values():
        for s in t.sites.values():
            lines.append('  {}: {} at {}:{} in {}() x{}'.format(
                t.name, s.event, s.file, s.line, s.func, s.calls))
    if rec.host_drops:
        reasons = protocol.HOST_DROP_REASONS
        row = '{:<10} {:>10}' + ' {:>12}' * len(reasons)
        lines.append(row.format('DEVICE', 'SERVED', *(r.upper() for r in reasons)))
        for name, d in sorted(rec.host_drops.items()):
            lines.append(row.format(name, d.served, *d[2:]))
        lines.append('driver host drops since its process started (docs/internals.md, '
                     '"Driver host")')
    return '\n'.join(lines) + '\n'


def main(argv: Sequence[str] | None = None, out: TextIO | None = None) -> int:
    """Print the table once (or repeatedly with --watch); exit 1 when no RT core runs."""
    ap = argparse.ArgumentParser(prog='rt_stat', description=__doc__.splitlines()[0])
    ap.add_argument('--port', default='stat', help='port label or number (default stat)')
    ap.add_argument('--runtime-dir', default=None)
    ap.add_argument('--wait', type=float, default=0.0, help='seconds to wait for the RT core')
    ap.add_argument('--timeout', type=float, default=3.0, help='seconds to wait for a batch')
    ap.add_argument('--watch', action='store_true', help='refresh every batch until Ctrl-C')
    args = rosargs.parse_args(ap, argv)
    out = out or sys.stdout
    port: int | str = int(args.port) if args.port.isdigit() else args.port
    try:
        ep = channel.nrt_xddp_open(port, wait=args.wait, runtime_dir=args.runtime_dir)
    except channel.XddpError as exc:
        sys.stderr.write('rt_stat: no RT core: {}\n'.format(exc))
        return 1
    rec = recorder.Recorder()
    try:
        while True:
            if not read_batch(ep, rec, args.timeout):
                sys.stderr.write('rt_stat: no batch within {:g} s\n'.format(args.timeout))
                return 1
            if args.watch:
                out.write('\x1b[H\x1b[2J')
            out.write(format_stat(rec))
            out.flush()
            if not args.watch:
                return 0
    except KeyboardInterrupt:
        return 0
    except BrokenPipeError:
        sys.stderr.write('rt_stat: RT core went away\n')
        return 1
    finally:
        ep.close()


if __name__ == '__main__':
    sys.exit(main())
