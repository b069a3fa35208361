"""sim-bus: SPI, I2C and GPIO transactions between the driver host and ``sim_robot``.

A Unix stream socket (``<runtime_dir>/sim-bus.sock``) carries what the real kernel interfaces
carry -- a full-duplex SPI transfer, an I2C register read or write, a GPIO level or edge event
with its timestamp -- so the protocol code above the transport is the code that runs on the
robot.  One connection is one opened device (like one fd on spidev / i2c-dev / a gpiochip
line request); closing the socket releases it.  The framing is documented in docs/sim-bus.md.

Every frame, both directions: ``u32 length`` (big-endian, bytes that follow) then the body.
Request body: ``u8 op`` + payload.  Reply body: ``u8 errno`` (0 = ok) + payload, or + UTF-8
message when errno != 0; the client raises ``OSError(errno, message)`` so the driver's error
wrapping (``wrap_os_error``) treats a simulated failure like a real one.

Clients here (one per kernel interface the real backends use):

* :class:`SpiClient` -- ``transfer(bytes) -> bytes``, ``close()``  (periphery.SPI's subset)
* :class:`I2cClient` -- smbus2.SMBus's ``read_byte_data``, ``read_i2c_block_data``,
  ``write_byte_data``, ``i2c_rdwr``, ``close`` plus :meth:`I2cClient.read_burst` (any length)
* :class:`SysfsWriter` -- one ``write(path, text)`` of a sysfs attribute, refused with the
  kernel's errno (the simulated PWM chip: :meth:`m4k_drivers.led.simfs.SysfsLeds.write_attr`)
* :class:`GpioClient` -- periphery.GPIO's ``write``, ``read``, ``poll``, ``read_event``,
  ``close``; events carry CLOCK_MONOTONIC nanosecond timestamps
"""

from __future__ import annotations

import errno
import json
import os
import socket
import struct
import threading
import time
from typing import Any, Callable, NamedTuple

__all__ = [
    'GpioClient', 'GpioEvent', 'I2cClient', 'Op', 'SOCKET_NAME', 'SimBusServer', 'SpiClient',
    'SysfsWriter',
    'read_truth', 'socket_path',
]

SOCKET_NAME = 'sim-bus.sock'
MAX_FRAME = 1 << 16          # nothing on these buses is longer; a bigger length is garbage

_LEN = struct.Struct('>I')
_I2C_READ = struct.Struct('>BBH')      # address, register, length
_I2C_WRITE = struct.Struct('>BB')      # address, register (+ data)
_EVENT_WAIT = struct.Struct('>q')      # timeout ns (0 = just look)
_EVENT = struct.Struct('>BQ')          # edge (1 rising, 2 falling), timestamp ns
_LEVEL = struct.Struct('>BQ')          # level, time of the write (CLOCK_MONOTONIC ns)
_STAMP = struct.Struct('>Q')           # CLOCK_MONOTONIC ns (SPI_TRANSFER_AT: CS asserts)


class Op:
    """Request opcodes (docs/sim-bus.md)."""

    OPEN = 0x01          # JSON {"bus": "spi"|"i2c"|"gpio", ...} -> JSON {"name": ...}
    SPI_TRANSFER = 0x02  # bytes out -> bytes in (same length)
    I2C_READ = 0x03      # addr, reg, n -> n bytes (register auto-increment)
    I2C_WRITE = 0x04     # addr, reg, data -> ''
    GPIO_WRITE = 0x05    # u8 level + u64 writer's CLOCK_MONOTONIC ns -> ''
    GPIO_READ = 0x06     # '' -> u8 level
    GPIO_EVENT = 0x07    # i64 timeout ns -> '' (none) or u8 edge + u64 timestamp ns
    TRUTH = 0x08         # '' -> JSON ground truth (no OPEN needed)
    SYSFS_WRITE = 0x09   # UTF-8 path + NUL + text -> '' (errno as the kernel's store())
    SPI_TRANSFER_AT = 0x0A  # u64 CLOCK_MONOTONIC ns of CS asserting + bytes out -> bytes in


