"""SCIP 2.0 protocol of the Hokuyo URG laser range finders: pure encoding and parsing, no I/O.

Wire format, as in the SCIP 2.0 communication protocol specification (C-42-03320B):

* A command is ASCII ending in LF, optionally followed by ``;tag`` (up to 16 characters) that the
  device echoes back.
* A response is the echo line, a status line (2 characters + sum; the SCIP2.0 switch may answer a
  bare ``0``), then zero or more payload lines each ending with a sum character, and an empty line:
  the response ends with LF LF.
* Sum of a line = (sum of the bytes before the sum character) & 0x3F, plus 0x30. Parameter lines
  (``VV``/``PP``/``II``) are ``KEY:value;`` + sum, where the spec's example sums ``KEY:value``.
* Numbers are 2/3/4 characters of 6 bits each, each character = value + 0x30, most significant
  first. Range data (GD/MD: 3 chars, GS/MS: 2 chars) come as 64-character blocks + sum per line; a
  value may be split across two lines, so the blocks are concatenated before decoding.
* Ranges are millimetres; values below 20 are error codes (``SCAN_ERROR_CODES``).
* Timestamps are a 24-bit millisecond counter (4 characters) that wraps every ~4.66 h.

Errors: ``ScipError`` (ValueError) is the base; ``ScipFormatError`` malformed bytes,
``ScipChecksumError`` a line whose sum does not match (carries the line), ``ScipStatusError`` a
device status other than success (carries command, status and its meaning).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import re
from typing import Iterable, Mapping, Sequence

import numpy as np

from m4k_rt.protocol import SCAN_ERROR_CODES

LF = b'\n'
BLOCK_CHARS = 64                 # payload characters per data line
TAG_MAX = 16                     # max length of the echoed string characters
TIMESTAMP_BITS = 24
TIMESTAMP_MODULO = 1 << TIMESTAMP_BITS
RANGE_ERROR_LIMIT = 20           # range values below this are error codes, not distances


# Statuses common to every command when the command itself is refused (spec section 9).
_INVALID_COMMAND = {
    '0A': 'unable to create transmission data or reply command internally',
    '0B': 'buffer shortage or command repeated that is already processed',
    '0C': 'command with insufficient parameters 1',
    '0D': 'undefined command 1',
    '0E': 'undefined command 2',
    '0F': 'command with insufficient parameters 2',
    '0G': 'string characters in command exceed 16 letters',
    '0H': 'string characters have invalid letters',
    '0I': 'sensor is in firmware update mode',
}
_SCAN_STATUS = {
    '00': 'command received without any error',
    '01': 'starting step has a non-numeric value',
    '02': 'end step has a non-numeric value',
    '03': 'cluster count has a non-numeric value',
    '04': 'end step is out of range',
    '05': 'end step is smaller than starting step',
    '06': 'scan interval has a non-numeric value',
    '07': 'number of scans has a non-numeric value',
    '10': 'laser is off',
    '98': 'resumption of process after confirming normal laser operation',
    '99': 'scan data follow',
}
_BM_STATUS = {
    '00': 'command received without any error',
    '01': 'unable to control due to laser malfunction',
    '02': 'laser is already on',
}
SCAN_COMMANDS = frozenset({'GD', 'GS', 'MD', 'MS'})
PARAM_COMMANDS = frozenset({'VV', 'PP', 'II'})


class ScipError(ValueError):
    """Base of every SCIP protocol error (bad bytes, bad sums, refused commands).

    ``echo`` is the echo line of the response the error was found in, when known (set by
    :class:`ScipParser`), so a driver can tell which command's reply was lost.
    """

    echo: bytes | None = None


class ScipFormatError(ScipError):
    """Bytes that do not form a valid SCIP 2.0 message."""


class ScipChecksumError(ScipError):
    """A line whose sum character does not match its content; ``line`` is the raw line."""

    def __init__(self, line: bytes, expected: int) -> None:
        super().__init__(f'SCIP checksum mismatch in line {line!r}: expected {chr(expected)!r}')
        self.line = line
        self.expected = expected


class ScipStatusError(ScipError):
    """The device answered a command with a non-success status."""

    def __init__(self, command: str, status: str) -> None:
        self.command = command
        self.status = status
        self.meaning = status_meaning(command, status)
        super().__init__(f'{command} failed with status {status!r}: {self.meaning}')


# --- character encoding ---------------------------------------------------------------------

def encode(value: int, nchars: int) -> bytes:
    """Encode a non-negative integer in ``nchars`` SCIP characters (6 bits each, MSB first)."""
    if nchars < 1 or nchars > 4:
        raise ValueError(f'SCIP encodes 1..4 characters, got nchars={nchars!r}')
    if not isinstance(value, (int, np.integer)) or not 0 <= value < (1 << (6 * nchars)):
        raise ValueError(f'value {value!r} does not fit in {nchars} SCIP characters')
    value = int(value)
    return bytes(((value >> (6 * i)) & 0x3F) + 0x30 for i in reversed(range(nchars)))


def decode(data: bytes) -> int:
    """Decode a run of SCIP characters (any length) into an integer."""
    value = 0
    for ch in data:
        if not 0x30 <= ch < 0x70:
            raise ScipFormatError(f'byte {ch:#04x} is not a SCIP character in {bytes(data)!r}')
        value = (value << 6) | (ch - 0x30)
    return value


def decode_array(data: bytes, nchars: int) -> np.ndarray:
    """Decode concatenated fixed-width SCIP values into a uint32 array."""
    if nchars not in (2, 3, 4):
        raise ValueError(f'SCIP range data use 2, 3 or 4 characters, got {nchars!r}')
    if len(data) % nchars:
        raise ScipFormatError(f'{len(data)} data characters are not a multiple of {nchars}')
    raw = np.frombuffer(data, dtype=np.uint8)
    if raw.size and (raw.min() < 0x30 or raw.max() >= 0x70):
        raise ScipFormatError('range data contain bytes outside the SCIP character set')
    digits = (raw.astype(np.uint32) - 0x30).reshape(-1, nchars)
    out = np.zeros(digits.shape[0], dtype=np.uint32)
    for i in range(nchars):
        out <<= 6
        out |= digits[:, i]
    return out


def encode_array(values: Iterable[int], nchars: int) -> bytes:
    """Encode integers as concatenated fixed-width SCIP characters."""
    return b''.join(encode(int(v), nchars) for v in values)


# --- sums and lines ----------------------------------------------------------------------------

def checksum(data: bytes) -> int:
    """Return the SCIP sum character (as a byte value) of ``data``."""
    return (sum(data) & 0x3F) + 0x30


def with_sum(data: bytes) -> bytes:
    """Return ``data`` followed by its sum character."""
    return data + bytes((checksum(data),))


def verify_line(line: bytes) -> bytes:
    """Check a status/timestamp/data line's sum and return its payload without the sum."""
    if len(line) < 2:
        raise ScipFormatError(f'line {line!r} is too short to carry a sum')
    expected = checksum(line[:-1])
    if line[-1] != expected:
        raise ScipChecksumError(line, expected)
    return line[:-1]


