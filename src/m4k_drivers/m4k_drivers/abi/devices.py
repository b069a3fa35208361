"""Device models behind the kernel stand-in, each from its part's datasheet.

They see what the wires carry: the bytes clocked during one chip select with the SPI mode and
clock, the I2C messages of one transaction, GPIO levels with the time they were driven.
Nothing here imports the driver code it serves (the test would then check the code against
itself).

* :class:`Mcp4911` -- Microchip MCP4901/4911/4921 datasheet (DS22248), section 5 "Serial
  interface": SPI modes 0,0 and 1,1, SCK up to 20 MHz; a write is exactly 16 clocks with /CS
  low -- bit 15 "0 = write to DAC register, 1 = ignore", bit 14 BUF, bit 13 /GA (1 = 1x),
  bit 12 /SHDN (0 = output off, 500 kOhm to ground), bits 11..2 the 10-bit code, bits 1..0
  ignored; "writes with a number of clocks other than 16 are ignored"; the input register
  latches on /CS rising, the output follows at once when /LDAC is low, else on /LDAC falling;
  Vout = Vref * G * D / 1024.
* :class:`As5045` -- ams AS5045 datasheet, "Synchronous Serial Interface": CLK idles high;
  after CSn falls the first falling clock edge latches the data, D11 leaves on the following
  rising edge, so a reader that samples on falling edges (SPI mode 2) sees one leading bit
  first; the frame is D11..D0, OCF, COF, LIN, MagINC, MagDEC, even parity (18 bits); clocks
  beyond 18 shift out the DI input (daisy chain; tied low here); fCLK <= 1 MHz.
* :class:`MyAhrsPlus` -- WithRobot myAHRS+ I2C interface (7-bit address 0x20): WHO_AM_I
  0x01 = 0xB1, revision 0x02/0x03, STATUS 0x04 bit 7 = initialised, data registers
  0x10..0x43 signed 16-bit little-endian, a register pointer that auto-increments within one
  transaction, scales acc g = v * 16 / 32767, gyro dps = v * 2000 / 32767, temperature
  degC = v * 200 / 32767, Euler deg = v * 180 / 32767, quaternion = v / 32767.
* :class:`Us100` -- US-100 in pulse mode (mode jumper off): TRIG high >= 10 us, ECHO rises
  after the burst and stays high for the round trip; with nothing in range it stays high
  for the part's no-echo width (``no_echo_s``, measured on the part: the HC-SR04's 38 ms is
  not the US-100's).
* :class:`RelayReadback` -- the e-stop read-back: the monostable's output through a
  safety-relay contact (either polarity), as wired in docs/real-robot.md section 5.
* :class:`Monostable` -- a retriggerable monostable on the heartbeat line (SN74AHC123A:
  output high from a rising B edge until t_w after the last one; output low at power-up).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
import struct
from typing import Callable

__all__ = ['As5045', 'DataReadyPin', 'ImuState', 'Line', 'Mcp4911', 'Monostable', 'MyAhrsPlus',
           'RelayReadback', 'SpiLoopback', 'Us100']

EmitEdge = Callable[[int, int], None]     # (1 rising | 2 falling, t_ns)


class Line:
    """One GPIO line as the device on it sees it (the stand-in calls these)."""

    def driven(self, level: bool, t_ns: int) -> None:
        """Take the level the host drove the line (output) to at ``t_ns`` (CLOCK_MONOTONIC)."""

    def level(self, t_ns: int) -> bool:
        """Return the level the line has at ``t_ns``."""
        return False

    def attach(self, emit: EmitEdge | None) -> None:
        """Start (or with None stop) reporting this input's edges through ``emit``."""


