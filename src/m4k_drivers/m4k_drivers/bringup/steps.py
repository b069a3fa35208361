"""The first-power checks, one function per bus: what each expects and what a failure means.

Every step opens the real backend (python-periphery spidev and GPIO v2, smbus2, pyserial), so
on the Pi it exercises the kernel drivers and the wiring, and here it runs unchanged against
the kernel-ABI stand-in (:mod:`m4k_drivers.abi`).  A step returns a :class:`StepResult`; it
never raises for a device fault (the fault is the result), and it releases what it opened.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
import time
from typing import Any, Callable

from m4k_drivers.handler import DriverError

__all__ = ['StepResult', 'amp_hold', 'gpio_loopback', 'i2c_who_am_i', 'sonar_no_echo',
           'spi_loopback', 'urg_version']

# Distinct bytes: a stuck line, a one-bit shift and a swapped nibble all show.
LOOP_PATTERN = bytes([0x55, 0xAA, 0x00, 0xFF, 0x01, 0x80, 0x3C, 0xC3, 0x12, 0x34])


@dataclass
class StepResult:
    """One step's verdict: passed True/False, None = could not be judged here (manual)."""

    step: str
    expect: str
    passed: bool | None
    detail: str
    failure_means: str

    def as_dict(self) -> dict[str, Any]:
        """Return the result as a JSON-ready dict."""
        return asdict(self)


def _shifted(tx: bytes, rx: bytes) -> bool:
    """Return True when ``rx`` is ``tx`` moved by one bit either way (a clock-phase error)."""
    a, b = int.from_bytes(tx, 'big'), int.from_bytes(rx, 'big')
    n = 8 * len(tx)
    mask = (1 << n) - 1
    return b in ((a >> 1) & mask, (a << 1) & mask)


def spi_loopback(path: str, mode: int, speed_hz: int) -> StepResult:
    """With a jumper MOSI -> MISO, what the controller sends must come back byte for byte."""
    step = f'spi loopback {path} @ {speed_hz} Hz mode {mode}'
    expect = (f'a jumper from MOSI to MISO (the devices on MISO unplugged): the '
              f'{len(LOOP_PATTERN)} bytes {LOOP_PATTERN.hex()} read back unchanged at the '
              'configured clock')
    means = ('SPI not enabled in config.txt or the node missing (errno), no jumper or the wrong '
             'pins (all 00 / all ff), a phase error (one bit shifted), or a jumper/wire too long '
             'for this clock (scattered bit errors)')
    from periphery import SPI
    try:
        spi = SPI(path, mode, speed_hz)
    except OSError as exc:
        return StepResult(step, expect, False, f'cannot open: {exc}', means)
    try:
        rx = bytes(spi.transfer(LOOP_PATTERN))
    except OSError as exc:
        return StepResult(step, expect, False, f'transfer failed: {exc}', means)
    finally:
        spi.close()
    if rx == LOOP_PATTERN:
        return StepResult(step, expect, True, f'read back {rx.hex()}', means)
    if rx in (bytes(len(rx)), b'\xff' * len(rx)):
        why = f'MISO reads constant 0x{rx[0]:02x}: no jumper, or MISO on the wrong pin'
    elif _shifted(LOOP_PATTERN, rx):
        why = 'the pattern came back shifted by one bit: clock phase (SPI mode) mismatch'
    else:
        bad = sum(bin(a ^ b).count('1') for a, b in zip(LOOP_PATTERN, rx, strict=True))
        why = f'{bad} bit errors: the jumper is too long for this clock, or a device drives MISO'
    return StepResult(step, expect, False, f'sent {LOOP_PATTERN.hex()}, read {rx.hex()}: {why}',
                      means)


def i2c_who_am_i(bus: int | str, address: int, register: int = 0x01,
                 expected: int = 0xB1) -> StepResult:
    """Check that the myAHRS+ acknowledges its address and WHO_AM_I reads 0xB1."""
    step = f'i2c {bus} 0x{address:02x} WHO_AM_I'
    expect = (f'0x{address:02x} acknowledges; register 0x{register:02x} (WHO_AM_I) reads '
              f'0x{expected:02x} (WithRobot myAHRS+ I2C register map)')
    means = ('no ACK (EREMOTEIO): power, SDA/SCL swapped, pull-ups, or another address; a '
             'different WHO_AM_I: another part at that address, or corrupted bytes (clock '
             'stretching: docs/real-robot.md section 6)')
    from m4k_drivers.imu.real import open_real_i2c
    try:
        dev = open_real_i2c(bus, address)
    except DriverError as exc:
        return StepResult(step, expect, False, f'cannot open: {exc}', means)
    try:
        value = dev.read_byte(register)
    except DriverError as exc:
        return StepResult(step, expect, False, f'no answer: {exc}', means)
    finally:
        dev.close()
    ok = value == expected
    return StepResult(step, expect, ok, f'WHO_AM_I = 0x{value:02x}', means)


