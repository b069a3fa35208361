"""Motor DAC and wheel encoder protocol (pure: bytes in, numbers out, no I/O).

DAC: **Microchip MCP4911** (10-bit, SPI mode 0, one chip per motor).  A write is one 16-bit
big-endian frame::

    bit 15  /A-B   0 = write the DAC register (1 = ignore the command)
    bit 14  BUF    1 = Vref input buffered
    bit 13  /GA    1 = gain 1x (Vout = Vref * D / 1024), 0 = gain 2x
    bit 12  /SHDN  1 = output active, 0 = shut down (output 500 kOhm to ground)
    bits 11..2     D9..D0
    bits 1..0      don't care (sent as 0)

The motor amplifier takes the DAC voltage with mid-scale as zero speed: code 512 = stop,
1023 = full forward, 1 = full reverse (WHEEL_CMD in docs/internals.md).  We never use /SHDN for
"safe": a shut-down MCP4911 drives 0 V, which the amplifier reads as full reverse.  Safe is
code 512 with the output active.  The normalized-command <-> code mapping has ONE owner,
:mod:`m4k_rt.control.dac` (the RT controller computes the codes); it is re-exported here.

Per-wheel trims (``dac_sign``, ``dac_zero_trim``; :func:`trim_dac_code`) map the WHEEL_CMD code
to the code written: a motor wired the other way round gets sign -1, an amplifier whose zero
is not exactly at mid-scale gets a zero trim (in codes, within +/-``DAC_TRIM_MAX``).

LDAC (/LDAC, pin 5): the MCP4911 moves its input register to the output on /LDAC low.  Tied
low (``ldac: tied_low``, the default), each DAC output changes when its /CS rises, so the two
wheels update one SPI frame (~20 us) apart.  Driven (``ldac: gpio``), the line idles high, both
words are written, then one low pulse (>= 100 ns, datasheet t_LD) updates both outputs together.

Encoder: **ams AS5045** 12-bit magnetic absolute encoder on each *wheel* shaft (after the
12:1 gear, so one count is 2*pi/4096 rad of wheel = 0.156 mm of travel and an absolute reading
survives a restart).  Its SSI frame is read as 3 bytes in SPI mode 2 (CPOL=1, CPHA=0); the
first clock edge only latches the data, so the 18-bit frame starts after ``lead_bits`` (1)
dummy bit, MSB first::

    D11..D0 (angle)  OCF  COF  LIN  MagINC  MagDEC  EvenPAR   then don't-care bits

    OCF     1 = offset compensation finished (must be 1)
    COF     1 = CORDIC overflow, angle invalid
    LIN     1 = linearity alarm, angle invalid
    MagINC & MagDEC both 1 = magnetic field out of range (Table 4), but the angle is still
            VALID: the datasheet's Table 3 ("Status Bit Outputs": D11:D0 valid when OCF=1,
            COF=0, LIN=0, any MagINC/MagDEC, even parity; 1/1 "only recommended in YELLOW
            mode") -- the handler accepts it and raises a warning in diagnostics
    EvenPAR makes the 18 bits contain an even number of ones

``lead_bits`` (0..6): the 18-bit frame must fit in the 24 bits read.  Per-wheel ``enc_direction``
(+1/-1) and ``enc_zero`` (0..4095) turn the shaft reading into the wheel angle the robot uses,
positive = forward (:func:`wheel_raw`).
"""

from __future__ import annotations

import math
from typing import NamedTuple, TypeGuard

from m4k_drivers.handler import DeviceProtocolError

# The one owner of the mapping and of the codes (m4k_rt.protocol: 0..1023, 512 = 0).
from m4k_rt.control.dac import code_to_command, command_to_code, DAC_MAX, DAC_SPAN, DAC_ZERO