def verify_param_line(line: bytes) -> bytes:
    """Check a ``KEY:value;sum`` line and return ``KEY:value``.

    The spec's example sums ``KEY:value`` without the ';'; the sum over ``KEY:value;`` is accepted
    too because open drivers report firmware disagreeing with the document on what is summed.
    """
    if len(line) < 3 or line[-2:-1] != b';':
        raise ScipFormatError(f'parameter line {line!r} does not end with ";" + sum')
    body = line[:-2]
    if line[-1] in (checksum(body), checksum(line[:-1])):
        return body
    raise ScipChecksumError(line, checksum(body))


def status_meaning(command: str, status: str) -> str:
    """Return the documented meaning of a status for a command."""
    if status in _INVALID_COMMAND:
        return _INVALID_COMMAND[status]
    if command == 'SCIP2.0' and status == '0':
        return 'changed to SCIP2.0'
    if command in SCAN_COMMANDS:
        if status in _SCAN_STATUS:
            return _SCAN_STATUS[status]
        if status.isdigit() and 21 <= int(status) <= 49:
            return 'processing stopped to verify the error'
        if status.isdigit() and 50 <= int(status) <= 97:
            return 'hardware trouble (laser, motor malfunction)'
    if command == 'BM' and status in _BM_STATUS:
        return _BM_STATUS[status]
    if status == '00':
        return 'command received without any error'
    return 'undocumented status'


def range_error_meaning(code: int) -> str:
    """Return the meaning of a range value below 20 (an URG-04LX error code)."""
    if code not in SCAN_ERROR_CODES:
        raise ValueError(f'{code!r} is a distance, not an error code (codes are 0..19)')
    return SCAN_ERROR_CODES[code]


# --- commands -----------------------------------------------------------------------------------

_TAG_RE = re.compile(rb'[\x21-\x7e]{0,16}')