def gpio_loopback(chip: str, heartbeat_line: int, readback_chip: str, readback_line: int, *,
                  active_low: bool, hold_s: float, period_s: float,
                  sleep: Callable[[float], None] = time.sleep) -> StepResult:
    """Heartbeat edges assert the read-back; once they stop it falls within the hold."""
    step = f'gpio heartbeat {chip}:{heartbeat_line} -> read-back {readback_chip}:{readback_line}'
    expect = ('e-stop released and the relay reset (or a jumper from the heartbeat pin to the '
              'read-back pin): the read-back is asserted while the heartbeat toggles, and not '
              f'asserted {3 * hold_s:.3f} s after it stops')
    means = ('never asserted: the read-back not wired, the relay open, the monostable not '
             'triggered (B input, /CLR) or estop_readback_active opposite to the wiring; still '
             'asserted after the stop: the monostable holds far longer than heartbeat_hold_s, '
             'or the read-back is tied to 3.3 V -- do not power the motors')
    from m4k_drivers.motors.real import open_real_enable, open_real_readback
    try:
        hb = open_real_enable(chip, heartbeat_line)
    except DriverError as exc:
        return StepResult(step, expect, False, f'cannot request the heartbeat: {exc}', means)
    try:
        back = open_real_readback(readback_chip, readback_line, active_low=active_low)
    except DriverError as exc:
        hb.close()
        return StepResult(step, expect, False, f'cannot request the read-back: {exc}', means)
    try:
        for _ in range(6):                    # three rising edges, ending high
            hb.toggle()
            sleep(period_s)
        if not hb.level:
            hb.toggle()
        during = back.read()
        if hb.level:
            hb.toggle()                       # end low: no more edges
        sleep(3 * hold_s)
        after = back.read()
    except DriverError as exc:
        return StepResult(step, expect, False, f'I/O error: {exc}', means)
    finally:
        back.close()
        hb.close()
    detail = f'asserted while toggling: {during}; {3 * hold_s:.3f} s after: {after}'
    return StepResult(step, expect, during and not after, detail, means)


def sonar_no_echo(chip: str, trigger_line: int, echo_line: int, *, no_echo_s: float,
                  timeout_s: float, pings: int = 5, wait_s: float = 0.5) -> StepResult:
    """Pointed at open space, every ping gives the part's no-echo width, matching the config."""
    step = f'sonar no-echo width {chip}:{trigger_line}/{echo_line}'
    expect = ('the sensor pointed at open space (nothing within 5 m in its cone): every ping a '
              'whole ECHO pulse longer than a 4.5 m echo; its width is the no-echo width, '
              f'configured now as no_echo_s {no_echo_s:.4f} s (timeout_s {timeout_s:.4f} s)')
    means = ('no pulse: TRIG/ECHO wiring, the echo divider, or the mode jumper (off = pulse '
             'mode); a short pulse: something in the cone; a width other than no_echo_s: put '
             'the measured value in devices.sonar (no_echo_s, timeout_s = width + 10 ms)')
    from m4k_drivers.sonar import protocol as sp
    from m4k_drivers.sonar.echowidth import measure_widths
    from m4k_drivers.sonar.real import open_gpio_sonar
    try:
        sonar = open_gpio_sonar(chip, trigger_line, echo_line)
    except DriverError as exc:
        return StepResult(step, expect, False, f'cannot request the lines: {exc}', means)
    try:
        widths = measure_widths(sonar, pings, wait_s)
    except DriverError as exc:
        return StepResult(step, expect, False, f'I/O error: {exc}', means)
    finally:
        sonar.close()
    whole = [w for w in widths if w is not None]
    if len(whole) < len(widths):
        return StepResult(step, expect, False, f'{len(widths) - len(whole)} of {len(widths)} '
                          'pings gave no whole ECHO pulse', means)
    hi = max(whole)
    if min(whole) < sp.range_to_pulse(sp.MAX_RANGE_M):
        return StepResult(step, expect, False, f'a pulse of {min(whole) * 1e3:.2f} ms is an '
                          'echo: something is in the cone', means)
    detail = (f'measured {min(whole) * 1e3:.2f}..{hi * 1e3:.2f} ms; set devices.sonar '
              f'no_echo_s: {hi:.4f}, timeout_s: {hi + 0.01:.4f}')
    ok = abs(hi - no_echo_s) <= 0.002 and timeout_s >= hi + 0.01
    return StepResult(step, expect, ok, detail, means)


