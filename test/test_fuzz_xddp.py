"""Fuzz every XDDP port of a real rt_core process: nothing crashes, every bad datagram counts.

Bounded form of ``make fuzz`` (``m4k_bench.fuzz``, up to 1e5 datagrams per port): rt_core runs
as its own process; a sender per port writes a deterministic stream of valid, mutated, random
and oversize datagrams (``status``/``stat`` through the fuzzer's own links); the counters rt_core
reports over XDDP (PORT_STATS, TASK_HEALTH) must match the prediction exactly. Timing verdicts
(cycle counts, overruns) are the benchmark's and are not asserted here.
"""

import re

from m4k_bench import fuzz, fuzzstream
from m4k_rt import protocol

SAMPLE = 40  # datagrams per port here; make fuzz sends up to 1e5


def _args(tmp_path, *extra):
    overlay = tmp_path / 'fast.yaml'
    # Configured periods, except a 100 ms monitor: a port settles after one more batch.
    overlay.write_text('runtime: {cpu_dma_latency: false, start_delay_ms: 10}\n'
                       'tasks: {monitor: {period_ms: 100}}\n')
    return fuzz._parse(['--count', str(SAMPLE), '--seed', '7', '--seconds-per-port', '5',
                        '--quiet-s', '1', '--config', str(overlay),
                        '--results', str(tmp_path / 'out'), *extra])


def test_fuzz_stream_covers_every_input_class():
    acc = fuzzstream.ACCEPTS['cmd']
    seen = {fuzzstream.classify(d, acc, protocol.MAX_DATAGRAM)
            for d in fuzzstream.datagrams('cmd', 400, 3)}
    assert seen == {'oversize', 'malformed', 'unexpected', 'accepted'}
    reasons = set()
    for d in fuzzstream.datagrams('motor', 2000, 3):
        try:
            protocol.decode(d)
        except protocol.ProtocolError as exc:
            reasons.add(exc.reason)
    assert {'short', 'magic', 'version', 'kind', 'length', 'nonfinite', 'range'} <= reasons
    assert list(fuzzstream.datagrams('led', 50, 9)) == list(fuzzstream.datagrams('led', 50, 9))
    # Classified a chunk at a time, any prefix totals as the whole stream cut there would.
    pred = fuzzstream.Predictor('cmd', 3, protocol.MAX_DATAGRAM, 400)
    assert pred.advance(100) == 100
    assert pred.expectation(50) == fuzzstream.expect('cmd', 50, 3, protocol.MAX_DATAGRAM)
    assert pred.expectation(400) == fuzzstream.expect('cmd', 400, 3, protocol.MAX_DATAGRAM)
    assert pred.advance(100) == 400     # the stream ends at its limit
    # Every kind can be generated valid (a layout change without a generator would hang).
    for kind in protocol.Kind:
        protocol.decode(fuzzstream.valid_datagram(fuzzstream.random.Random(1), kind))


def test_rt_core_counts_every_fuzzed_datagram_on_every_port_and_keeps_cycling(tmp_path):
    args = _args(tmp_path)
    out = fuzz.run(args)
    ports = {p['label']: p for p in out['ports']}
    assert set(ports) == set(fuzzstream.ACCEPTS), 'ACCEPTS must cover every configured port'
    for label, p in ports.items():
        e = p['expected']
        assert p['ok'], (label, p['problems'])
        assert e['sent'] == SAMPLE and p['received'] == e['sent'] - e['oversize']
        assert (p['malformed'], p['oversize'], p['unexpected']) == (
            e['malformed'], e['oversize'], e['unexpected'])
    # The ports the RT side only writes were judged too: what a peer writes there counts.
    for label in ('status', 'stat', 'imu_out', 'sonar_out', 'lrf_out'):
        assert ports[label]['malformed'] > 0 and ports[label]['unexpected'] > 0, label
    assert sum(p['expected']['accepted'] for p in ports.values()) > 0
    rc = out['rt_core']
    assert rc['alive_at_end'] and rc['exit'] == 0, rc['log_tail']
    assert out['rt_status']['policy'] == 1 and out['rt_status']['mem_locked'] == 1
    for name, t in out['tasks'].items():
        assert t['campaign']['cycles'] > 0 and t['body_errors'] == 0, (name, t)
    assert 'port ' not in ' '.join(out['failures']), out['failures']
    fuzz._write_results(str(tmp_path / 'out'), out)
    report = (tmp_path / 'out' / 'report.md').read_text()
    assert '| stat | monitor | {} |'.format(SAMPLE) in report


def test_a_wrong_prediction_fails_the_verdict(tmp_path):
    # Claim led_in takes nothing: every valid LED override is then predicted "unexpected",
    # but rt_core's LED body accepts them, so its TASK_HEALTH.unexpected stays lower.
    wrong = dict(fuzzstream.ACCEPTS, led_in=frozenset())
    out = fuzz.run(_args(tmp_path, '--ports', 'led_in'), accepts=wrong)
    (p,) = out['ports']
    assert not p['ok'] and not out['ok']
    m = re.fullmatch(r'unexpected: expected (\d+), counted (\d+)', p['problems'][0])
    assert m and int(m.group(1)) > int(m.group(2)), p['problems']
    assert any(f.startswith('port led_in: unexpected') for f in out['failures'])
    assert out['rt_core']['alive_at_end'] and out['rt_core']['exit'] == 0