EDGES = {1: 'rising', 2: 'falling'}
EDGE_CODES = {v: k for k, v in EDGES.items()}


def socket_path(runtime_dir: str) -> str:
    """Return the sim-bus socket path inside a runtime directory."""
    return os.path.join(runtime_dir, SOCKET_NAME)


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    buf = bytearray()
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            raise ConnectionResetError(errno.ECONNRESET, 'sim-bus peer closed the connection')
        buf += chunk
    return bytes(buf)


def send_frame(sock: socket.socket, body: bytes) -> None:
    """Send one length-prefixed frame."""
    sock.sendall(_LEN.pack(len(body)) + body)


def recv_frame(sock: socket.socket) -> bytes:
    """Receive one length-prefixed frame (EPROTO for an impossible length)."""
    (n,) = _LEN.unpack(_recv_exact(sock, _LEN.size))
    if n == 0 or n > MAX_FRAME:
        raise OSError(errno.EPROTO, f'sim-bus frame length {n} out of range')
    return _recv_exact(sock, n)


# -- clients ------------------------------------------------------------------------------------
class _Connection:
    """One open device on the sim-bus: synchronous request/reply."""

    def __init__(self, runtime_dir: str, spec: dict[str, Any]) -> None:
        self.path = socket_path(runtime_dir)
        self._lock = threading.Lock()
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            self.sock.connect(self.path)
        except OSError as exc:
            self.sock.close()
            # No simulator running looks like a missing device node.
            raise OSError(exc.errno or errno.ENOENT, f'sim-bus {self.path}: {exc.strerror}'
                          ) from exc
        try:
            self.name = json.loads(self.call(Op.OPEN, json.dumps(spec).encode()))['name']
        except BaseException:
            self.sock.close()
            raise

    def call(self, op: int, payload: bytes = b'') -> bytes:
        """Send one request and return the reply payload (OSError from the simulator)."""
        with self._lock:
            if self.sock.fileno() < 0:
                raise OSError(errno.EBADF, 'sim-bus device closed')
            try:
                send_frame(self.sock, bytes([op]) + payload)
                reply = recv_frame(self.sock)
            except (BrokenPipeError, ConnectionError) as exc:
                # The simulator went away: like a device that vanished under an open fd.
                raise OSError(errno.EIO, f'sim-bus: {exc}') from exc
        if reply[0]:
            raise OSError(reply[0], reply[1:].decode(errors='replace'))
        return reply[1:]

    def close(self) -> None:
        """Close the connection (releases the device in the simulator)."""
        self.sock.close()


class SpiClient:
    """A spidev node in the simulator (``name``: e.g. ``left_dac``)."""

    def __init__(self, runtime_dir: str, name: str) -> None:
        self._conn = _Connection(runtime_dir, {'bus': 'spi', 'name': name})
        self._timed = True

    def transfer(self, data: bytes) -> bytes:
        """Clock ``data`` out and return the bytes clocked in.

        Sent with the instant chip select asserts (SPI_TRANSFER_AT): a device that latches on
        it (an AS5045's angle) answers as of then, however late the simulator handles it. A
        simulator without that op (EOPNOTSUPP) gets plain SPI_TRANSFERs from then on.
        """
        if self._timed:
            try:
                return self._conn.call(Op.SPI_TRANSFER_AT,
                                       _STAMP.pack(time.monotonic_ns()) + bytes(data))
            except OSError as exc:
                if exc.errno != errno.EOPNOTSUPP:
                    raise
                self._timed = False
        return self._conn.call(Op.SPI_TRANSFER, bytes(data))

    def close(self) -> None:
        """Release the node."""
        self._conn.close()


