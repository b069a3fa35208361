"""The fleet's drops: a host log's counters across restarts, pooled robots, runs, the tables."""

import signal
import sys
import time

from m4k_bench import fleetdrops
from m4k_bench.benchlib import fleetagg
from m4k_bringup.child import Child, Output, Stopping


def _line(served, host=0, sim=0, lost=0, dev='motor', tail=''):
    return ('[driver_host] 2026-11-29 05:08:28,343 m4k_drivers.host WARNING: {}: drops '
            'served={} stale_host={} stale_device={} malformed=0 unexpected=0 inactive=0 '
            'encode=0 reply_lost={}{}\n'.format(dev, served, host, sim, lost, tail))


def test_the_counters_are_the_last_line_of_each_host_process_summed_across_restarts():
    log = (_line(100, host=1) + _line(200, host=2) + _line(50, lost=1, dev='imu')
           # the host restarted: its counters start again from zero
           + '[bringup] driver_host exited 1, restarting\n'
           + _line(30, sim=1) + _line(400, host=1, sim=3, tail=' at exit'))
    motor = fleetagg.device_totals(log)
    assert motor is not None
    assert (motor['served'], motor['stale_host'], motor['stale_device']) == (600, 3, 3)
    assert motor['segments'] == 2
    imu = fleetagg.device_totals(log, 'imu')
    assert imu is not None and (imu['served'], imu['reply_lost'], imu['segments']) == (50, 1, 1)
    assert fleetagg.device_totals(log, 'sonar') is None
    assert fleetagg.device_totals('') is None


def test_the_fleet_pools_the_robots_counters_before_the_rate():
    logs = {'r1': _line(9_990, host=10), 'r2': _line(5_000, sim=5, lost=7), 'r3': ''}
    host = {r: fleetagg.device_totals(t) for r, t in logs.items()}
    rt = {'r1': {'sent': 9_000, 'queue': 0, 'link': 10}, 'r2': {'sent': 990, 'queue': 0,
                                                               'link': 0}, 'r3': None}
    s = fleetagg.run_summary(host, rt)
    r1 = s['robots']['r1']['host']
    assert (r1['commands'], r1['dropped'], r1['host_per_10k']) == (10_000, 10, 10.0)
    assert s['robots']['r3']['host'] is None
    p = s['pooled']
    # 15 of 15 005 commands (the lost replies are no commands): not the mean of the rates
    assert (p['commands'], p['dropped']) == (15_005, 15)
    assert abs(p['per_10k'] - 1e4 * 15 / 15_005) < 1e-9
    assert abs(p['host_per_10k'] - 1e4 * 10 / 15_005) < 1e-9
    assert abs(p['sim_per_10k'] - 1e4 * 5 / 15_005) < 1e-9
    assert p['by_reason']['reply_lost'] == 7
    assert s['pooled_rt'] == {'sent': 9_990, 'queue': 0, 'link': 10, 'queue_per_10k': 0.0,
                              'link_per_10k': 10.0}
    assert fleetagg.pool({'r1': None}) is None and fleetagg.pool_rt({'r1': None}) is None


def _run(host_drops, sim_drops, load):
    host = {'r1': fleetagg.device_totals(_line(10_000 - host_drops - sim_drops,
                                               host=host_drops, sim=sim_drops))}
    return {'drops': fleetagg.run_summary(host, {'r1': None}),
            'load': {'load_1min': load, 'busy_percent': 99.0, 'cpus': 2,
                     'stack_cores': {'r1': 0.6}, 'stacks_cores': 1.8}}


def test_the_summary_spreads_the_pooled_rates_over_runs_and_sums_the_reasons():
    runs = [_run(0, 0, 6.0), _run(2, 1, 7.0), _run(8, 0, 5.0)]
    s = fleetagg.summarize(runs)
    assert s['runs'] == 3
    assert s['host_per_10k']['values'] == [0.0, 2.0, 8.0]
    assert (s['host_per_10k']['median'], s['sim_per_10k']['max']) == (2.0, 1.0)
    assert s['by_reason']['stale_host'] == 10 and s['by_reason']['stale_device'] == 1
    assert s['load_1min']['median'] == 6.0


