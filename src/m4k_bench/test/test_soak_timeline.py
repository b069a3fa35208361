"""The soak's timeline: cyclictest -v/--spike parsing and the stall attribution, worked by hand."""

import csv

from m4k_bench import soaktime

# cyclictest 2.x output of `-q -v --spike=9999` (one thread, 10 ms): headers, one line per
# sample, the spike list after the run. Sample 3 woke 26.4 ms late: cyclictest's next target
# is 3 intervals on (it skips the two periods that expired), so sample 4 is at 60 ms, not 40.
VERBOSE = """Max CPUs = 2
Online CPUs = 2
# /dev/cpu_dma_latency set to 0us
Thread 0 Interval: 10000
       0:       0:      57
       0:       1:      40
       0:       2:      41
       0:       3:   26436
       0:       4:      38
       0:       5:   12000
       0:       6:      30

T: 0 Spike:   26436: TS:   1000056436
T: 0 Spike:   12000: TS:   1000082000
spikes = 2

"""


def test_verbose_lines_parse_to_cycle_and_latency_and_skip_everything_else():
    s = soaktime.parse_verbose(VERBOSE)
    assert s == [(0, 57), (1, 40), (2, 41), (3, 26436), (4, 38), (5, 12000), (6, 30)]
    assert soaktime.parse_verbose(VERBOSE, thread=1) == []


def test_spike_lines_give_latency_and_monotonic_wakeup_in_seconds():
    assert soaktime.parse_spikes(VERBOSE) == [(0, 26436, 1000.056436), (0, 12000, 1000.082)]


def test_sample_times_follow_cyclictests_skip_after_a_stall():
    t = soaktime.sample_times(soaktime.parse_verbose(VERBOSE), 10_000)
    # targets (ms): 0 10 20 30, then 30 + 3*10 (26.4 ms late), then 60 + 2*10 (12 ms late)
    assert [round(x * 1e3) for x, _ in t] == [0, 10, 20, 30, 60, 70, 90]
    # a stall of 26.4 ms is 2 skipped releases of a 10 ms timerfd task, 12 ms is 1
    assert soaktime.skipped_releases([lat for _, lat in t], 10_000) == 3


def test_reference_uses_the_spike_stamps_and_agrees_with_the_reconstruction():
    r = soaktime.reference(VERBOSE, 10_000, start_s=999.0, t0=1000.0)
    assert r['samples'] == 7 and r['late'] == 2 and r['spikes'] == 2
    assert r['late_latencies_us'] == [26436, 12000] and r['skipped_releases'] == 3
    assert r['times_from'] == '--spike stamps'
    assert r['late_times_s'] == [1000.056436, 1000.082]
    # anchored on the first spike, the -v reconstruction lands on the second spike exactly
    assert r['spike_vs_v_max_ms'] is not None and r['spike_vs_v_max_ms'] < 1e-6
    assert r['per_second_max_us'] == {0: 26436}


def test_reference_without_spikes_anchors_on_the_process_start():
    text = '\n'.join(line for line in VERBOSE.splitlines() if 'Spike' not in line)
    r = soaktime.reference(text, 10_000, start_s=500.0, t0=500.0)
    assert r['times_from'] == '-v, anchored on process start' and r['late'] == 2
    # first target = start + 1 interval; sample 3 at +30 ms woke 26.436 ms later
    assert abs(r['late_times_s'][0] - (500.0 + 0.010 + 0.030 + 0.026436)) < 1e-9


def test_attribution_splits_events_near_a_stall_from_m4k_alone():
    t0 = 100.0
    late = {'actuator': [110.5, 150.2], 'imu': [170.9]}
    events = {
        # second 10: the stall itself (2 releases); 11: the next second, still near;
        # 13: two seconds on, alone; 30: alone; 50 near the first reference (+-1: 49..51);
        # 71 near the second reference (70 +- 1)
        'imu': [(110.6, 2), (111.2, 1), (113.0, 1), (130.0, 1), (149.9, 1), (171.5, 3)],
        'actuator': [(110.7, 1)],
        'led': [],
    }
    a = soaktime.attribute(events, late, t0)
    imu = a['tasks']['imu']
    assert imu['total'] == 9
    assert imu['coincide'] == 2 + 1 + 1 + 3 and imu['alone'] == 2
    assert imu['by_ref'] == {'actuator': 4, 'imu': 3}
    assert imu['alone_seconds'] == [13, 30]
    assert imu['per_second'] == {10: 2, 11: 1, 13: 1, 30: 1, 49: 1, 71: 3}
    assert (imu['max_burst'], imu['max_burst_s']) == (3, 71)
    assert a['tasks']['actuator'] == {
        'total': 1, 'coincide': 1, 'alone': 0, 'by_ref': {'actuator': 1, 'imu': 0},
        'per_second': {10: 1}, 'max_burst': 1, 'max_burst_s': 10, 'alone_seconds': []}
    assert a['tasks']['led']['total'] == 0 and a['tasks']['led']['max_burst_s'] is None
    assert a['late_seconds'] == {'actuator': [10, 50], 'imu': [70]}


