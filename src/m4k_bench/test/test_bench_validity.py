"""A round whose cyclictest reference shows the host stalling gives no verdict (issue 42)."""

from m4k_bench.benchlib import analysis
from m4k_bench.benchlib.report import verdict
from m4k_bench.benchlib.validity import broken_reference, round_invalid

PERIOD_US = 10_000.0


def test_a_reference_with_a_stall_tail_or_a_missed_period_is_broken():
    assert broken_reference({'p50': 8, 'p99': 40}, PERIOD_US) is None          # a long-ish tail
    assert broken_reference({'p50': 20, 'p99': 450}, PERIOD_US) is None        # below the floor
    why = broken_reference({'p50': 25, 'p99': 6954}, PERIOD_US)                # committed run
    assert why == 'cyclictest p99 6954 µs = 278× its p50 25 µs (the host stalls)'
    why = broken_reference({'p50': 900, 'p99': 12806}, PERIOD_US)
    assert why == 'cyclictest p99 12806 µs > the period 10000 µs (the host skipped releases)'
    assert broken_reference(None, PERIOD_US) is None                          # no reference
    assert broken_reference({'error': 'not installed'}, PERIOD_US) is None


def _round(n, ct_stress_p99, m4k_ct_p99):
    return {'round': n,
            'ct_idle': {'latency_us': {'p50': 10, 'p99': 30, 'p999': 50}},
            'm4k_idle': {'latency_us': {'p50': 12, 'p99': 36, 'p999': 60},
                         'cyclictest': {'p50': 10, 'p99': 30, 'p999': 50},
                         'hardening': {'ok': True}},
            'ct_stress': {'latency_us': {'p50': 25, 'p99': ct_stress_p99, 'p999': 9000}},
            'm4k_stress': {'latency_us': {'p50': 30, 'p99': 900, 'p999': 2000},
                           'cyclictest': {'p50': 25, 'p99': m4k_ct_p99, 'p999': 9000},
                           'hardening': {'ok': True}}}


def test_a_stalled_round_is_left_out_and_no_valid_round_means_invalid_not_met():
    rounds_ = [_round(1, 7000, 8000), _round(2, 7000, 8000)]
    assert round_invalid(rounds_[0], ('m4k_stress', 'ct_stress'), PERIOD_US).startswith(
        'm4k_stress: cyclictest p99 8000 µs')
    r = analysis.round_ratios(rounds_)
    # 900 / 8000 would read 0.11, "met": it is no value at all
    assert r['release_p99_over_cyclictest_stress']['values'] == [None, None]
    assert len(r['release_p99_over_cyclictest_stress']['invalid']) == 2
    assert r['release_p99_over_cyclictest_idle']['values'] == [1.2, 1.2]
    rows = {t['key']: t for t in analysis.evaluate_targets(r, [])}
    stress = rows['release_p99_stricter_stress']
    assert stress['met'] is None and stress['invalid']
    assert verdict(stress).startswith('INVALID: round 1: m4k_stress: cyclictest p99 8000 µs')
    assert rows['release_p99_stricter_idle']['met'] is True
    assert verdict(rows['release_p99_stricter_idle']) == 'met'


def test_one_valid_round_still_gives_a_verdict_and_says_what_was_left_out():
    rounds_ = [_round(1, 7000, 8000), _round(2, 100, 120)]
    r = analysis.round_ratios(rounds_)
    assert r['release_p99_over_cyclictest_stress']['values'] == [None, 7.5]
    row = {t['key']: t for t in analysis.evaluate_targets(r, [])}['release_p99_stricter_stress']
    assert row['met'] is False and not row['invalid']
    assert verdict(row) == 'NOT met (2 round(s) left out: no valid reference)'


def test_host_drops_per_10k_separate_the_simulations_share():
    from m4k_bench.benchlib import hostdrops
    log = ('m4k_drivers.host: motor: drops served=10 stale_host=0 stale_device=1 malformed=0\n'
           '[INFO] motor: drops served=9990 stale_host=3 stale_device=5 malformed=0 unexpected=0 '
           'inactive=2 encode=0 reply_lost=4 at exit\n'
           'imu: drops served=5 stale_host=0 stale_device=0\n')
    counts = hostdrops.parse(log)
    assert counts['motor'] == {'served': 9990, 'stale_host': 3, 'stale_device': 5,
                               'malformed': 0, 'unexpected': 0, 'inactive': 2, 'encode': 0,
                               'reply_lost': 4}
    r = hostdrops.per_10k(counts['motor'])
    assert r['commands'] == 10_000 and r['dropped'] == 10     # replies lost: not commands
    assert (r['per_10k'], r['host_per_10k'], r['sim_per_10k']) == (10.0, 5.0, 5.0)
    assert hostdrops.per_10k({'served': 0})['per_10k'] is None


def test_commands_lost_before_the_host_are_the_rt_sides_queue_and_link_drops():
    from m4k_bench.benchlib import hostdrops
    from m4k_rt import protocol
    ps = protocol.PortStats('motor', 2, 1, 9_990, 0, 6, 4, 0, 0, 1)
    r = hostdrops.rt_side(ps)
    assert (r['sent'], r['queue'], r['link']) == (9_990, 4, 6)
    assert (r['queue_per_10k'], r['link_per_10k']) == (4.0, 6.0)
    assert hostdrops.rt_side(None) is None


def test_the_executive_section_names_a_broken_reference_per_condition():
    from m4k_bench.benchlib import execreport
    rnd = _round(0, 100, 8000)
    rnd['m4k_frame_idle'] = dict(rnd['m4k_idle'], cpu_per_cycle_us=50.0, cpu_percent=1.5,
                                 host_drops={'host_per_10k': 0.0, 'sim_per_10k': 1.0,
                                             'dropped': 1, 'commands': 10_000,
                                             'by_reason': {'stale_device': 1}})
    rnd['floor_frame'] = {'cpu_per_cycle_us': 20.0}
    lines = execreport.section({'rounds': [rnd]})
    rows = [ln for ln in lines if ln.startswith('| 0 |')]
    assert len(rows) == 3          # threads idle, frame idle, threads stress
    frame = next(r for r in rows if '| frame | idle |' in r)
    assert '| 20.0 / - |' in frame and '0.00 host + 1.00 sim / 10k (1 of 10000' in frame
    assert frame.endswith('| valid |')
    stress = next(r for r in rows if 'stress-ng' in r)
    assert '| INVALID: cyclictest p99 8000 µs = 320× its p50 25 µs (the host stalls) |' in stress
    assert execreport.section({'rounds': [{'round': 0}]}) == []
