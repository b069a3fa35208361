"""Fuzz the SCIP 2.0 framer and scan decoder: any bytes, any chunking, only typed errors.

Properties, for arbitrary and for damaged-valid input:

* ``ScipParser.feed`` never raises; it returns Responses and ``ScipError`` instances only, its
  buffer stays bounded and its counters add up;
* ``parse_scan`` / ``parse_params`` raise nothing but ``ScipError``;
* a single flipped bit anywhere in a valid scan never yields a scan with different ranges
  (the 6-bit line sum misses +-64 changes, but those leave the SCIP character set).

Run with atheris (coverage-guided, optional) as a script::

    python src/m4k_drivers/test/test_fuzz_scip.py -atheris_runs=200000
"""

import sys

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np

from m4k_drivers.lrf import scip
from m4k_testing import examples

GD_ECHO = 'GD0044072501'
N_STEPS = 725 - 44 + 1


def _valid_scan(seed: int = 0, cluster: int = 1) -> tuple[bytes, np.ndarray]:
    rng = np.random.default_rng(seed)
    count = (N_STEPS + cluster - 1) // cluster
    ranges = rng.integers(0, 5600, count)
    return scip.format_scan('GD', 44, 725, cluster, 123456, ranges), ranges


VALID, VALID_RANGES = _valid_scan()
PP = scip.format_response(b'PP', '00', [b'MODL:URG-04LX', b'DMIN:20', b'DMAX:5600',
                                        b'ARES:1024', b'AMIN:44', b'AMAX:725', b'AFRT:384',
                                        b'SCAN:600'], param_lines=True)


def check_stream(chunks) -> list:
    """Feed ``chunks``; check the parser's invariants; return what it produced."""
    p = scip.ScipParser()
    out = []
    for c in chunks:
        got = p.feed(bytes(c))
        assert isinstance(got, list)
        for item in got:
            assert isinstance(item, (scip.Response, scip.ScipError)), item
        out += got
        assert len(p._buf) <= p.MAX_LINE + 1, len(p._buf)
        assert len(p._lines) <= p.MAX_LINES
    errors = [x for x in out if isinstance(x, scip.ScipError)]
    assert p.responses == len(out) - len(errors)
    assert p.checksum_errors + p.format_errors >= len(errors)
    for r in out:
        if isinstance(r, scip.Response):
            decode_response(r)
    return out


def decode_response(r: scip.Response):
    """Decode a Response the way the driver would; only ScipError may escape."""
    try:
        if scip.is_scan(r):
            s = scip.parse_scan(r)
            assert s.count == s.ranges.size and s.ranges.dtype == np.uint32
            assert 0 <= s.timestamp < scip.TIMESTAMP_MODULO
            return s
        if r.command in scip.PARAM_COMMANDS:
            params = scip.parse_params(r)
            if r.command == 'PP':
                scip.SensorSpec.from_params(params)
            return params
        return r.check()
    except scip.ScipError:
        return None


def _chunked(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({c % (len(data) + 1) for c in cuts})
    out, prev = [], 0
    for c in points + [len(data)]:
        out.append(data[prev:c])
        prev = c
    return out


@settings(max_examples=examples(300))
@given(st.lists(st.binary(max_size=300), max_size=8))
def test_random_bytes_never_raise(chunks):
    check_stream(chunks)


_ALPHABET = b'\n\r;:0123456789GDMSPVIBQTRC0?@O_o\x7f\x00\xff' + bytes(range(0x30, 0x70))


@settings(max_examples=examples(300))
@given(st.lists(st.sampled_from(list(_ALPHABET)), max_size=600),
       st.lists(st.integers(0, 10_000), max_size=6))
def test_scip_alphabet_soup_never_raises(data, cuts):
    # Bytes drawn from the protocol's own alphabet reach deeper than uniform random ones.
    check_stream(_chunked(b'GD0044072501\n00P\n' + bytes(data), cuts))


@settings(max_examples=examples(300))
@given(st.integers(0, len(VALID) * 8 - 1), st.lists(st.integers(0, 10_000), max_size=5))
def test_single_bit_flip_never_yields_different_ranges(bit, cuts):
    data = bytearray(VALID)
    data[bit // 8] ^= 1 << (bit % 8)
    for r in check_stream(_chunked(bytes(data), cuts)):
        if isinstance(r, scip.Response) and scip.is_scan(r):
            s = decode_response(r)
            if s is not None:
                assert np.array_equal(s.ranges, VALID_RANGES), bit


def mutate(b: bytearray, draw) -> None:
    """Apply 1..6 random edits (replace, delete, insert, duplicate) to ``b`` in place."""
    for _ in range(draw(st.integers(1, 6))):
        # A deletion may empty the buffer: then only an insertion applies (and there is no
        # index 0..len-1 to draw -- the flaky InvalidArgument of issue 10).
        op = draw(st.integers(0, 3)) if b else 2
        i = draw(st.integers(0, max(len(b) - 1, 0)))
        if op == 0:
            b[i] = draw(st.integers(0, 255))
        elif op == 1:
            del b[i:i + draw(st.integers(1, 80))]
        elif op == 2:
            b[i:i] = draw(st.binary(min_size=1, max_size=40))
        elif len(b) > 2:
            b[i:i] = b[draw(st.integers(0, len(b) - 2)):][:draw(st.integers(1, 200))]


@settings(max_examples=examples(200))
@given(st.data())
def test_mutated_responses_only_raise_scip_errors(data):
    base = data.draw(st.sampled_from([VALID, PP, _valid_scan(1, 3)[0],
                                      scip.format_scan('MD', 44, 725, 1, 5, [1000] * N_STEPS,
                                                       remaining=3, tag=b'x')]))
    b = bytearray(base)
    mutate(b, data.draw)
    check_stream([bytes(b), b'\n\n'])


def test_mutation_after_a_deletion_emptied_the_buffer_inserts():
    # Scripted draws: 2 edits; delete 80 bytes at 0 (empties the 4-byte buffer); then the
    # next edit draws its index from 0..0 and must insert.
    script = iter([2, 1, 0, 80, 0, b'QT\n'])
    b = bytearray(b'00P\n')
    mutate(b, lambda strategy: next(script))
    assert b == bytearray(b'QT\n')
    assert next(script, None) is None


def test_valid_stream_survives_garbage_between_responses():
    garbage = bytes(range(256)) * 3
    out = check_stream([garbage, VALID, garbage + b'\n\n', VALID[:100], VALID[100:], PP])
    scans = [decode_response(r) for r in out if isinstance(r, scip.Response)
             and scip.is_scan(r)]
    assert len(scans) == 2 and all(np.array_equal(s.ranges, VALID_RANGES) for s in scans)


def atheris_main() -> None:  # pragma: no cover -- run by hand
    """Coverage-guided fuzzing of the framer + decoders with atheris."""
    import atheris

    def one(data: bytes) -> None:
        fdp = atheris.FuzzedDataProvider(data)
        cuts = [fdp.ConsumeIntInRange(0, 4096) for _ in range(fdp.ConsumeIntInRange(0, 4))]
        payload = fdp.ConsumeBytes(fdp.remaining_bytes())
        prefix = VALID[:fdp.ConsumeIntInRange(0, 40)] if cuts else b''
        check_stream(_chunked(prefix + payload, cuts))
    atheris.instrument_all()  # coverage feedback from the already imported scip module
    atheris.Setup(sys.argv, one)
    atheris.Fuzz()


if __name__ == '__main__':
    atheris_main()
