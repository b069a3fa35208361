"""The flight recorder's pure parts: the ring's bounds, trigger edges, the rate limit, a dump.

The dump is read back with the ``mcap`` package's reader and its ``metadata.yaml`` with
PyYAML, not with the code that wrote them.
"""

from __future__ import annotations

import os
import random

from mcap.reader import make_reader
import pytest
import yaml

from m4k_bridge import flightrec as fr
from m4k_rt import protocol

S = 1_000_000_000


def test_ring_never_exceeds_its_byte_cap_under_a_flood():
    cap = 64 * 1024
    ring = fr.Ring(span_s=3600.0, max_bytes=cap)   # age never evicts here: only bytes do
    rng = random.Random(7)
    t = 0
    for _ in range(20_000):
        t += rng.randrange(1, 1000)
        ring.add(t, 'odom', bytes(rng.randrange(0, 4000)))
        assert ring.bytes <= cap
    assert ring.peak_bytes <= cap
    assert ring.evicted_bytes > 0 and ring.evicted_age == 0
    # what it holds is the newest messages, contiguous up to the last one added
    snap = ring.snapshot()
    assert snap[-1][0] == t
    assert sum(len(d) + fr.ENTRY_OVERHEAD for _, _, d in snap) == ring.bytes


def test_ring_refuses_one_message_larger_than_the_cap_and_keeps_the_rest():
    ring = fr.Ring(10.0, 4096)
    ring.add(1, 'a', b'x' * 100)
    assert not ring.add(2, 'b', b'x' * 5000)
    assert ring.refused == 1 and [k for _, k, _ in ring.snapshot()] == ['a']


def test_ring_forgets_by_age():
    ring = fr.Ring(span_s=10.0, max_bytes=1 << 20)
    for i in range(30):
        ring.add(i * S, 'odom', b'1234')
    times = [t for t, _, _ in ring.snapshot()]
    assert times[0] == 19 * S and times[-1] == 29 * S
    assert ring.evicted_age == 19 and ring.evicted_bytes == 0
    assert [t for t, _, _ in ring.snapshot(25 * S)] == [25 * S, 26 * S, 27 * S, 28 * S, 29 * S]


def test_ring_rejects_nonsense_bounds():
    with pytest.raises(ValueError):
        fr.Ring(0.0, 1 << 20)
    with pytest.raises(ValueError):
        fr.Ring(10.0, fr.ENTRY_OVERHEAD)


def test_flags_trigger_on_rising_edges_only():
    F = protocol.OdomFlag
    tr = fr.Triggers()
    assert tr.on_odometry(F.E_STOP) == []                # the first one is the reference
    assert tr.on_odometry(F.E_STOP) == []
    assert tr.on_odometry(0) == []
    kinds = [k for k, _ in tr.on_odometry(F.E_STOP | F.GUARD)]
    assert kinds == ['e_stop', 'guard_stop']
    assert [k for k, _ in tr.on_odometry(F.E_STOP | F.GUARD | F.MOTOR_FAULT)] == ['motor_fault']
    assert [k for k, _ in tr.on_odometry(F.ESTOP_OPEN)] == ['e_stop']
    assert tr.on_odometry(F.SLOWDOWN | F.BRAKING | F.CLAMPED) == []


def test_the_guard_flag_rising_at_rest_stopped_nothing_and_dumps_nothing():
    # What every start-up does: the first ODOMETRY (motor not yet heard), then the guard's
    # fail-safe hold while its sensors have not reported (at rest), then clear.
    F = protocol.OdomFlag
    tr = fr.Triggers()
    assert tr.on_odometry(F.MOTOR_STALE, 0.0) == []
    assert tr.on_odometry(F.GUARD, -0.002) == []            # standing: a state, not a stop
    assert tr.on_odometry(0, 0.003) == []
    assert tr.on_odometry(F.GUARD, 0.01) == []              # creeping below GUARD_MOVING_V
    assert tr.on_odometry(0, 0.3) == []
    assert [k for k, _ in tr.on_odometry(F.GUARD, 0.3)] == ['guard_stop']   # driving: a stop
    # the other latches are events whatever the speed
    assert [k for k, _ in tr.on_odometry(F.GUARD | F.E_STOP, 0.0)] == ['e_stop']


