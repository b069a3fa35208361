"""The soak's verdicts on counters whose answers were worked out by hand."""

from m4k_bench import soak


def test_every_task_is_judged_on_overruns_plus_misses_against_cyclictest_late_samples():
    tasks = {'actuator': {'overruns': 3, 'deadline_misses': 0},   # 3 <= 4
             'imu': {'overruns': 2, 'deadline_misses': 3},        # 5 > 4: judged, fails
             'lrf': {'overruns': 0, 'deadline_misses': 0}}
    v = soak.late_verdict(tasks, 4)
    assert v['tasks'] == {'actuator': {'late': 3, 'ok': True}, 'imu': {'late': 5, 'ok': False},
                          'lrf': {'late': 0, 'ok': True}}
    assert v['all_ok'] is False and v['cyclictest_late'] == 4
    assert soak.late_verdict({'actuator': tasks['actuator']}, 4)['all_ok'] is True


def test_without_cyclictest_or_counters_there_is_no_verdict():
    assert soak.late_verdict({'a': {'overruns': 1, 'deadline_misses': 0}}, None)['all_ok'] is None
    v = soak.late_verdict({'a': {'overruns': None, 'deadline_misses': 0}}, 3)
    assert v['tasks']['a'] == {'late': None, 'ok': None} and v['all_ok'] is None
    assert soak.late_verdict({}, 3)['all_ok'] is None
