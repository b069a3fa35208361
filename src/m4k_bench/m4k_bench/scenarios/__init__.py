"""scenarios: the robot in every world, judged on the simulator's ground truth.

``make scenarios`` / ``scenarios [FILE_OR_DIR ...] [--short] [--only NAME ...] [--results DIR]``
runs each scenario (:mod:`.spec`: world overlay, scripted commander, faults, expected outcome)
on a fresh stack (:mod:`.run`), prints a progress line per scenario, and writes
``<results>/README.md`` (the table), ``<results>/<name>.png`` (world, obstacles' paths, the
robot's true path) and ``<results>/<name>.csv`` (the ground-truth samples, every 20 ms);
written to the default ``docs/results/scenarios``, they also regenerate docs/safety.md's
hazard table. A partial run (``--only``) or a short one (``--short``) writes to
``log/scenarios`` unless ``--results`` says otherwise: the published table and the hazard
table quote the full run, and one scenario run alone had rewritten both with only itself.
Default: every ``*.yaml`` of ``<config dir>/scenarios``; a path to an envelope declaration
(``config/envelope.yaml``, :mod:`.grid`) adds every promised cell of the grid. The progress
line states the elapsed time and an estimate of the time left (the mean so far x the scenarios
left). Exit 0 when every scenario passed, 1 otherwise, 2 on a bad scenario file.
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import tempfile
import time
from typing import Sequence

from m4k_bench.benchlib import provenance
from m4k_bench.benchlib.results import write_text

__all__ = ['main']

RESULTS = os.path.join('docs', 'results', 'scenarios')
SCRATCH = os.path.join('log', 'scenarios')      # a partial or short run's default


def _default_dir() -> str:
    from m4k_rt import config
    return os.path.join(config.find_config_dir(), 'scenarios')


def main(argv: Sequence[str] | None = None) -> int:
    """Run the suite; return the exit code."""
    ap = argparse.ArgumentParser(prog='scenarios', description=__doc__.split('\n\n')[0])
    ap.add_argument('paths', nargs='*', help='scenario files or directories (default: '
                    '<config dir>/scenarios)')
    ap.add_argument('--only', nargs='+', metavar='NAME', help='run only these scenarios')
    ap.add_argument('--short', action='store_true', help='the short versions (as the tests)')
    ap.add_argument('--results', default=None,
                    metavar='DIR', help='where the table and plots go (default: '
                    'docs/results/scenarios; log/scenarios with --only or --short)')
    from m4k_rt import rosargs
    args = rosargs.parse_args(ap, argv)       # launch_ros's --ros-args are taken, not refused
    from m4k_bench.scenarios import grid, report, spec
    from m4k_bench.scenarios.run import run_scenario
    scs: list[spec.Scenario] = []
    outside: list[grid.Cell] = []
    try:
        for p in args.paths or [_default_dir()]:
            if grid.is_grid(p):
                cells = grid.cells(p)
                scs += [c.scenario for c in cells if c.scenario is not None]
                outside += [c for c in cells if c.scenario is None]
            else:
                scs += spec.load_dir(p) if os.path.isdir(p) else [spec.load(p)]
    except (OSError, spec.ScenarioError) as exc:
        print(f'scenarios: {exc}', file=sys.stderr)
        return 2
    if args.only:
        scs = [s for s in scs if s.name in args.only]
    if args.results is None:
        args.results = SCRATCH if args.only or args.short else RESULTS
    os.makedirs(args.results, exist_ok=True)
    results = []
    prov = provenance.provenance()    # before the run writes its own results into the tree
    t_all = time.monotonic()
    with tempfile.TemporaryDirectory(prefix='m4k-scenarios-') as work:
        for i, sc in enumerate(scs, 1):
            t0 = time.monotonic()
            spent = t0 - t_all
            left = '' if i == 1 else f', about {spent / (i - 1) * (len(scs) - i + 1):.0f} s left'
            print(f'[{i}/{len(scs)}, {spent:.0f} s{left}] {sc.name}: {sc.description}',
                  file=sys.stderr, flush=True)
            res = run_scenario(sc, work, short=args.short,
                               progress=lambda m: print('    ' + m, file=sys.stderr, flush=True))
            results.append(res)
            report.plot(sc, res, os.path.join(args.results, f'{sc.name}.png'), sc.world)
            report.write_csv(res, os.path.join(args.results, f'{sc.name}.csv'))
            verdict = 'PASS' if res.passed else 'FAIL (' + '; '.join(res.failures) + ')'
            print(f'    {verdict}: {res.travelled:.2f} m of {res.commanded:.2f} m, min clearance '
                  f'{res.min_clearance:.3f} m, contacts {res.contacts}, stop '
                  f'{res.stop_s if res.stop_s is None else round(res.stop_s, 3)} s '
                  f'[{time.monotonic() - t0:.0f} s]', file=sys.stderr, flush=True)
            if not res.passed and res.log_tail:
                print('    bringup log tail:\n      ' + res.log_tail.replace('\n', '\n      '),
                      file=sys.stderr)
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')
    header = (f'# Scenario suite ({"short" if args.short else "full"} versions)\n\n'
              f'`make scenarios` at {provenance.text(prov)}; {stamp}, '
              f'{time.monotonic() - t_all:.0f} s. Every '
              f"number is the simulator's ground truth (sim_truth), never odometry. Bounds from "
              f'config/ (m4k_bench.scenarios.bounds); the scenarios are config/scenarios/*.yaml; '
              f'one plot per scenario beside this file.')
    if outside:
        whys: dict[str, int] = {}
        for c in outside:
            whys[c.why] = whys.get(c.why, 0) + 1
        header += (f'\n\n{len(outside)} envelope cells are not promised (config/envelope.yaml, '
                   'not run): ' + '; '.join(f'{n} cells: {w}' for w, n in whys.items()) + '.')
    write_text(os.path.join(args.results, 'README.md'), report.table(results, header))
    if os.path.abspath(args.results) == os.path.abspath(RESULTS) and os.path.isfile(
            os.path.join('docs', 'safety.md')):
        # the hazard table quotes these results: keep it in step (m4k_bench.hazards)
        from m4k_bench import hazards
        hazards.main(['--write'])
    n_ok = sum(r.passed for r in results)
    print(f'scenarios: {n_ok}/{len(results)} passed; {args.results}/README.md', file=sys.stderr)
    return 0 if n_ok == len(results) else 1


if __name__ == '__main__':
    sys.exit(main())
