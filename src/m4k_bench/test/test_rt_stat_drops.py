"""rt_stat's driver-host drop table, from the HOST_DROPS datagrams the monitor forwards (pure)."""

from m4k_bench import recorder, rt_stat
from m4k_rt import protocol

K = protocol.Kind


def test_rt_stat_prints_each_devices_host_drops_by_reason_from_the_latest_report():
    rec = recorder.Recorder()
    assert 'SERVED' not in rt_stat.format_stat(rec)          # no report: no table
    for data in (protocol.encode(K.HOST_DROPS, 1, 5, 'motor', 10, 1, 0, 0, 0, 0, 0, 0),
                 protocol.encode(K.HOST_DROPS, 2, 6, 'motor', 9_990, 7, 1, 0, 2, 0, 0, 3),
                 protocol.encode(K.HOST_DROPS, 3, 7, 'imu', 500, 0, 0, 0, 0, 4, 0, 0)):
        assert rec.feed(data) == K.HOST_DROPS
    assert rec.ignored == 0
    lines = rt_stat.format_stat(rec).splitlines()
    head = lines.index(next(ln for ln in lines if ln.startswith('DEVICE')))
    assert lines[head].split() == ['DEVICE', 'SERVED', 'STALE_HOST', 'STALE_DEVICE', 'MALFORMED',
                                   'UNEXPECTED', 'INACTIVE', 'ENCODE', 'REPLY_LOST']
    assert lines[head + 1].split() == ['imu', '500', '0', '0', '0', '0', '4', '0', '0']
    assert lines[head + 2].split() == ['motor', '9990', '7', '1', '0', '2', '0', '0', '3']