# -- SPI ----------------------------------------------------------------------------------------
class Mcp4911:
    """MCP4911 10-bit DAC: the 16-bit write word, the input/output registers, /LDAC."""

    MAX_HZ = 20_000_000

    def __init__(self, vref: float = 3.3, vdd: float = 3.3) -> None:
        self.vref, self.vdd = vref, vdd
        self.input_word: int | None = None   # the input register (None: nothing written yet)
        self.output_word: int | None = None  # what drives Vout (power-on: 0 V, shut down)
        self.ldac_low = True                 # /LDAC tied low unless a line drives it
        self.writes = 0
        self.ignored: list[str] = []         # every frame the chip ignored, and why

    def transfer(self, tx: bytes, mode: int, speed_hz: int, bits_per_word: int) -> bytes:
        """One /CS-low period: clock ``tx`` in; SDO does not exist (MISO reads 0)."""
        reason = None
        if mode & 0x3 not in (0, 3):
            reason = f'SPI mode {mode & 3} (the MCP4911 samples SDI on rising SCK: mode 0 or 3)'
        elif speed_hz > self.MAX_HZ:
            reason = f'SCK {speed_hz} Hz > 20 MHz'
        elif len(tx) * 8 != 16:
            reason = f'{len(tx) * 8} clocks with /CS low (a write is exactly 16)'
        if reason is None:
            word = tx[0] << 8 | tx[1]
            if word & 0x8000:
                reason = 'bit 15 set: "ignore this command"'
            else:
                self.input_word = word
                self.writes += 1
                if self.ldac_low:
                    self.output_word = word
        if reason is not None:
            self.ignored.append(reason)
        return bytes(len(tx))

    def ldac(self, low: bool) -> None:
        """/LDAC driven: a falling edge (and a held low) moves input to output."""
        if low and self.input_word is not None:
            self.output_word = self.input_word
        self.ldac_low = low

    @property
    def code(self) -> int | None:
        """The 10-bit code on the output (None: shut down or never written)."""
        w = self.output_word
        if w is None or not w & 0x1000:
            return None
        return (w >> 2) & 0x3FF

    @property
    def volts(self) -> float:
        """Vout: Vref * G * D / 1024, limited to VDD; 0 V shut down or at power-up."""
        w = self.output_word
        if w is None or not w & 0x1000:
            return 0.0
        gain = 1 if w & 0x2000 else 2
        return min(self.vref * gain * ((w >> 2) & 0x3FF) / 1024.0, self.vdd)


class As5045:
    """AS5045 12-bit magnetic encoder read over SSI: 18-bit frame, status, even parity."""

    MAX_HZ = 1_000_000

    def __init__(self, counts: Callable[[], int]) -> None:
        self.counts = counts       # the magnet angle now, 0..4095
        self.ocf, self.cof, self.lin, self.mag_inc, self.mag_dec = 1, 0, 0, 0, 0
        self.reads = 0

    def frame(self) -> int:
        """Return the 18-bit frame for the angle now (even parity in bit 0)."""
        bits = (self.counts() & 0xFFF) << 5 | self.ocf << 4 | self.cof << 3 | self.lin << 2 \
            | self.mag_inc << 1 | self.mag_dec
        parity = bin(bits).count('1') & 1
        return bits << 1 | parity

    def transfer(self, tx: bytes, mode: int, speed_hz: int, bits_per_word: int) -> bytes:
        """One CSn-low period: the bits the master samples, MSB first."""
        n = len(tx) * 8
        if speed_hz > self.MAX_HZ:
            return b'\xff' * len(tx)   # DO cannot settle: the master reads the idle level
        self.reads += 1
        if mode & 0x2 == 0:
            # CPOL 0: the clock idles low, so CSn falling is followed by a rising edge that
            # the part takes for the end of a clock: the frame arrives shifted by one bit and
            # the master samples D11 before it is valid -- read as all ones (idle DO).
            return b'\xff' * len(tx)
        lead = 1 if mode & 0x1 == 0 else 0    # mode 2 samples before D11 leaves; mode 3 after
        word = 0
        bits = [1] * lead + [(self.frame() >> (17 - i)) & 1 for i in range(18)]
        bits += [0] * max(0, n - len(bits))   # DI (daisy-chain input) tied low
        for b in bits[:n]:
            word = word << 1 | b
        return word.to_bytes(len(tx), 'big')


