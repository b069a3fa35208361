"""make demo end to end: the paper's Fig. 9 drive on the simulated stack, judged by its outputs.

Runs ``demo`` from the source tree (bringup --python-m, the DWA planner node, the recorder) in
a private runtime directory and ROS domain, bounded by a 60 s driving timeout, then checks
what it wrote: the goal reached within tolerance without contact, a trajectory that went
around the triangular obstacle, both figures, the CSV, the latest-run link and the run's
MCAP recording.
"""

import csv
import json
import os
import sys

from mcap.reader import make_reader
import pytest
from test_bringup import write_overlay
from wsenv import check_provenance, stack_env

pytestmark = pytest.mark.allow_leaks('fds')

OBSTACLE_X = (1.5, 1.9)       # devices.yaml world.obstacles[0] x extent
OBSTACLE_HALF_WIDTH = 0.25    # its half width at x = 1.5 m
ROBOT_HALF_WIDTH = 0.14       # Table 2 body width 0.28 m


def test_demo_reaches_the_goal_around_the_obstacle_without_contact(procs, tmp_path,
                                                                    m4k_runtime_dir):
    overlay = write_overlay(tmp_path)
    results = tmp_path / 'results'
    out = open(tmp_path / 'demo.out', 'w')
    try:
        proc = procs.start([sys.executable, '-m', 'm4k_bench.demo', '--python-m',
                            '--config', overlay, '--results', str(results),
                            '--timeout', '60'],
                           env=stack_env(m4k_runtime_dir), stdout=out, stderr=out)
    finally:
        out.close()
    try:
        rc = proc.wait(150)
    except Exception:
        procs.stop(proc)
        raise
    log = (tmp_path / 'demo.out').read_text()
    assert rc == 0, log[-3000:]

    latest = results / 'demo-latest'
    assert latest.is_symlink()
    run = results / os.readlink(latest)
    assert run.name.startswith('demo-') and run.is_dir()

    summary = json.loads((run / 'summary.json').read_text())
    assert summary['passed'] is True and summary['goal_reached'] is True
    check_provenance(summary)
    assert summary['contacts'] == 0
    assert summary['final_error_m'] <= summary['goal_tolerance_m']
    assert summary['min_clearance_m'] > 0.0
    assert summary['timed_out'] is False
    assert summary['cmd_samples'] > 100 and summary['odom_samples'] > 100

    with open(run / 'trajectory.csv', newline='') as f:
        rows = list(csv.DictReader(f))
    xs = [float(r['x_m']) for r in rows]
    assert min(xs) > -0.1 and max(xs) > 2.9
    # Beside the obstacle the robot's centre was clear of it by at least half its width.
    beside = [abs(float(r['y_m'])) for r in rows if OBSTACLE_X[0] <= float(r['x_m'])
              <= OBSTACLE_X[1]]
    assert beside and min(beside) > OBSTACLE_HALF_WIDTH + ROBOT_HALF_WIDTH
    # The reference never exceeded the paper's 0.25 m/s.
    assert max(float(r['v_ref_mps']) for r in rows) <= 0.25 + 1e-9
    assert all(float(r['clearance_m']) > 0.0 for r in rows)

    for name in ('fig9a_trajectory.png', 'fig9b_velocity.png'):
        data = (run / name).read_bytes()
        assert data[:8] == b'\x89PNG\r\n\x1a\n' and len(data) > 20_000, name
    report = (run / 'report.md').read_text()
    assert 'PASS' in report and 'Fig. 9' in report

    # The run is also recorded as MCAP (m4k_bridge.bag.record): the planner's commands and odom.
    # It is indexed, and names the same commit as summary.json (one lookup for both).
    with open(run / 'bag' / 'bag_0.mcap', 'rb') as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    counts = {ch.topic: summary.statistics.channel_message_counts.get(cid, 0)
              for cid, ch in summary.channels.items()}
    assert counts.get('/odom', 0) > 100 and counts.get('/cmd_vel', 0) > 100, counts
    assert summary.chunk_indexes and not (run / 'bag.partial').exists()
    prov = json.loads((run / 'summary.json').read_text())['provenance']
    assert meta['m4k']['m4k.commit'] == prov['commit'] + ('-dirty' if prov['dirty'] else '')
