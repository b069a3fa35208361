"""Tests of the NRT timing recorder (in-process datagram lists, no sockets)."""

import csv
import json

import pytest

from m4k_bench import recorder
from m4k_rt import protocol

MS = 1_000_000


def _batch(name, index, prio, period, first_cycle, n, response=100_000, seq=0, late=None,
           forbidden=0):
    samples = []
    for i in range(first_cycle, first_cycle + n):
        rel = 10**9 + i * period
        start = rel + 50_000 + (10_000 if i % 2 else 0)
        end = start + response
        if late is not None and i == late:
            end = rel + period + 1
        samples.append((rel, start, end, 1))
    buf = bytearray(protocol.MAX_DATAGRAM)
    size = protocol.encode_task_stats_into(buf, 0, seq, 0, name, index, prio, -1, period,
                                           first_cycle + n, first_cycle + n, 3, 7, forbidden,
                                           samples)
    return bytes(buf[:size])


def _health(name, index, body_errors=0):
    buf = bytearray(128)
    n = protocol.encode_task_health_into(buf, 0, 0, 0, name, index, 0, 0, body_errors, 0, 2, 0,
                                         1, 90, 0)
    return bytes(buf[:n])


def _site(name):
    buf = bytearray(256)
    n = protocol.encode_forbidden_site_into(buf, 0, 0, 0, name, 2, protocol.EVENT_CODES['open'],
                                            5, 42, 5, '/x/test_body.py', 'body')
    return bytes(buf[:n])


def test_summary_computes_stats_counters_and_tests():
    rec = recorder.Recorder()
    rec.feed_all([_batch('actuator', 0, 90, 10 * MS, 0, 50),
                  _batch('actuator', 0, 90, 10 * MS, 50, 50, late=70),
                  _batch('led', 2, 80, 20 * MS, 0, 40, response=500_000, forbidden=5),
                  _health('actuator', 0, body_errors=3), _site('led'),
                  protocol.encode(protocol.Kind.RT_STATUS, 0, 0, 1, 1, 0, 1, 0, 2, 40)])
    s = rec.summary()
    names = [t['name'] for t in s['tasks']]
    assert names == ['actuator', 'led']
    act = s['tasks'][0]
    assert act['samples'] == 100 and act['cycles'] == 100
    assert act['deadline_misses'] == 1 and act['overruns'] == 0
    assert act['latency_us']['min'] == pytest.approx(50.0)
    assert act['latency_us']['max'] == pytest.approx(60.0)
    assert act['period_ms_stats']['n'] == 99
    assert act['body_errors'] == 3 and act['nvcsw_extra'] == 2
    led = s['tasks'][1]
    assert led['forbidden_calls'] == 5
    assert led['forbidden_sites'][0]['file'].endswith('test_body.py')
    assert s['utilization']['liu_layland_bound'] == pytest.approx(0.8284, abs=1e-4)
    assert s['utilization']['per_task']['led'] == pytest.approx(0.025)
    # The late actuator cycle ended past its deadline (deadline_misses == 1): with its release
    # jitter (60 us) on top of its worst response, R = J + C > T, and the LED task no longer
    # fits either.
    assert [r['schedulable'] for r in s['rta']] == [False, False]
    assert s['utilization_p999']['from'] == 'response p999'
    assert s['rt_status']['ntasks'] == 2


def test_duplicate_batches_from_two_ports_are_counted_once():
    rec = recorder.Recorder()
    b = _batch('imu', 1, 85, 10 * MS, 0, 20)
    rec.feed_all([b, b])
    assert len(rec.tasks['imu'].t_rel) == 20 and rec.tasks['imu'].duplicates == 20


def test_malformed_datagrams_are_counted_not_raised():
    rec = recorder.Recorder()
    assert rec.feed(b'garbage') == -1
    assert rec.feed(b'MK\x01\x40' + b'\x00' * 12) == -1
    assert rec.malformed == {'short': 1, 'length': 1}  # a FORBIDDEN_SITE header, no payload
    assert rec.summary()['tasks'] == []


def test_write_outputs_table_csv_and_json(tmp_path):
    rec = recorder.Recorder()
    rec.feed_all([_batch('sonar', 3, 75, 30 * MS, 0, 10), _site('sonar')])
    paths = rec.write(str(tmp_path))
    md = open(paths['table1']).read()
    assert '| sonar | Ave | 30.001 | 100.000 | 55.000 |' in md
    assert 'open /x/test_body.py:42 (body)' in md
    assert 'Liu-Layland bound 100.0 % for 1 tasks: schedulable' in md
    rows = list(csv.reader(open(paths['csv'])))
    assert rows[0][0] == 'task' and len(rows) == 11 and rows[1][0] == 'sonar'
    summ = json.load(open(paths['json']))
    assert summ['tasks'][0]['samples'] == 10


class _FakeLink:
    def __init__(self, items):
        self.items = list(items)

    def read(self, timeout):
        return self.items.pop(0) if self.items else None


def test_record_link_reads_until_duration():
    rec = recorder.record_link(_FakeLink([_batch('lrf', 4, 70, 200 * MS, 0, 3)]), 0.05,
                               recorder.Recorder(), poll_s=0.01)
    assert len(rec.tasks['lrf'].t_rel) == 3


def test_warmup_cycles_are_left_out_of_statistics_only():
    rec = recorder.Recorder(warmup_cycles=1)
    rec.feed(_batch('imu', 1, 85, 10 * MS, 0, 10, late=0))
    t = rec.summary()['tasks'][0]
    assert t['samples'] == 9 and t['deadline_misses'] == 0
    assert len(rec.tasks['imu'].t_rel) == 10
    assert rec.summary()['warmup_cycles_skipped'] == 1


def test_extra_voluntary_switches_come_from_task_stats_without_health():
    # TASK_HEALTH travels on the `stat` port only; a recorder on `status` still gets the
    # mode-switch analogue from TASK_STATS's cumulative counters (one wait per cycle is normal).
    buf = bytearray(protocol.MAX_DATAGRAM)
    samples = [(10**9 + i * 20 * MS, 10**9 + i * 20 * MS + 1000, 10**9 + i * 20 * MS + 9000, 1)
               for i in range(40)]
    size = protocol.encode_task_stats_into(buf, 0, 0, 0, 'led', 2, 80, -1, 20 * MS, 40, 52, 0,
                                           0, 0, samples)
    rec = recorder.Recorder()
    rec.feed_all([bytes(buf[:size])])
    (led,) = rec.summary()['tasks']
    assert led['nvcsw_extra'] == 12
