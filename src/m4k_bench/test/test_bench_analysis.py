"""Tests of the bench's pure parts: samples CSV, condition stats, ratios, targets, plan."""

import math

import pytest

from m4k_bench import bench
from m4k_bench.benchlib import analysis, stack

MS = 1_000_000


def _rows(n, period=10 * MS, latency=50_000, response=20_000, late_every=0, late_by=0):
    rows = []
    for k in range(n):
        rel = 10**9 + k * period
        start = rel + latency + (late_by if late_every and k % late_every == 0 else 0)
        rows.append((rel, start, start + response, 1))
    return rows


def _m4k(lat_p99, ct_p99, jit_p99=10.0, ok=True, cpu=None):
    return {'latency_us': {'p99': lat_p99, 'p999': lat_p99 * 2}, 'jitter_us': {'p99': jit_p99},
            'cyclictest': {'p99': ct_p99, 'p999': ct_p99 * 2},
            'hardening': {'ok': ok, 'why': '' if ok else 'not SCHED_FIFO'},
            'cpu_per_cycle_us': cpu}


def _paired(m4k_cpu, floor_cpu):
    return {'cpu_per_cycle_us': m4k_cpu, 'floor': {'cpu_per_cycle_us': floor_cpu},
            'hardening': {'ok': True, 'why': ''}}


def _rounds():
    # Three rounds; per-round ratio p99 / ct p99 = 1.2, 3.0, 1.4 -> median 1.4.
    # cyclictest alone p99 40, 100, 70 -> p99 ÷ alone 1.5, 3.0, 1.0.
    return [
        {'round': 0, 'm4k_idle': _m4k(60.0, 50.0, cpu=80.0), 'm4k_alone': _m4k(50.0, 50.0),
         'ct_idle': {'latency_us': {'p99': 40.0, 'p999': 80.0}},
         'floor': {'cpu_per_cycle_us': 40.0}, 'm4k_floor_paired': _paired(90.0, 60.0),
         'rtt': {'xddp': {'p50_us': 12.0}, 'raw': {'p50_us': 10.0}}},
        {'round': 1, 'm4k_idle': _m4k(300.0, 100.0, cpu=90.0), 'm4k_alone': _m4k(60.0, 50.0),
         'ct_idle': {'latency_us': {'p99': 100.0, 'p999': 200.0}},
         'floor': {'cpu_per_cycle_us': 30.0}, 'm4k_floor_paired': _paired(100.0, 40.0)},
        {'round': 2, 'm4k_idle': _m4k(70.0, 50.0, cpu=100.0), 'm4k_alone': _m4k(70.0, 50.0),
         'ct_idle': {'latency_us': {'p99': 70.0, 'p999': 140.0}},
         'floor': {'cpu_per_cycle_us': 50.0}, 'm4k_floor_paired': _paired(80.0, 50.0)},
    ]


def test_load_samples_csv_groups_rows_by_task(tmp_path):
    p = tmp_path / 's.csv'
    p.write_text('task,t_rel_ns,t_start_ns,t_end_ns,expirations\n'
                 'a,1,2,3,1\nb,10,20,30,2\na,4,5,6,1\n')
    got = analysis.load_samples_csv(str(p))
    assert got == {'a': [(1, 2, 3, 1), (4, 5, 6, 1)], 'b': [(10, 20, 30, 2)]}


def test_load_samples_csv_rejects_wrong_header_and_bad_rows(tmp_path):
    p = tmp_path / 'x.csv'
    p.write_text('a,b,c\n1,2,3\n')
    with pytest.raises(ValueError, match='not a timing samples CSV'):
        analysis.load_samples_csv(str(p))
    p.write_text('task,t_rel_ns,t_start_ns,t_end_ns,expirations\na,1,two,3,1\n')
    with pytest.raises(ValueError, match=r'x.csv:2: bad sample row'):
        analysis.load_samples_csv(str(p))


def test_condition_summary_measures_jitter_of_late_cycles():
    # every 10th cycle starts 2 ms late: two periods per late cycle deviate by 2 ms
    rows = _rows(200, late_every=10, late_by=2 * MS)
    c = analysis.condition_summary(analysis.series_from_rows('baseline', 10 * MS, rows))
    assert c['samples'] == 200
    assert c['jitter_us']['max'] == pytest.approx(2000.0)
    assert c['jitter_us']['p50'] == pytest.approx(0.0)
    assert c['latency_us']['min'] == pytest.approx(50.0)
    assert c['deadline_misses'] == 0


