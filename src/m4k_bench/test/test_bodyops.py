"""bodyops counts what the RT bodies run per cycle on real sockets (counts, never times)."""

from m4k_bench.benchlib import bodyops


def test_every_body_runs_its_cycles_and_counts_are_reproducible():
    first = bodyops.count_ops(cycles=20, warmup=10)
    again = bodyops.count_ops(cycles=20, warmup=10)
    assert set(first) == set(bodyops.BODIES)
    for name, r in first.items():
        assert r['body_cycles'] == 30, name            # warm-up + counted cycles all ran
        assert r['opcodes'] > 0 and r['calls'] > 0, name
        assert r['functions'], name
        # the same code on the same inputs and the same virtual clock: the same count, exactly
        assert again[name]['opcodes'] == r['opcodes'], name
        assert again[name]['calls'] == r['calls'], name
    # the actuator decoded its encoder replies and ran the controller
    assert any(k.endswith(':step') and k.startswith('base.py')
               for k in first['actuator']['functions'])
    assert any(k.startswith('protocol.py:decode_from') for k in first['actuator']['functions'])
