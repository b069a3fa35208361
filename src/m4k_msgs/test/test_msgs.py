"""The m4k_msgs interfaces are generated, importable and serialize losslessly."""

import pytest
from rclpy.serialization import deserialize_message, serialize_message

from m4k_msgs.msg import RtStatus, TaskTiming, TimingStats, XddpPort


def _status() -> RtStatus:
    msg = RtStatus()
    msg.header.frame_id = 'base_link'
    msg.policy = RtStatus.POLICY_FIFO
    msg.memory_locked = True
    msg.degraded_reasons = ['cpu_dma_latency: EACCES']
    task = TaskTiming(name='actuator', priority=90, cpu=-1, period=0.01, cycles=1234)
    task.release_latency = TimingStats(samples=100, avg=5e-5, std=1e-5, min=2e-5, max=4e-4,
                                       p50=4e-5, p99=2e-4, p999=3.5e-4)
    task.overruns = 2
    task.last_forbidden_call = 'open at tasks/led.py:42 in body'
    msg.tasks = [task]
    msg.ports = [XddpPort(port=1, label='cmd', linked=True, sent=10, dropped_full=1)]
    msg.total_utilization = 0.0947
    msg.liu_layland_bound = 0.743
    msg.schedulable = True
    return msg


def test_policy_constants_are_distinct():
    assert RtStatus.POLICY_OTHER == 0
    assert RtStatus.POLICY_FIFO == 1


def test_status_round_trips_through_cdr_serialization():
    msg = _status()
    back = deserialize_message(serialize_message(msg), RtStatus)
    assert back == msg
    assert back.tasks[0].release_latency.p99 == pytest.approx(2e-4)
    assert back.ports[0].label == 'cmd'


def test_task_timing_carries_the_documented_contract():
    # The public contract of issue 2: every field a consumer relies on is there, with its type.
    fields = TaskTiming.get_fields_and_field_types()
    for name in ('name', 'priority', 'cpu', 'period', 'cycles', 'overruns', 'deadline_misses',
                 'voluntary_switches', 'involuntary_switches', 'page_faults', 'forbidden_calls'):
        assert name in fields, name
    for stats in ('release_latency', 'jitter', 'response_time', 'period_measured'):
        assert fields[stats] == 'm4k_msgs/TimingStats'
    assert set(TimingStats.get_fields_and_field_types()) >= {
        'avg', 'max', 'min', 'std', 'p99', 'samples'}
    status = RtStatus.get_fields_and_field_types()
    assert status['tasks'] == 'sequence<m4k_msgs/TaskTiming>'
    assert status['liu_layland_bound'] == 'double' and status['schedulable'] == 'boolean'