def build_command(code: str, args: str = '', tag: str = '') -> bytes:
    """Build a command line: code + arguments + optional ``;tag`` + LF."""
    tag_bytes = tag.encode('ascii', 'replace')
    if len(tag_bytes) > TAG_MAX or not _TAG_RE.fullmatch(tag_bytes) or b';' in tag_bytes:
        raise ValueError(f'SCIP tag {tag!r} must be up to 16 printable characters without ";"')
    line = (code + args).encode('ascii')
    if tag_bytes:
        line += b';' + tag_bytes
    return line + LF


def _check_steps(start: int, end: int, cluster: int) -> None:
    if not (0 <= start <= 9999 and 0 <= end <= 9999 and start <= end):
        raise ValueError(f'bad step range start={start!r} end={end!r} (need 0 <= start <= end)')
    if not 0 <= cluster <= 99:
        raise ValueError(f'cluster count {cluster!r} out of range 0..99')


def gd_command(start: int, end: int, cluster: int = 1, *, two_chars: bool = False,
               tag: str = '') -> bytes:
    """Build a GD (3-char) or GS (2-char) single-scan request."""
    _check_steps(start, end, cluster)
    return build_command('GS' if two_chars else 'GD', f'{start:04d}{end:04d}{cluster:02d}', tag)


def md_command(start: int, end: int, cluster: int = 1, interval: int = 0, num_scans: int = 0, *,
               two_chars: bool = False, tag: str = '') -> bytes:
    """Build an MD/MS continuous request; ``num_scans`` 0 streams until QT."""
    _check_steps(start, end, cluster)
    if not 0 <= interval <= 9:
        raise ValueError(f'scan interval {interval!r} out of range 0..9')
    if not 0 <= num_scans <= 99:
        raise ValueError(f'number of scans {num_scans!r} out of range 0..99')
    args = f'{start:04d}{end:04d}{cluster:02d}{interval:01d}{num_scans:02d}'
    return build_command('MS' if two_chars else 'MD', args, tag)


# --- responses ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class Response:
    """One complete, sum-checked response: echo fields, status and payload lines (sums removed)."""

    command: str
    args: bytes
    tag: bytes
    status: str
    lines: tuple[bytes, ...]

    def check(self, ok: Sequence[str] = ('00',)) -> Response:
        """Return self when the status is one of ``ok``; raise ScipStatusError otherwise."""
        if self.status not in ok:
            raise ScipStatusError(self.command, self.status)
        return self


# Echo patterns: anything before a match on an echo line is stray bytes. MD/MS echo the number of
# scans in the acknowledgement and the remaining scans in each data response.
_ECHO_RE = re.compile(
    rb'(?P<cmd>GD|GS)(?P<args>\d{10})(?:;(?P<tag>[\x21-\x7e]{0,16}))?\Z'
    rb'|(?P<cmd2>MD|MS)(?P<args2>\d{13})(?:;(?P<tag2>[\x21-\x7e]{0,16}))?\Z'
    rb'|(?P<cmd3>BM|QT|RS|VV|PP|II)(?:;(?P<tag3>[\x21-\x7e]{0,16}))?\Z'
    rb'|(?P<cmd5>TM)(?P<args5>[0-2])(?:;(?P<tag5>[\x21-\x7e]{0,16}))?\Z'
    rb'|(?P<cmd4>SCIP2\.0)\Z')


def match_echo(line: bytes) -> tuple[int, str, bytes, bytes] | None:
    """Find a valid echo at the end of ``line``: (offset, command, args, tag) or None."""
    m = _ECHO_RE.search(line)
    if m is None:
        return None
    g = m.groupdict()
    if g['cmd']:
        return m.start(), g['cmd'].decode(), g['args'], g['tag'] or b''
    if g['cmd2']:
        return m.start(), g['cmd2'].decode(), g['args2'], g['tag2'] or b''
    if g['cmd3']:
        return m.start(), g['cmd3'].decode(), b'', g['tag3'] or b''
    if g['cmd5']:
        return m.start(), g['cmd5'].decode(), g['args5'], g['tag5'] or b''
    return m.start(), g['cmd4'].decode(), b'', b''