__all__ = [
    'DAC_MAX', 'DAC_SPAN', 'DAC_ZERO', 'DeviceProtocolError', 'ENC_COUNTS', 'ENC_READ_LEN',
    'DacFrame', 'EncoderFrame',
    'EncoderFieldWarning', 'EncoderFrameError', 'EncoderJumpError', 'Unwrapper',
    'code_to_command', 'code_to_volts',
    'command_to_code', 'decode_dac', 'decode_encoder', 'encode_dac', 'encode_encoder',
    'DAC_TRIM_MAX', 'LEAD_BITS_MAX', 'check_lead_bits', 'check_sign_pair', 'check_trim_pair',
    'check_zero_pair', 'mag_out_of_range', 'trim_dac_code', 'wheel_raw',
]

DAC_BITS = 10

ENC_BITS = 12
ENC_COUNTS = 1 << ENC_BITS
ENC_FRAME_BITS = 18
ENC_READ_LEN = 3
RAD_PER_COUNT = 2.0 * math.pi / ENC_COUNTS
LEAD_BITS_MAX = ENC_READ_LEN * 8 - ENC_FRAME_BITS      # 6: the frame must fit in the read
DAC_TRIM_MAX = 64                                      # zero trim limit, codes (12.5 % span)


class EncoderFrameError(DeviceProtocolError):
    """Raise when an encoder frame fails parity or its status bits flag an invalid angle."""


class EncoderFieldWarning(DeviceProtocolError):
    """Recorded (not raised) when MagINC = MagDEC = 1: valid angle, marginal magnet gap."""


class EncoderJumpError(DeviceProtocolError):
    """Raise when a reading implies a wheel speed the robot cannot have."""


class DacFrame(NamedTuple):
    """Fields of one decoded MCP4911 write frame."""

    code: int
    write: bool       # /A-B == 0
    buffered: bool
    gain1x: bool
    active: bool      # /SHDN == 1


class EncoderFrame(NamedTuple):
    """Fields of one decoded AS5045 frame."""

    raw: int
    ocf: bool
    cof: bool
    lin: bool
    mag_inc: bool
    mag_dec: bool


def encode_dac(code: int, *, buffered: bool = False, gain1x: bool = True,
               active: bool = True) -> bytes:
    """Return the 2-byte MCP4911 frame writing ``code`` (0..1023)."""
    if isinstance(code, bool) or not isinstance(code, int) or not 0 <= code <= DAC_MAX:
        raise ValueError(f'DAC code must be an int in 0..{DAC_MAX}, got {code!r}')
    word = (buffered << 14) | (gain1x << 13) | (active << 12) | (code << 2)
    return word.to_bytes(2, 'big')


def decode_dac(frame: bytes | bytearray) -> DacFrame:
    """Decode a 2-byte MCP4911 frame (what the chip would latch)."""
    if len(frame) != 2:
        raise DeviceProtocolError(f'MCP4911 frame must be 2 bytes, got {bytes(frame)!r}')
    word = int.from_bytes(frame, 'big')
    return DacFrame((word >> 2) & DAC_MAX, not word & 0x8000, bool(word & 0x4000),
                    bool(word & 0x2000), bool(word & 0x1000))


def code_to_volts(code: int, vref: float = 3.3, gain: int = 1) -> float:
    """Return the MCP4911 output voltage for ``code``: Vref * gain * code / 1024."""
    return vref * gain * code / (DAC_MAX + 1)


def volts_to_code(volts: float, vref: float = 3.3, gain: int = 1) -> int:
    """Return the nearest code producing ``volts`` (clamped to 0..1023)."""
    code = round(volts * (DAC_MAX + 1) / (vref * gain))
    return max(0, min(DAC_MAX, code))


def trim_dac_code(code: int, sign: int = 1, zero_trim: int = 0) -> int:
    """Return the code to write for WHEEL_CMD ``code``: mirrored by ``sign``, shifted by trim.

    512 + trim + sign * (code - 512), clamped to 0..1023; with sign 1 and trim 0 the identity.
    """
    return max(0, min(DAC_MAX, DAC_ZERO + zero_trim + sign * (code - DAC_ZERO)))