def test_condition_summary_of_empty_series_is_none():
    assert analysis.condition_summary(analysis.series_from_rows('x', 10 * MS, [])) is None


def test_ratio_handles_missing_zero_and_nan():
    assert analysis.ratio(10.0, 4.0) == 2.5
    assert analysis.ratio(None, 4.0) is None
    assert analysis.ratio(1.0, 0.0) is None
    assert analysis.ratio(math.nan, 1.0) is None


def test_round_ratios_are_per_round_with_the_median_and_spread():
    r = analysis.round_ratios(_rounds())
    assert set(analysis.RATIO_KEYS) <= set(r)
    idle = r['release_p99_over_cyclictest_idle']
    assert idle['values'] == pytest.approx([1.2, 3.0, 1.4])
    assert idle['spread']['median'] == pytest.approx(1.4)
    assert (idle['spread']['min'], idle['spread']['max']) == pytest.approx((1.2, 3.0))
    # five tasks / alone: 60/50, 300/60, 70/70 -> 1.2, 5.0, 1.0 -> median 1.2
    assert r['five_tasks_over_alone_p99']['spread']['median'] == pytest.approx(1.2)
    # CPU per cycle / floor alone: 80/40, 90/30, 100/50 -> 2, 3, 2 -> median 2
    assert r['cpu_per_cycle_over_floor_alone']['spread']['median'] == pytest.approx(2.0)
    # paired, one run: 90/60, 100/40, 80/50 -> 1.5, 2.5, 1.6 -> median 1.6
    assert r['cpu_per_cycle_over_floor']['values'] == pytest.approx([1.5, 2.5, 1.6])
    assert r['xddp_rtt_p50_over_raw']['values'] == [pytest.approx(1.2), None, None]
    assert r['release_p99_over_cyclictest_stress']['spread'] is None


def test_a_degraded_m4k_run_is_left_out_of_the_m4k_ratios():
    rs = _rounds()
    rs[1]['m4k_idle']['hardening'] = {'ok': False, 'why': 'not SCHED_FIFO'}
    r = analysis.round_ratios(rs)
    assert r['release_p99_over_cyclictest_idle']['values'] == pytest.approx([1.2, None, 1.4])
    assert r['release_p99_over_cyclictest_idle']['spread']['median'] == pytest.approx(1.3)
    assert r['_excluded'] == ['round 1 m4k_idle: not SCHED_FIFO']


def test_targets_judge_the_median_and_keep_the_spread():
    r = analysis.round_ratios(_rounds())
    scaling = [{'rate_hz': 1000, 'set': 'alone', 'ratio_p99': 2.5, 'ratio_p99_alone': 1.5,
                'ratio_p99_stricter': 2.5},
               {'rate_hz': 1000, 'set': 'task set', 'ratio_p99': 1.0,
                'ratio_p99_stricter': 1.0}]
    rows = {t['key']: t for t in analysis.evaluate_targets(r, scaling)}
    # stricter of concurrent (1.2, 3.0, 1.4) and alone (1.5, 3.0, 1.0): 1.5, 3.0, 1.4 -> 1.5
    idle = rows['release_p99_stricter_idle']
    assert idle['spread']['values'] == pytest.approx([1.5, 3.0, 1.4])
    assert idle['met'] is True                                           # 1.5 <= 1.5
    assert idle['of']['concurrent']['median'] == pytest.approx(1.4)
    assert idle['of']['alone']['median'] == pytest.approx(1.5)
    assert rows['five_tasks_over_alone_p99']['met'] is True             # 1.2 <= 1.25
    assert rows['cpu_per_cycle_over_floor']['met'] is True              # 1.6 <= 2
    assert rows['release_p99_stricter_stress']['met'] is None           # not measured
    assert rows['scaling_1khz_release_p99_over_cyclictest']['met'] is False   # 2.5 > 2
    assert all(set(t) == {'key', 'label', 'target', 'spread', 'met', 'of', 'invalid',
                          'rounds_invalid'}
               for t in rows.values())


