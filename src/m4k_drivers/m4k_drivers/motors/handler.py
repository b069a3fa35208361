"""Motor handler: WHEEL_CMD codes -> two MCP4911 DACs; two AS5045 encoders -> ENCODERS.

Thin: frames come from :mod:`m4k_drivers.motors.protocol`, bytes move through a
:class:`~m4k_drivers.motors.real.MotorBus` (real spidev or simulated peers).  A watchdog makes
the outputs safe (code 512 on both DACs) when no command arrived for ``watchdog_periods``
actuator periods, until a fresh command comes (docs/internals.md, driver host watchdog).
Every fresh command with its enable bit set toggles the amplifier-enable heartbeat line when
the bus has one (a command with the bit clear lets the enable drop): the
enable is a retriggerable monostable, so when this process dies or stalls the motors lose
their drive within the monostable's hold time even though the DACs keep their last word.

The e-stop read-back (``devices.motor.estop_readback_line``) is an input on the monostable's
output after a dedicated safety-relay contact, at 3.3 V (docs/real-robot.md, section 5): it is
*asserted* (the line request's polarity: ``estop_readback_active``) while the enable reaches
the amplifier's driver stage. While this handler drives the enable -- its heartbeat live (the
last command younger than the monostable's hold) or the enable strapped on -- and the
read-back is not asserted, the relay is open: every ENCODERS datagram then carries
``EncoderStatus.ESTOP_OPEN`` (also when the read-back cannot be read: fail-safe). The reverse
contradicts the command: asserted while the heartbeat has been silent for two hold times (or
never ran), ``READBACK_FAULT_SAMPLES`` readings in a row, means the enable is held by
something other than this handler (a stuck monostable, a bridged contact, a wrong polarity):
a latched fault, ``READBACK_FAULT | ESTOP_OPEN`` in every reading until the handler is
configured again. Without a read-back line neither bit is set, and configure logs that the
software cannot see the contact.
"""

from __future__ import annotations

import math
import time
from typing import Any, Callable, NamedTuple, Sequence

from m4k_drivers.handler import DeviceHandler, DeviceIdentityError, DriverError
from m4k_drivers.motors import protocol as p
from m4k_drivers.motors.real import MotorBus
from m4k_drivers.registry import Derived, Param
from m4k_rt.config import shipped_period_s
from m4k_rt.protocol import EncoderStatus

__all__ = ['HANDLER_PARAMS', 'READBACK_FAULT_SAMPLES', 'EncoderReading', 'EstopReadbackFault',
           'MotorHandler', 'WheelCommand']


class WheelCommand(NamedTuple):
    """The WHEEL_CMD payload: DAC codes (512 = zero) and the enable flag."""

    left_code: int
    right_code: int
    enable: int = 1


class EncoderReading(NamedTuple):
    """The ENCODERS payload plus the host's read time."""

    left_raw: int
    right_raw: int
    left_angle: float
    right_angle: float
    status: int
    t_ns: int


_FRAME_BITS = (EncoderStatus.LEFT_FRAME, EncoderStatus.RIGHT_FRAME)
READBACK_FAULT_SAMPLES = 3           # readings in a row before a contradiction latches


def _actuator_period_s() -> float:
    return shipped_period_s('actuator')


# The handler's settings, declared once: the config schema of both backends (registry.Param)
# and the constructor's defaults below are this table.
HANDLER_PARAMS: dict[str, Param] = {
    # The actuator's period, declared once in tasks: (config/m4k.yaml); the driver host
    # fills it from the layered configuration (config.fill_actuator_period), a bare section
    # from the shipped one.
    'period_s': Param(float, Derived('tasks.actuator.period_ms', _actuator_period_s),
                      "service period, s (the actuator task's period_ms / 1000); the "
                      'watchdog and the stale-command age count in it.'),
    'watchdog_periods': Param(int, 10, 'periods without WHEEL_CMD before outputs go safe'),
    'max_wheel_rad_s': Param(float, 30.0, 'fastest plausible wheel speed for jump rejection'),
    'lead_bits': Param(int, 1, 'dummy bits before the AS5045 frame in an SPI read (0..6)',
                       p.check_lead_bits),
    'dac_sign': Param(list, [1, 1], '[left, right] +1/-1: -1 mirrors a DAC code about 512 '
                      '(a motor wired the other way round)', p.check_sign_pair),
    'dac_zero_trim': Param(list, [0, 0], '[left, right] codes added to 512 so the amplifier '
                           f'sees zero (|trim| <= {p.DAC_TRIM_MAX})', p.check_trim_pair),
    'enc_direction': Param(list, [1, 1], '[left, right] +1/-1 so wheel angles grow forward',
                           p.check_sign_pair),
    'enc_zero': Param(list, [0, 0], '[left, right] AS5045 reading taken as wheel angle 0',
                      p.check_zero_pair),
}
_DEFAULT = {k: v.default for k, v in HANDLER_PARAMS.items()}


