"""Bounded soak: the stack driving in a loop for a few seconds, the soak tool's verdicts and files.

The full soak (default 10 minutes, under stress-ng) is ``python -m m4k_bench.soak``; this
runs the same code for 35 s without stress so ``make test`` proves the tool and the stack's
short-term health: no crash, no restart, no body error, no RSS growth of rt_core or the
driver host beyond the tool's leak limit (the bridge's is reported), every output file written
(timing verdicts are the benchmarks' business). The run's
length is soak.QUICK_*: the leak verdict's limit depends on the window it judges, and the
unit tests hold the verdict at this same window.
"""

import json
import os
import subprocess
import sys

from wsenv import check_provenance, PYTHON_PACKAGES, ROOT

from m4k_bench import soak


def test_short_soak_runs_clean_and_writes_its_report(tmp_path):
    env = dict(os.environ, M4K_CONFIG_DIR=os.path.join(ROOT, 'config'))
    src = [os.path.join(ROOT, 'src', p) for p in PYTHON_PACKAGES]
    env['PYTHONPATH'] = os.pathsep.join(
        src + [x for x in env.get('PYTHONPATH', '').split(os.pathsep) if x])
    over = tmp_path / 'o.yaml'
    over.write_text('runtime: {mlockall: false, cpu_dma_latency: false}\n')
    # The warm-up outlasts the bridge's diagnostic windows (stats_window, 10 s), which fill
    # during the first seconds: measured, the bridge's RSS rises ~400 KiB in its first 15 s,
    # then stays flat (90 s run: +60 KiB from 15 s to 90 s). Judged before that, warm-up looks
    # like a leak to the slope verdict.
    p = subprocess.run([sys.executable, '-m', 'm4k_bench.soak',
                        '--duration', str(soak.QUICK_DURATION_S),
                        '--warmup', str(soak.QUICK_WARMUP_S),
                        '--sample', str(soak.QUICK_SAMPLE_S), '--no-stress', '--config', str(over),
                        '--results', str(tmp_path / 'results')],
                       env=env, capture_output=True, text=True, timeout=180)
    (out,) = os.listdir(tmp_path / 'results')
    assert out.startswith('soak-')
    d = tmp_path / 'results' / out
    assert {'report.md', 'summary.json', 'rss.csv', 'rss.png', 'bringup.log'} <= set(
        os.listdir(d)), p.stderr
    s = json.loads((d / 'summary.json').read_text())
    assert s['verdicts']['no_crash'] is True, (d / 'bringup.log').read_text()[-2000:]
    assert s['verdicts']['no_body_errors'] is True
    # The leak verdict of the RT side and the driver host is enforced: their memory is
    # allocated at start-up and nothing of theirs fills with time, so their RSS after the
    # warm-up is flat whatever the load. The bridge's is judged and reported, not asserted
    # here: its diagnostic windows and flight-recorder ring fill on wall time from its DDS
    # start, which a loaded host delays past the 25 s warm-up (seen: +308 and +604 KiB in the
    # 20 s window at load 9, on code with no leak) -- a load-dependent figure, which belongs
    # to `make soak` (10 minutes, published) and not to a test.
    assert {'rt_core', 'driver_host', 'bridge'} <= set(s['rss']), s['rss']
    for name in ('rt_core', 'driver_host'):
        assert s['rss'][name]['verdict'] == 'flat', (name, s['rss'][name])
    assert s['rss']['bridge']['verdict'] in ('flat', 'GROWING'), s['rss']['bridge']
    assert s['restarts'] == 0 and s['bringup_exit'] == 0
    check_provenance(s)
    assert set(s['rss']) == {'bringup', 'rt_core', 'driver_host', 'bridge'}
    assert all(r['samples'] >= 5 for r in s['rss'].values()), s['rss']
    # Judged over the window the unit tests hold the verdict at (test_soak_verdicts.py).
    window = soak.QUICK_DURATION_S - soak.QUICK_WARMUP_S
    assert all(r['window_s'] >= window - 3 * soak.QUICK_SAMPLE_S
               for r in s['rss'].values()), s['rss']
    assert all(r['limit_kib_per_min'] < 20 * 60 for r in s['rss'].values()), s['rss']
    act = s['tasks']['actuator']
    assert act['cycles'] > 500 and act['body_errors'] == 0
    assert '## Verdicts' in (d / 'report.md').read_text()
    assert p.returncode in (0, 1), p.stderr
