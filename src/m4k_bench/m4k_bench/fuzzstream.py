"""The fuzz stream: random, mutated and oversize datagrams per port, and what the RT side must do.

Pure (no I/O): the stream of a port is a function of (seed, port label) only, so the sender
processes of ``fuzz`` generate it and the checker regenerates it to predict, for every
datagram, the RT side's answer (:func:`classify`):

* longer than the owning body's receive buffer -> ``dropped_oversize`` on the socket;
* rejected by ``protocol.decode`` -> ``malformed`` on the socket;
* valid, but a kind the port does not carry (:data:`ACCEPTS`) -> the body's ``unexpected``
  counter (TASK_HEALTH.unexpected);
* valid and expected -> consumed by the body.
"""

from __future__ import annotations

import dataclasses
import math
import random
import struct
from typing import Any, Iterator, Mapping, Sequence

from m4k_rt import protocol
from m4k_rt.protocol import Kind

__all__ = ['ACCEPTS', 'Expectation', 'Predictor', 'classify', 'datagrams', 'expect', 'mutate',
           'one_datagram', 'valid_datagram']

K = Kind
# What each port's RT body consumes (docs/internals.md, "Ports"); anything else valid is
# "unexpected". Ports the RT side only writes accept nothing.
ACCEPTS: Mapping[str, frozenset[int]] = {
    'status': frozenset(), 'stat': frozenset(),
    'cmd': frozenset({K.VELOCITY_CMD, K.E_STOP, K.ODOM_RESET, K.SET_POSE}),
    'motor': frozenset({K.ENCODERS, K.DEVICE_STATUS, K.HOST_DROPS}),
    'imu': frozenset({K.IMU, K.DEVICE_STATUS, K.HOST_DROPS}), 'imu_out': frozenset(),
    'led': frozenset({K.DEVICE_STATUS, K.HOST_DROPS}), 'led_in': frozenset({K.LED}),
    'sonar': frozenset({K.SONAR, K.DEVICE_STATUS, K.HOST_DROPS}), 'sonar_out': frozenset(),
    'lrf': frozenset({K.LASER_SCAN, K.DEVICE_STATUS, K.HOST_DROPS}), 'lrf_out': frozenset(),
}

_F64 = (0.0, -0.0, 1.0, -1.0, 0.25, 2.0, -2.0, 1e308, -1e308, 5e-324, -5e-324, 1e-9, 3.4e38,
        math.pi, 1e6, -1e6)
_F32 = (0.0, -0.0, 1.0, -1.0, 0.25, 5.6, 0.02, 3.4e38, -3.4e38, 1e-45, 1e6, math.pi, 1e-3)
_NONFINITE = (math.nan, math.inf, -math.inf, -math.nan)


def _f64(rng: random.Random) -> float:
    return rng.choice(_F64) if rng.random() < 0.5 else rng.gauss(0.0, 10.0)


def _f32(rng: random.Random) -> float:
    return rng.choice(_F32) if rng.random() < 0.5 else rng.uniform(-100.0, 100.0)


def _u(rng: random.Random, bits: int) -> int:
    return rng.choice((0, 1, (1 << bits) - 1, rng.getrandbits(bits)))