class I2cClient:
    """An i2c-dev bus in the simulator, with the smbus2.SMBus methods the IMU code uses."""

    def __init__(self, runtime_dir: str, bus: int | str) -> None:
        self._conn = _Connection(runtime_dir, {'bus': 'i2c', 'i2c_bus': str(bus)})

    def read_burst(self, i2c_addr: int, register: int, length: int) -> bytes:
        """Read ``length`` registers from ``register`` in one transaction (any length)."""
        return self._conn.call(Op.I2C_READ, _I2C_READ.pack(i2c_addr, register, length))

    def read_byte_data(self, i2c_addr: int, register: int) -> int:
        """Read one register."""
        return self.read_burst(i2c_addr, register, 1)[0]

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]:
        """Read ``length`` consecutive registers (SMBus limit: 1..32)."""
        if not 1 <= length <= 32:
            raise ValueError(f'SMBus block length must be 1..32, got {length!r}')
        return list(self.read_burst(i2c_addr, register, length))

    def write_byte_data(self, i2c_addr: int, register: int, value: int) -> None:
        """Write one register."""
        self._conn.call(Op.I2C_WRITE, _I2C_WRITE.pack(i2c_addr, register) + bytes([value]))

    def i2c_rdwr(self, *messages: Any) -> None:
        """Run smbus2 ``i2c_msg`` messages as one combined transaction (I2C_RDWR).

        A write of one byte sets the register pointer, a longer write writes registers from
        it; a read fills the message's buffer from the pointer (auto-increment) in one I2C_READ.
        """
        import ctypes
        addr, pointer = None, 0
        for msg in messages:
            addr = msg.addr
            if msg.flags & 0x0001:                       # I2C_M_RD (linux/i2c.h)
                data = self.read_burst(addr, pointer, msg.len)
                ctypes.memmove(msg.buf, data, msg.len)
                pointer += msg.len
                continue
            data = bytes(msg)
            if not data:
                continue
            pointer = data[0]
            if len(data) > 1:
                self._conn.call(Op.I2C_WRITE, _I2C_WRITE.pack(addr, pointer) + data[1:])
                pointer += len(data) - 1

    def close(self) -> None:
        """Release the bus."""
        self._conn.close()


class SysfsWriter:
    """Sysfs attribute writes applied by sim_robot's simulated kernel (connects on first use).

    Called like :func:`m4k_drivers.led.real.write_attr`; a refused write raises the OSError the
    kernel would return for it.  ``close()`` releases the connection.
    """

    def __init__(self, runtime_dir: str) -> None:
        self.runtime_dir = runtime_dir
        self._conn: _Connection | None = None

    def __call__(self, path: str, text: str) -> None:
        """Write ``text`` to the attribute ``path`` (OSError as the kernel refuses it)."""
        if self._conn is None:
            self._conn = _Connection(self.runtime_dir, {'bus': 'sysfs'})
        try:
            self._conn.call(Op.SYSFS_WRITE, path.encode() + b'\0' + text.encode())
        except OSError as exc:
            if exc.errno == errno.EIO:       # the simulator went away: reconnect next time
                self.close()
            raise OSError(exc.errno, exc.strerror, path) from None

    def close(self) -> None:
        """Release the connection (the next write reconnects)."""
        if self._conn is not None:
            self._conn.close()
            self._conn = None


class GpioEvent(NamedTuple):
    """An edge event as periphery reports it: ``edge`` 'rising'/'falling', ns timestamp."""

    edge: str
    timestamp: int