def test_a_latency_target_met_on_the_concurrent_denominator_fails_on_the_alone_one():
    # p99 60 over a concurrent cyclictest of 50 (1.2: met) but 30 alone (2.0: not met)
    rs = [{'round': k, 'm4k_idle': _m4k(60.0, 50.0),
           'ct_idle': {'latency_us': {'p99': 30.0, 'p999': 60.0}}} for k in range(3)]
    r = analysis.round_ratios(rs)
    assert r['release_p99_over_cyclictest_idle']['spread']['median'] == pytest.approx(1.2)
    rows = {t['key']: t for t in analysis.evaluate_targets(r, [])}
    assert rows['release_p99_stricter_idle']['spread']['median'] == pytest.approx(2.0)
    assert rows['release_p99_stricter_idle']['met'] is False
    # without cyclictest alone there is no stricter figure: not measured, never "met"
    del rs[0]['ct_idle'], rs[1]['ct_idle'], rs[2]['ct_idle']
    rows = {t['key']: t for t in analysis.evaluate_targets(analysis.round_ratios(rs), [])}
    assert rows['release_p99_stricter_idle']['met'] is None


def test_median_round_table_picks_the_median_round():
    tables = {'r0_m4k_idle': 'T0', 'r1_m4k_idle': 'T1', 'r2_m4k_idle': 'T2'}
    # actuator p99: 60, 300, 70 -> median 70 -> round 2
    assert analysis.median_round_table(_rounds(), tables) == (2, 'T2')
    assert analysis.median_round_table([], tables) == (None, None)


def test_loop_cost_spreads_cpu_per_cycle_and_floor():
    lc = analysis.loop_cost(_rounds())
    assert lc['m4k_cpu_per_cycle_us']['median'] == 90.0
    assert lc['floor_cpu_per_cycle_us']['median'] == 40.0


def test_plan_durations_quick_full_and_overrides():
    assert bench.plan_durations(False, None, None) == bench.FULL
    q = bench.plan_durations(True, None, None)
    assert q['rounds'] == 3 and bench.FULL['rounds'] >= 5
    assert bench.plan_durations(True, 3.0, None, 2) == dict(bench.QUICK, condition_s=3.0,
                                                            rounds=2)
    with pytest.raises(ValueError, match='> 0'):
        bench.plan_durations(False, 0.0, None)
    with pytest.raises(ValueError, match='--rounds'):
        bench.plan_durations(False, None, None, 0)


def test_the_full_plan_fits_in_65_minutes_and_quick_in_18():
    # 35 (was 30): the scaling sweep now runs in every round, not once; 38: the paired
    # floor run and cyclictest alone at 1 kHz (the stricter denominators) in every round;
    # 41: the live view with a viewer (m4k_live) in every round; 45 (quick 13): the guard's
    # reaction phase, 215 s estimated in the full plan (50 trials at 0.5 m/s, the published
    # figure's count, + 5 each at 1.0 and 2.0 m/s; the same trials alone took ~7 min on the
    # loaded VM, docs/results/reaction), 79 s in the quick one; 47 (quick 14): the two channel
    # floors (socket, shared memory) beside the bare floor in every round; 61 (quick 16):
    # both executives side by side (issue 42: the frame executive idle and stressed, a slow
    # body under each) and the two frame-structure floors in every round; 65 (quick 18): the
    # three-robot fleet (fleet_idle, issue 42's wheel-command drops) in every round.
    assert bench.estimate_s(bench.FULL) <= 65 * 60
    assert bench.estimate_s(bench.QUICK) <= 18 * 60


def test_bench_rejects_unknown_skip_phase(capsys):
    with pytest.raises(SystemExit) as exc:
        bench.main(['--skip', 'floor,nope'])
    assert exc.value.code == 2
    assert "unknown phase(s) ['nope']" in capsys.readouterr().err


def test_bench_only_runs_the_named_phases_and_does_not_publish(capsys):
    args = bench._parse_args(['--only', 'cmdlat'])
    assert set(args.skip.split(',')) == set(bench.PHASES) - {'cmdlat'}
    assert args.publish == ''
    assert bench._parse_args(['--only', 'cmdlat', '--publish', 'x']).publish == 'x'
    for argv, msg in ((['--only', 'nope'], "--only: unknown phase(s) ['nope']"),
                      (['--only', 'cmdlat', '--skip', 'floor'], 'give one of them')):
        with pytest.raises(SystemExit) as exc:
            bench.main(argv)
        assert exc.value.code == 2
        assert msg in capsys.readouterr().err