class SpiLoopback:
    """A jumper from MOSI to MISO: the master reads what it sends (``open``: no jumper)."""

    def __init__(self) -> None:
        self.open = False
        self.transfers = 0

    def transfer(self, tx: bytes, mode: int, speed_hz: int, bits_per_word: int) -> bytes:
        """Return MOSI as MISO, or the idle-low line when the jumper is off."""
        self.transfers += 1
        return bytes(len(tx)) if self.open else bytes(tx)


# -- I2C ----------------------------------------------------------------------------------------
@dataclass
class ImuState:
    """What the myAHRS+ measures now, in its own units and board frame."""

    acc_g: tuple[float, float, float] = (0.0, 0.0, -1.0)
    gyro_dps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    magnet: tuple[float, float, float] = (0.0, 0.0, 0.0)
    temp_c: float = 25.0
    euler_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quat: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    raw: tuple[int, ...] = field(default_factory=lambda: (0,) * 9)


def _s16(value: float) -> int:
    return max(-32768, min(32767, round(value)))


class MyAhrsPlus:
    """myAHRS+ register file on I2C (address 0x20): pointer, auto-increment, snapshots."""

    ADDRESS = 0x20

    def __init__(self, state: Callable[[], ImuState], address: int = ADDRESS) -> None:
        self.state = state
        self.address = address
        self.pointer = 0
        self.regs = bytearray(0x44)
        self.regs[0x01] = 0xB1
        self.regs[0x02], self.regs[0x03] = 1, 5
        self.regs[0x04] = 0x80
        self.transactions = 0

    def _snapshot(self) -> None:
        """Latch the measurement into the data registers (once per transaction)."""
        s = self.state()
        vals = list(s.raw) + [_s16(v * 32767 / 16) for v in s.acc_g]
        vals += [_s16(v * 32767 / 2000) for v in s.gyro_dps]
        vals += [_s16(v) for v in s.magnet]
        vals.append(_s16(s.temp_c * 32767 / 200))
        vals += [_s16(v * 32767 / 180) for v in s.euler_deg]
        vals += [_s16(v * 32767) for v in s.quat]
        self.regs[0x10:0x44] = struct.pack('<26h', *vals)

    def i2c_transaction(self, msgs: list[tuple[bool, bytes | int]]) -> list[bytes]:
        """Run one START..STOP: (read?, bytes written | length read) -> the bytes read."""
        self.transactions += 1
        self._snapshot()
        out = []
        for is_read, data in msgs:
            if is_read:
                n = int(data)
                got = bytes(self.regs[(self.pointer + i) % len(self.regs)] for i in range(n))
                self.pointer = (self.pointer + n) % len(self.regs)
                out.append(got)
            else:
                buf = bytes(data)
                if buf:                        # pointer, then data: the registers are
                    self.pointer = (buf[0] + len(buf) - 1) % len(self.regs)   # read-only
        return out


class DataReadyPin(Line):
    """The myAHRS+ J3-1 DATA READY output: a pulse (rising, then falling) when a test says."""

    def __init__(self) -> None:
        self.emit: EmitEdge | None = None
        self.high = False

    def attach(self, emit: EmitEdge | None) -> None:
        """Start (or stop) reporting edges."""
        self.emit = emit

    def pulse(self, t_ns: int, width_ns: int = 50_000) -> None:
        """Announce a sample at ``t_ns``: rising edge then, falling ``width_ns`` later."""
        if self.emit is not None:
            self.emit(1, t_ns)
            self.emit(2, t_ns + width_ns)

    def level(self, t_ns: int) -> bool:
        """Return the idle level (low)."""
        return False


# -- GPIO ---------------------------------------------------------------------------------------
class Monostable(Line):
    """Retriggerable monostable on the enable heartbeat (output low at power-up)."""

    def __init__(self, hold_s: float) -> None:
        self.hold_ns = int(hold_s * 1e9)
        self.last_rise_ns: int | None = None
        self.high = False
        self.rising_edges = 0

    def driven(self, level: bool, t_ns: int) -> None:
        """Retrigger on a rising edge."""
        if level and not self.high:
            self.last_rise_ns = t_ns
            self.rising_edges += 1
        self.high = level

    def level(self, t_ns: int) -> bool:
        """Return the input level (the heartbeat as driven)."""
        return self.high

    def enabled(self, t_ns: int) -> bool:
        """Return True while the monostable's output holds the amplifier enabled."""
        return self.last_rise_ns is not None and t_ns - self.last_rise_ns < self.hold_ns