def _fields(rng: random.Random, kind: int) -> tuple[Any, ...]:
    f, g, u = _f64, _f32, _u
    if kind == K.VELOCITY_CMD:
        return (f(rng), f(rng))
    if kind == K.ODOMETRY:
        return tuple(f(rng) for _ in range(9)) + (u(rng, 32),)
    if kind == K.WHEEL_CMD:
        return (rng.randint(0, 1023), rng.randint(0, 1023), rng.randint(0, 1))
    if kind == K.ENCODERS:
        return (rng.randint(0, 4095), rng.randint(0, 4095), f(rng), f(rng), u(rng, 8))
    if kind == K.IMU:
        return tuple(f(rng) for _ in range(10)) + (u(rng, 8),)
    if kind == K.SONAR:
        return (abs(g(rng)), rng.randint(0, 3))
    if kind == K.LASER_SCAN:
        n = rng.choice((0, 1, 2, 683, rng.randint(0, protocol.MAX_SCAN_RANGES)))
        ranges = [rng.choice((0, 19, 20, 65535, rng.getrandbits(16))) for _ in range(n)]
        return tuple(g(rng) for _ in range(6)) + (rng.randint(0, 0xFFFFFF), ranges)
    if kind == K.LED:
        return (u(rng, 8), u(rng, 8), u(rng, 8), u(rng, 8), rng.randint(0, 1))
    if kind == K.TASK_STATS:
        n = rng.choice((0, 1, rng.randint(0, protocol.MAX_STATS_SAMPLES)))
        rows = [(rng.getrandbits(62), rng.getrandbits(62), rng.getrandbits(62), u(rng, 32))
                for _ in range(n)]
        return ('fuzz', u(rng, 8), rng.randint(-5, 99), rng.randint(-1, 3), u(rng, 32),
                u(rng, 32), u(rng, 32), u(rng, 32), u(rng, 32), u(rng, 32), rows)
    if kind == K.REQUEST:
        return (u(rng, 32), u(rng, 32))
    if kind == K.RT_STATUS:
        return tuple(rng.randint(0, 1) for _ in range(4)) + (u(rng, 32), u(rng, 32), u(rng, 32))
    if kind == K.DEVICE_STATUS:
        return ('dev', u(rng, 8), rng.randint(0, 3), u(rng, 32), u(rng, 32))
    if kind == K.PORT_STATS:
        return ('port', u(rng, 16), rng.randint(0, 1)) + tuple(u(rng, 64) for _ in range(7))
    if kind == K.E_STOP:
        return (rng.randint(0, 1),)
    if kind == K.ODOM_RESET:
        return (u(rng, 32),)
    if kind == K.APPLIED_VELOCITY:
        return (f(rng), f(rng))
    if kind == K.SET_POSE:
        return (u(rng, 32), f(rng), f(rng), f(rng))
    if kind == K.FAULT_RESET:
        return (u(rng, 32), rng.randint(0, 1))
    if kind == K.HOST_DROPS:
        return ('dev',) + tuple(u(rng, 64) for _ in range(8))
    if kind == K.SAFETY_STATUS:
        return tuple(f(rng) for _ in range(8)) + (u(rng, 32), u(rng, 32), u(rng, 32))
    if kind == K.FORBIDDEN_SITE:
        return ('fuzz', u(rng, 8), rng.choice(sorted(protocol.EVENT_NAMES)), u(rng, 32),
                u(rng, 32), u(rng, 32), '/fuzz/' * rng.randint(0, 12) + 'body.py', 'cycle')
    if kind == K.TASK_HEALTH:
        return ('fuzz', u(rng, 8)) + tuple(u(rng, 32) for _ in range(6)) + (
            rng.randint(0, 1), u(rng, 8), u(rng, 32))
    if kind == K.FAULT_TRACE:
        count = rng.randint(1, 0xFFFF)
        return (u(rng, 32), u(rng, 32), rng.randint(0, count - 1), count, u(rng, 63)) + tuple(
            f(rng) for _ in protocol.TRACE_FLOAT_FIELDS) + (
            rng.randint(0, protocol.TRACE_FLAGS_MAX),)
    raise ValueError('no field generator for kind {!r}'.format(kind))


def valid_datagram(rng: random.Random, kind: int | None = None) -> bytes:
    """Return a well-formed datagram of ``kind`` (random kind when None) with edgy values."""
    kind = rng.choice(list(Kind)) if kind is None else kind
    for _ in range(1000):  # a value outside the layout (f32 overflow, a range): draw again
        try:
            return protocol.encode(kind, rng.getrandbits(32), rng.getrandbits(63),
                                   *_fields(rng, kind))
        except protocol.ProtocolError as exc:
            err = exc
    raise ValueError('no valid {!r} in 1000 draws: {}'.format(kind, err))


def mutate(rng: random.Random, data: bytes) -> bytes:
    """Return ``data`` damaged one way: bit flips, cut, extension, header or float poison."""
    b = bytearray(data)
    op = rng.randrange(9)
    if op == 0:                                           # flip 1..8 bits
        for _ in range(rng.randint(1, 8)):
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
    elif op == 1:                                         # truncate
        del b[rng.randrange(1, len(b)):]
    elif op == 2:                                         # extend
        b += rng.randbytes(rng.randint(1, 64))
    elif op == 3:                                         # magic / version
        b[rng.choice((0, 1, 2))] = rng.getrandbits(8)
    elif op == 4:                                         # another (or unknown) kind
        b[3] = rng.choice([int(k) for k in Kind] + [0, max(Kind) + 1, 63, 255])  # + unknown
    elif op == 5 and len(b) >= 24:                        # NaN / inf into a double slot
        off = rng.randrange(16, len(b) - 7)
        struct.pack_into('<d', b, off, rng.choice(_NONFINITE))
    elif op == 6 and len(b) >= 20:                        # NaN / inf into a float slot
        off = rng.randrange(16, len(b) - 3)
        struct.pack_into('<f', b, off, rng.choice(_NONFINITE))
    elif op == 7:                                         # random payload behind the header
        b[16:] = rng.randbytes(max(0, len(b) - 16))
    elif len(b) >= 4:                                     # a random u32 anywhere (counts)
        struct.pack_into('<I', b, rng.randrange(len(b) - 3), rng.getrandbits(32))
    return bytes(b) if b else b'\x00'