def test_actuator_periods_skip_non_consecutive_cycles():
    rel = [0, 10 * MS, 30 * MS, 40 * MS]       # a batch lost between cycles 1 and 2
    start = [1, 10 * MS + 1, 30 * MS + 5, 40 * MS + 2]
    series = analysis.series_from_rows('actuator', 10 * MS, [
        (r, st, st + 5, 1) for r, st in zip(rel, start, strict=True)])
    assert list(bench._periods(series)) == [10 * MS, 10 * MS - 3]


def test_velocity_profile_alternates_at_paper_speed():
    assert stack.velocity_profile(0.0) == (0.25, 0.0)
    assert stack.velocity_profile(5.0) == (-0.25, 0.0)
    assert stack.velocity_profile(8.5) == (0.25, 0.0)


def test_entry_argv_runs_module_main():
    argv = stack.entry_argv('m4k_rt.rt_core', '--tasks', 'actuator')
    assert argv[1] == '-c' and 'from m4k_rt.rt_core import main' in argv[2]
    assert argv[3:] == ['--tasks', 'actuator']


def test_trim_warmup_drops_the_first_second_of_every_task_and_reports_it():
    a = analysis.series_from_rows('actuator', 10 * MS, _rows(300, latency=50_000))
    a.t_start[0] += 5 * MS                    # a start-up hiccup
    b = analysis.series_from_rows('lrf', 200 * MS, _rows(10, period=200 * MS))
    got = analysis.trim_warmup([a, b], 1_000 * MS)
    assert got['cycles'] == {'actuator': 100, 'lrf': 5}
    assert got['max_latency_us'] == pytest.approx(5050.0)
    assert len(a.t_rel) == 200 and len(a.t_start) == 200 and len(a.expirations) == 200
    assert a.t_rel[0] == 10**9 + 1_000 * MS
    assert analysis.trim_warmup([], 1) == {'cycles': {}, 'max_latency_us': None}


def test_interference_finds_cycles_released_while_another_task_ran():
    act = analysis.series_from_rows('actuator', 10 * MS, _rows(100, latency=20_000))
    # imu runs [rel - 5 us, rel + 300 us] on every 4th release: the actuator waits for it
    rows = []
    for k in range(0, 100, 4):
        rel = 10**9 + k * 10 * MS
        rows.append((rel, rel - 5_000, rel + 300_000, 1))
        act.t_start[k] = rel + 310_000
    imu = analysis.series_from_rows('imu', 10 * MS, rows)
    led = analysis.series_from_rows('led', 20 * MS, [(10**9 + 5 * MS, 10**9 + 5 * MS,
                                                       10**9 + 6 * MS, 1)])
    got = analysis.interference({'actuator': act, 'imu': imu, 'led': led}, 'actuator')
    assert got['cycles'] == 100
    assert got['interfered_share'] == pytest.approx(0.25)
    assert got['share_by_task'] == {'imu': 0.25, 'led': 0.0}
    assert got['latency_p99_interfered_us'] == pytest.approx(310.0)
    assert got['latency_p99_clean_us'] == pytest.approx(20.0)
    assert analysis.interference({'imu': imu}, 'actuator') is None


def test_scaling_summary_spreads_over_rounds_and_leaves_out_degraded_runs():
    rows = [{'round': k, 'rate_hz': hz, 'set': 'alone', 'release_p99_us': float(10 * hz + k),
             'release_p999_us': None, 'cyclictest_p99_us': 10.0,
             'ratio_p99': (10 * hz + k) / 10.0, 'ratio_p99_stricter': (10 * hz + k) / 10.0,
             'cpu_per_cycle_us': 5.0 + k,
             'overruns': k, 'deadline_misses': 0, 'hardening_ok': k != 2}
            for k in range(3) for hz in ((100, 1000) if k % 2 == 0 else (1000, 100))]
    out = analysis.scaling_summary(rows)
    assert [(r['rate_hz'], r['set']) for r in out] == [(100, 'alone'), (1000, 'alone')]
    r1k = out[1]
    assert r1k['runs'] == 3 and r1k['degraded'] == 1
    # round 2 was degraded: only rounds 0 and 1 count
    assert r1k['release_p99_us'] == {'median': 10000.5, 'min': 10000.0, 'max': 10001.0,
                                     'n': 2, 'values': [10000.0, 10001.0]}
    assert r1k['cpu_per_cycle_us']['median'] == 5.5
    assert r1k['release_p999_us'] is None
    assert r1k['overruns'] == 0 + 1 + 2        # summed over every run, degraded included
    target = {t['key']: t for t in analysis.evaluate_targets({}, rows)}[
        'scaling_1khz_release_p99_over_cyclictest']
    assert target['spread']['n'] == 2 and target['met'] is False