def parse_response(lines: Sequence[bytes]) -> Response:
    """Turn the lines of one response (echo first, no terminating empty line) into a Response."""
    if len(lines) < 2:
        raise ScipFormatError(f'response {list(lines)!r} lacks a status line')
    found = match_echo(lines[0])
    if found is None or found[0] != 0:
        raise ScipFormatError(f'{lines[0]!r} is not a SCIP 2.0 echo')
    _, command, args, tag = found
    status_line = lines[1]
    if command == 'SCIP2.0' and len(status_line) == 1:
        status = status_line.decode('ascii', 'replace')   # the switch reply carries no sum
    elif len(status_line) == 3:
        status = verify_line(status_line).decode('ascii', 'replace')
    else:
        raise ScipFormatError(f'status line {status_line!r} of {command} is malformed')
    body = lines[2:]
    if command in PARAM_COMMANDS:
        payload = tuple(verify_param_line(line) for line in body)
    else:
        payload = tuple(verify_line(line) for line in body)
    return Response(command, args, tag, status, payload)


def format_response(echo: bytes, status: str, lines: Iterable[bytes] = (), *,
                    param_lines: bool = False) -> bytes:
    """Build the bytes of a response (used by the simulator and for test vectors).

    ``status`` of one character (the SCIP2.0 switch reply) is sent without a sum; parameter lines
    are sent as ``KEY:value;`` + the sum of ``KEY:value``, as in the spec's example.
    """
    out = [echo, LF, status.encode() if len(status) == 1 else with_sum(status.encode()), LF]
    for line in lines:
        out += [line + b';' + bytes((checksum(line),)) if param_lines else with_sum(line), LF]
    out.append(LF)
    return b''.join(out)


def data_lines(payload: bytes) -> list[bytes]:
    """Split encoded range data into the 64-character blocks that go one per line."""
    return [payload[i:i + BLOCK_CHARS] for i in range(0, len(payload), BLOCK_CHARS)]


# --- parameters (VV / PP / II) -------------------------------------------------------------------

def parse_param_line(line: bytes) -> tuple[str, str]:
    """Split a sum-checked ``KEY:value`` payload into (key, value)."""
    key, sep, value = line.partition(b':')
    if not sep or not key:
        raise ScipFormatError(f'parameter line {line!r} is not KEY:value')
    return key.decode('ascii', 'replace'), value.decode('ascii', 'replace')


def parse_params(response: Response) -> dict[str, str]:
    """Return the KEY -> value mapping of a VV/PP/II response (status must be 00)."""
    if response.command not in PARAM_COMMANDS:
        raise ScipFormatError(f'{response.command} carries no parameters')
    response.check()
    return dict(parse_param_line(line) for line in response.lines)


def _leading_int(params: Mapping[str, str], key: str) -> int:
    if key not in params:
        raise ScipFormatError(f'PP response lacks {key} (got keys {sorted(params)!r})')
    m = re.match(r'\s*(-?\d+)', params[key])
    if m is None:
        raise ScipFormatError(f'PP value {key}={params[key]!r} is not a number')
    return int(m.group(1))


@dataclass(frozen=True)
class ScanGeometry:
    """Angles and limits of one requested step range, in ROS LaserScan units."""

    start: int
    end: int
    cluster: int
    count: int                  # number of range values
    angle_min: float            # rad, angle of the first value (counter-clockwise positive)
    angle_max: float            # rad, angle of the last value
    angle_increment: float      # rad between values
    range_min: float            # m
    range_max: float            # m
    scan_time: float            # s per revolution
    time_increment: float       # s between consecutive values (step period * cluster)