def wheel_raw(raw: int, direction: int = 1, zero: int = 0) -> int:
    """Return the wheel-frame reading of a shaft reading: direction * (raw - zero) mod 4096."""
    return (direction * (raw - zero)) % ENC_COUNTS


def mag_out_of_range(frame: EncoderFrame) -> bool:
    """Return True for MagINC = MagDEC = 1 (Table 4: field out of range; angle still valid)."""
    return frame.mag_inc and frame.mag_dec


# -- config checks (registry.Param.check: None = fine, else the reason) ---------------------
def _is_int(v: object) -> TypeGuard[int]:
    return isinstance(v, int) and not isinstance(v, bool)


def check_lead_bits(value: object) -> str | None:
    """Check an AS5045 lead_bits setting."""
    if not _is_int(value) or not 0 <= value <= LEAD_BITS_MAX:
        return (f'must be an int 0..{LEAD_BITS_MAX} (the 18-bit frame must fit in the '
                f'{ENC_READ_LEN * 8} bits read)')
    return None


def check_sign_pair(value: object) -> str | None:
    """Check a per-wheel [left, right] pair of +1/-1."""
    if not (isinstance(value, list) and len(value) == 2
            and all(_is_int(v) and v in (1, -1) for v in value)):
        return 'expected [left, right], each 1 or -1'
    return None


def check_zero_pair(value: object) -> str | None:
    """Check a per-wheel [left, right] pair of encoder zero offsets."""
    if not (isinstance(value, list) and len(value) == 2
            and all(_is_int(v) and 0 <= v < ENC_COUNTS for v in value)):
        return f'expected [left, right], each an int 0..{ENC_COUNTS - 1} (counts)'
    return None


def check_trim_pair(value: object) -> str | None:
    """Check a per-wheel [left, right] pair of DAC zero trims."""
    if not (isinstance(value, list) and len(value) == 2
            and all(_is_int(v) and abs(v) <= DAC_TRIM_MAX for v in value)):
        return f'expected [left, right], each an int -{DAC_TRIM_MAX}..{DAC_TRIM_MAX} (codes)'
    return None


def encode_encoder(raw: int, *, ocf: bool = True, cof: bool = False, lin: bool = False,
                   mag_inc: bool = False, mag_dec: bool = False, parity: int | None = None,
                   lead_bits: int = 1) -> bytes:
    """Return the 3 bytes an AS5045 shifts out for ``raw`` (used by the sim and tests)."""
    if not 0 <= raw < ENC_COUNTS:
        raise ValueError(f'encoder raw must be in 0..{ENC_COUNTS - 1}, got {raw!r}')
    bits17 = (raw << 5) | (ocf << 4) | (cof << 3) | (lin << 2) | (mag_inc << 1) | mag_dec
    if parity is None:
        parity = bin(bits17).count('1') & 1
    frame = (bits17 << 1) | (parity & 1)
    total = ENC_READ_LEN * 8
    return (frame << (total - lead_bits - ENC_FRAME_BITS)).to_bytes(ENC_READ_LEN, 'big')


