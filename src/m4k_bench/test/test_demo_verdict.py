"""The demo's verdict rests on the simulator's ground truth, never on the robot's odometry."""

from m4k_bench import demo


def test_without_the_world_report_the_demo_fails_saying_so():
    v = demo.judge(True, None)
    assert v['passed'] is False and v['contacts'] is None
    assert 'no ground truth' in v['failure']


def test_the_simulators_contact_counter_decides():
    clean = {'collisions': 0, 'in_contact': False}
    assert demo.judge(True, clean) == {
        'contacts': 0, 'passed': True, 'failure': None,
        'contacts_source': demo.judge(True, clean)['contacts_source']}
    assert demo.judge(True, {'collisions': 2, 'in_contact': False})['passed'] is False
    assert demo.judge(True, {'collisions': 0, 'in_contact': True})['contacts'] == 1
    assert demo.judge(False, clean)['passed'] is False