def test_the_tables_show_each_robot_and_the_fleet():
    run = _run(2, 1, 7.0)
    rows = fleetagg.run_rows(run, '1')
    assert [r[1] for r in rows] == ['r1', '**fleet**']
    assert rows[0][2].startswith('2.00 host + 1.00 sim / 10k (3 of 10000: ')
    assert rows[1][4] == '-' and rows[1][5] == '7.00 (99 % of 2 CPUs busy; stacks 1.80 cores)'
    lines = fleetagg.bench_rows([{'round': 0, 'fleet_idle': run}, {'round': 1}])
    assert lines[0] == '## Wheel-command drops in the three-robot fleet'
    assert sum(1 for ln in lines if ln.startswith('| round 0 |')) == 2
    assert fleetagg.bench_rows([{'round': 0}]) == []
    text = fleetagg.render({'runs': [run], 'summary': fleetagg.summarize([run]),
                            'command': 'python -m m4k_bench.fleetdrops --runs 1',
                            'duration_s': 60, 'provenance': {'commit': 'abc', 'dirty': False}})
    assert "host's own: **2.00 (2.00–2.00, n=1)** per 10 000" in text
    assert 'commit `abc`' in text and 'stale_device 1, stale_host 2' in text


def test_every_robot_moves_and_two_stay_near_their_start():
    for t in (0.0, 1.0, 3.0, 9.0):
        assert all(fleetagg.command(r, t) != (0.0, 0.0) for r in fleetagg.ROBOTS)
    assert fleetagg.command('r1', 1.0) == (0.25, 0.0)
    assert fleetagg.command('r1', 3.0) == (-0.25, 0.0)
    assert fleetagg.command('r2', 3.0) == (0.0, 0.6)
    assert fleetagg.command('r3', 3.0) == (-0.05, 0.0)
    # r1 never further ahead than half a second's turn of the profile: 0.5 m
    ahead, x = 0.0, 0.0
    for i in range(2000):
        x += fleetagg.command('r1', i * 0.01)[0] * 0.01
        ahead = max(ahead, x)
    assert 0.49 < ahead < 0.51


def test_the_target_is_met_only_when_every_run_is_within_it():
    within = fleetagg.summarize([_run(0, 9, 6.0), _run(10, 0, 6.0)])
    assert within['met'] is True        # the simulation's drops are not the host's
    over = fleetagg.summarize([_run(0, 0, 6.0), _run(11, 0, 6.0), _run(0, 0, 6.0)])
    assert over['met'] is False and over['host_per_10k']['median'] == 0.0
    assert fleetagg.summarize([{'drops': None}])['met'] is None
    lines = fleetagg.combined_lines([within, None])
    assert "* run 1: host's own 5.00 (0.00–10.00, n=2)" in lines[-2]
    assert lines[-2].endswith('-- met') and lines[-1] == '* run 2: not measured'
    assert fleetagg.combined_lines([None]) == []


def test_bench_combine_carries_each_runs_fleet_rounds():
    from m4k_bench.benchlib import combine
    runs = [{'rounds': [{'round': 0, 'fleet_idle': _run(2, 0, 6.0)},
                        {'round': 1, 'fleet_idle': _run(4, 0, 7.0)}]},
            {'rounds': [{'round': 0}]}]
    comb = combine.combine(runs)
    assert comb['fleet'][0]['host_per_10k']['values'] == [2.0, 4.0]
    assert comb['fleet'][1] is None
    text = combine.render(comb)
    assert "* run 1: host's own 3.00 (2.00–4.00, n=2)" in text
    assert '* run 2: not measured' in text


def test_the_bench_report_and_readme_snippet_carry_the_fleet():
    from m4k_bench.benchlib import report
    summ = {'rounds': [{'round': 0, 'fleet_idle': _run(2, 1, 7.0)}]}
    text = report.render(summ)
    assert '## Wheel-command drops in the three-robot fleet' in text
    assert "\n\n* this run: host's own 2.00 (2.00–2.00, n=1)" in text
    snippet = report.readme_snippet(summ)
    assert "* this run: host's own 2.00 (2.00–2.00, n=1), the simulation's 1.00" in snippet
    assert 'three-robot fleet' not in report.readme_snippet({'rounds': [{'round': 0}]})


def _stamped(hms, text):
    return text.replace('05:08:28,343', hms)