class GpioClient:
    """One requested GPIO line of a simulated gpiochip (periphery.GPIO's subset)."""

    def __init__(self, runtime_dir: str, chip: str, line: int, direction: str,
                 edge: str = 'none', event_clock: str = 'monotonic') -> None:
        if event_clock not in ('monotonic', 'realtime'):
            raise ValueError(f"event_clock must be 'monotonic' or 'realtime', "
                             f'got {event_clock!r}')
        self.chip, self.line = chip, line
        self._conn = _Connection(runtime_dir, {'bus': 'gpio', 'chip': chip, 'line': line,
                                               'direction': direction, 'edge': edge,
                                               'event_clock': event_clock})
        self._pending: list[GpioEvent] = []
        if direction in ('low', 'high'):
            self.write(direction == 'high')

    def write(self, value: bool) -> None:
        """Drive the (output) line.

        The write time travels with the level: an electrical edge happens when the driver
        writes it, not when the simulator gets round to reading the socket.
        """
        self._conn.call(Op.GPIO_WRITE, _LEVEL.pack(1 if value else 0, time.monotonic_ns()))

    def read(self) -> bool:
        """Return the line level."""
        return bool(self._conn.call(Op.GPIO_READ)[0])

    def poll(self, timeout: float | None = None) -> bool:
        """Wait up to ``timeout`` s (None: 60 s) for an edge event; True if one is ready."""
        if self._pending:
            return True
        wait_ns = int((60.0 if timeout is None else max(timeout, 0.0)) * 1e9)
        reply = self._conn.call(Op.GPIO_EVENT, _EVENT_WAIT.pack(wait_ns))
        if not reply:
            return False
        code, stamp = _EVENT.unpack(reply)
        self._pending.append(GpioEvent(EDGES.get(code, 'none'), stamp))
        return True

    def read_event(self) -> GpioEvent:
        """Return the next edge event (waits for one)."""
        while not self._pending:
            self.poll(None)
        return self._pending.pop(0)

    def close(self) -> None:
        """Release the line."""
        self._conn.close()