class _OutputPin(Line):
    def __init__(self, on_change: Callable[[bool, int], None]) -> None:
        self.on_change = on_change
        self.high = False

    def driven(self, level: bool, t_ns: int) -> None:
        if level != self.high:
            self.high = level
            self.on_change(level, t_ns)

    def level(self, t_ns: int) -> bool:
        return self.high


class LdacPin(_OutputPin):
    """/LDAC of one or more MCP4911s (a falling edge updates every output)."""

    def __init__(self, dacs: list[Mcp4911]) -> None:
        # Before the host requests it the pin reads low (the Pi's default pull-down on the
        # GPIOs m4k uses): the DACs follow every write until the line idles high.
        super().__init__(self._apply)
        self.dacs = dacs

    def _apply(self, level: bool, t_ns: int) -> None:
        for dac in self.dacs:
            dac.ldac(not level)


class RelayReadback(Line):
    """The e-stop read-back input: 1Q of the monostable through a safety-relay contact.

    ``active_low`` False: 1Q (3.3 V logic) -> the relay's N/O safety contact -> the GPIO, with
    a 10 kOhm pull-down: high only while 1Q holds the enable *and* the relay is energised.
    True: the same path drives an inverting stage (optocoupler or NPN to GND, pull-up to
    3.3 V): low then.  ``stuck`` forces what reaches the stage (True: a bridged contact and a
    1Q stuck high, the enable held by nothing the host commands).
    """

    def __init__(self, monostable: Monostable, *, active_low: bool = False) -> None:
        self.monostable = monostable
        self.active_low = active_low
        self.relay_closed = True          # e-stop released and the relay reset
        self.stuck: bool | None = None

    def level(self, t_ns: int) -> bool:
        """Return the pin level at ``t_ns``."""
        passed = self.stuck if self.stuck is not None else (
            self.relay_closed and self.monostable.enabled(t_ns))
        return passed != self.active_low


class Us100:
    """US-100 in pulse mode: a TRIG line and an ECHO line with edges at the wire's times."""

    SOUND_MPS_20C = 343.4
    MIN_TRIGGER_NS = 10_000

    def __init__(self, range_m: Callable[[], float | None], *, no_echo_s: float = 0.038,
                 echo_delay_s: float = 0.0005, temperature_c: float = 20.0) -> None:
        self.range_m = range_m           # the distance to what reflects, None: nothing
        self.no_echo_s = no_echo_s
        self.echo_delay_ns = int(echo_delay_s * 1e9)
        self.speed = 331.3 + 0.606 * temperature_c
        self.emit: EmitEdge | None = None
        self.rise_ns: int | None = None
        self.pings = 0
        self.short_triggers = 0
        self.busy_until_ns = 0
        self.trigger = _OutputPin(self._trig)
        self.echo = _EchoPin(self)

    def width_s(self) -> float:
        """Return the echo width the part produces now, s."""
        r = self.range_m()
        return self.no_echo_s if r is None else 2.0 * r / self.speed

    def _trig(self, level: bool, t_ns: int) -> None:
        if level:
            self.rise_ns = t_ns
            return
        if self.rise_ns is None:
            return
        width = t_ns - self.rise_ns
        self.rise_ns = None
        if width < self.MIN_TRIGGER_NS:
            self.short_triggers += 1       # too short: the part does not fire
            return
        if t_ns < self.busy_until_ns or self.emit is None:
            return                         # still measuring, or nobody listens for edges
        self.pings += 1
        rise = t_ns + self.echo_delay_ns
        fall = rise + int(self.width_s() * 1e9)
        self.busy_until_ns = fall
        self.emit(1, rise)
        self.emit(2, fall)


class _EchoPin(Line):
    def __init__(self, part: Us100) -> None:
        self.part = part

    def level(self, t_ns: int) -> bool:
        return t_ns < self.part.busy_until_ns

    def attach(self, emit: EmitEdge | None) -> None:
        self.part.emit = emit


