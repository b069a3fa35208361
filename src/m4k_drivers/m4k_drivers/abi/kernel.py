"""A stand-in for the kernel at the open/ioctl/read/close boundary of spidev, i2c-dev, GPIO v2.

:class:`KernelStandIn` replaces ``os.open``, ``os.close``, ``os.read``, ``fcntl.ioctl`` (and
smbus2's own reference to it) while installed.  A path it serves opens to a real file
descriptor (``/dev/null`` for a node, a pipe for a GPIO line request: its read end is what
``poll()`` and ``read()`` see, so python-periphery's ``select.poll`` runs unchanged); every
other path and descriptor goes to the real call.  Each ioctl on a served descriptor is decoded
from the argument's bytes with the :mod:`~m4k_drivers.abi.uapi` layouts -- the pointers inside
(``spi_ioc_transfer.tx_buf``, ``i2c_msg.buf``, ``i2c_smbus_ioctl_data.data``) are followed into
the caller's memory as the kernel's ``copy_from_user`` would -- checked as the kernel checks it
(errno on anything it refuses), and handed to the device models of
:mod:`~m4k_drivers.abi.devices`.  GPIO edge events are written to the line's pipe as
``struct gpio_v2_line_event`` records at the moment the edge happens, stamped with the clock
the line request asked for (CLOCK_MONOTONIC unless ``EVENT_CLOCK_REALTIME``).

Every call is recorded in :attr:`KernelStandIn.log` (what, decoded) so a test can assert the
backend did what the hardware needs (mode, speed, bits per word, chip-select changes).
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import heapq
import os
import select
import threading
import time
from typing import Any, Callable

from m4k_drivers.abi import uapi as u
from m4k_drivers.abi.devices import Line

__all__ = ['GpioChip', 'I2cAdapter', 'KernelStandIn', 'SpiNode']

SPIDEV_BUFSIZ = 4096          # spidev module parameter bufsiz: the most one message may carry
I2C_MSG_MAX = 8192            # i2c-dev refuses a longer i2c_msg


def _err(code: int, what: str) -> OSError:
    return OSError(code, f'{os.strerror(code)} ({what})')


class SpiNode:
    """``/dev/spidevB.C``: the per-open settings and the device on that chip select."""

    def __init__(self, device: Any, max_speed_hz: int = 125_000_000) -> None:
        self.device = device      # transfer(tx, mode, speed_hz, bits_per_word) -> rx
        self.mode = 0
        self.bits_per_word = 8
        self.max_speed_hz = max_speed_hz
        self.messages = 0


class I2cAdapter:
    """``/dev/i2c-N``: the devices on the bus by 7-bit address."""

    def __init__(self, devices: dict[int, Any] | None = None) -> None:
        # addr -> i2c_transaction(msgs) -> reads; a dict subclass may answer any address
        self.devices = devices if devices is not None else {}


class GpioChip:
    """``/dev/gpiochipN``: ``nlines`` lines, some with a device (a :class:`Line`) on them."""

    def __init__(self, nlines: int = 54, lines: dict[int, Line] | None = None,
                 label: str = 'pinctrl-bcm2835') -> None:
        self.nlines = nlines
        self.label = label
        self.lines: dict[int, Line] = dict(lines or {})
        self.requested: dict[int, _LineRequest] = {}


class _Open:
    """One open file description."""

    def __init__(self, kind: str, node: Any, path: str) -> None:
        self.kind, self.node, self.path = kind, node, path
        self.i2c_addr: int | None = None
        self.spi_mode = node.mode if kind == 'spi' else 0
        self.spi_bits = node.bits_per_word if kind == 'spi' else 8
        self.spi_speed = node.max_speed_hz if kind == 'spi' else 0


class _LineRequest:
    """An open line request (GPIO_V2_GET_LINE_IOCTL): its lines, flags and event pipe."""

    def __init__(self, chip: GpioChip, offsets: list[int], consumer: str) -> None:
        self.chip, self.offsets, self.consumer = chip, offsets, consumer
        self.flags = [0] * len(offsets)
        self.values = [False] * len(offsets)
        self.rfd, self.wfd = os.pipe()
        self.seqno = 0
        self.line_seqno = [0] * len(offsets)
        self.lock = threading.Lock()
        self.closed = False


def _release(device: Any) -> None:
    """Tell a device its node was closed (a model holding a connection drops it)."""
    release = getattr(device, 'release', None)
    if release is not None:
        release()


def _line_flags_valid(flags: int) -> str | None:
    """Return why the kernel refuses these v2 line flags (gpiolib-cdev.c's rules), or None."""
    inp, out = flags & u.GPIO_V2_LINE_FLAG_INPUT, flags & u.GPIO_V2_LINE_FLAG_OUTPUT
    edges = flags & (u.GPIO_V2_LINE_FLAG_EDGE_RISING | u.GPIO_V2_LINE_FLAG_EDGE_FALLING)
    known = (1 << 13) - 2       # bits 1..12; USED (bit 0) is never a request flag
    if flags & ~known:
        return f'unknown flag bits 0x{flags & ~known:x}'
    if inp and out:
        return 'INPUT and OUTPUT together'
    if edges and not inp:
        return 'edge detection without INPUT'
    if (flags & (u.GPIO_V2_LINE_FLAG_OPEN_DRAIN | u.GPIO_V2_LINE_FLAG_OPEN_SOURCE)) and not out:
        return 'drive flags without OUTPUT'
    if (flags & u.GPIO_V2_LINE_FLAG_EVENT_CLOCK_REALTIME) and (
            flags & u.GPIO_V2_LINE_FLAG_EVENT_CLOCK_HTE):
        return 'two event clocks'
    bias = flags & (u.GPIO_V2_LINE_FLAG_BIAS_PULL_UP | u.GPIO_V2_LINE_FLAG_BIAS_PULL_DOWN
                    | u.GPIO_V2_LINE_FLAG_BIAS_DISABLED)
    if bias & (bias - 1):
        return 'more than one bias'
    if bias and not (inp or out):
        return 'bias without a direction'
    return None


class KernelStandIn:
    """Serve spidev, i2c-dev and gpiochip paths to this process's real backends."""

    def __init__(self) -> None:
        self.spi: dict[str, SpiNode] = {}
        self.i2c: dict[str, I2cAdapter] = {}
        self.gpio: dict[str, GpioChip] = {}
        self.log: list[tuple[str, str, dict[str, Any]]] = []   # (path, call, decoded)
        self._files: dict[int, _Open | _LineRequest] = {}
        self._saved: list[tuple[Any, str, Any]] = []
        self._lock = threading.RLock()
        self._events: list[tuple[int, int, Callable[[], None]]] = []
        self._event_seq = 0
        self._wake = threading.Condition(self._lock)
        self._thread: threading.Thread | None = None
        self._stop = False
        self._real_open = os.open
        self._real_close = os.close
        self._real_read = os.read
        self._real_ioctl = fcntl.ioctl
        self._real_poll = select.poll

    # -- installing ----------------------------------------------------------------------------
    def install(self) -> KernelStandIn:
        """Take over the calls (until :meth:`uninstall`); returns self."""
        targets: list[tuple[Any, str, Any]] = [
            (os, 'open', self._open), (os, 'close', self._close), (os, 'read', self._read),
            (fcntl, 'ioctl', self._ioctl), (select, 'poll', self._poll_object)]
        try:
            from smbus2 import smbus2 as sm  # it bound ``ioctl`` by name at import
            targets.append((sm, 'ioctl', self._ioctl))
        except ImportError:  # pragma: no cover - smbus2 is a dependency
            pass
        for mod, name, repl in targets:
            self._saved.append((mod, name, getattr(mod, name)))
            setattr(mod, name, repl)
        self._stop = False
        self._thread = threading.Thread(target=self._deliver, name='abi-edges', daemon=True)
        self._thread.start()
        return self

    def uninstall(self) -> None:
        """Give the calls back, close every descriptor still open here."""
        with self._lock:
            self._stop = True
            self._wake.notify_all()
        if self._thread is not None:
            self._thread.join(2.0)
        for fd in list(self._files):
            try:
                self._close(fd)
            except OSError:
                pass
        for mod, name, orig in reversed(self._saved):
            setattr(mod, name, orig)
        self._saved = []

    def __enter__(self) -> KernelStandIn:
        return self.install()

    def __exit__(self, *exc: object) -> None:
        self.uninstall()

    def open_fds(self) -> list[int]:
        """Return the descriptors the backends hold open here (leak checks)."""
        return sorted(self._files)

    # -- os.open / os.close / os.read ----------------------------------------------------------
    def _open(self, path: Any, flags: int, mode: int = 0o777, *, dir_fd: Any = None) -> int:
        key = path if isinstance(path, str) else None
        for kind, table in (('spi', self.spi), ('i2c', self.i2c), ('gpio', self.gpio)):
            if key is not None and key in table:
                fd = self._real_open('/dev/null', os.O_RDWR | os.O_CLOEXEC)
                self._files[fd] = _Open(kind, table[key], key)
                self.log.append((key, 'open', {'flags': flags}))
                return fd
        if dir_fd is None:
            return self._real_open(path, flags, mode)
        return self._real_open(path, flags, mode, dir_fd=dir_fd)

    def _close(self, fd: int) -> None:
        f = self._files.pop(fd, None)
        if isinstance(f, _LineRequest):
            with f.lock:
                f.closed = True
                for off in f.offsets:
                    f.chip.requested.pop(off, None)
                    line = f.chip.lines.get(off)
                    if line is not None:
                        line.attach(None)
                self._real_close(f.wfd)
                for off in f.offsets:
                    _release(f.chip.lines.get(off))
        elif isinstance(f, _Open) and f.kind == 'spi':
            _release(f.node.device)
        elif isinstance(f, _Open) and f.kind == 'i2c':
            for dev in list(f.node.devices.values()):
                _release(dev)
        self._real_close(fd)

    def _read(self, fd: int, n: int) -> bytes:
        f = self._files.get(fd)
        if f is None:
            return self._real_read(fd, n)
        if isinstance(f, _LineRequest):
            self._flush_due()
            size = ctypes.sizeof(u.GpioV2LineEvent)
            if n < size:
                raise _err(errno.EINVAL, f'read of {n} bytes < one gpio_v2_line_event')
            return self._real_read(fd, n - n % size)
        raise _err(errno.EOPNOTSUPP, f'{f.path}: read() is not modelled')

    # -- fcntl.ioctl -----------------------------------------------------------------------------
    def _ioctl(self, fd: Any, request: int, arg: Any = 0, mutate_flag: bool = True) -> Any:
        fdn = fd if isinstance(fd, int) else fd.fileno()
        f = self._files.get(fdn)
        if f is None:
            return self._real_ioctl(fd, request, arg, mutate_flag)
        request &= 0xFFFFFFFF
        if isinstance(arg, int):
            buf, data = None, None
        else:
            mv = memoryview(arg).cast('B')
            buf, data = mv, bytearray(mv.tobytes())
            size = u.ioc_size(request) if u.ioc_dir(request) != u.IOC_NONE else 0
            if size and len(data) < size:
                raise _err(errno.EFAULT, f'ioctl 0x{request:08x} wants {size} bytes, '
                                         f'the buffer has {len(data)}')
        if isinstance(f, _LineRequest):
            ret = self._line_ioctl(f, request, data)
        elif f.kind == 'spi':
            ret = self._spi_ioctl(f, request, arg, data)
        elif f.kind == 'i2c':
            ret = self._i2c_ioctl(f, request, arg, data)
        else:
            ret = self._chip_ioctl(f, request, data)
        if buf is None or data is None:
            return ret
        if mutate_flag and not buf.readonly:
            buf[:] = data
            return ret
        return bytes(data)

    # -- spidev ----------------------------------------------------------------------------------
    def _spi_ioctl(self, f: _Open, req: int, arg: Any, data: bytearray | None) -> int:
        node: SpiNode = f.node
        simple = {u.SPI_IOC_WR_MODE: ('mode', 1), u.SPI_IOC_WR_MODE32: ('mode', 4),
                  u.SPI_IOC_WR_BITS_PER_WORD: ('bits', 1),
                  u.SPI_IOC_WR_MAX_SPEED_HZ: ('speed', 4)}
        reads = {u.SPI_IOC_RD_MODE: ('mode', 1), u.SPI_IOC_RD_MODE32: ('mode', 4),
                 u.SPI_IOC_RD_BITS_PER_WORD: ('bits', 1),
                 u.SPI_IOC_RD_MAX_SPEED_HZ: ('speed', 4),
                 u.SPI_IOC_RD_LSB_FIRST: ('lsb', 1)}
        if data is None:
            raise _err(errno.EFAULT, f'{f.path}: spidev ioctls take a pointer')
        if req in simple:
            what, n = simple[req]
            value = int.from_bytes(data[:n], 'little')
            if what == 'mode':
                # spidev refuses mode bits the controller cannot do (bcm2835: CPOL, CPHA,
                # CS_HIGH, NO_CS; LSB_FIRST is refused with EINVAL).
                if value & ~(u.SPI_MODE_X_MASK | u.SPI_CS_HIGH | u.SPI_NO_CS):
                    raise _err(errno.EINVAL, f'{f.path}: unsupported SPI mode bits 0x{value:x}')
                # A controller model may do less (the aux SPI has no CPHA: spi_setup EINVAL).
                allowed = getattr(node.device, 'MODE_BITS', None)
                if allowed is not None and value & u.SPI_MODE_X_MASK & ~allowed:
                    raise _err(errno.EINVAL, f'{f.path}: SPI mode {value & 3} is not supported '
                                             'by this controller')
                f.spi_mode = node.mode = value
            elif what == 'bits':
                if value not in (0, 8):       # bcm2835 does 8-bit words only (0 means 8)
                    raise _err(errno.EINVAL, f'{f.path}: bits_per_word {value}')
                f.spi_bits = node.bits_per_word = value or 8
            else:
                if value == 0:
                    raise _err(errno.EINVAL, f'{f.path}: max_speed_hz 0')
                f.spi_speed = node.max_speed_hz = value
            self.log.append((f.path, 'spi_set', {what: value}))
            return 0
        if req in reads:
            what, n = reads[req]
            value = {'mode': f.spi_mode, 'bits': f.spi_bits, 'speed': f.spi_speed,
                     'lsb': 0}[what]
            data[:n] = value.to_bytes(n, 'little')
            return 0
        if (u.ioc_type(req), u.ioc_nr(req), u.ioc_dir(req)) == (u.SPI_IOC_MAGIC, 0, u.IOC_WRITE):
            return self._spi_message(f, req, data)
        raise _err(errno.ENOTTY, f'{f.path}: ioctl 0x{req:08x} is not a spidev ioctl')

    def _spi_message(self, f: _Open, req: int, data: bytearray) -> int:
        size = u.ioc_size(req)
        if size == 0 or size % u.SPI_TRANSFER_SIZE:
            raise _err(errno.EINVAL, f'{f.path}: SPI_IOC_MESSAGE size {size}')
        xfers = [u.SpiIocTransfer.from_buffer_copy(bytes(data[i:i + u.SPI_TRANSFER_SIZE]))
                 for i in range(0, size, u.SPI_TRANSFER_SIZE)]
        total = sum(x.len for x in xfers)
        if total > SPIDEV_BUFSIZ:
            raise _err(errno.EMSGSIZE, f'{f.path}: {total} bytes > bufsiz {SPIDEV_BUFSIZ}')
        node: SpiNode = f.node
        node.messages += 1
        # One chip-select period runs until a transfer with cs_change (or the message ends).
        segment: list[tuple[u.SpiIocTransfer, bytes]] = []
        for i, x in enumerate(xfers):
            if x.bits_per_word not in (0, 8):
                raise _err(errno.EINVAL, f'{f.path}: transfer bits_per_word {x.bits_per_word}')
            if x.speed_hz and x.speed_hz > f.spi_speed:
                raise _err(errno.EINVAL, f'{f.path}: transfer speed {x.speed_hz} > max')
            tx = ctypes.string_at(x.tx_buf, x.len) if x.tx_buf else bytes(x.len)
            segment.append((x, tx))
            if x.cs_change or i == len(xfers) - 1:
                self._spi_cs_period(f, segment)
                segment = []
        return total

    def _spi_cs_period(self, f: _Open, segment: list[tuple[u.SpiIocTransfer, bytes]]) -> None:
        tx = b''.join(t for _, t in segment)
        speed = min((x.speed_hz or f.spi_speed) for x, _ in segment)
        rx = bytes(f.node.device.transfer(tx, f.spi_mode, speed, f.spi_bits))
        if len(rx) != len(tx):
            raise _err(errno.EIO, f'{f.path}: model returned {len(rx)} bytes for {len(tx)}')
        self.log.append((f.path, 'spi_xfer', {'tx': tx, 'rx': rx, 'mode': f.spi_mode,
                                              'speed_hz': speed, 'bits': f.spi_bits}))
        pos = 0
        for x, t in segment:
            if x.rx_buf:
                ctypes.memmove(x.rx_buf, rx[pos:pos + len(t)], len(t))
            pos += len(t)

    # -- i2c-dev ---------------------------------------------------------------------------------
    def _i2c_ioctl(self, f: _Open, req: int, arg: Any, data: bytearray | None) -> int:
        if req in (u.I2C_SLAVE, u.I2C_SLAVE_FORCE):
            addr = arg if isinstance(arg, int) else int.from_bytes(bytes(data or b''), 'little')
            if not 0 <= addr <= 0x7F:
                raise _err(errno.EINVAL, f'{f.path}: address 0x{addr:x} (7-bit)')
            f.i2c_addr = addr
            return 0
        if req == u.I2C_FUNCS:
            if data is None:
                raise _err(errno.EFAULT, f'{f.path}: I2C_FUNCS takes a pointer')
            funcs = (u.I2C_FUNC_I2C | u.I2C_FUNC_SMBUS_READ_BYTE_DATA
                     | u.I2C_FUNC_SMBUS_WRITE_BYTE_DATA | u.I2C_FUNC_SMBUS_READ_I2C_BLOCK
                     | u.I2C_FUNC_SMBUS_WRITE_I2C_BLOCK)
            # The kernel writes an unsigned long: 8 bytes on a 64-bit kernel.
            out = funcs.to_bytes(ctypes.sizeof(ctypes.c_ulong), 'little')
            data[:min(len(data), len(out))] = out[:len(data)]
            return 0
        if req == u.I2C_RDWR:
            return self._i2c_rdwr(f, data)
        if req == u.I2C_SMBUS:
            return self._i2c_smbus(f, data)
        if req in (u.I2C_RETRIES, u.I2C_TIMEOUT, u.I2C_PEC, u.I2C_TENBIT):
            return 0
        raise _err(errno.ENOTTY, f'{f.path}: ioctl 0x{req:08x} is not an i2c-dev ioctl')

    def _transaction(self, f: _Open, addr: int, msgs: list[tuple[bool, bytes | int]]
                     ) -> list[bytes]:
        dev = f.node.devices.get(addr)
        if dev is None:
            # i2c-bcm2835 reports an address nobody acknowledged as EREMOTEIO.
            raise _err(errno.EREMOTEIO, f'{f.path}: no ACK from 0x{addr:02x}')
        reads = dev.i2c_transaction(msgs)
        self.log.append((f.path, 'i2c', {'addr': addr, 'msgs': msgs, 'reads': reads}))
        return list(reads)

    def _i2c_rdwr(self, f: _Open, data: bytearray | None) -> int:
        if data is None:
            raise _err(errno.EFAULT, f'{f.path}: I2C_RDWR takes a pointer')
        rd = u.I2cRdwrIoctlData.from_buffer_copy(bytes(data[:ctypes.sizeof(
            u.I2cRdwrIoctlData)]))
        if not 0 < rd.nmsgs <= u.I2C_RDWR_IOCTL_MAX_MSGS or not rd.msgs:
            raise _err(errno.EINVAL, f'{f.path}: I2C_RDWR with {rd.nmsgs} messages')
        size = ctypes.sizeof(u.I2cMsg)
        msgs = [u.I2cMsg.from_buffer_copy(ctypes.string_at(rd.msgs + i * size, size))
                for i in range(rd.nmsgs)]
        addrs = {m.addr for m in msgs}
        if len(addrs) != 1:
            raise _err(errno.EOPNOTSUPP, f'{f.path}: one transaction to several addresses '
                                         f'{sorted(addrs)} is not modelled')
        plan: list[tuple[bool, bytes | int]] = []
        for m in msgs:
            if m.len > I2C_MSG_MAX or m.flags & (u.I2C_M_TEN | u.I2C_M_RECV_LEN):
                raise _err(errno.EINVAL, f'{f.path}: i2c_msg len {m.len} flags 0x{m.flags:x}')
            if m.flags & u.I2C_M_RD:
                plan.append((True, m.len))
            else:
                plan.append((False, ctypes.string_at(m.buf, m.len) if m.len else b''))
        reads = iter(self._transaction(f, msgs[0].addr, plan))
        for m in msgs:
            if m.flags & u.I2C_M_RD:
                got = next(reads)
                ctypes.memmove(m.buf, got, m.len)
        return len(msgs)

    def _i2c_smbus(self, f: _Open, data: bytearray | None) -> int:
        if data is None:
            raise _err(errno.EFAULT, f'{f.path}: I2C_SMBUS takes a pointer')
        if f.i2c_addr is None:
            raise _err(errno.EINVAL, f'{f.path}: I2C_SMBUS before I2C_SLAVE')
        s = u.I2cSmbusIoctlData.from_buffer_copy(bytes(data[:ctypes.sizeof(
            u.I2cSmbusIoctlData)]))
        read = s.read_write == u.I2C_SMBUS_READ
        usize = ctypes.sizeof(u.I2cSmbusData)
        payload = bytearray(ctypes.string_at(s.data, usize)) if s.data else bytearray(usize)
        # i2c_smbus_xfer_emulated(): each SMBus transaction as the I2C messages it is.
        plan: list[tuple[bool, bytes | int]]
        if s.size == u.I2C_SMBUS_QUICK:
            plan = [(read, 0 if read else b'')]
        elif s.size == u.I2C_SMBUS_BYTE:
            plan = [(True, 1)] if read else [(False, bytes([s.command]))]
        elif s.size in (u.I2C_SMBUS_BYTE_DATA, u.I2C_SMBUS_WORD_DATA):
            n = 1 if s.size == u.I2C_SMBUS_BYTE_DATA else 2
            plan = ([(False, bytes([s.command])), (True, n)] if read
                    else [(False, bytes([s.command]) + bytes(payload[:n]))])
        elif s.size == u.I2C_SMBUS_I2C_BLOCK_DATA:
            n = payload[0]
            if not 1 <= n <= u.I2C_SMBUS_BLOCK_MAX:
                raise _err(errno.EINVAL, f'{f.path}: I2C block length {n}')
            plan = ([(False, bytes([s.command])), (True, n)] if read
                    else [(False, bytes([s.command]) + bytes(payload[1:1 + n]))])
        else:
            raise _err(errno.EOPNOTSUPP, f'{f.path}: SMBus transaction size {s.size}')
        if not s.data and (read or s.size != u.I2C_SMBUS_QUICK):
            raise _err(errno.EINVAL, f'{f.path}: I2C_SMBUS without a data pointer')
        reads = self._transaction(f, f.i2c_addr, plan)
        if read and reads and s.size != u.I2C_SMBUS_QUICK:
            got = reads[-1]
            if s.size == u.I2C_SMBUS_I2C_BLOCK_DATA:
                payload[0] = len(got)
                payload[1:1 + len(got)] = got
            else:
                payload[:len(got)] = got
            ctypes.memmove(s.data, bytes(payload), usize)
        return 0

    # -- gpiochip ------------------------------------------------------------------------------
    def _chip_ioctl(self, f: _Open, req: int, data: bytearray | None) -> int:
        chip: GpioChip = f.node
        if data is None:
            raise _err(errno.EFAULT, f'{f.path}: gpiochip ioctls take a pointer')
        if req == u.ioc(u.IOC_READ, 0xB4, 0x01, 68):          # GPIO_GET_CHIPINFO_IOCTL
            name = os.path.basename(f.path).encode()[:31]
            data[0:32] = name.ljust(32, b'\0')
            data[32:64] = chip.label.encode()[:31].ljust(32, b'\0')
            data[64:68] = chip.nlines.to_bytes(4, 'little')
            return 0
        if req != u.GPIO_V2_GET_LINE_IOCTL:
            raise _err(errno.ENOTTY if u.ioc_type(req) != 0xB4 else errno.EINVAL,
                       f'{f.path}: gpiochip ioctl 0x{req:08x} is not modelled')
        r = u.GpioV2LineRequest.from_buffer_copy(bytes(data))
        if not 0 < r.num_lines <= u.GPIO_V2_LINES_MAX:
            raise _err(errno.EINVAL, f'{f.path}: num_lines {r.num_lines}')
        if any(r.padding) or any(r.config.padding):
            raise _err(errno.EINVAL, f'{f.path}: padding not zero')
        offsets = [r.offsets[i] for i in range(r.num_lines)]
        for off in offsets:
            if off >= chip.nlines:
                raise _err(errno.EINVAL, f'{f.path}: line {off} >= {chip.nlines} lines')
            if off in chip.requested:
                raise _err(errno.EBUSY, f'{f.path}: line {off} already requested')
        req_obj = _LineRequest(chip, offsets, r.consumer.decode(errors='replace'))
        try:
            self._apply_config(f.path, req_obj, r.config, initial=True)
        except OSError:
            os.close(req_obj.rfd)
            os.close(req_obj.wfd)
            raise
        for off in offsets:
            chip.requested[off] = req_obj
        self._files[req_obj.rfd] = req_obj
        r.fd = req_obj.rfd
        data[:] = bytes(r)
        return 0

    def _apply_config(self, path: str, req: _LineRequest, cfg: u.GpioV2LineConfig,
                      initial: bool) -> None:
        if cfg.num_attrs > u.GPIO_V2_LINE_NUM_ATTRS_MAX:
            raise _err(errno.EINVAL, f'{path}: num_attrs {cfg.num_attrs}')
        flags = [cfg.flags] * len(req.offsets)
        outputs: dict[int, bool] = {}
        for a in list(cfg.attrs)[:cfg.num_attrs]:
            for i in range(len(req.offsets)):
                if not a.mask >> i & 1:
                    continue
                if a.attr.id == u.GPIO_V2_LINE_ATTR_ID_FLAGS:
                    flags[i] = a.attr.flags
                elif a.attr.id == u.GPIO_V2_LINE_ATTR_ID_OUTPUT_VALUES:
                    outputs[i] = bool(a.attr.values >> i & 1)
                elif a.attr.id != u.GPIO_V2_LINE_ATTR_ID_DEBOUNCE:
                    raise _err(errno.EINVAL, f'{path}: attribute id {a.attr.id}')
        for fl in flags:
            why = _line_flags_valid(fl)
            if why is not None:
                raise _err(errno.EINVAL, f'{path}: line flags 0x{fl:x}: {why}')
        if not initial and any(not fl & (u.GPIO_V2_LINE_FLAG_INPUT | u.GPIO_V2_LINE_FLAG_OUTPUT)
                               for fl in flags):
            raise _err(errno.EINVAL, f'{path}: SET_CONFIG needs a direction for every line')
        now = time.monotonic_ns()
        with req.lock:
            req.flags = flags
            for i, off in enumerate(req.offsets):
                line = req.chip.lines.get(off)
                fl = flags[i]
                if fl & u.GPIO_V2_LINE_FLAG_OUTPUT:
                    value = outputs.get(i, req.values[i] if not initial else False)
                    self._drive(req, i, value, now)
                    if line is not None:
                        line.attach(None)
                elif line is not None:
                    edges = fl & (u.GPIO_V2_LINE_FLAG_EDGE_RISING
                                  | u.GPIO_V2_LINE_FLAG_EDGE_FALLING)
                    line.attach(self._edge_sink(req, i) if edges else None)
        self.log.append((path, 'line_config', {'offsets': list(req.offsets),
                                               'flags': list(flags), 'initial': initial}))

    def _drive(self, req: _LineRequest, i: int, value: bool, t_ns: int) -> None:
        req.values[i] = value
        level = value != bool(req.flags[i] & u.GPIO_V2_LINE_FLAG_ACTIVE_LOW)
        line = req.chip.lines.get(req.offsets[i])
        if line is not None:
            line.driven(level, t_ns)

    def _edge_sink(self, req: _LineRequest, i: int) -> Callable[[int, int], None]:
        def emit(edge_id: int, t_ns: int) -> None:
            self._schedule(t_ns, lambda: self._post_event(req, i, edge_id, t_ns))
        return emit

    def _post_event(self, req: _LineRequest, i: int, edge_id: int, t_ns: int) -> None:
        with req.lock:
            if req.closed:
                return
            fl = req.flags[i]
            if fl & u.GPIO_V2_LINE_FLAG_ACTIVE_LOW:
                edge_id = 3 - edge_id
            want = {1: u.GPIO_V2_LINE_FLAG_EDGE_RISING, 2: u.GPIO_V2_LINE_FLAG_EDGE_FALLING}
            if not fl & want[edge_id]:
                return
            stamp = t_ns
            if fl & u.GPIO_V2_LINE_FLAG_EVENT_CLOCK_REALTIME:
                stamp += time.time_ns() - time.monotonic_ns()
            req.seqno += 1
            req.line_seqno[i] += 1
            ev = u.GpioV2LineEvent(timestamp_ns=stamp, id=edge_id, offset=req.offsets[i],
                                   seqno=req.seqno, line_seqno=req.line_seqno[i])
            os.write(req.wfd, bytes(ev))

    def _line_ioctl(self, req: _LineRequest, code: int, data: bytearray | None) -> int:
        path = f'line request {req.offsets} ({req.consumer})'
        if data is None:
            raise _err(errno.EFAULT, f'{path}: line ioctls take a pointer')
        if code in (u.GPIO_V2_LINE_SET_VALUES_IOCTL, u.GPIO_V2_LINE_GET_VALUES_IOCTL):
            v = u.GpioV2LineValues.from_buffer_copy(bytes(data))
            now = time.monotonic_ns()
            if code == u.GPIO_V2_LINE_SET_VALUES_IOCTL:
                if not v.mask:
                    raise _err(errno.EINVAL, f'{path}: SET_VALUES with an empty mask')
                for i in range(len(req.offsets)):
                    if v.mask >> i & 1:
                        if not req.flags[i] & u.GPIO_V2_LINE_FLAG_OUTPUT:
                            raise _err(errno.EPERM, f'{path}: line {req.offsets[i]} is an input')
                        self._drive(req, i, bool(v.bits >> i & 1), now)
                self.log.append((path, 'set_values', {'bits': v.bits, 'mask': v.mask,
                                                      't_ns': now}))
                return 0
            bits = 0
            for i, off in enumerate(req.offsets):
                if v.mask >> i & 1:
                    line = req.chip.lines.get(off)
                    level = req.values[i] if req.flags[i] & u.GPIO_V2_LINE_FLAG_OUTPUT else (
                        line.level(now) if line is not None else False)
                    active = level != bool(req.flags[i] & u.GPIO_V2_LINE_FLAG_ACTIVE_LOW)
                    bits |= int(active) << i
            v.bits = bits
            data[:] = bytes(v)
            return 0
        if code == u.GPIO_V2_LINE_SET_CONFIG_IOCTL:
            cfg = u.GpioV2LineConfig.from_buffer_copy(bytes(data))
            if any(cfg.padding):
                raise _err(errno.EINVAL, f'{path}: padding not zero')
            self._apply_config(path, req, cfg, initial=False)
            return 0
        raise _err(errno.ENOTTY, f'{path}: ioctl 0x{code:08x} is not a line ioctl')

    # -- edge delivery ---------------------------------------------------------------------------
    # An edge is queued on its line at the moment it happens, as the kernel's interrupt handler
    # does.  Two paths do that: the delivery thread (for readers that block in read()), and a
    # reader's own poll()/read() on a line fd, which first queues every edge already due -- so
    # what a reader sees depends on the edges' times, not on when the delivery thread ran.
    def _flush_due(self) -> int | None:
        """Queue every edge whose time has come; return ns until the next one (None: none)."""
        with self._lock:
            now = time.monotonic_ns()
            while self._events and self._events[0][0] <= now:
                _, _, fn = heapq.heappop(self._events)
                fn()
            return self._events[0][0] - now if self._events else None

    def _poll_object(self) -> Any:
        return _Poll(self)


    def _schedule(self, t_ns: int, fn: Callable[[], None]) -> None:
        with self._lock:
            self._event_seq += 1
            heapq.heappush(self._events, (t_ns, self._event_seq, fn))
            self._wake.notify_all()

    def _deliver(self) -> None:
        with self._lock:
            while not self._stop:
                now = time.monotonic_ns()
                while self._events and self._events[0][0] <= now:
                    _, _, fn = heapq.heappop(self._events)
                    fn()
                wait = (self._events[0][0] - now) * 1e-9 if self._events else 1.0
                self._wake.wait(max(wait, 0.0))


class _Poll:
    """``select.poll()`` while the stand-in is installed: due edges are queued before looking."""

    def __init__(self, kernel: KernelStandIn) -> None:
        self.kernel = kernel
        self.real = kernel._real_poll()
        self.fds: set[int] = set()

    def register(self, fd: Any, eventmask: int = select.POLLIN | select.POLLPRI) -> None:
        fdn = fd if isinstance(fd, int) else fd.fileno()
        self.fds.add(fdn)
        self.real.register(fdn, eventmask)

    def modify(self, fd: Any, eventmask: int) -> None:
        self.real.modify(fd, eventmask)

    def unregister(self, fd: Any) -> None:
        self.fds.discard(fd if isinstance(fd, int) else fd.fileno())
        self.real.unregister(fd)

    def poll(self, timeout: float | None = None) -> list[tuple[int, int]]:
        served = any(isinstance(self.kernel._files.get(fd), _LineRequest) for fd in self.fds)
        if not served:
            return self.real.poll(timeout)
        forever = timeout is None or timeout < 0
        end = time.monotonic_ns() + (0 if timeout is None or forever else int(timeout * 1e6))
        while True:
            next_ns = self.kernel._flush_due()
            ready = self.real.poll(0)
            if ready:
                return ready
            left = None if forever else end - time.monotonic_ns()
            if left is not None and left <= 0:
                return []
            waits = [w for w in (left, next_ns) if w is not None]
            ready = self.real.poll(max(1, -(-min(waits) // 1_000_000)) if waits else None)
            if ready:
                return ready