def read_truth(runtime_dir: str, timeout_s: float = 2.0) -> dict[str, Any]:
    """Ask a running simulator for its ground truth (OSError when none answers)."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(timeout_s)
    try:
        sock.connect(socket_path(runtime_dir))
        send_frame(sock, bytes([Op.TRUTH]))
        reply = recv_frame(sock)
    finally:
        sock.close()
    if reply[0]:
        raise OSError(reply[0], reply[1:].decode(errors='replace'))
    return json.loads(reply[1:])


# -- server -------------------------------------------------------------------------------------
class SimBusServer:
    """Serve device models on the sim-bus socket, one thread per connection.

    ``open_device(spec) -> (name, device)`` resolves an OPEN request to a model object (raise
    OSError, e.g. ENOENT, for nothing at that address); ``truth()`` returns the JSON-able ground
    truth.  Models: SPI ``transfer(bytes)``; I2C ``read_burst(addr, reg, n)``,
    ``write_byte_data(addr, reg, value)``; GPIO ``write(bool, t_ns)``, ``read()``,
    ``wait_event(timeout_s) -> (edge, t_ns) | None``; all optionally ``release()``.
    """

    def __init__(self, path: str, open_device: Callable[[dict[str, Any]], tuple[str, Any]],
                 truth: Callable[[], dict[str, Any]]) -> None:
        self.path = path
        self.open_device = open_device
        self.truth = truth
        self.connections = 0
        self.errors = 0
        self._stop = threading.Event()
        self._clients: set[socket.socket] = set()
        self._lock = threading.Lock()
        try:
            os.unlink(path)
        except FileNotFoundError:
            pass
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.bind(path)
        # Like the XDDP sockets: the owner only, or the group the runtime dir is shared with.
        shared = os.stat(os.path.dirname(path) or '.').st_mode & 0o070
        os.chmod(path, 0o660 if shared else 0o600)
        self.sock.listen(16)
        self.thread = threading.Thread(target=self._accept, name='sim-bus', daemon=True)

    def start(self) -> SimBusServer:
        """Start accepting connections."""
        self.thread.start()
        return self

    def close(self) -> None:
        """Stop accepting, drop every connection and remove the socket."""
        self._stop.set()
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()
        with self._lock:
            for c in list(self._clients):
                try:
                    c.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
        try:
            os.unlink(self.path)
        except FileNotFoundError:
            pass
        if self.thread.is_alive():
            self.thread.join(2.0)

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.connections += 1
            with self._lock:
                self._clients.add(conn)
            threading.Thread(target=self._serve, args=(conn,), name='sim-bus-conn',
                             daemon=True).start()

    def _serve(self, conn: socket.socket) -> None:
        device: Any = None
        realtime = False
        try:
            while not self._stop.is_set():
                try:
                    body = recv_frame(conn)
                except OSError:
                    return
                try:
                    if body[0] == Op.OPEN:
                        if device is not None:
                            raise OSError(errno.EBUSY, 'this connection already has a device')
                        spec = json.loads(body[1:])
                        name, device = self.open_device(spec)
                        realtime = spec.get('event_clock') == 'realtime'
                        reply = json.dumps({'name': name}).encode()
                    elif body[0] == Op.TRUTH:
                        reply = json.dumps(self.truth()).encode()
                    else:
                        if device is None:
                            raise OSError(errno.EBADF, 'no device opened on this connection')
                        reply = self._device_op(device, body[0], body[1:], realtime)
                    send_frame(conn, b'\x00' + reply)
                except OSError as exc:
                    self.errors += 1
                    code = exc.errno if exc.errno and 0 < exc.errno < 256 else errno.EIO
                    send_frame(conn, bytes([code]) + str(exc.strerror or exc).encode())
                except (ValueError, KeyError, TypeError, IndexError, struct.error) as exc:
                    self.errors += 1
                    send_frame(conn, bytes([errno.EINVAL]) + f'bad request: {exc}'.encode())
                except Exception as exc:  # noqa: BLE001 - a model's complaint, not our crash
                    self.errors += 1
                    send_frame(conn, bytes([errno.EIO]) + f'{type(exc).__name__}: {exc}'.encode())
        except OSError:
            return
        finally:
            with self._lock:
                self._clients.discard(conn)
            conn.close()
            release = getattr(device, 'release', None)
            if release is not None:
                release()

    @staticmethod
    def _device_op(device: Any, op: int, payload: bytes, realtime: bool = False) -> bytes:
        if op == Op.SPI_TRANSFER:
            return bytes(device.transfer(payload))
        if op == Op.SPI_TRANSFER_AT:
            if len(payload) < _STAMP.size:
                raise OSError(errno.EINVAL, 'SPI_TRANSFER_AT: no timestamp')
            (t_ns,) = _STAMP.unpack(payload[:_STAMP.size])
            at = getattr(device, 'transfer_at', None)
            data = payload[_STAMP.size:]
            return bytes(device.transfer(data) if at is None else at(data, t_ns))
        if op == Op.I2C_READ:
            addr, reg, n = _I2C_READ.unpack(payload)
            return bytes(device.read_burst(addr, reg, n))
        if op == Op.I2C_WRITE:
            addr, reg = _I2C_WRITE.unpack(payload[:_I2C_WRITE.size])
            for i, value in enumerate(payload[_I2C_WRITE.size:]):
                device.write_byte_data(addr, reg + i, value)
            return b''
        if op == Op.GPIO_WRITE:
            level, t_ns = _LEVEL.unpack(payload)
            device.write(bool(level), t_ns)
            return b''
        if op == Op.GPIO_READ:
            return bytes([1 if device.read() else 0])
        if op == Op.GPIO_EVENT:
            (timeout_ns,) = _EVENT_WAIT.unpack(payload)
            ev = device.wait_event(max(timeout_ns, 0) * 1e-9)
            if ev is None:
                return b''
            stamp = ev[1]
            if realtime:    # what a line request with EVENT_CLOCK_REALTIME reports
                stamp += time.time_ns() - time.monotonic_ns()
            return _EVENT.pack(EDGE_CODES[ev[0]], stamp)
        if op == Op.SYSFS_WRITE:
            path, _, text = payload.partition(b'\0')
            device.write_attr(path.decode(), text.decode())
            return b''
        raise OSError(errno.EOPNOTSUPP, f'unknown sim-bus op 0x{op:02x}')