def counts_of(angle_rad: float) -> int:
    """Return the AS5045 reading (0..4095) of a shaft angle."""
    return int(math.floor(angle_rad / (2 * math.pi) * 4096)) % 4096


class Ws2812Strip:
    """A WS2812B pixel strip on MOSI: the waveform decoded by the datasheet's timing.

    The line level is MOSI at the SPI clock.  A high run then a low run is one bit: a 0 when
    T0H = 400 +/- 150 ns and T0L = 850 +/- 150 ns, a 1 when T1H = 800 +/- 150 ns and
    T1L = 450 +/- 150 ns, and TH + TL = 1.25 us +/- 600 ns; anything else is out of tolerance
    (counted in ``bad_bits``, and the frame is not shown).  A low run >= ``reset_us`` latches:
    the first 24 bits go to pixel 0 (G, R, B, MSB first), the next 24 are passed on to pixel
    1, and so on.  The line idles low between SPI messages (longer than any reset).
    """

    TOL_NS = 150
    PERIOD_NS, PERIOD_TOL_NS = 1250, 600

    def __init__(self, pixels: int, reset_us: float = 280.0) -> None:
        self.pixels = pixels
        self.reset_ns = reset_us * 1000.0
        self.shown: list[tuple[int, int, int]] = [(0, 0, 0)] * pixels   # r, g, b
        self.frames = 0
        self.bad_bits = 0
        self.rejected_frames = 0

    def _classify(self, high_ns: float, low_ns: float) -> int | None:
        t = self.TOL_NS
        if not abs(high_ns + low_ns - self.PERIOD_NS) <= self.PERIOD_TOL_NS:
            return None
        if abs(high_ns - 400) <= t and abs(low_ns - 850) <= t:
            return 0
        if abs(high_ns - 800) <= t and abs(low_ns - 450) <= t:
            return 1
        return None

    def transfer(self, tx: bytes, mode: int, speed_hz: int, bits_per_word: int) -> bytes:
        """Decode one SPI message sent by an ideal controller (no gaps) at ``speed_hz``."""
        bit_ns = 1e9 / speed_hz
        runs: list[tuple[int, float]] = []         # (level, duration ns)
        for byte in tx:
            for i in range(8):
                level = byte >> (7 - i) & 1
                if runs and runs[-1][0] == level:
                    runs[-1] = (level, runs[-1][1] + bit_ns)
                else:
                    runs.append((level, bit_ns))
        self.line(runs)
        return bytes(len(tx))

    def line(self, waveform: list[tuple[int, float]]) -> None:
        """Decode DIN as (level, ns) runs -- what a controller really drove; latch on resets."""
        runs = list(waveform)
        runs.append((0, float('inf')))             # the line idles low after the message
        bits: list[int] = []
        bad = 0
        i = 0
        while i < len(runs):
            level, dur = runs[i]
            if level == 0:
                if dur >= self.reset_ns:
                    self._latch(bits, bad)
                    bits, bad = [], 0
                i += 1
                continue
            low = runs[i + 1][1]
            if low >= self.reset_ns:
                # the last bit's low time merges into the reset: judge its high time alone
                b = 0 if abs(dur - 400) <= self.TOL_NS else 1 if abs(
                    dur - 800) <= self.TOL_NS else None
            else:
                b = self._classify(dur, low)
            if b is None:
                bad += 1
            else:
                bits.append(b)
            if low >= self.reset_ns:
                i += 1                              # the reset run is handled next round
            else:
                i += 2

    def _latch(self, bits: list[int], bad: int) -> None:
        if not bits and not bad:
            return
        if bad:
            self.bad_bits += bad
            self.rejected_frames += 1
            return
        self.frames += 1
        for p in range(min(self.pixels, len(bits) // 24)):
            word = 0
            for b in bits[p * 24:(p + 1) * 24]:
                word = word << 1 | b
            g, r, bl = word >> 16 & 0xFF, word >> 8 & 0xFF, word & 0xFF
            self.shown[p] = (r, g, bl)