def test_the_cache_ab_of_the_profiled_runs_is_a_median_over_rounds():
    prof = {'actuator': {'period_ns': 10 * MS, 'parts_us': {}, 'thread_cpu_per_cycle_us': 50}}
    rs = [{'round': k, 'm4k_profiled': {
        'cycle_profile': {'tasks': prof}, 'cpu_per_cycle_us': 60.0,
        'floor': {'probe_us': {'cold_p50': c, 'warm_p50': 2.0, 'cold_over_warm_p50': c / 2.0,
                               'n': 100}}}} for k, c in enumerate((8.0, 10.0, 9.0))]
    ab = analysis.cycle_breakdown(rs)['cache_ab_us']
    assert ab['cold_p50']['median'] == 9.0 and ab['cold_over_warm_p50']['median'] == 4.5
    assert 'n' not in ab


def test_floor_probe_weights_threads_by_cycles():
    from m4k_bench.benchlib import floor
    got = floor._weighted_probe([
        {'cold_p50': 10.0, 'warm_p50': 2.0, 'cold_p99': 20.0, 'warm_p99': 4.0, 'n': 300},
        {'cold_p50': 6.0, 'warm_p50': 2.0, 'cold_p99': 12.0, 'warm_p99': 4.0, 'n': 100}])
    assert got['cold_p50'] == pytest.approx(9.0) and got['warm_p50'] == pytest.approx(2.0)
    assert got['cold_over_warm_p50'] == pytest.approx(4.5) and got['n'] == 400


def test_floor_channel_traffic_moves_a_task_cycles_datagrams():
    from m4k_bench.benchlib import floor
    sock, close = floor._channel_call('socket')
    try:
        assert sock() == 0                                  # nothing sent yet: port empty
        assert sock() == 2 * floor._DATAGRAM                # the two of the cycle before
        assert sock() == 2 * floor._DATAGRAM                # and nothing piles up
    finally:
        close()
    shm, close = floor._channel_call('shm')
    try:
        assert [shm(), shm(), shm()] == [0, 2, 4]           # sequence numbers read back
    finally:
        close()
    assert floor._channel_call('none')[0] is None
    with pytest.raises(ValueError, match='channel'):
        floor._channel_call('pipe')


def test_floor_pins_its_loops_as_the_task_set_pins_its_tasks():
    import os

    from m4k_bench.benchlib import floor
    assert floor.parse_cpus('', 3) == [None, None, None]
    assert floor.parse_cpus('1,-,0', 3) == [1, None, 0]
    assert floor.format_cpus([1, None, 0]) == '1,-,0'
    for bad, match in (('1,2', 'entries'), ('1,x,2', "'x'"), ('1,-1,2', "'-1'")):
        with pytest.raises(ValueError, match=match):
            floor.parse_cpus(bad, 3)
    # a real floor process: the pinned loop's thread runs on that CPU only (the kernel's
    # view, read by the thread), the unpinned one is left alone
    last = max(os.sched_getaffinity(0))
    out = floor.run_floor_child([10_000_000, 20_000_000], [1, 1], [0, 0], 0.1,
                                cpus=[last, None])
    assert isinstance(out, dict), out
    assert out['cpus'] == [last, None]
    pinned, free = out['threads']
    assert pinned['affinity'] == [last] and pinned['cpu'] == last
    assert 'cpu' not in free and 'affinity' not in free


def test_loop_cost_reports_what_the_channel_alone_costs():
    rounds_ = [{'round': k, 'floor': {'cpu_per_cycle_us': 40.0},
                'floor_socket': {'cpu_per_cycle_us': 40.0 * s},
                'floor_shm': {'cpu_per_cycle_us': 40.0 * m}}
               for k, (s, m) in enumerate([(2.0, 1.25), (2.5, 1.5), (2.25, 1.0)])]
    r = analysis.round_ratios(rounds_)
    assert r['socket_channel_floor_over_floor']['values'] == pytest.approx([2.0, 2.5, 2.25])
    assert r['shm_channel_floor_over_floor']['spread']['median'] == pytest.approx(1.25)
    lc = analysis.loop_cost(rounds_)
    assert lc['channel_floor_cpu_per_cycle_us']['socket']['median'] == pytest.approx(90.0)
    assert lc['channel_floor_cpu_per_cycle_us']['shm']['max'] == pytest.approx(60.0)
