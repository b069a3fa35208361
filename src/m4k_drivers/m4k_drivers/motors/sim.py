"""Simulated SPI peers for the motors: MCP4911 DACs feeding the world, AS5045 encoders reading it.

They expose the same ``transfer(bytes) -> bytes`` as a spidev node, so the protocol code runs
unchanged.  The DAC peer models the chip (Vout = Vref * code / 1024 at gain 1x, 0 V when shut
down) and the motor amplifier (mid-scale Vref/2 = 0 V armature, full scale = +/- supply).
The encoder peer is on the wheel shaft, like the real one, and adds +/-1 LSB noise.
"""

from __future__ import annotations

import math

from m4k_drivers.handler import DeviceProtocolError
from m4k_drivers.motors import protocol as p
from m4k_drivers.motors.real import MotorBus, SpiPort
from m4k_drivers.world import World

__all__ = ['SimDac', 'SimEncoder', 'open_sim_bus']


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

    def raw(self) -> int:
        """Return the current 12-bit reading with noise."""
        angle = self.world.wheel_angle_at(self.side)   # the angle at the read time
        counts = angle / (2.0 * math.pi) * p.ENC_COUNTS
        if self.noise_lsb:
            counts += float(self.rng.normal(0.0, self.noise_lsb))
        return int(math.floor(counts)) % p.ENC_COUNTS

    def transfer(self, data: bytes) -> bytes:
        """Answer a 3-byte read with the current frame."""
        if self.closed:
            raise OSError(9, 'Bad file descriptor')
        if len(data) != p.ENC_READ_LEN:
            raise DeviceProtocolError(f'AS5045 sim: expected a {p.ENC_READ_LEN}-byte read, '
                                      f'got {bytes(data)!r}')
        return p.encode_encoder(self.raw(), lead_bits=self.lead_bits, **(self.fault or {}))

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