class EstopReadbackFault(DriverError):
    """The read-back shows the enable asserted while this handler does not command it."""

_JUMP_BITS = (EncoderStatus.LEFT_JUMP, EncoderStatus.RIGHT_JUMP)


class MotorHandler(DeviceHandler):
    """Lifecycle handler for the two drive motors and their wheel encoders."""

    kind = 'motor'

    def __init__(self, opener: Callable[[], MotorBus], *, period_s: float, name: str = 'motor',
                 watchdog_periods: int = _DEFAULT['watchdog_periods'],
                 max_wheel_rad_s: float = _DEFAULT['max_wheel_rad_s'],
                 lead_bits: int = _DEFAULT['lead_bits'],
                 dac_sign: Sequence[int] = _DEFAULT['dac_sign'],
                 dac_zero_trim: Sequence[int] = _DEFAULT['dac_zero_trim'],
                 enc_direction: Sequence[int] = _DEFAULT['enc_direction'],
                 enc_zero: Sequence[int] = _DEFAULT['enc_zero'],
                 clock: Callable[[], int] = time.monotonic_ns,
                 enable_hold_s: float | None = None, **kw: Any) -> None:
        super().__init__(name, **kw)
        for field, value, check in (('lead_bits', lead_bits, p.check_lead_bits),
                                    ('dac_sign', list(dac_sign), p.check_sign_pair),
                                    ('dac_zero_trim', list(dac_zero_trim), p.check_trim_pair),
                                    ('enc_direction', list(enc_direction), p.check_sign_pair),
                                    ('enc_zero', list(enc_zero), p.check_zero_pair)):
            reason = check(value)
            if reason:
                raise ValueError(f'{name}.{field}: {reason}, got {value!r}')
        self.dac_sign, self.dac_zero_trim = tuple(dac_sign), tuple(dac_zero_trim)
        self.enc_direction, self.enc_zero = tuple(enc_direction), tuple(enc_zero)
        self._opener = opener
        self.bus: MotorBus | None = None
        self.clock = clock
        self.period_s = period_s
        self.watchdog_ns = int(period_s * watchdog_periods * 1e9)
        self.lead_bits = lead_bits
        self.max_wheel_rad_s = max_wheel_rad_s
        max_rate = max_wheel_rad_s / (2 * math.pi) * p.ENC_COUNTS
        self.unwrap = (p.Unwrapper(max_rate), p.Unwrapper(max_rate))
        self.codes = (p.DAC_ZERO, p.DAC_ZERO)
        self.safe = True
        self.last_cmd_ns: int | None = None
        # the heartbeat's last rising edge (when this handler's clock read it, before the
        # write): the monostable's hold runs from it -- not from the last toggle, which is a
        # falling edge every other command. While the enable is off on purpose (no rising
        # edge for a hold), a low read-back is no open e-stop contact.
        self.last_rise_ns: int | None = None
        self.watchdog_trips = 0
        self.write_error = False
        self.last_raw = [0, 0]
        self.written = (p.DAC_ZERO, p.DAC_ZERO)      # codes on the wires, after the trims
        self.mag_warnings = [0, 0]                   # frames with MagINC = MagDEC = 1
        self._mag_bad = [False, False]
        # The heartbeat monostable's hold (None: no heartbeat, the enable is strapped on).
        self.enable_hold_ns = None if enable_hold_s is None else int(enable_hold_s * 1e9)
        self.estop_open = False              # the read-back's last verdict
        # Each wheel's last valid (angle rad, latch ns): its speed carries the angle to the
        # reading's stamp (on_read)
        self._latched: list[tuple[float, int] | None] = [None, None]
        self.estop_readback = 'none'         # where the read-back is wired (diagnostics)
        self.readback_fault: str | None = None   # the latched contradiction, if any
        self._contradictions = 0

    # -- hooks ----------------------------------------------------------------------------
    def on_configure(self) -> None:
        """Open the four SPI endpoints, zero the DACs and check both encoders answer."""
        self.bus = self._opener()
        self._latched = [None, None]
        back = self.bus.readback
        self.estop_readback = 'none' if back is None else back.where
        if back is None:
            self.log.warning('%s: no e-stop read-back (devices.motor.estop_readback_line: '
                             'null): an open e-stop contact is not seen by the software, '
                             'ENCODERS never carries ESTOP_OPEN', self.name)
        self.estop_open = False
        self.readback_fault = None
        self._contradictions = 0
        self._write_codes(p.DAC_ZERO, p.DAC_ZERO)
        for side, port in enumerate(self.bus.encoders):
            try:
                frame = p.decode_encoder(port.transfer(bytes(p.ENC_READ_LEN)), self.lead_bits)
            except p.EncoderFrameError as exc:
                raise DeviceIdentityError(f'{port.path}: no valid AS5045 frame: {exc}') from exc
            raw = self._wheel(side, frame)
            self.unwrap[side].reset()
            self.unwrap[side].update(raw, self.clock())
            self.last_raw[side] = raw

    def on_activate(self) -> None:
        """Accept commands; outputs stay at zero until the first one."""
        self.make_safe()

    def on_write(self, command: WheelCommand) -> None:
        """Write both DACs (enable 0 -> code 512) and feed the watchdog."""
        left, right, enable = command
        for code in (left, right):
            if isinstance(code, bool) or not isinstance(code, int) or not 0 <= code <= p.DAC_MAX:
                raise p.DeviceProtocolError(f'WHEEL_CMD code must be 0..{p.DAC_MAX}, '
                                            f'got {command!r}')
        if not enable:
            left = right = p.DAC_ZERO
        self.last_cmd_ns = self.clock()
        self._write_codes(left, right)
        self.safe = not enable
        if enable and self.bus is not None and self.bus.enable is not None:
            # After the DACs: the enable never outlives a write. A command with the enable
            # off does not feed the heartbeat, so the monostable drops the amplifier enable
            # within its hold: the end of a category-1 stop (the RT side braked first).
            line = self.bus.enable
            if line.level and not self.driving_enable(self.last_cmd_ns):
                # The hold ran out with the line high (a stall, the enable off on purpose):
                # the next toggle would be a falling edge, which retriggers nothing -- pull
                # it low first, so this command's edge rises and the drive is back now, not
                # one command later.
                line.toggle()
            line.toggle()
            if line.level:
                self.last_rise_ns = self.last_cmd_ns

    def on_read(self) -> EncoderReading:
        """Read both encoders (a bad frame sets its status bit, keeps the last angle)."""
        assert self.bus is not None
        self.poll_watchdog()
        status = 0
        latch = [0, 0]
        fresh = [False, False]
        for side, port in enumerate(self.bus.encoders):
            t0 = self.clock()
            data = port.transfer(bytes(p.ENC_READ_LEN))
            t = self.clock()
            latch[side] = t0
            try:
                frame = p.decode_encoder(data, self.lead_bits)
                raw = self._wheel(side, frame)
                self.unwrap[side].update(raw, t, t0)
                self.last_raw[side] = raw
                fresh[side] = True
            except p.EncoderJumpError as exc:
                self.record_fault(exc)
                status |= _JUMP_BITS[side]
            except p.EncoderFrameError as exc:
                self.record_fault(exc)
                status |= _FRAME_BITS[side]
        if self._estop_read():
            status |= EncoderStatus.ESTOP_OPEN
        if self.readback_fault is not None:
            status |= EncoderStatus.READBACK_FAULT
        if self.safe:
            status |= EncoderStatus.SAFE
        if self.write_error:
            status |= EncoderStatus.WRITE_ERROR
        # The sample time is when the wheels were read, not when the reading is sent: the RT
        # odometry divides angle steps by stamp steps, and a send delayed by a busy interpreter
        # would otherwise show up as a speed spike. An AS5045 latches its angle at the falling
        # edge of CSn, i.e. when its transfer starts; the time after the transfer returned is
        # late by however long this thread waited for the CPU (and the GIL) to come back. The
        # two wheels are read one after the other, so their latches differ by the first
        # transfer's whole duration; one stamp for both would read that gap as a speed
        # difference of the wheel read first (a turn that never happened). Both angles are
        # therefore carried to the mean latch time at their own wheel's speed.
        stamp = (latch[0] + latch[1]) // 2
        angles = [self.unwrap[0].angle, self.unwrap[1].angle]
        for side in (0, 1):
            if fresh[side]:
                angles[side] += self._carry(side, angles[side], latch[side], stamp)
        return EncoderReading(self.last_raw[0], self.last_raw[1], angles[0], angles[1],
                              status, stamp)

    def _carry(self, side: int, angle: float, latch_ns: int, stamp_ns: int) -> float:
        """Return how far ``side`` turned from its latch to ``stamp_ns`` (rad).

        At the wheel's speed over its previous valid reading (0 before there is one): the
        gap is one SPI transfer, a few microseconds on the bus and at most milliseconds when
        the host was preempted, so the speed of the last period is the speed over it.
        """
        prev = self._latched[side]
        self._latched[side] = (angle, latch_ns)
        if prev is None or latch_ns <= prev[1]:
            return 0.0
        rate = (angle - prev[0]) / (latch_ns - prev[1])       # rad/ns
        cap = self.max_wheel_rad_s * 1e-9                    # a resync step is no speed
        return max(-cap, min(cap, rate)) * (stamp_ns - latch_ns)

    def on_deactivate(self) -> None:
        """Write code 512 to both DACs."""
        self.make_safe()

    def on_cleanup(self) -> None:
        """Close the SPI endpoints."""
        if self.bus is not None:
            self.bus.close()
            self.bus = None

    # -- helpers --------------------------------------------------------------------------
    def _wheel(self, side: int, frame: p.EncoderFrame) -> int:
        """Return the wheel-frame raw reading; warn (diagnostics) on a weak/strong field."""
        bad = p.mag_out_of_range(frame)
        if bad:
            self.mag_warnings[side] += 1
            if not self._mag_bad[side]:
                # Valid data per the datasheet (Table 3), so it is used -- but the magnet gap
                # is marginal: one counted fault per episode puts DEVICE_STATUS at warn.
                self.record_fault(p.EncoderFieldWarning(
                    f'{self.name}: {("left", "right")[side]} AS5045 magnetic field out of '
                    f'range (MagINC=MagDEC=1); angle used, check the magnet gap'))
                self.log.warning('%s', self.last_exception)
        self._mag_bad[side] = bad
        return p.wheel_raw(frame.raw, self.enc_direction[side], self.enc_zero[side])

    def _write_codes(self, left: int, right: int) -> None:
        assert self.bus is not None
        out = (p.trim_dac_code(left, self.dac_sign[0], self.dac_zero_trim[0]),
               p.trim_dac_code(right, self.dac_sign[1], self.dac_zero_trim[1]))
        try:
            for port, code in zip(self.bus.dacs, out, strict=True):
                port.transfer(p.encode_dac(code))
            self.bus.latch()           # /LDAC pulse when driven: both outputs change together
        except DriverError:
            self.write_error = True
            raise
        self.write_error = False
        self.codes = (left, right)
        self.written = out

    def driving_enable(self, now_ns: int | None = None) -> bool:
        """Return True while this handler drives the amplifier enable (heartbeat live).

        Live: the heartbeat's last rising edge is younger than the monostable's hold -- the
        monostable's own rule. Timed from the last toggle instead (a falling edge every other
        command), a 40 ms host stall left a 10 ms window in which the handler drove an enable
        the monostable had dropped, and the queued readings served in it all read an open
        e-stop contact (four in a row in a burst: one short of the RT side's latch).
        """
        if self.bus is None or self.bus.enable is None:
            return self.bus is not None      # strapped on: always driven
        if self.last_rise_ns is None or self.enable_hold_ns is None:
            return self.last_rise_ns is not None
        now = self.clock() if now_ns is None else now_ns
        return now - self.last_rise_ns < self.enable_hold_ns

    def _estop_read(self) -> bool:
        """Read the e-stop read-back; True (stop) when driven and not asserted, or latched."""
        back = None if self.bus is None else self.bus.readback
        if back is None:
            self.estop_open = False
            return False
        driving = self.driving_enable()
        try:
            asserted = back.read()
        except DriverError as exc:
            self.record_fault(exc)
            self.estop_open = driving or self.readback_fault is not None   # unknown: fail-safe
            return self.estop_open
        if not driving and asserted and self._silent_long():
            self._contradictions += 1
            if self._contradictions >= READBACK_FAULT_SAMPLES and self.readback_fault is None:
                self.readback_fault = (
                    f'{self.name}: e-stop read-back {back.where} shows the enable asserted '
                    f'with the heartbeat silent for {READBACK_FAULT_SAMPLES} readings: the '
                    'monostable or the relay contact holds it (stuck, bridged, or the wrong '
                    'estop_readback_active); latched until reconfigured')
                self.record_fault(EstopReadbackFault(self.readback_fault))
                self.log.error('%s', self.readback_fault)
        else:
            self._contradictions = 0
        self.estop_open = (driving and not asserted) or self.readback_fault is not None
        return self.estop_open

    def _silent_long(self) -> bool:
        """Return True when no command came for two monostable holds (or none ever came)."""
        if self.last_cmd_ns is None:
            return True
        hold = self.enable_hold_ns or 0
        return self.clock() - self.last_cmd_ns >= 2 * hold

    def make_safe(self) -> None:
        """Write the zero code to both DACs (outputs active, so the amplifier sees 0 V)."""
        if self.bus is not None:
            self._write_codes(p.DAC_ZERO, p.DAC_ZERO)
        self.safe = True

    def poll_watchdog(self, now_ns: int | None = None) -> bool:
        """Make outputs safe if the last command is older than the watchdog; True if tripped."""
        if self.safe or self.last_cmd_ns is None:
            return False
        now = self.clock() if now_ns is None else now_ns
        if now - self.last_cmd_ns <= self.watchdog_ns:
            return False
        self.watchdog_trips += 1
        try:
            self.make_safe()
        except DriverError as exc:
            self.record_fault(exc)
        return True