@dataclass(frozen=True)
class SensorSpec:
    """Sensor parameters from a PP response (steps, limits, motor speed)."""

    model: str
    dmin: int        # mm
    dmax: int        # mm
    ares: int        # steps per revolution
    amin: int        # first measurable step
    amax: int        # last measurable step
    afrt: int        # step on the front axis
    scan_rpm: int

    @classmethod
    def from_params(cls, params: Mapping[str, str]) -> SensorSpec:
        """Build from a PP mapping, validating every field."""
        spec = cls(params.get('MODL', ''), *(_leading_int(params, k) for k in
                   ('DMIN', 'DMAX', 'ARES', 'AMIN', 'AMAX', 'AFRT', 'SCAN')))
        if not (0 < spec.dmin < spec.dmax and spec.ares > 0 and spec.scan_rpm > 0
                and 0 <= spec.amin <= spec.afrt <= spec.amax < spec.ares * 2):
            raise ScipFormatError(f'inconsistent PP parameters: {spec!r}')
        return spec

    def step_angle(self, step: float) -> float:
        """Return the angle (rad, counter-clockwise from the front axis) of a step."""
        return (step - self.afrt) * 2.0 * math.pi / self.ares

    def geometry(self, start: int | None = None, end: int | None = None,
                 cluster: int = 1) -> ScanGeometry:
        """Return the geometry of a request for steps ``start..end`` merged by ``cluster``."""
        start = self.amin if start is None else start
        end = self.amax if end is None else end
        if not (self.amin <= start <= end <= self.amax):
            raise ValueError(f'step range {start!r}..{end!r} outside the measurable '
                             f'{self.amin}..{self.amax} of {self.model or "the sensor"}')
        if not 0 <= cluster <= 99:
            raise ValueError(f'cluster count {cluster!r} out of range 0..99')
        group = max(cluster, 1)
        count = (end - start + 1 + group - 1) // group
        step_rad = 2.0 * math.pi / self.ares
        scan_time = 60.0 / self.scan_rpm
        return ScanGeometry(
            start=start, end=end, cluster=group, count=count,
            angle_min=self.step_angle(start),
            angle_max=self.step_angle(start + (count - 1) * group),
            angle_increment=step_rad * group,
            range_min=self.dmin / 1000.0, range_max=self.dmax / 1000.0,
            # One value every ``group`` steps: the seconds between two consecutive *values*
            # are the step period (scan_time / ARES, 1024 on the URG-04LX) times the cluster.
            scan_time=scan_time, time_increment=scan_time / self.ares * group)


# --- scans -------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ScanData:
    """One decoded GD/GS/MD/MS scan."""

    command: str
    start: int
    end: int
    cluster: int
    interval: int | None        # MD/MS only
    remaining: int | None       # MD/MS only: scans still to come (0 also for endless streams)
    timestamp: int              # device 24-bit ms counter
    ranges: np.ndarray          # uint32 mm; values < 20 are error codes
    tag: bytes

    @property
    def count(self) -> int:
        """Return the number of range values."""
        return int(self.ranges.size)


def is_scan(response: Response) -> bool:
    """Tell whether a response carries scan data (GD/GS status 00, MD/MS status 99)."""
    if response.command in ('GD', 'GS'):
        return response.status == '00' and len(response.lines) >= 1
    if response.command in ('MD', 'MS'):
        return response.status == '99'
    return False


def parse_scan(response: Response) -> ScanData:
    """Decode the ranges of a scan response; the value count must match the echoed steps."""
    cmd = response.command
    if cmd not in SCAN_COMMANDS:
        raise ScipFormatError(f'{cmd} is not a scan command')
    response.check(('99',) if cmd in ('MD', 'MS') else ('00',))
    if not response.lines:
        raise ScipFormatError(f'{cmd} scan lacks its timestamp line')
    a = response.args.decode()
    start, end, cluster = int(a[0:4]), int(a[4:8]), int(a[8:10])
    interval = remaining = None
    if cmd in ('MD', 'MS'):
        interval, remaining = int(a[10:11]), int(a[11:13])
    if end < start:
        raise ScipFormatError(f'{cmd} echo has end step {end} before start step {start}')
    ts_line = response.lines[0]
    if len(ts_line) != 4:
        raise ScipFormatError(f'timestamp {ts_line!r} is not 4 characters')
    nchars = 3 if cmd in ('GD', 'MD') else 2
    ranges = decode_array(b''.join(response.lines[1:]), nchars)
    group = max(cluster, 1)
    expected = (end - start + 1 + group - 1) // group
    if ranges.size != expected:
        raise ScipFormatError(f'{cmd} carries {ranges.size} ranges, expected {expected} for '
                              f'steps {start}..{end} cluster {cluster}')
    return ScanData(cmd, start, end, cluster, interval, remaining, decode(ts_line), ranges,
                    response.tag)


def format_scan(command: str, start: int, end: int, cluster: int, timestamp: int,
                ranges: Iterable[int], *, interval: int = 0, remaining: int = 0,
                tag: bytes = b'') -> bytes:
    """Build the bytes of a scan response (GD/GS status 00, MD/MS status 99)."""
    if command not in SCAN_COMMANDS:
        raise ValueError(f'{command!r} is not a scan command')
    echo = f'{command}{start:04d}{end:04d}{cluster:02d}'.encode()
    status = '00'
    if command in ('MD', 'MS'):
        echo += f'{interval:01d}{remaining:02d}'.encode()
        status = '99'
    if tag:
        echo += b';' + tag
    nchars = 3 if command in ('GD', 'MD') else 2
    payload = encode_array(ranges, nchars)
    lines = [encode(timestamp % TIMESTAMP_MODULO, 4), *data_lines(payload)]
    return format_response(echo, status, lines)