def decode_encoder(data: bytes | bytearray, lead_bits: int = 1) -> EncoderFrame:
    """Decode and validate one AS5045 read; raise EncoderFrameError if it is not a valid angle.

    MagINC = MagDEC = 1 is valid data (Table 3); check :func:`mag_out_of_range` to warn.
    """
    reason = check_lead_bits(lead_bits)
    if reason:
        raise ValueError(f'AS5045 lead_bits {reason}, got {lead_bits!r}')
    if len(data) != ENC_READ_LEN:
        raise EncoderFrameError(f'AS5045 read must be {ENC_READ_LEN} bytes, got {bytes(data)!r}')
    word = int.from_bytes(data, 'big')
    frame = (word >> (ENC_READ_LEN * 8 - lead_bits - ENC_FRAME_BITS)) & ((1 << 18) - 1)
    if frame == 0 or frame == (1 << 18) - 1:
        level = 'low' if frame == 0 else 'high'
        raise EncoderFrameError(f'AS5045: no response (MISO stuck {level}), read {bytes(data)!r}')
    if bin(frame).count('1') & 1:
        raise EncoderFrameError(f'AS5045: parity error in {bytes(data)!r}')
    f = EncoderFrame(frame >> 6, bool(frame & 0x20), bool(frame & 0x10), bool(frame & 0x08),
                     bool(frame & 0x04), bool(frame & 0x02))
    if not f.ocf:
        raise EncoderFrameError(f'AS5045: offset compensation not finished (OCF=0) {f!r}')
    if f.cof or f.lin:
        raise EncoderFrameError(f'AS5045: angle invalid (COF={f.cof:d}, LIN={f.lin:d}) {f!r}')
    return f


class Unwrapper:
    """Turn 12-bit absolute readings into a continuous count across 4095 <-> 0.

    A reading is accepted when the shortest wrap-around step from the last accepted one is
    within what the wheel can turn since then (``max_rate`` counts/s over the elapsed time,
    plus ``slack`` counts for noise, never more than half a turn).  A larger step is rejected
    with :class:`EncoderJumpError` and the count keeps its value; after ``resync_after``
    consecutive rejections the unwrapper accepts the shortest step to the new reading (the
    wheel did move, e.g. after a long gap) and counts a resync.
    """

    def __init__(self, max_rate: float, slack: int = 8, resync_after: int = 3,
                 counts: int = ENC_COUNTS) -> None:
        self.max_rate = max_rate
        self.slack = slack
        self.resync_after = resync_after
        self.counts = counts
        self.count = 0
        self.last_raw: int | None = None
        self.last_t_ns = 0
        self.rejected = 0
        self.resyncs = 0
        self._consecutive = 0

    def reset(self) -> None:
        """Forget the last reading (the next one anchors the count)."""
        self.last_raw = None
        self._consecutive = 0

    def limit(self, dt_s: float) -> int:
        """Return the largest accepted step in counts after ``dt_s`` seconds."""
        return min(self.counts // 2 - 1, int(self.max_rate * max(dt_s, 0.0)) + self.slack)

    def update(self, raw: int, t_ns: int, since_ns: int | None = None) -> int:
        """Accept one reading and return the continuous count.

        ``t_ns`` is the latest the reading can have been taken (the clock read after the
        transfer returned), ``since_ns`` the earliest (read before the transfer started;
        default ``t_ns``). A step is bounded by the longest time the wheel can have turned:
        from the previous reading's earliest to this one's latest. Bounding it by the two
        clock reads after the transfers would turn an honest step into a "jump" whenever the
        previous reading's clock was read late (its process preempted after the transfer).
        """
        since = t_ns if since_ns is None else since_ns
        if self.last_raw is None:
            self.last_raw, self.last_t_ns = raw, since
            self.count = raw
            return self.count
        half = self.counts // 2
        delta = (raw - self.last_raw + half) % self.counts - half
        limit = self.limit((t_ns - self.last_t_ns) * 1e-9)
        if abs(delta) > limit:
            self.rejected += 1
            self._consecutive += 1
            if self._consecutive < self.resync_after:
                raise EncoderJumpError(f'encoder jump {self.last_raw} -> {raw} '
                                       f'({delta:+d} counts, limit {limit})')
            # The wheel did move this far (the readings agree with each other); the number of
            # whole turns is unknowable, so take the shortest step and keep count == raw mod 4096.
            self.resyncs += 1
        self._consecutive = 0
        self.count += delta
        self.last_raw, self.last_t_ns = raw, since
        return self.count

    @property
    def angle(self) -> float:
        """Return the continuous wheel angle in radians."""
        return self.count * 2.0 * math.pi / self.counts
