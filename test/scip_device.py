"""A test-owned URG-04LX stand-in on a pseudo terminal, written from the SCIP 2.0 spec.

Independent of m4k_drivers.lrf (no shared encoder, parser or simulator): it answers the
commands a SCIP 2.0 client sends at connect (SCIP2.0, QT, VV, PP, II, TM0/1/2, BM) and streams
MD scans of a constant range every scan period, so a test can put the *real* lrf backend on a
serial port it owns and check what reaches /scan.
"""

import os
import select
import threading
import time
import tty

PP = [b'MODL:URG-04LX(Hokuyo Automatic Co.,Ltd.)', b'DMIN:20', b'DMAX:5600', b'ARES:1024',
      b'AMIN:44', b'AMAX:725', b'AFRT:384', b'SCAN:600']
VV = [b'VEND:Hokuyo Automatic Co.,Ltd.', b'PROD:SOKUIKI Sensor URG-04LX',
      b'FIRM:3.4.03(test stand-in)', b'PROT:SCIP 2.0', b'SERI:H0000001']


def _sum(data: bytes) -> bytes:
    """The spec's check code: the low 6 bits of the byte sum, plus 0x30."""
    return bytes([(sum(data) & 0x3F) + 0x30])


def _chars(value: int, n: int) -> bytes:
    """The spec's character encoding: 6 bits per character, each plus 0x30, MSB first."""
    return bytes(((value >> (6 * (n - 1 - i))) & 0x3F) + 0x30 for i in range(n))


class ScipDevice:
    """SCIP 2.0 on a pty: ``path`` is the port to configure; ``range_mm`` every step."""

    def __init__(self, range_mm: int = 1500, period_s: float = 0.1) -> None:
        self.range_mm = range_mm
        self.period_s = period_s
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.t0 = time.monotonic()
        self.md: tuple[bytes, int, int] | None = None     # echo head, start, end
        self.commands: list[bytes] = []
        self.scans = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='scip-device', daemon=True)

    def __enter__(self) -> 'ScipDevice':
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5.0)
        os.close(self.master)
        os.close(self.slave)

    def _ms(self) -> int:
        return int((time.monotonic() - self.t0) * 1000) & 0xFFFFFF

    def _reply(self, echo: bytes, status: bytes, lines=(), params=False) -> None:
        out = echo + b'\n' + (status if len(status) == 1 else status + _sum(status)) + b'\n'
        for line in lines:
            out += line + (b';' if params else b'') + _sum(line) + b'\n'
        os.write(self.master, out + b'\n')

    def _command(self, line: bytes) -> None:
        self.commands.append(line)
        code, args = line[:2], line[2:]
        if line == b'SCIP2.0':
            self._reply(line, b'0')
        elif code in (b'QT', b'RS'):
            self.md = None
            self._reply(line, b'00')
        elif code == b'VV':
            self._reply(line, b'00', VV, params=True)
        elif code == b'PP':
            self._reply(line, b'00', PP, params=True)
        elif code == b'II':
            self._reply(line, b'00', [b'LASR:ON', b'TIME:' + _chars(self._ms(), 4)], params=True)
        elif code == b'BM':
            self._reply(line, b'00')
        elif line in (b'TM0', b'TM2'):
            self._reply(line, b'00')
        elif line == b'TM1':
            self._reply(line, b'00', [_chars(self._ms(), 4)])
        elif code == b'MD' and len(args) == 13:
            self._reply(line, b'00')
            self.md = (line[:13], int(args[0:4]), int(args[4:8]))
            self.next_scan = time.monotonic() + self.period_s
        else:
            self._reply(line, b'0E')

    def _scan(self) -> None:
        head, start, end = self.md
        data = b''.join(_chars(self.range_mm, 3) for _ in range(start, end + 1))
        lines = [_chars(self._ms(), 4)] + [data[i:i + 64] for i in range(0, len(data), 64)]
        self._reply(head + b'00', b'99', lines)        # remaining 00: endless
        self.scans += 1

    def _run(self) -> None:
        buf = b''
        while not self._stop.is_set():
            wait = 0.05 if self.md is None else max(0.0, self.next_scan - time.monotonic())
            readable, _, _ = select.select([self.master], [], [], min(wait, 0.05))
            if readable:
                try:
                    buf += os.read(self.master, 4096)
                except OSError:
                    buf = b''
                while b'\n' in buf:
                    line, buf = buf.split(b'\n', 1)
                    if line.strip(b'\r'):
                        self._command(line.strip(b'\r'))
            if self.md is not None and time.monotonic() >= self.next_scan:
                self.next_scan += self.period_s
                self._scan()
