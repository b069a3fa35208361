"""The kernel stand-in wired to ``sim_robot``: what the wires carry, over the sim-bus.

With ``kernel_standin: {enabled: true}`` the driver host installs a
:class:`~m4k_drivers.abi.kernel.KernelStandIn` whose devices forward to the simulated robot:
the stand-in plays the kernel (decodes ``spi_ioc_transfer``, ``i2c_msg``, the GPIO v2 line
requests), the sim-bus carries the wire-level result (the bytes of one chip-select period, the
register pointer and data of one I2C transaction, a level with the time it was driven, an edge
with its time), and ``sim_robot``'s MCP4911/AS5045/myAHRS+/US-100/monostable models answer.
So ``make run CONFIG=config/standin.yaml`` runs the real motor, IMU and sonar backends --
python-periphery and smbus2 included -- on the simulated world.
"""

from __future__ import annotations

import threading
from typing import Any

from m4k_drivers.abi.devices import EmitEdge, Line
from m4k_drivers.abi.kernel import GpioChip, I2cAdapter, KernelStandIn, SpiNode

__all__ = ['SimBusI2cDevice', 'SimBusLine', 'SimBusSpiDevice', 'standin_for']

_EDGE_IDS = {'rising': 1, 'falling': 2}


class SimBusSpiDevice:
    """A chip select whose device is ``sim_robot``'s SPI model ``name``."""

    def __init__(self, runtime_dir: str, name: str) -> None:
        self.runtime_dir, self.name = runtime_dir, name
        self.client: Any = None

    def transfer(self, tx: bytes, mode: int, speed_hz: int, bits_per_word: int) -> bytes:
        """Clock one chip-select period through the simulator (connects on first use)."""
        from m4k_drivers.simbus import SpiClient
        if self.client is None:
            self.client = SpiClient(self.runtime_dir, self.name)
        try:
            return bytes(self.client.transfer(tx))
        except OSError:
            self.close()                  # the simulator restarted: reconnect next time
            raise

    def close(self) -> None:
        """Drop the connection."""
        if self.client is not None:
            self.client.close()
            self.client = None

    release = close          # the node was closed (KernelStandIn)


class SimBusI2cDevice:
    """One I2C address on ``sim_robot``'s bus ``bus``: transactions as pointer + data."""

    def __init__(self, runtime_dir: str, bus: str, addr: int) -> None:
        self.runtime_dir, self.bus, self.addr = runtime_dir, bus, addr
        self.client: Any = None
        self.pointer = 0

    def i2c_transaction(self, msgs: list[tuple[bool, bytes | int]]) -> list[bytes]:
        """Run one transaction: a write sets the pointer (+ data), a read auto-increments."""
        from m4k_drivers.simbus import I2cClient
        if self.client is None:
            self.client = I2cClient(self.runtime_dir, self.bus)
        out = []
        try:
            for is_read, data in msgs:
                if is_read:
                    n = int(data)
                    out.append(bytes(self.client.read_burst(self.addr, self.pointer, n)))
                    self.pointer = (self.pointer + n) & 0xFF
                    continue
                buf = bytes(data)
                if not buf:
                    continue
                self.pointer = buf[0]
                for b in buf[1:]:
                    self.client.write_byte_data(self.addr, self.pointer, b)
                    self.pointer = (self.pointer + 1) & 0xFF
        except OSError:
            if self.client is not None:
                self.client.close()
                self.client = None
            raise
        return out

    def release(self) -> None:
        """Drop the connection (the bus node was closed)."""
        if self.client is not None:
            self.client.close()
            self.client = None


class _AnyAddress(dict):
    """Every address forwards; the simulator NACKs (EREMOTEIO) the ones nobody answers."""

    def __init__(self, runtime_dir: str, bus: str) -> None:
        super().__init__()
        self.runtime_dir, self.bus = runtime_dir, bus

    def get(self, addr: int, default: Any = None) -> Any:   # noqa: D102
        if addr not in self:
            self[addr] = SimBusI2cDevice(self.runtime_dir, self.bus, addr)
        return self[addr]


