"""Datagram wire protocol between RT tasks and NRT processes (pure: no I/O).

Every datagram is a 16-byte little-endian header ``<HBBIq`` (magic ``0x4B4D``, version, kind,
sequence number, sender's CLOCK_MONOTONIC stamp in ns) followed by one fixed payload layout per
kind; LASER_SCAN and TASK_STATS end with a counted array. The layouts are the table in
``docs/internals.md``.

Encoding writes into a caller-owned preallocated buffer with precompiled :class:`struct.Struct`
objects, so an RT loop pays for one ``pack_into`` and allocates nothing but the argument tuple.
Decoding validates everything a receiver must not trust (length, magic, version, kind, finite
floats, ranges implied by the layout) and raises :class:`ProtocolError`, whose ``reason`` slug
the receiver counts. No other exception escapes :func:`decode` for any input bytes.
"""

from array import array
from enum import IntEnum, IntFlag
import math
import struct
import sys
from typing import Any, NamedTuple, Sequence

from m4k_rt.channel.contract import DEFAULT_MAX_DATAGRAM

MAGIC = 0x4B4D  # b'MK' on the wire
VERSION = 1
HEADER_FORMAT = '<HBBIq'
HEADER_SIZE = 16
# The channel's default limit (declared once, in its contract): every encodable datagram fits
# in it, so MAX_SCAN_RANGES and MAX_STATS_SAMPLES below are derived from it.
MAX_DATAGRAM = DEFAULT_MAX_DATAGRAM
SEQ_MASK = 0xFFFFFFFF

DAC_ZERO = 512
DAC_MAX = 1023
ENCODER_MAX = 4095
SCAN_STAMP_MAX = 0xFFFFFF  # URG time stamps are 24-bit ms counters
SCAN_ERROR_CODE_MAX = 19  # ranges (mm) below 20 are URG error codes, not distances

# The one table of URG range error codes (LASER_SCAN ranges below 20 mm), from Hokuyo's
# "Communication Protocol Specification For SCIP2.0" (C-42-03320B), Table 3 "ERROR CODES
# (URG-04LX, UBG-04LX-F01, UHG-08LX)"; 3..5 are not in the table. The driver names them in
# logs (m4k_drivers.lrf.scip) and the bridge maps them (m4k_bridge.convert).
SCAN_ERROR_CODES: dict[int, str] = {
    0: 'detected object is possibly at 22 m',
    1: 'reflected light has low intensity',
    2: 'reflected light has low intensity',
    3: 'undocumented error',
    4: 'undocumented error',
    5: 'undocumented error',
    6: 'others',
    7: 'distance data on the preceding and succeeding steps have errors',
    8: 'intensity difference of two waves',
    9: 'the same step had an error in the last two scans',
    **dict.fromkeys(range(10, 18), 'others'),
    18: 'error reading due to a strongly reflective object',
    19: 'non-measurable step',
}
# Codes Table 3 documents as "no object within the measurable range": only 0 (the object, if
# any, is beyond the 5.6 m range). REP-117 +inf; every other code is an invalid reading (NaN).
# No code means "too close" (REP-117 -inf): ranges below DMIN (20 mm) are the codes themselves.
SCAN_FAR_CODES = frozenset((0,))


class OdomFlag(IntFlag):
    """ODOMETRY.flags bits (set by the RT actuator's controller)."""

    BRAKING = 0x1
    GUARD = 0x2
    MOTOR_STALE = 0x4
    CLAMPED = 0x8
    E_STOP = 0x10       # the e-stop latch is engaged (E_STOP engage 1)
    HOLD = 0x20         # stopped until a velocity command newer than an e-stop release
    MOTOR_FAULT = 0x40  # wheel supervision latched a motor fault: outputs zero, enable dropped
    ESTOP_OPEN = 0x80   # the hardware e-stop contact reads open (enable line read back low)
    SLOWDOWN = 0x100    # the speed-aware guard's slow-down zone limits forward speed


class EncoderStatus(IntFlag):
    """ENCODERS.status bits (set by the motor driver)."""

    LEFT_FRAME = 0x01
    RIGHT_FRAME = 0x02
    LEFT_JUMP = 0x04
    RIGHT_JUMP = 0x08
    SAFE = 0x10          # the driver holds the DACs at zero (link loss / watchdog)
    WRITE_ERROR = 0x20
    # The amplifier enable line read back after the e-stop contact (a GPIO input) reads low
    # while the driver drives the enable: the contact is open (e-stop pressed or wiring cut).
    ESTOP_OPEN = 0x40
    # The read-back contradicts the enable the driver commands: the enable is asserted while
    # the heartbeat has stopped (monostable or contact stuck). Latched in the driver until the
    # handler is reconfigured; every reading then also carries ESTOP_OPEN (fail-safe stop).
    READBACK_FAULT = 0x80
    # The bits that make the angles untrustworthy (frame or jump error, either wheel); SAFE
    # and WRITE_ERROR leave the angles valid.
    INVALID = LEFT_FRAME | RIGHT_FRAME | LEFT_JUMP | RIGHT_JUMP


class ImuStatus(IntEnum):
    """IMU.status (set by the IMU driver)."""

    OK = 0
    NOT_READY = 1
    BAD_QUATERNION = 2


class SonarStatus(IntEnum):
    """SONAR.status (set by the sonar driver)."""

    OK = 0
    NO_ECHO = 1       # nothing within range: a valid reading (REP-117 +inf)
    TIMEOUT = 2       # no edges: sensor not answering
    FAULT = 3         # invalid: unmeasurable echo, clock step, inconsistent edges


