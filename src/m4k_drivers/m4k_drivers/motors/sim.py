"""Simulated SPI peers for the motors: MCP4911 DACs feeding the world, AS5045 encoders reading it.

They expose the same ``transfer(bytes) -> bytes`` as a spidev node, so the protocol code runs
unchanged; ``sim_robot`` serves them on the sim-bus (:func:`open_simbus_bus` is the driver
side).  The DAC peer models the chip (Vout = Vref * code / 1024 at gain 1x, 0 V when shut
down) and the motor amplifier (mid-scale Vref/2 = 0 V armature, full scale = +/- supply).  Like
the MCP4911 with LDAC tied low, the output holds the last written word until a new one comes:
nothing resets it when its SPI master goes away.  :class:`EnableMonostable` is the amplifier
enable: a retriggerable monostable on the heartbeat line.  The encoder peer is on the wheel
shaft, like the real one, and adds +/-1 LSB noise.
"""

from __future__ import annotations

import math

from m4k_drivers.handler import DeviceProtocolError, DriverError, wrap_os_error
from m4k_drivers.motors import protocol as p
from m4k_drivers.motors.real import EnableLine, MotorBus, ReadbackLine, SpiPort
from m4k_drivers.world import World

__all__ = ['EnableMonostable', 'EstopReadback', 'SPI_NAMES', 'SimDac', 'SimEncoder',
           'open_sim_bus', 'open_simbus_bus']

# The four spidev nodes of the base as sim_robot names them on the sim-bus.
SPI_NAMES = ('left_dac', 'right_dac', 'left_enc', 'right_enc')


class SimDac:
    """An MCP4911 plus motor amplifier driving one motor of the simulated world."""

    def __init__(self, world: World, side: int, vref: float = 3.3) -> None:
        self.world = world
        self.side = side
        self.vref = vref
        self.last: p.DacFrame | None = None
        self.frames = 0
        self.closed = False

    def transfer(self, data: bytes) -> bytes:
        """Latch one write frame, set the motor voltage, return what MISO shows (zeros)."""
        if self.closed:
            raise OSError(9, 'Bad file descriptor')
        frame = p.decode_dac(data)
        if not frame.write:
            return bytes(len(data))
        self.world.now()          # apply the new voltage from the present time on
        gain = 1 if frame.gain1x else 2
        vout = p.code_to_volts(frame.code, self.vref, gain) if frame.active else 0.0
        # The amplifier is trimmed so code 512 -> 0 V and code 1023 -> +supply at gain 1x.
        mid = p.code_to_volts(p.DAC_ZERO, self.vref)
        full = p.code_to_volts(p.DAC_MAX, self.vref) - mid
        armature = (vout - mid) / full * self.world.robot.supply_v
        self.world.set_motor_voltage(self.side, armature)
        self.last = frame
        self.frames += 1
        return bytes(len(data))

    def close(self) -> None:
        """Mark closed (further transfers fail like a closed fd)."""
        self.closed = True


class SimEncoder:
    """An AS5045 on one wheel shaft of the simulated world."""

    def __init__(self, world: World, side: int, noise_lsb: float = 0.5,
                 lead_bits: int = 1) -> None:
        self.world = world
        self.side = side
        self.noise_lsb = noise_lsb
        self.lead_bits = lead_bits
        self.rng = world.rng(f'encoder.{side}')
        self.closed = False
        self.fault: dict[str, bool] | None = None    # status-bit override for fault injection

    def raw(self, t_ns: int | None = None) -> int:
        """Return the 12-bit reading of ``t_ns`` (default now) with noise (a faulty one's too)."""
        # The angle at the read time, as the world's encoder faults have it (m4k_drivers.faults)
        angle, frozen = self.world.encoder_angle(self.side, t_ns)
        counts = angle / (2.0 * math.pi) * p.ENC_COUNTS
        if self.noise_lsb and not frozen:
            counts += float(self.rng.normal(0.0, self.noise_lsb))
        return int(math.floor(counts)) % p.ENC_COUNTS

    def transfer(self, data: bytes) -> bytes:
        """Answer a 3-byte read with the current frame."""
        return self.transfer_at(data, None)

    def transfer_at(self, data: bytes, t_ns: int | None) -> bytes:
        """Answer a 3-byte read with the frame latched at ``t_ns`` (CSn's falling edge).

        The AS5045 latches its angle when CSn falls, the instant the read starts (datasheet:
        SSI, "the data is latched at the falling edge of CSn"), not when a simulator short of
        CPU gets round to the request; ``None``: now.
        """
        if self.closed:
            raise OSError(9, 'Bad file descriptor')
        if len(data) != p.ENC_READ_LEN:
            raise DeviceProtocolError(f'AS5045 sim: expected a {p.ENC_READ_LEN}-byte read, '
                                      f'got {bytes(data)!r}')
        if t_ns is not None and t_ns > self.world.clock():
            t_ns = None         # a stamp from the future is another clock (a test's): now
        return p.encode_encoder(self.raw(t_ns), lead_bits=self.lead_bits, **(self.fault or {}))

    def close(self) -> None:
        """Mark closed."""
        self.closed = True