def one_datagram(rng: random.Random, accepts: Sequence[int] = ()) -> bytes:
    """Return one fuzz datagram: valid, mutated valid, random bytes or oversize.

    Half of the valid and mutated ones are of a kind in ``accepts`` (what the port takes), so
    the bodies' handling of valid-but-extreme values gets exercised, not only the decoder.
    """
    r = rng.random()
    kind = rng.choice(accepts) if accepts and rng.random() < 0.5 else None
    if r < 0.25:
        return valid_datagram(rng, kind)
    if r < 0.80:
        return mutate(rng, valid_datagram(rng, kind))
    if r < 0.99:
        n = rng.choice((1, 15, 16, 17, rng.randint(1, 128)))
        head = struct.pack('<HBB', protocol.MAGIC, protocol.VERSION, rng.getrandbits(8))
        data = rng.randbytes(n)
        return (head + data[4:]) if rng.random() < 0.5 and n > 4 else data
    return rng.randbytes(rng.randint(4097, 6000))


def _seed(seed: int, label: str) -> int:
    return seed * 1_000_003 + sum(ord(c) * 31 ** i for i, c in enumerate(label))


def datagrams(label: str, count: int, seed: int) -> Iterator[bytes]:
    """Yield the deterministic fuzz stream of one port (same in sender and checker)."""
    rng = random.Random(_seed(seed, label))
    accepts = sorted(ACCEPTS.get(label, ()))
    for _ in range(count):
        yield one_datagram(rng, accepts)


def classify(data: bytes, accepts: frozenset[int], bufsize: int) -> str:
    """Return what the RT side must do with ``data``: oversize/malformed/unexpected/accepted."""
    if len(data) > bufsize:
        return 'oversize'
    try:
        hdr, _ = protocol.decode(data)
    except protocol.ProtocolError:
        return 'malformed'
    return 'accepted' if hdr.kind in accepts else 'unexpected'


@dataclasses.dataclass
class Expectation:
    """Predicted outcome counts of one port's fuzz stream."""

    sent: int = 0
    oversize: int = 0
    malformed: int = 0
    unexpected: int = 0
    accepted: int = 0


class Predictor:
    """Classify one port's stream a chunk at a time (the checker keeps reading in between).

    ``advance(n)`` classifies the next ``n`` datagrams of the stream (at most ``limit``);
    ``expectation(sent)`` totals the first ``sent`` -- the stream is the same prefix however
    many a sender got to write.
    """

    def __init__(self, label: str, seed: int, bufsize: int, limit: int,
                 accepts: Mapping[str, frozenset[int]] = ACCEPTS) -> None:
        """Prepare the stream of ``label`` (``limit`` datagrams at most)."""
        self._stream = datagrams(label, limit, seed)
        self._accepts = accepts.get(label, frozenset())
        self._bufsize = bufsize
        self.limit = limit
        self.classes: list[str] = []

    def advance(self, n: int) -> int:
        """Classify up to ``n`` more datagrams; return how many are classified in all."""
        for _ in range(n):
            d = next(self._stream, None)
            if d is None:
                break
            self.classes.append(classify(d, self._accepts, self._bufsize))
        return len(self.classes)

    def expectation(self, sent: int) -> Expectation:
        """Return the predicted counts of the first ``sent`` datagrams (classifying the rest)."""
        if len(self.classes) < sent:
            self.advance(sent - len(self.classes))
        e = Expectation(sent=sent)
        for what in self.classes[:sent]:
            setattr(e, what, getattr(e, what) + 1)
        return e


def expect(label: str, count: int, seed: int, bufsize: int,
           accepts: Mapping[str, frozenset[int]] = ACCEPTS) -> Expectation:
    """Classify the fuzz stream of ``label`` without sending it.

    ``accepts`` is what each port's body takes (:data:`ACCEPTS`; a test passes a wrong table
    to see the verdict fail).
    """
    return Predictor(label, seed, bufsize, count, accepts).expectation(count)