class SafetyFlag(IntFlag):
    """SAFETY_STATUS.flags bits (the RT actuator's guard, supervision and e-stop state)."""

    GUARD_ENABLED = 0x1
    SLOW_DOWN = 0x2          # the slow-down zone is on
    SUPERVISION = 0x4        # wheel supervision is on
    TEST_WEAKENED = 0x8      # the guard runs weakened by the test-only hook
    MOTOR_FAULT = 0x10       # a motor fault is latched
    ESTOP_OPEN = 0x20        # the e-stop contact reads open now
    E_STOP = 0x40            # the RT e-stop latch is engaged
    GUARD_STOP = 0x80        # the guard's stop zone holds forward motion at zero now
    SLOWING = 0x100          # the slow-down zone caps forward speed now


class FaultCause(IntFlag):
    """SAFETY_STATUS.fault_cause bits: why wheel supervision latched a motor fault."""

    LEFT_WRONG_WAY = 0x01
    RIGHT_WRONG_WAY = 0x02
    LEFT_FROZEN = 0x04       # encoder angle unchanged while commanded (or a stalled wheel)
    RIGHT_FROZEN = 0x08
    LEFT_STALL = 0x10        # not following its drive effort (stalled, or saturated)
    RIGHT_STALL = 0x20
    SWAPPED = 0x40           # each wheel answers the other's setpoint
    LEFT_STILL = 0x80        # the wheel turns while commanded still, not braking down
    RIGHT_STILL = 0x100
    YAW = 0x200              # the wheels' yaw rate disagrees with the IMU's gyro


class RtFlag(IntFlag):
    """RT_STATUS.flags bits (set by rt_core's monitor task)."""

    GC_FROZEN = 0x1      # gc frozen and disabled in the RT process
    DMA_LATENCY = 0x2    # /dev/cpu_dma_latency held at 0 us
    GUARD_VALID = 0x4    # an actuator runs: guard_active is its collision guard's state
    AUDIT = 0x8          # the forbidden-call audit hook is installed