def _stats(samples, period_ns=10_000_000):
    return protocol.TaskStats('actuator', 0, 90, -1, period_ns, 100, 0, 0, 0, 0,
                              tuple(protocol.TaskSample(*s) for s in samples))


def test_a_cycle_past_its_deadline_triggers_naming_the_task():
    tr = fr.Triggers()
    p = 10_000_000
    assert tr.on_task_stats(_stats([(0, 100, 5_000_000, 1), (p, p + 100, p + 9_000_000, 1)])) \
        == []
    found = tr.on_task_stats(_stats([(0, 100, 12_500_000, 1)]))
    assert found[0][0] == 'deadline_miss' and 'actuator' in found[0][1]
    assert '2.50 ms' in found[0][1]


def test_a_device_entering_error_triggers_once():
    tr = fr.Triggers()
    st = protocol.DeviceStatus

    def dev(level):
        return st('sonar', 3, level, 4, 110)
    assert tr.on_device_status(dev(protocol.LEVEL_OK)) == []
    assert [k for k, _ in tr.on_device_status(dev(protocol.LEVEL_ERROR))] == ['device_fault']
    assert tr.on_device_status(dev(protocol.LEVEL_ERROR)) == []
    assert tr.on_device_status(dev(protocol.LEVEL_WARN)) == []


def test_rate_limit_is_per_kind():
    rl = fr.RateLimit(30.0)
    assert rl.allow('e_stop', 0)
    assert not rl.allow('e_stop', 29 * S)
    assert rl.allow('guard_stop', 29 * S)
    assert rl.allow('e_stop', 31 * S)
    assert rl.suppressed['e_stop'] == 1


def _share(tmp_path):
    """A share/ tree with std_msgs/String's definition, as the interface packages install it."""
    msg = tmp_path / 'share' / 'std_msgs' / 'msg'
    msg.mkdir(parents=True)
    (msg / 'String.msg').write_text('string data\n')
    return lambda pkg: str(tmp_path / 'share' / pkg)


def test_a_dump_holds_the_window_before_and_after_with_the_trigger_in_metadata(tmp_path):
    ring = fr.Ring(13.0, 1 << 20)
    hi = b'\x00\x01\x00\x00\x03\x00\x00\x00hi\x00'
    t0 = 1_700_000_000 * S
    for i in range(150):                                 # 15 s at 10 Hz
        ring.add(t0 + i * S // 10, 'chatter', hi)
    ring.add(t0, 'unknown_key', hi)                      # not a declared topic: left out
    spec = fr.TopicSpec('/chatter', 'std_msgs/msg/String', [{'history': 'keep_last'}], '')
    out = tmp_path / 'dumps'
    d = fr.Dumper(ring, {'chatter': spec}, str(out), pre_s=10.0, post_s=2.0,
                  share=_share(tmp_path))
    try:
        trig = fr.Trigger('e_stop', 'e-stop latch engaged', t0 + 12 * S, 0)
        path = d.dump(trig)
    finally:
        d.close()
    assert os.path.basename(path).startswith('flight_') and path.endswith('_e_stop')
    bag = os.path.join(path, os.path.basename(path) + '_0.mcap')
    with open(bag, 'rb') as f:
        times = [m.log_time for _, ch, m in make_reader(f).iter_messages()
                 if ch.topic == '/chatter']
    assert times[0] == t0 + 2 * S and times[-1] == t0 + 149 * S // 10
    assert len(times) == 130                             # 2.0 s .. 14.9 s
    with open(os.path.join(path, 'metadata.yaml'), encoding='utf-8') as f:
        meta = yaml.safe_load(f)['rosbag2_bagfile_information']
    assert meta['message_count'] == 130
    cd = meta['custom_data']
    assert cd['m4k.flight_recorder.trigger'] == 'e_stop'
    assert cd['m4k.flight_recorder.detail'] == 'e-stop latch engaged'
    assert cd['m4k.flight_recorder.trigger_time_ns'] == str(t0 + 12 * S)