# --- timestamps -----------------------------------------------------------------------------

class TimestampUnwrapper:
    """Turn the device's 24-bit ms counter into a monotonic ms count across wrap-arounds."""

    def __init__(self) -> None:
        self._last: int | None = None
        self._total = 0
        self.wraps = 0

    def update(self, raw: int) -> int:
        """Feed a raw 24-bit timestamp; return the unwrapped ms count since the first one."""
        if not 0 <= raw < TIMESTAMP_MODULO:
            raise ValueError(f'timestamp {raw!r} is not a 24-bit value')
        if self._last is not None:
            if raw < self._last:
                self.wraps += 1
            self._total += (raw - self._last) % TIMESTAMP_MODULO
        self._last = raw
        return self._total

    def reset(self) -> None:
        """Forget history (the device timer was reset, e.g. by RS or a reconnect)."""
        self._last = None
        self._total = 0
        self.wraps = 0


# --- incremental parser --------------------------------------------------------------------------

class ScipParser:
    """Incremental SCIP 2.0 framer, in the spirit of pyserial's Packetizer.

    ``feed(data)`` returns the complete responses and the errors (``ScipError`` instances,
    returned rather than raised so one bad response never hides the good ones after it), in
    arrival order. Bytes before a valid echo are skipped and counted in ``stray_bytes``. After a
    bad line the rest of that response is dropped: framing resynchronises on LF LF.
    """

    MAX_LINES = 512          # a full 1080-step UTM scan is ~52 lines; anything longer is garbage
    MAX_LINE = 256           # longest legal line is an echo or a param line, well below this

    def __init__(self) -> None:
        self._buf = bytearray()
        self._lines: list[bytes] = []
        self._in_response = False
        self._discarding = False
        self.stray_bytes = 0
        self.responses = 0
        self.checksum_errors = 0
        self.format_errors = 0

    def reset(self) -> None:
        """Drop any partial data (e.g. after reopening the port)."""
        self._buf.clear()
        self._lines.clear()
        self._in_response = False
        self._discarding = False

    def feed(self, data: bytes) -> list[Response | ScipError]:
        """Consume bytes; return complete responses and errors in arrival order."""
        self._buf += data
        out: list[Response | ScipError] = []
        while True:
            idx = self._buf.find(LF)
            if idx < 0:
                self._trim_partial(out)
                return out
            line = bytes(self._buf[:idx])
            del self._buf[:idx + 1]
            if line.endswith(b'\r'):
                line = line[:-1]       # tolerate CR LF from bridges that add it
            self._on_line(line, out)

    def _trim_partial(self, out: list[Response | ScipError]) -> None:
        # An unterminated partial line longer than any legal line is garbage: keep only the tail
        # that might still begin an echo, and give up on a response it was part of.
        if len(self._buf) <= self.MAX_LINE:
            return
        drop = len(self._buf) - self.MAX_LINE
        del self._buf[:drop]
        if not self._in_response:
            self.stray_bytes += drop
        elif not self._discarding:
            self._overflow(out)

    def _overflow(self, out: list[Response | ScipError]) -> None:
        self._discarding = True
        self.format_errors += 1
        exc = ScipFormatError(f'{self._lines[0]!r} response exceeds {self.MAX_LINES} '
                              f'lines or has a line over {self.MAX_LINE} bytes')
        exc.echo = self._lines[0]
        out.append(exc)

    def _on_line(self, line: bytes, out: list[Response | ScipError]) -> None:
        if not self._in_response:
            found = match_echo(line)
            if found is None:
                self.stray_bytes += len(line) + 1
                return
            self.stray_bytes += found[0]
            self._lines = [line[found[0]:]]
            self._in_response = True
            self._discarding = False
            return
        if line:
            if self._discarding:
                return
            if len(self._lines) >= self.MAX_LINES or len(line) > self.MAX_LINE:
                self._overflow(out)
                return
            self._lines.append(line)
            return
        # Empty line: end of response (LF LF).
        lines, discarding = self._lines, self._discarding
        self._lines, self._in_response, self._discarding = [], False, False
        if discarding:
            return
        try:
            out.append(parse_response(lines))
            self.responses += 1
        except ScipChecksumError as exc:
            self.checksum_errors += 1
            exc.echo = lines[0]
            out.append(exc)
        except ScipError as exc:
            self.format_errors += 1
            exc.echo = lines[0]
            out.append(exc)