class Level(IntEnum):
    """DEVICE_STATUS.level (and the bridge's diagnostic levels)."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


class LedSource(IntEnum):
    """LED.source: who sets the colour."""

    STATE = 0      # the RT LED task shows the robot state
    OVERRIDE = 1   # the bridge's ~/led command overrides it (brightness 0 releases it)


class DeviceState(IntEnum):
    """DEVICE_STATUS.state: lifecycle states, numbered as ROS 2 lifecycle_msgs/State."""

    UNCONFIGURED = 1
    INACTIVE = 2
    ACTIVE = 3
    FINALIZED = 4
    ERROR = 5


class DeviceError(IntEnum):
    """DEVICE_STATUS.last_error codes (the device driver's last error class)."""

    NONE = 0
    OTHER = 1
    NOT_FOUND = 2
    PERMISSION = 3
    IO = 4
    IDENTITY = 5
    PROTOCOL = 6
    LIFECYCLE = 7
    WATCHDOG = 8


# Plain-int views of the bits the RT loops combine every cycle: IntFlag arithmetic calls into
# Python and allocates a member per result, an int constant does neither.
ODOM_BRAKING = int(OdomFlag.BRAKING)
ODOM_GUARD = int(OdomFlag.GUARD)
ODOM_MOTOR_STALE = int(OdomFlag.MOTOR_STALE)
ODOM_CLAMPED = int(OdomFlag.CLAMPED)
ODOM_E_STOP = int(OdomFlag.E_STOP)
ODOM_HOLD = int(OdomFlag.HOLD)
ODOM_MOTOR_FAULT = int(OdomFlag.MOTOR_FAULT)
ODOM_ESTOP_OPEN = int(OdomFlag.ESTOP_OPEN)
ODOM_SLOWDOWN = int(OdomFlag.SLOWDOWN)
ENC_SAFE = int(EncoderStatus.SAFE)
ENC_ESTOP_OPEN = int(EncoderStatus.ESTOP_OPEN)
ENC_INVALID_MASK = int(EncoderStatus.INVALID)

SONAR_OK = int(SonarStatus.OK)
SONAR_NO_ECHO = int(SonarStatus.NO_ECHO)
SONAR_TIMEOUT = int(SonarStatus.TIMEOUT)
SONAR_FAULT = int(SonarStatus.FAULT)

SAFETY_GUARD_ENABLED = int(SafetyFlag.GUARD_ENABLED)
SAFETY_SLOW_DOWN = int(SafetyFlag.SLOW_DOWN)
SAFETY_SUPERVISION = int(SafetyFlag.SUPERVISION)
SAFETY_TEST_WEAKENED = int(SafetyFlag.TEST_WEAKENED)
SAFETY_MOTOR_FAULT = int(SafetyFlag.MOTOR_FAULT)
SAFETY_ESTOP_OPEN = int(SafetyFlag.ESTOP_OPEN)
SAFETY_E_STOP = int(SafetyFlag.E_STOP)
SAFETY_GUARD_STOP = int(SafetyFlag.GUARD_STOP)
SAFETY_SLOWING = int(SafetyFlag.SLOWING)

RT_FLAG_GC_FROZEN = int(RtFlag.GC_FROZEN)
RT_FLAG_DMA_LATENCY = int(RtFlag.DMA_LATENCY)
RT_FLAG_GUARD_VALID = int(RtFlag.GUARD_VALID)
RT_FLAG_AUDIT = int(RtFlag.AUDIT)

LEVEL_OK = int(Level.OK)
LEVEL_WARN = int(Level.WARN)
LEVEL_ERROR = int(Level.ERROR)
LEVEL_STALE = int(Level.STALE)

NAME_SIZE = 16
LABEL_SIZE = 32  # PORT_STATS labels: XDDP labels are at most 32 characters
SITE_FILE_SIZE = 40  # FORBIDDEN_SITE file: the tail of the path (the file name) is kept
SITE_FUNC_SIZE = 24
U32_MAX = 0xFFFFFFFF

# FORBIDDEN_SITE event codes: the audit events an RT loop must not raise (m4k_rt.modeswitch).
# 'console' is not an audit event: the console guard reports writes to sys.stdout/sys.stderr
# under that name. Codes are contiguous from 1 (0 marks an empty slot in a site table).
EVENT_CODES: dict[str, int] = {
    'open': 1, 'import': 2, 'time.sleep': 3, 'subprocess.Popen': 4, 'os.system': 5,
    'os.exec': 6, 'os.posix_spawn': 7, 'os.fork': 8, 'socket.__new__': 9, 'console': 10,
    'os.listdir': 11, 'os.scandir': 12, 'os.remove': 13, 'os.rename': 14, 'os.mkdir': 15,
    'socket.getaddrinfo': 16, 'shutil.copyfile': 17, 'os.truncate': 18, 'glob.glob': 19,
}
EVENT_NAMES: dict[int, str] = {v: k for k, v in EVENT_CODES.items()}


class Kind(IntEnum):
    """Datagram kinds (the header's kind byte)."""

    VELOCITY_CMD = 1
    ODOMETRY = 2
    WHEEL_CMD = 3
    ENCODERS = 4
    IMU = 5
    SONAR = 6
    LASER_SCAN = 7
    LED = 8
    TASK_STATS = 9
    REQUEST = 10
    RT_STATUS = 11
    DEVICE_STATUS = 12
    PORT_STATS = 13
    E_STOP = 14
    ODOM_RESET = 15
    APPLIED_VELOCITY = 16
    SET_POSE = 17
    FAULT_RESET = 18
    HOST_DROPS = 19
    # Sent by the RT monitor (FORBIDDEN_SITE, TASK_HEALTH on `stat` only, SAFETY_STATUS on
    # `status`; docs/internals.md); numbered apart from the kinds above since they were
    # introduced as an extension.
    FORBIDDEN_SITE = 64
    TASK_HEALTH = 65
    SAFETY_STATUS = 66
    FAULT_TRACE = 67


class ProtocolError(ValueError):
    """Reject a datagram (or fields to encode); ``reason`` is a short slug for counting.

    Decode reasons: ``short`` (less than a header), ``magic``, ``version``, ``kind``,
    ``length`` (wrong size for the kind or its count), ``nonfinite`` (NaN/inf float),
    ``range`` (a value outside what the layout allows). Encode failures use ``encode``.
    """

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


class Header(NamedTuple):
    """Decoded datagram header."""

    kind: Kind
    seq: int
    stamp_ns: int


class VelocityCmd(NamedTuple):
    """Body velocity command (m/s, rad/s)."""

    linear_x: float
    angular_z: float


class Odometry(NamedTuple):
    """Odometry estimate; ``flags`` holds the ODOM_* bits.

    ``left_wheel``/``right_wheel`` are wheel speeds [rad/s]; ``left_position``/
    ``right_position`` the wheels' accumulated angles [rad] (joint_states), continuous across
    driver restarts.
    """

    x: float
    y: float
    yaw: float
    v: float
    w: float
    left_wheel: float
    right_wheel: float
    left_position: float
    right_position: float
    flags: int


class WheelCmd(NamedTuple):
    """Motor command as 10-bit DAC codes (512 = zero) and an enable bit."""

    left_code: int
    right_code: int
    enable: int


class Encoders(NamedTuple):
    """Encoder reading: 12-bit raw values and unwrapped wheel angles (rad)."""

    left_raw: int
    right_raw: int
    left_angle: float
    right_angle: float
    status: int


class Imu(NamedTuple):
    """IMU sample: orientation quaternion, angular velocity (rad/s), acceleration (m/s^2)."""

    qx: float
    qy: float
    qz: float
    qw: float
    gx: float
    gy: float
    gz: float
    ax: float
    ay: float
    az: float
    status: int


class Sonar(NamedTuple):
    """Sonar range (m) and a SONAR_* status."""

    range_m: float
    status: int


class LaserScan(NamedTuple):
    """Laser scan geometry (rad, m, s), 24-bit device stamp (ms) and ranges (mm)."""

    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    scan_time: float
    time_increment: float
    device_stamp: int
    ranges: tuple[int, ...]


class Led(NamedTuple):
    """LED colour, brightness and source (0 state, 1 bridge override)."""

    r: int
    g: int
    b: int
    brightness: int
    source: int


class TaskSample(NamedTuple):
    """One cycle of an RT task: ideal release, start, end (ns) and timerfd expirations."""

    t_rel: int
    t_start: int
    t_end: int
    expirations: int


class TaskStats(NamedTuple):
    """A batch of per-cycle timing samples plus counters of one RT task."""

    name: str
    task_index: int
    priority: int
    cpu: int
    period_ns: int
    cycles: int
    nvcsw: int
    nivcsw: int
    minflt: int
    forbidden_calls: int
    samples: tuple[TaskSample, ...]


class Request(NamedTuple):
    """Request to a device handler (e.g. sonar trigger, scan request)."""

    request_id: int
    arg: int


class RtStatus(NamedTuple):
    """RT process status: scheduling policy, hardening, collision guard and task counts.

    ``guard_active`` is the actuator's collision guard (limiting forward velocity now); it is
    meaningful only when ``flags`` has RT_FLAG_GUARD_VALID (no actuator: always 0).
    """

    policy: int
    mem_locked: int
    degraded: int
    guard_active: int
    flags: int
    ntasks: int
    cycles_min: int


class DeviceStatus(NamedTuple):
    """Device handler status: lifecycle state, LEVEL_* level, fault count, last error code."""

    device: str
    state: int
    level: int
    faults: int
    last_error: int


class PortStats(NamedTuple):
    """Counters of one XDDP port as seen by the RT side (``m4k_rt.channel.XddpCounters``)."""

    label: str
    port: int
    linked: int
    sent: int
    received: int
    dropped_no_peer: int
    dropped_full: int
    dropped_oversize: int
    malformed: int
    peer_restarts: int


class HostDrops(NamedTuple):
    """What the driver host did with one device's datagrams from the RT side (cumulative).

    ``served`` datagrams reached the device; every other field counts one drop reason
    (:data:`HOST_DROP_REASONS`, m4k_drivers.host): ``stale_host``/``stale_device`` older than
    the device's max age (the host was not scheduled / the last device transaction kept it),
    ``malformed``, ``unexpected`` (a kind the device does not take), ``inactive`` (device not
    ACTIVE), ``encode`` (a reply the wire cannot carry), ``reply_lost`` (a reply the link did
    not take).  The counters start at 0 with each host process.
    """

    device: str
    served: int
    stale_host: int
    stale_device: int
    malformed: int
    unexpected: int
    inactive: int
    encode: int
    reply_lost: int


# The one list of the driver host's drop reasons: HOST_DROPS's counter fields, in wire order.
HOST_DROP_REASONS: tuple[str, ...] = HostDrops._fields[2:]


class EStop(NamedTuple):
    """Emergency stop request: ``engage`` 1 latches the stop in the RT actuator, 0 releases it."""

    engage: int


class OdomReset(NamedTuple):
    """Odometry pose reset: the request (NRT -> RT) and its acknowledgement carry one id."""

    request_id: int


class AppliedVelocity(NamedTuple):
    """The body velocity the RT actuator applies this cycle (m/s, rad/s).

    The command after the limiter, the collision guard, the e-stop ramp and the timeout.
    """

    linear_x: float
    angular_z: float


class SetPose(NamedTuple):
    """Odometry pose set: the request (NRT -> RT) and its acknowledgement carry one id."""

    request_id: int
    x: float
    y: float
    yaw: float


class FaultReset(NamedTuple):
    """Motor fault reset: the request (NRT -> RT) and its answer carry one id.

    The request's ``cleared`` is 0; the answer's is 1 when a latched fault was cleared, 0 when
    none was latched.
    """

    request_id: int
    cleared: int


class SafetyStatus(NamedTuple):
    """The guard's stated figures and the supervision / e-stop state (monitor, 1 Hz).

    ``top_speed`` (m/s) the forward cap applied; ``sensor_speed`` the speed whose stop
    distance is what the sensors see (0: unguarded); ``reaction_time`` (s),
    ``brake_deceleration`` (m/s^2) and ``margin`` (m) of d(v); ``trip_distance`` (m) the
    stop zone now; ``weaken`` (m) the test-only weakening; ``reverse_creep`` (m/s; 0: none);
    ``flags`` SafetyFlag bits; ``fault_cause`` FaultCause bits of the latched fault;
    ``motor_faults`` faults latched since rt_core started.
    """

    top_speed: float
    sensor_speed: float
    reaction_time: float
    brake_deceleration: float
    margin: float
    trip_distance: float
    weaken: float
    reverse_creep: float
    flags: int
    fault_cause: int
    motor_faults: int


class ForbiddenSite(NamedTuple):
    """One call site of a task's forbidden calls (``event`` is a name of EVENT_CODES)."""

    name: str
    task_index: int
    event: str
    calls: int
    line: int
    total: int
    file: str
    func: str


class TaskHealth(NamedTuple):
    """The per-task counters TASK_STATS does not carry."""

    name: str
    task_index: int
    overruns: int
    deadline_misses: int
    body_errors: int
    majflt: int
    nvcsw_extra: int
    lost_samples: int
    fifo: int
    priority: int
    unexpected: int  # the body's valid datagrams of a kind its ports do not carry


class TraceFlag(IntFlag):
    """FAULT_TRACE.flags bits: what the supervision had in that cycle."""

    SATURATED_LEFT = 0x01      # the left output at its limit
    SATURATED_RIGHT = 0x02
    HELD_LEFT = 0x04           # the standstill hold holds the left wheel (read still in it)
    HELD_RIGHT = 0x08
    GYRO = 0x10                # a fresh gyro sample (yaw_rate valid; else 0)
    LEVEL = 0x20               # the level test's hold integrals given (hold_*; else 0)
    ENCODERS = 0x40            # a new encoder sample this cycle (else nothing was measured)


TRACE_FLAGS_MAX = 0x7F


class FaultTrace(NamedTuple):
    """One actuator cycle of the wheel supervision's inputs, from the ring frozen at a latch.

    Sent by the monitor (``status`` port), ``rows`` datagrams per latched fault, oldest
    first (``row`` 0 .. rows-1; the last row is the cycle that latched). ``fault`` is the
    supervisor's fault count (which latch), ``cause`` its FaultCause bits; ``t_ns`` the cycle's
    CLOCK_MONOTONIC time; ``sp_*`` the wheel setpoints and ``meas_*`` the measured wheel
    speeds (rad/s), ``u_*`` the outputs (-1..1), ``angle_*`` the newest encoder angles (rad),
    ``yaw_rate`` the gyro's (rad/s), ``hold_*`` the standstill hold's integrals the level test
    reads, ``bound_*`` the still test's falling speed bound (rad/s; < 0: not commanded still),
    ``t_*`` the symptom times after the cycle (s; the test latches at its configured time);
    ``flags`` TraceFlag bits.
    """

    fault: int
    cause: int
    row: int
    rows: int
    t_ns: int
    sp_left: float
    sp_right: float
    meas_left: float
    meas_right: float
    u_left: float
    u_right: float
    angle_left: float
    angle_right: float
    yaw_rate: float
    hold_left: float
    hold_right: float
    bound_left: float
    bound_right: float
    t_wrong_left: float
    t_wrong_right: float
    t_frozen_left: float
    t_frozen_right: float
    t_stall_left: float
    t_stall_right: float
    t_still_left: float
    t_still_right: float
    t_swap: float
    t_yaw: float
    flags: int


# FAULT_TRACE's float fields in wire order, after t_ns (control.supervision writes its ring
# rows in this order).
TRACE_FLOAT_FIELDS = FaultTrace._fields[5:-1]


class _Spec(NamedTuple):
    kind: Kind
    payload: struct.Struct  # fixed part of the payload (with the count for variable kinds)
    full: struct.Struct  # header + fixed payload, packed in one call
    type: Any  # the payload NamedTuple class
    floats: tuple[int, int]  # float fields are the contiguous slice [start, stop)
    ranges: tuple[tuple[int, float, float], ...]  # (field index, lo, hi) inclusive
    string: int  # > 0: field 0 is a NUL-padded ASCII name of at most this many bytes
    item: struct.Struct | None  # array element of variable kinds
    max_items: int
    texts: tuple[int, ...]  # NUL-padded UTF-8 text fields (lenient: undecodable bytes replaced)


_I32_MAX = 2 ** 31 - 1


def _spec(kind: Kind, fmt: str, cls: Any, floats: tuple[int, int] = (0, 0),
          ranges: tuple[tuple[int, float, float], ...] = (), string: int = 0,
          item: str | None = None, texts: tuple[int, ...] = ()) -> _Spec:
    payload = struct.Struct('<' + fmt)
    item_struct = struct.Struct('<' + item) if item else None
    max_items = 0
    if item_struct is not None:
        max_items = (MAX_DATAGRAM - HEADER_SIZE - payload.size) // item_struct.size
    return _Spec(kind, payload, struct.Struct(HEADER_FORMAT + fmt), cls, floats, ranges,
                 string, item_struct, max_items, texts)


_SPECS: dict[int, _Spec] = {s.kind: s for s in (
    _spec(Kind.VELOCITY_CMD, 'dd', VelocityCmd, (0, 2)),
    _spec(Kind.ODOMETRY, 'dddddddddI', Odometry, (0, 9)),
    _spec(Kind.WHEEL_CMD, 'HHB', WheelCmd,
          ranges=((0, 0, DAC_MAX), (1, 0, DAC_MAX), (2, 0, 1))),
    _spec(Kind.ENCODERS, 'HHddB', Encoders, (2, 4),
          ranges=((0, 0, ENCODER_MAX), (1, 0, ENCODER_MAX))),
    _spec(Kind.IMU, '4d3d3dB', Imu, (0, 10)),
    _spec(Kind.SONAR, 'fB', Sonar, (0, 1), ranges=((0, 0.0, math.inf), (1, 0, max(SonarStatus)))),
    _spec(Kind.LASER_SCAN, 'ffffffIH', LaserScan, (0, 6),
          ranges=((6, 0, SCAN_STAMP_MAX),), item='H'),
    _spec(Kind.LED, 'BBBBB', Led, ranges=((4, 0, 1),)),
    _spec(Kind.TASK_STATS, '16sBiiIIIIIIH', TaskStats, ranges=((3, -1, _I32_MAX),),
          string=NAME_SIZE, item='qqqI'),
    _spec(Kind.REQUEST, 'II', Request),
    _spec(Kind.RT_STATUS, 'BBBBIII', RtStatus,
          ranges=((0, 0, 1), (1, 0, 1), (2, 0, 1), (3, 0, 1))),
    _spec(Kind.DEVICE_STATUS, '16sBBII', DeviceStatus, ranges=((2, 0, max(Level)),),
          string=NAME_SIZE),
    _spec(Kind.PORT_STATS, '32sHBQQQQQQQ', PortStats, ranges=((2, 0, 1),),
          string=LABEL_SIZE),
    _spec(Kind.E_STOP, 'B', EStop, ranges=((0, 0, 1),)),
    _spec(Kind.ODOM_RESET, 'I', OdomReset),
    _spec(Kind.APPLIED_VELOCITY, 'dd', AppliedVelocity, (0, 2)),
    _spec(Kind.SET_POSE, 'Iddd', SetPose, (1, 4)),
    _spec(Kind.FAULT_RESET, 'IB', FaultReset, ranges=((1, 0, 1),)),
    _spec(Kind.HOST_DROPS, '16s8Q', HostDrops, string=NAME_SIZE),
    _spec(Kind.SAFETY_STATUS, 'ddddddddIII', SafetyStatus, (0, 8)),
    _spec(Kind.FAULT_TRACE, 'IIHHq%ddB' % len(TRACE_FLOAT_FIELDS), FaultTrace,
          (5, 5 + len(TRACE_FLOAT_FIELDS)),
          ranges=((len(FaultTrace._fields) - 1, 0, TRACE_FLAGS_MAX),)),
    _spec(Kind.FORBIDDEN_SITE, '16sBBIII%ds%ds' % (SITE_FILE_SIZE, SITE_FUNC_SIZE),
          ForbiddenSite, ranges=((2, min(EVENT_NAMES), max(EVENT_NAMES)),), string=NAME_SIZE,
          texts=(6, 7)),
    _spec(Kind.TASK_HEALTH, '16sBIIIIIIBBI', TaskHealth, ranges=((8, 0, 1),), string=NAME_SIZE),
)}

_HEADER = struct.Struct(HEADER_FORMAT)
_unpack_header = _HEADER.unpack_from
_tuple_new = tuple.__new__
_isfinite = math.isfinite
# The short decode path (decode_from): kind -> (Kind, datagram size, payload unpack_from,
# payload class, float fields [start, stop), ranges), for fixed layouts without text fields.
_FAST: dict[int, tuple[Kind, int, Any, Any, int, int, tuple[tuple[int, float, float], ...]]] = {
    k: (sp.kind, sp.full.size, sp.payload.unpack_from, sp.type, sp.floats[0], sp.floats[1],
        sp.ranges)
    for k, sp in _SPECS.items() if sp.item is None and not sp.string and not sp.texts}
# The short encode path (PortWriter.send): kind -> (pack_into of header + payload, size), for
# the same kinds; ``pack_into(buf, offset, MAGIC, VERSION, kind, seq, stamp_ns, *fields)``
# writes what ``encode_into`` writes.
FIXED_PACKERS: dict[int, tuple[Any, int]] = {
    k: (sp.full.pack_into, sp.full.size) for k, sp in _SPECS.items()
    if sp.item is None and not sp.string and not sp.texts}
_SCAN = _SPECS[Kind.LASER_SCAN]
_STATS = _SPECS[Kind.TASK_STATS]
_SITE = _SPECS[Kind.FORBIDDEN_SITE]
_HEALTH = _SPECS[Kind.TASK_HEALTH]
TASK_STATS_SAMPLE = struct.Struct('<qqqI')  # same layout as _STATS.item
MAX_SCAN_RANGES = _SCAN.max_items
MAX_STATS_SAMPLES = _STATS.max_items
_LITTLE_ENDIAN = sys.byteorder == 'little'
_U16_CACHE: dict[int, struct.Struct] = {}
# What struct's pack_into raises for fields it cannot pack (encode_into turns it into a
# ProtocolError 'encode'; a FIXED_PACKERS caller catches it itself).
PACK_ERRORS = (struct.error, OverflowError, TypeError, ValueError)
_ENCODE_ERRORS = PACK_ERRORS


def _u16_array(count: int) -> struct.Struct:
    # Scans have a fixed count per device, so this cache holds one or two entries.
    s = _U16_CACHE.get(count)
    if s is None:
        if len(_U16_CACHE) > 16:
            _U16_CACHE.clear()
        s = _U16_CACHE[count] = struct.Struct('<%dH' % count)
    return s


def _spec_for(kind: int) -> _Spec:
    spec = _SPECS.get(kind)
    if spec is None:
        raise ProtocolError('kind', 'unknown datagram kind {!r}'.format(kind))
    return spec


def encoded_size(kind: int, count: int = 0) -> int:
    """Return the datagram size of ``kind`` with ``count`` array items (variable kinds)."""
    spec = _spec_for(kind)
    size = spec.full.size
    if spec.item is not None:
        size += count * spec.item.size
    return size


def _name_bytes(name: str | bytes, size: int = NAME_SIZE) -> bytes:
    # Struct's '16s' silently truncates: refuse names that would not decode back unchanged.
    if isinstance(name, str):
        try:
            name = name.encode('ascii')
        except UnicodeEncodeError:
            raise ProtocolError('encode', 'name {!r} is not ASCII'.format(name)) from None
    if not isinstance(name, bytes) or len(name) > size or b'\x00' in name:
        raise ProtocolError(
            'encode', 'name {!r} must be ASCII, without NUL, at most {} bytes'.format(
                name, size))
    return name


def _check(spec: _Spec, values: Sequence[Any]) -> None:
    start, stop = spec.floats
    if start != stop and not all(map(math.isfinite, values[start:stop])):
        for i in range(start, stop):
            if not math.isfinite(values[i]):
                raise ProtocolError('nonfinite', '{} field {!r} is not finite: {!r}'.format(
                    spec.kind.name, spec.type._fields[i], values[i]))
    for i, lo, hi in spec.ranges:
        v = values[i]
        if not lo <= v <= hi:
            raise ProtocolError('range', '{} field {!r} = {!r} outside [{}, {}]'.format(
                spec.kind.name, spec.type._fields[i], v, lo, hi))


def _check_fields(spec: _Spec, fields: Sequence[Any]) -> None:
    if len(fields) != len(spec.type._fields):
        raise ProtocolError('encode', '{} takes {} fields {}, got {!r}'.format(
            spec.kind.name, len(spec.type._fields), spec.type._fields, fields))
    if spec.item is not None:
        try:
            len(fields[-1])
        except TypeError:
            raise ProtocolError('encode', '{} field {!r} must be a sequence, got {!r}'.format(
                spec.kind.name, spec.type._fields[-1], fields[-1])) from None
    try:
        _check(spec, fields)
    except TypeError as exc:
        raise ProtocolError('encode', 'cannot check {} fields {!r}: {}'.format(
            spec.kind.name, fields, exc)) from None


def encode_into(buf: bytearray | memoryview, offset: int, kind: int, seq: int, stamp_ns: int,
                *fields: Any, check: bool = False) -> int:
    """Encode one datagram into ``buf`` at ``offset`` and return the number of bytes written.

    ``fields`` are the payload fields in table order; for LASER_SCAN and TASK_STATS the last
    field is the ranges / samples sequence (the count is derived). ``seq`` is reduced modulo
    2**32. Integer fields are checked by ``struct``; floats and layout ranges are only checked
    with ``check=True`` (the receiver's :func:`decode` always checks them).
    """
    spec = _spec_for(kind)
    if spec is _SITE:
        return encode_forbidden_site_into(buf, offset, seq, stamp_ns, *fields)
    if check:
        _check_fields(spec, fields)
    if spec is _HEALTH:
        return encode_task_health_into(buf, offset, seq, stamp_ns, *fields)
    if spec.item is not None:
        if spec is _SCAN:
            return encode_scan_into(buf, offset, seq, stamp_ns, *fields)
        return encode_task_stats_into(buf, offset, seq, stamp_ns, *fields)
    if spec.string and fields:
        fields = (_name_bytes(fields[0], spec.string),) + fields[1:]
    try:
        spec.full.pack_into(buf, offset, MAGIC, VERSION, kind, seq & SEQ_MASK, stamp_ns, *fields)
    except _ENCODE_ERRORS as exc:
        raise ProtocolError('encode', 'cannot encode {} fields {!r}: {}'.format(
            spec.kind.name, fields, exc)) from None
    return spec.full.size


def encode_scan_into(buf: bytearray | memoryview, offset: int, seq: int, stamp_ns: int,
                     angle_min: float, angle_increment: float, range_min: float,
                     range_max: float, scan_time: float, time_increment: float,
                     device_stamp: int, ranges_mm: 'Sequence[int] | array[int]') -> int:
    """Encode a LASER_SCAN datagram into ``buf`` and return the number of bytes written.

    ``ranges_mm`` may be any sequence of ints; an ``array('H')`` is copied without unpacking.
    """
    count = len(ranges_mm)
    if count > MAX_SCAN_RANGES:
        raise ProtocolError('encode', 'scan has {} ranges, at most {} fit a datagram'.format(
            count, MAX_SCAN_RANGES))
    head = _SCAN.full
    try:
        head.pack_into(buf, offset, MAGIC, VERSION, Kind.LASER_SCAN, seq & SEQ_MASK, stamp_ns,
                       angle_min, angle_increment, range_min, range_max, scan_time,
                       time_increment, device_stamp, count)
        start = offset + head.size
        if isinstance(ranges_mm, array) and ranges_mm.typecode == 'H' and _LITTLE_ENDIAN:
            memoryview(buf)[start:start + 2 * count] = memoryview(ranges_mm).cast('B')
        else:
            _u16_array(count).pack_into(buf, start, *ranges_mm)
    except _ENCODE_ERRORS as exc:
        raise ProtocolError('encode', 'cannot encode LASER_SCAN: {}'.format(exc)) from None
    return head.size + 2 * count


def encode_task_stats_head_into(buf: bytearray | memoryview, offset: int, seq: int,
                                stamp_ns: int, name: str | bytes, index: int, priority: int,
                                cpu: int, period_ns: int, cycles: int, nvcsw: int, nivcsw: int,
                                minflt: int, forbidden_calls: int, count: int) -> int:
    """Encode the TASK_STATS header and fixed part for ``count`` samples; return its size.

    The caller then writes sample ``i`` with ``TASK_STATS_SAMPLE.pack_into(buf, offset + size
    + i * TASK_STATS_SAMPLE.size, t_rel, t_start, t_end, expirations)`` straight from its
    ring buffers. Pass ``name`` as pre-encoded bytes in RT loops.
    """
    if not 0 <= count <= MAX_STATS_SAMPLES:
        raise ProtocolError('encode', 'TASK_STATS count {!r} outside [0, {}]'.format(
            count, MAX_STATS_SAMPLES))
    full = _STATS.full
    try:
        full.pack_into(buf, offset, MAGIC, VERSION, Kind.TASK_STATS, seq & SEQ_MASK, stamp_ns,
                       _name_bytes(name), index, priority, cpu, period_ns, cycles, nvcsw,
                       nivcsw, minflt, forbidden_calls, count)
    except _ENCODE_ERRORS as exc:
        raise ProtocolError('encode', 'cannot encode TASK_STATS: {}'.format(exc)) from None
    return full.size


def encode_task_stats_into(buf: bytearray | memoryview, offset: int, seq: int, stamp_ns: int,
                           name: str | bytes, index: int, priority: int, cpu: int,
                           period_ns: int, cycles: int, nvcsw: int, nivcsw: int, minflt: int,
                           forbidden_calls: int,
                           samples: Sequence[Sequence[int]]) -> int:
    """Encode a TASK_STATS batch with sample rows (t_rel, t_start, t_end, expirations)."""
    size = encode_task_stats_head_into(buf, offset, seq, stamp_ns, name, index, priority, cpu,
                                       period_ns, cycles, nvcsw, nivcsw, minflt,
                                       forbidden_calls, len(samples))
    pack = TASK_STATS_SAMPLE.pack_into
    step = TASK_STATS_SAMPLE.size
    pos = offset + size
    try:
        for row in samples:
            pack(buf, pos, *row)
            pos += step
    except _ENCODE_ERRORS as exc:
        raise ProtocolError('encode', 'cannot encode TASK_STATS sample {!r}: {}'.format(
            row, exc)) from None
    return pos - offset


def _text_bytes(text: str, size: int, tail: bool = False) -> bytes:
    raw = text.encode('utf-8', 'replace')
    return raw[-size:] if tail else raw[:size]


def encode_forbidden_site_into(buf: bytearray | memoryview, offset: int, seq: int,
                               stamp_ns: int, name: str | bytes, task_index: int,
                               event: int | str, calls: int, line: int, total: int, file: str,
                               func: str) -> int:
    """Encode a FORBIDDEN_SITE datagram into ``buf`` and return the number of bytes written.

    ``event`` is an EVENT_CODES code (RT loops) or name. Counters saturate at 2**32 - 1; a long
    ``file`` keeps its tail (the file name), a long ``func`` its head.
    """
    code = EVENT_CODES.get(event, 0) if isinstance(event, str) else event
    if code not in EVENT_NAMES:
        raise ProtocolError('encode', 'unknown forbidden event {!r}'.format(event))
    full = _SITE.full
    try:
        full.pack_into(buf, offset, MAGIC, VERSION, Kind.FORBIDDEN_SITE, seq & SEQ_MASK,
                       stamp_ns, _name_bytes(name), task_index, code, min(calls, U32_MAX),
                       line, min(total, U32_MAX), _text_bytes(file, SITE_FILE_SIZE, tail=True),
                       _text_bytes(func, SITE_FUNC_SIZE))
    except _ENCODE_ERRORS as exc:
        raise ProtocolError('encode', 'cannot encode FORBIDDEN_SITE: {}'.format(exc)) from None
    return full.size


def encode_task_health_into(buf: bytearray | memoryview, offset: int, seq: int, stamp_ns: int,
                            name: str | bytes, task_index: int, overruns: int,
                            deadline_misses: int, body_errors: int, majflt: int,
                            nvcsw_extra: int, lost_samples: int, fifo: int,
                            priority: int, unexpected: int) -> int:
    """Encode a TASK_HEALTH datagram into ``buf``; counters saturate at 2**32 - 1."""
    m = U32_MAX
    full = _HEALTH.full
    try:
        full.pack_into(buf, offset, MAGIC, VERSION, Kind.TASK_HEALTH, seq & SEQ_MASK, stamp_ns,
                       _name_bytes(name), task_index, min(overruns, m),
                       min(deadline_misses, m), min(body_errors, m), min(majflt, m),
                       min(nvcsw_extra, m), min(lost_samples, m), fifo, priority,
                       min(unexpected, m))
    except _ENCODE_ERRORS as exc:
        raise ProtocolError('encode', 'cannot encode TASK_HEALTH: {}'.format(exc)) from None
    return full.size


def encode(kind: int, seq: int, stamp_ns: int, *fields: Any) -> bytes:
    """Encode and fully validate one datagram into new bytes (convenience for NRT code)."""
    spec = _spec_for(kind)
    if spec is _SITE and len(fields) > 2 and isinstance(fields[2], str):
        fields = fields[:2] + (EVENT_CODES.get(fields[2], 0),) + fields[3:]
    _check_fields(spec, fields)
    count = len(fields[-1]) if spec.item is not None else 0
    buf = bytearray(encoded_size(kind, count))
    encode_into(buf, 0, kind, seq, stamp_ns, *fields)
    return bytes(buf)


def _decode_name(spec: _Spec, raw: bytes) -> str:
    name = raw.rstrip(b'\x00')
    if b'\x00' not in name:
        try:
            return name.decode('ascii')
        except UnicodeDecodeError:
            pass
    raise ProtocolError('range', '{} name {!r} is not NUL-padded ASCII'.format(
        spec.kind.name, raw))


def decode(data: bytes | bytearray | memoryview) -> tuple[Header, Any]:
    """Validate and decode one datagram into its Header and payload NamedTuple."""
    return decode_from(data, len(data))


def decode_from(buf: bytes | bytearray | memoryview, n: int) -> tuple[Header, Any]:
    """Validate and decode the datagram held in the first ``n`` bytes of ``buf``.

    The receive path of RT loops: no slice of the receive buffer is made. Fixed-layout kinds
    without text fields (every kind a task receives each cycle) take a short path that accepts
    exactly what the full validation accepts and builds the same tuples; anything else, and
    every datagram that fails a check, goes through the full validation, which raises the
    precise :class:`ProtocolError`.
    """
    if not 0 <= n <= len(buf):
        raise ProtocolError('length', 'datagram length {!r} outside the {}-byte buffer'.format(
            n, len(buf)))
    if n >= HEADER_SIZE:
        magic, version, kind, seq, stamp_ns = _unpack_header(buf)
        fast = _FAST.get(kind)
        if fast is not None and magic == MAGIC and version == VERSION:
            kind_e, size, unpack, cls, f0, f1, ranges = fast
            if n == size:
                values = unpack(buf, HEADER_SIZE)
                if f0 == f1 or all(map(_isfinite, values[f0:f1])):
                    for i, lo, hi in ranges:
                        if not lo <= values[i] <= hi:
                            break
                    else:
                        return (_tuple_new(Header, (kind_e, seq, stamp_ns)),
                                _tuple_new(cls, values))
    return _decode_checked(buf, n)


def _decode_checked(data: bytes | bytearray | memoryview, n: int) -> tuple[Header, Any]:
    if n < HEADER_SIZE:
        raise ProtocolError('short', 'datagram of {} bytes is shorter than the {}-byte '
                            'header'.format(n, HEADER_SIZE))
    magic, version, kind, seq, stamp_ns = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise ProtocolError('magic', 'bad magic 0x{:04X}'.format(magic))
    if version != VERSION:
        raise ProtocolError('version', 'unsupported protocol version {!r}'.format(version))
    spec = _SPECS.get(kind)
    if spec is None:
        raise ProtocolError('kind', 'unknown datagram kind {!r}'.format(kind))
    fixed_end = spec.full.size
    if spec.item is None:
        if n != fixed_end:
            raise ProtocolError('length', '{} datagram is {} bytes, expected {}'.format(
                spec.kind.name, n, fixed_end))
        values: tuple[Any, ...] = spec.payload.unpack_from(data, HEADER_SIZE)
    else:
        if n < fixed_end:
            raise ProtocolError('length', '{} datagram is {} bytes, expected at least '
                                '{}'.format(spec.kind.name, n, fixed_end))
        values = spec.payload.unpack_from(data, HEADER_SIZE)
        count = values[-1]
        if count > spec.max_items:
            raise ProtocolError('range', '{} count {} exceeds {}'.format(
                spec.kind.name, count, spec.max_items))
        expected = fixed_end + count * spec.item.size
        if n != expected:
            raise ProtocolError('length', '{} datagram with count {} is {} bytes, expected '
                                '{}'.format(spec.kind.name, count, n, expected))
        if spec is _SCAN:
            items: tuple[Any, ...] = _u16_array(count).unpack_from(data, fixed_end)
        else:
            rows = spec.item.iter_unpack(memoryview(data)[fixed_end:n])
            items = tuple(map(TaskSample._make, rows))
        values = values[:-1] + (items,)
    _check(spec, values)
    if spec.string:
        values = (_decode_name(spec, values[0]),) + values[1:]
    if spec.texts:
        texts = list(values)
        for i in spec.texts:
            texts[i] = texts[i].rstrip(b'\x00').decode('utf-8', 'replace')
        if spec is _SITE:
            texts[2] = EVENT_NAMES[texts[2]]  # in range: checked above
        values = tuple(texts)
    return Header(spec.kind, seq, stamp_ns), spec.type._make(values)


def next_seq(seq: int) -> int:
    """Return the sequence number following ``seq`` (wraps at 2**32)."""
    return (seq + 1) & SEQ_MASK


def seq_newer(prev: int, cur: int) -> bool:
    """Return True when ``cur`` is ahead of ``prev`` in wrap-around (serial number) order."""
    d = (cur - prev) & SEQ_MASK
    return 0 < d < 0x80000000


def seq_gap(prev: int, cur: int) -> int:
    """Return how many datagrams were lost between ``prev`` and ``cur`` (0 if consecutive).

    A repeated or older number (sender restarted or reordering) returns 0: it is not a loss
    and the receiver should simply resynchronise on ``cur``.
    """
    d = (cur - prev) & SEQ_MASK
    return d - 1 if 0 < d < 0x80000000 else 0