def amp_hold(motor: dict[str, Any], *, hold_s: float = 0.5, poll_s: float = 0.01,
             sleep: Callable[[float], None] = time.sleep) -> StepResult:
    """Both DACs at zero, the heartbeat requested low and never toggled: the enable stays off."""
    step = 'amplifier hold with the enable off'
    expect = ('both MCP4911 written with code 512 (zero), the heartbeat line held low: the '
              f'e-stop read-back never asserted for {hold_s:.1f} s (the meter check of '
              'docs/real-robot.md section 5a confirms ENABLE at the amplifier)')
    means = ('a DAC write error: the SPI0 node or /CS; the read-back asserted: something holds '
             'the enable without a heartbeat (monostable stuck, strapped enable, bridged relay '
             'contact) -- do not power the motors')
    from m4k_drivers.motors import protocol as p
    from m4k_drivers.motors.real import open_real_bus, open_real_enable, open_real_readback
    m = motor
    rb = m.get('estop_readback_line')
    try:
        bus = open_real_bus(
            m['left_dac'], m['right_dac'], m['left_enc'], m['right_enc'],
            dac_mode=m['dac_mode'], dac_speed_hz=m['dac_speed_hz'], enc_mode=m['enc_mode'],
            enc_speed_hz=m['enc_speed_hz'],
            enable=(lambda: open_real_enable(m['heartbeat_chip'], m['heartbeat_line']))
            if m['heartbeat'] else None,
            readback=(lambda: open_real_readback(m['estop_readback_chip'], rb,
                                                 active_low=m['estop_readback_active'] == 'low'))
            if rb is not None else None)
    except DriverError as exc:
        return StepResult(step, expect, False, f'cannot open the motor bus: {exc}', means)
    try:
        for port in bus.dacs:
            port.transfer(p.encode_dac(p.DAC_ZERO))
        if bus.readback is None:
            return StepResult(step, expect, None, 'DACs at code 512; no read-back configured: '
                              'meter ENABLE at the amplifier (section 5a)', means)
        seen = 0
        for _ in range(max(1, round(hold_s / poll_s))):
            seen += bus.readback.read()
            sleep(poll_s)
    except DriverError as exc:
        return StepResult(step, expect, False, f'I/O error: {exc}', means)
    finally:
        bus.close()
    return StepResult(step, expect, seen == 0,
                      f'DACs at code 512; read-back asserted in {seen} reads', means)


def urg_version(port: str) -> StepResult:
    """Check that the URG answers SCIP 2.0 VV, PP and II: version, model, geometry, state."""
    step = f'urg {port} VV/PP/II'
    expect = ('SCIP 2.0 answers to VV (vendor, product, firmware, protocol, serial), PP (model, '
              'range and step geometry) and II (model, laser, motor speed, state)')
    means = ('cannot open: the udev rule / dialout group / cable; no answer or a protocol '
             'error: not a SCIP 2.0 sensor, or another program holds it')
    from m4k_drivers.lrf.urg import UrgDriver, UrgError
    drv = UrgDriver(port, timeout=1.0)
    try:
        drv.open()
    except (UrgError, OSError) as exc:
        return StepResult(step, expect, False, f'{exc}', means)
    try:
        v, st, spec = drv.version, drv.status, drv.spec
    finally:
        drv.close()
    prot = str(v.get('PROT', ''))
    detail = (f"VEND {v.get('VEND', '?')}; PROD {v.get('PROD', '?')}; FIRM {v.get('FIRM', '?')}; "
              f"PROT {prot}; SERI {v.get('SERI', '?')}; MODL {st.get('MODL', '?')}; "
              f"MESM {st.get('MESM', '?')}; STAT {st.get('STAT', '?')}; steps "
              + (f'{spec.amin}..{spec.amax} of {spec.ares}' if spec is not None else '?'))
    return StepResult(step, expect, 'SCIP 2.0' in prot, detail, means)