def test_attribution_without_any_cyclictest_lateness_is_all_m4k_alone():
    a = soaktime.attribute({'imu': [(5.5, 2), (6.1, 1)]}, {'actuator': []}, 0.0)
    assert (a['tasks']['imu']['coincide'], a['tasks']['imu']['alone']) == (0, 3)


def test_counter_timeline_keeps_per_second_deltas():
    tl = soaktime.CounterTimeline({'imu': {'overruns': 5, 'deadline_misses': 1},
                                   'led': {'overruns': 0, 'deadline_misses': 0}})
    tl.poll(1.0, {'imu': {'overruns': 5, 'deadline_misses': 1},
                  'led': {'overruns': 0, 'deadline_misses': 0}})
    tl.poll(2.0, {'imu': {'overruns': 7, 'deadline_misses': 1},
                  'led': {'overruns': 1, 'deadline_misses': 0}})
    tl.poll(3.0, {'imu': {'overruns': 7, 'deadline_misses': 2},
                  'led': {'overruns': 1, 'deadline_misses': 0},
                  'monitor': {'overruns': None, 'deadline_misses': None}})
    assert tl.rows == [(2.0, 'imu', 2, 0), (2.0, 'led', 1, 0), (3.0, 'imu', 0, 1)]
    assert tl.events() == {'imu': [(2.0, 2), (3.0, 1)], 'led': [(2.0, 1)]}


def test_sample_events_count_skipped_releases_and_misses_inside_the_window():
    ms = 1_000_000
    # (release, start, end, expirations) ms, period 10: the cycle at 50 woke at 76.4 (3
    # expirations: 2 overruns); the cycle at 90 ended at 101 (a miss); the one at 200 is
    # outside the window.
    rel = [40 * ms, 70 * ms, 90 * ms, 200 * ms]
    start = [40 * ms + 50_000, 76_400_000, 90 * ms + 50_000, 200 * ms]
    end = [41 * ms, 77 * ms, 101 * ms, 201 * ms]
    exp = [1, 3, 1, 2]
    over, miss = soaktime.sample_events(rel, start, end, exp, 10 * ms, 0, 150 * ms)
    assert over == [(0.0764, 2)] and miss == [(0.101, 1)]


def test_analyze_puts_samples_counters_and_references_in_one_report(tmp_path):
    from m4k_bench.recorder import TaskSeries
    ms = 1_000_000
    imu = TaskSeries('imu', period_ns=10 * ms)
    # one cycle at 1000.0 s, then a wake-up 26.4 ms after the release at 30 ms: 3 expirations
    # (2 overruns), the cycle stamped with the latest release (50 ms), as m4k_rt.task does
    for rel, start, end, exp in ((1000_000 * ms, 1000_000 * ms + 50_000, 1000_001 * ms, 1),
                                 (1000_050 * ms, 1000_056_436_000, 1000_057 * ms, 3)):
        imu.t_rel.append(rel)
        imu.t_start.append(start)
        imu.t_end.append(end)
        imu.expirations.append(exp)
    counters = soaktime.CounterTimeline({'imu': {'overruns': 0, 'deadline_misses': 0}})
    counters.poll(1002.0, {'imu': {'overruns': 2, 'deadline_misses': 0}})   # 2 s later
    ref = dict(soaktime.reference(VERBOSE, 10_000, 999.0, 1000.0), priority=90)
    tl = soaktime.analyze({'actuator': ref}, counters, {'imu': imu}, 1000.0, 1010.0)
    s, c = tl['samples']['tasks']['imu'], tl['counters']['tasks']['imu']
    assert (s['overruns'], s['deadline_misses'], s['coincide'], s['alone']) == (2, 0, 2, 0)
    assert (c['total'], c['coincide'], c['per_second']) == (2, 2, {2: 2})
    text = '\n'.join(soaktime.report_lines(tl, 10_000))
    assert '| actuator | 90 | 7 | 2 | 26.4, 12.0 | 3 | --spike stamps |' in text
    assert '| imu | 2 + 0 | 2 | 2 | 0 | 2 (0) | 2 | 2 | 0 |' in text
    # timeline.csv bins the task at its cycle (second 0), not where the counters showed it (2).
    soaktime.write_csv(str(tmp_path / 't.csv'), tl)
    with open(tmp_path / 't.csv', newline='') as f:
        rows = {r['second']: r for r in csv.DictReader(f)}
    assert rows['0']['imu_late'] == '2'
    assert all(r['imu_late'] == '0' for sec, r in rows.items() if sec != '0')