def open_sim_bus(world: World, *, vref: float = 3.3, noise_lsb: float = 0.5,
                 lead_bits: int = 1) -> MotorBus:
    """Return a MotorBus whose four endpoints are simulated peers on ``world``."""
    return MotorBus(SpiPort(SimDac(world, 0, vref), 'sim:left_dac'),
                    SpiPort(SimDac(world, 1, vref), 'sim:right_dac'),
                    SpiPort(SimEncoder(world, 0, noise_lsb, lead_bits), 'sim:left_enc'),
                    SpiPort(SimEncoder(world, 1, noise_lsb, lead_bits), 'sim:right_enc'))


class EnableMonostable:
    """The amplifier enable: a retriggerable monostable clocked by the heartbeat line.

    As a 74HC123 with the heartbeat on B and A tied low: every rising edge restarts the hold
    time; the enable output is on while the last rising edge is younger than ``hold_s``, so a
    heartbeat toggled every command period retriggers it every two periods.  It starts off:
    no drive until the first heartbeat.
    """

    def __init__(self, world: World, hold_s: float) -> None:
        self.world = world
        self.hold_ns = round(hold_s * 1e9)
        self.level = False
        self.edges = 0
        self.last_edge_ns: int | None = None
        self.drops = 0
        t = world.now()
        world.set_enable_until(t)

    def write(self, value: bool, t_ns: int | None = None) -> None:
        """Drive the heartbeat line (written at ``t_ns``); a rising edge retriggers the hold."""
        rising = bool(value) and not self.level
        self.level = bool(value)
        if not rising:
            return
        t = self.world.now()         # integrate up to the edge under the old hold time
        self.edges += 1
        if not self.world.drive_enabled(t) and self.last_edge_ns is not None:
            self.drops += 1          # the hold ran out between two edges of a live heartbeat
        # The writer's time of the edge (the socket may have delayed it), when it is on the
        # world's clock: within a hold time of it (a test world may run on a fake clock).
        edge = t if t_ns is None or abs(t - t_ns) > self.hold_ns else min(t, t_ns)
        self.world.set_enable_until(edge + self.hold_ns)
        self.last_edge_ns = edge

    def read(self) -> bool:
        """Return the line level."""
        return self.level

    def close(self) -> None:
        """Release the line: the pull-down holds it low, which never retriggers."""
        self.level = False

    def wait_event(self, timeout_s: float) -> None:
        """Raise: an output line has no edge events."""
        raise OSError(22, 'heartbeat line was requested as an output: no edge events')


class EstopReadback:
    """The e-stop read-back input: the amplifier enable after the e-stop contact (a GPIO model).

    High while the enable reaches the amplifiers (heartbeat live and contact closed); low while
    the contact is open or the heartbeat has run out.
    """

    def __init__(self, world: World, active_low: bool = False) -> None:
        self.world = world
        self.active_low = active_low         # the inverting stage of docs/real-robot.md
        self.reads = 0

    def write(self, value: bool, t_ns: int | None = None) -> None:
        """Refuse: the read-back is an input."""
        raise OSError(1, 'e-stop read-back was requested as an input')

    def read(self) -> bool:
        """Return the wire level: the enable after the contact, through the wired polarity."""
        self.world.now()
        self.reads += 1
        return self.world.drive_enabled() != self.active_low

    def close(self) -> None:
        """Nothing to release."""

    def wait_event(self, timeout_s: float) -> None:
        """Raise: requested without edge detection."""
        raise OSError(22, 'e-stop read-back was requested without edge events')


def open_simbus_bus(runtime_dir: str, enable_line: tuple[str, int] | None = None,
                    readback_line: tuple[str, int] | None = None, *,
                    readback_low: bool = False) -> MotorBus:
    """Open the four SPI nodes, the heartbeat and read-back lines of sim_robot on its sim-bus."""
    from m4k_drivers.simbus import GpioClient, SpiClient
    opened: list[SpiPort] = []
    try:
        for name in SPI_NAMES:
            where = f'sim-bus:{name}'
            try:
                opened.append(SpiPort(SpiClient(runtime_dir, name), where))
            except OSError as exc:
                raise wrap_os_error(exc, where) from exc
        line = back = None
        if enable_line is not None:
            where = f'sim-bus:{enable_line[0]} line {enable_line[1]}'
            try:
                line = EnableLine(GpioClient(runtime_dir, *enable_line, 'low'), where)
            except OSError as exc:
                raise wrap_os_error(exc, where) from exc
        if readback_line is not None:
            where = f'sim-bus:{readback_line[0]} line {readback_line[1]} (e-stop read-back)'
            try:
                back = ReadbackLine(GpioClient(runtime_dir, *readback_line, 'in'), where,
                                    invert=readback_low)
            except OSError as exc:
                if line is not None:
                    line.close()
                raise wrap_os_error(exc, where) from exc
    except DriverError:
        for port in opened:
            port.close()
        raise
    dac_l, dac_r, enc_l, enc_r = opened
    return MotorBus(dac_l, dac_r, enc_l, enc_r, enable=line, readback=back)