class SimBusLine(Line):
    """A GPIO line of ``sim_robot``: outputs drive it, inputs forward its edges."""

    def __init__(self, runtime_dir: str, chip: str, line: int,
                 wake: threading.Event | None = None) -> None:
        self.runtime_dir, self.chip, self.line = runtime_dir, chip, line
        # An input with ``wake`` asks for edges only after it is set (the US-100's TRIG fell):
        # sim_robot's echo model sleeps a whole poll timeout when nothing is pending, so an
        # idle poll would hold back the edges of a ping that starts meanwhile.
        self.wake = wake
        self.out: Any = None
        self.inp: Any = None
        self.reader: Any = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def driven(self, level: bool, t_ns: int) -> None:
        """Drive the simulated line (requested as an output on first use)."""
        from m4k_drivers.simbus import GpioClient
        if self.out is None:
            self.out = GpioClient(self.runtime_dir, self.chip, self.line,
                                  'high' if level else 'low')
            return
        self.out.write(level)
        if not level and self.wake is not None:
            self.wake.set()

    def level(self, t_ns: int) -> bool:
        """Read the simulated line (an input without edges is requested on first read)."""
        from m4k_drivers.simbus import GpioClient
        client = self.out or self.inp or self.reader
        if client is None:
            client = self.reader = GpioClient(self.runtime_dir, self.chip, self.line, 'in')
        return bool(client.read())

    def attach(self, emit: EmitEdge | None) -> None:
        """Forward the simulated line's edges (monotonic stamps) while attached."""
        from m4k_drivers.simbus import GpioClient
        self._detach()
        if emit is None:
            return
        self.inp = GpioClient(self.runtime_dir, self.chip, self.line, 'in', edge='both')
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._forward, args=(self.inp, emit, self._stop),
                                        name=f'abi-edges-{self.line}', daemon=True)
        self._thread.start()

    def _forward(self, client: Any, emit: EmitEdge, stop: threading.Event) -> None:
        while not stop.is_set():
            if self.wake is not None:
                if not self.wake.wait(0.2):
                    continue
                self.wake.clear()
            try:
                while client.poll(0.1):       # the edges of this ping, at their times
                    ev = client.read_event()
                    emit(_EDGE_IDS.get(ev.edge, 0), ev.timestamp)
                    if ev.edge == 'falling' and self.wake is not None:
                        break
            except OSError:
                return

    def release(self) -> None:
        """Release the simulated line (the line request was closed)."""
        self._detach()
        for client in (self.out, self.reader):
            if client is not None:
                client.close()
        self.out = self.reader = None

    def _detach(self) -> None:
        self._stop.set()
        if self.inp is not None:
            self.inp.close()       # unblocks the forwarder's poll with an error
            self.inp = None
        if self._thread is not None:
            self._thread.join(1.0)
            self._thread = None


def standin_for(devices: dict[str, dict[str, Any]], runtime_dir: str) -> KernelStandIn:
    """Return a stand-in serving the nodes of the enabled real motor/imu/sonar sections."""
    k = KernelStandIn()
    chips: dict[str, GpioChip] = {}

    def line(chip: str, offset: int, wake: threading.Event | None = None) -> None:
        chips.setdefault(chip, GpioChip()).lines[offset] = SimBusLine(runtime_dir, chip, offset,
                                                                      wake)

    m = devices.get('motor')
    if m and m['enabled'] and m['backend'] == 'real':
        for name in ('left_dac', 'right_dac', 'left_enc', 'right_enc'):
            k.spi[m[name]] = SpiNode(SimBusSpiDevice(runtime_dir, name))
        if m['heartbeat']:
            line(m['heartbeat_chip'], m['heartbeat_line'])
        if m.get('estop_readback_line') is not None:
            line(m['estop_readback_chip'], m['estop_readback_line'])
        if m['ldac'] == 'gpio':
            # sim_robot's DACs update on every write (/LDAC low); a driven /LDAC line is
            # served (so the request succeeds) but has nothing behind it.
            chips.setdefault(m['ldac_chip'], GpioChip()).lines.setdefault(m['ldac_line'], Line())
    i = devices.get('imu')
    if i and i['enabled'] and i['backend'] == 'real':
        path = i['bus'] if isinstance(i['bus'], str) else f'/dev/i2c-{i["bus"]}'
        bus = str(i['bus']).removeprefix('/dev/i2c-')
        k.i2c[path] = I2cAdapter(_AnyAddress(runtime_dir, bus))
    s = devices.get('sonar')
    if s and s['enabled'] and s['backend'] in ('real', 'gpio'):
        ping = threading.Event()
        line(s['chip'], s['trigger_line'], ping)
        line(s['chip'], s['echo_line'], ping)
    k.gpio.update(chips)
    return k