def test_drops_after_the_stop_signal_are_the_stops_and_left_out_of_the_running_rate():
    import time
    stop = time.mktime(time.strptime('2026-11-29 05:10:00', '%Y-%m-%d %H:%M:%S')) + 0.5
    log = (_stamped('05:09:00,000', _line(5_000, host=1))
           + '[bridge] a line without a stamp\n'
           + _stamped('05:10:00,499', _line(9_000, host=3, sim=1))
           + _stamped('05:10:00,500', _line(9_990, host=6, sim=2, lost=2, tail=' at exit')))
    assert fleetagg.before(log, stop).count('drops served=') == 2
    assert 'without a stamp' in fleetagg.before(log, stop)
    assert fleetagg.before(log, stop - 120) == ''
    whole = fleetagg.device_totals(log)
    running = fleetagg.device_totals(fleetagg.before(log, stop))
    assert fleetagg.at_stop(whole, running) == {
        'stale_host': 3, 'stale_device': 1, 'malformed': 0, 'unexpected': 0, 'inactive': 0,
        'encode': 0, 'reply_lost': 2}
    assert fleetagg.at_stop(whole, None)['stale_host'] == 6   # no line before the stop
    s = fleetagg.run_summary({'r1': whole, 'r2': None}, {}, {'r1': running, 'r2': None})
    assert s['pooled']['commands'] == 9_998 and s['pooled']['dropped'] == 8
    run = s['pooled_running']
    # the same commands, only the 4 drops before the stop (3 host's own, 1 simulation's)
    assert (run['commands'], run['dropped'], run['by_reason']['stale_host']) == (9_998, 4, 3)
    assert s['pooled_at_stop']['stale_host'] == 3 and s['robots']['r2']['at_stop'] is None
    row = fleetagg.run_rows({'drops': s}, '1')[0]
    assert row[2].endswith('; at the stop: stale_device 1, stale_host 3')
    assert fleetagg.summarize([{'drops': s}])['running_host_per_10k']['median'] == \
        1e4 * 3 / 9_998


def test_the_bridges_late_cmd_vel_and_guard_stops_are_read_from_its_log():
    log = ('[bridge] [WARN] [1.2] [r1.m4k_bridge]: cmd_vel processed 0.51 s after it arrived '
           '(> cmd_vel_timeout 0.5 s: a stall?): dropped (3 so far)\n'
           '[bridge] [WARN] [1.3] [r1.m4k_bridge]: flight recorder: guard_stop (collision guard '
           'stopped forward motion (flags 0xa)): 551 messages -> /tmp/x\n'
           '[bridge] [WARN] [1.4] [r1.m4k_bridge]: cmd_vel processed 0.70 s after it arrived '
           '(> cmd_vel_timeout 0.5 s: a stall?): dropped (8 so far)\n')
    assert fleetagg.bridge_counts(log) == {'cmd_vel_late': 8, 'guard_stops': 1}
    assert fleetagg.bridge_counts('') == {'cmd_vel_late': 0, 'guard_stops': 0}
    run = dict(_run(0, 0, 6.0), bridge={'r1': {'cmd_vel_late': 8, 'guard_stops': 1,
                                                'cmd_vel_sent': 1200}})
    rows = fleetagg.run_rows(run, '1')
    assert rows[0][4] == '8 of 1200 late; 1 guard stops' == rows[1][4]
    assert fleetagg.run_rows(_run(0, 0, 6.0), '1')[0][4] == '-'


def test_a_bringup_that_does_not_stop_is_named_with_what_it_still_runs(tmp_path):
    # a stack that ignores its stop signal is killed, and the error says what its process
    # tree was doing at the kill (the fleet's stop once took over 60 s, with no trace)
    argv = [sys.executable, '-c', 'import signal, time; '
            'signal.signal(signal.SIGTERM, signal.SIG_IGN); '
            'print("handler " + "set", flush=True); time.sleep(60)']
    k = Child('r9', argv, output=Output(log_path=str(tmp_path / 'r9.log')),
              stopping=Stopping(sig=signal.SIGTERM, timeout=0.5, must_end=True)).start()
    end = time.monotonic() + 10
    while 'handler set' not in (tmp_path / 'r9.log').read_text() and time.monotonic() < end:
        time.sleep(0.02)
    pid = k.pid
    out = {'errors': []}
    fleetdrops._stop_all({'r9': k}, out)
    assert len(out['errors']) == 1, out
    err = out['errors'][0]
    assert err.startswith('bringup r9 exited -9 (still running at the kill: {} S '.format(
        pid)), err                                  # the pid, sleeping, and its command line
    assert 'time.sleep' in err and err.rstrip().endswith('handler set'), err
