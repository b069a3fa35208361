"""Tests for m4k_rt.protocol: exact bytes, round trips, validation and fuzzing."""

from array import array
import ast
import math
import struct

from hypothesis import given, settings
from hypothesis import strategies as st
import pytest

from m4k_rt import protocol as p
from m4k_rt import schema
from m4k_rt.channel import contract
from m4k_rt.protocol import Header, Kind, ProtocolError
from m4k_testing import examples

U8 = st.integers(0, 0xFF)
U16 = st.integers(0, 0xFFFF)
U32 = st.integers(0, 0xFFFFFFFF)
I32 = st.integers(-2 ** 31, 2 ** 31 - 1)
I64 = st.integers(-2 ** 63, 2 ** 63 - 1)
F64 = st.floats(allow_nan=False, allow_infinity=False)
F32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
BIT = st.integers(0, 1)
U64 = st.integers(0, 2 ** 64 - 1)
NAME = st.text(st.characters(min_codepoint=1, max_codepoint=127), max_size=16)
LABEL = st.text(st.characters(min_codepoint=1, max_codepoint=127), max_size=32)
FILE = st.text(st.characters(min_codepoint=1, max_codepoint=127), max_size=p.SITE_FILE_SIZE)
FUNC = st.text(st.characters(min_codepoint=1, max_codepoint=127), max_size=p.SITE_FUNC_SIZE)

FIELDS = {
    Kind.VELOCITY_CMD: st.tuples(F64, F64),
    Kind.ODOMETRY: st.tuples(*[F64] * 9, U32),
    Kind.WHEEL_CMD: st.tuples(st.integers(0, 1023), st.integers(0, 1023), BIT),
    Kind.ENCODERS: st.tuples(st.integers(0, 4095), st.integers(0, 4095), F64, F64, U8),
    Kind.IMU: st.tuples(*[F64] * 10, U8),
    Kind.SONAR: st.tuples(st.floats(0.0, width=32, allow_infinity=False), st.integers(0, 3)),
    Kind.LASER_SCAN: st.tuples(*[F32] * 6, st.integers(0, 0xFFFFFF),
                               st.lists(U16, max_size=p.MAX_SCAN_RANGES).map(tuple)),
    Kind.LED: st.tuples(U8, U8, U8, U8, BIT),
    Kind.TASK_STATS: st.tuples(
        NAME, U8, I32, st.integers(-1, 2 ** 31 - 1), *[U32] * 6,
        st.lists(st.tuples(I64, I64, I64, U32).map(lambda r: p.TaskSample(*r)),
                 max_size=p.MAX_STATS_SAMPLES).map(tuple)),
    Kind.REQUEST: st.tuples(U32, U32),
    Kind.RT_STATUS: st.tuples(BIT, BIT, BIT, BIT, U32, U32, U32),
    Kind.DEVICE_STATUS: st.tuples(NAME, U8, st.integers(0, 3), U32, U32),
    Kind.PORT_STATS: st.tuples(LABEL, U16, BIT, *[U64] * 7),
    Kind.E_STOP: st.tuples(BIT),
    Kind.ODOM_RESET: st.tuples(U32),
    Kind.APPLIED_VELOCITY: st.tuples(F64, F64),
    Kind.SET_POSE: st.tuples(U32, F64, F64, F64),
    Kind.FAULT_RESET: st.tuples(U32, st.integers(0, 1)),
    Kind.HOST_DROPS: st.tuples(NAME, *[U64] * 8),
    Kind.SAFETY_STATUS: st.tuples(F64, F64, F64, F64, F64, F64, F64, F64, U32, U32, U32),
    Kind.FORBIDDEN_SITE: st.tuples(NAME, U8, st.sampled_from(sorted(p.EVENT_CODES)), U32, U32,
                                   U32, FILE, FUNC),
    Kind.TASK_HEALTH: st.tuples(NAME, U8, *[U32] * 6, BIT, U8, U32),
    Kind.FAULT_TRACE: st.tuples(U32, U32, U16, U16, I64, *[F64] * len(p.TRACE_FLOAT_FIELDS),
                                st.integers(0, p.TRACE_FLAGS_MAX)),
}

PAYLOAD_TYPES = {
    Kind.VELOCITY_CMD: p.VelocityCmd, Kind.ODOMETRY: p.Odometry, Kind.WHEEL_CMD: p.WheelCmd,
    Kind.ENCODERS: p.Encoders, Kind.IMU: p.Imu, Kind.SONAR: p.Sonar,
    Kind.LASER_SCAN: p.LaserScan, Kind.LED: p.Led, Kind.TASK_STATS: p.TaskStats,
    Kind.REQUEST: p.Request, Kind.RT_STATUS: p.RtStatus, Kind.DEVICE_STATUS: p.DeviceStatus,
    Kind.PORT_STATS: p.PortStats, Kind.E_STOP: p.EStop, Kind.ODOM_RESET: p.OdomReset,
    Kind.APPLIED_VELOCITY: p.AppliedVelocity, Kind.SET_POSE: p.SetPose,
    Kind.FAULT_RESET: p.FaultReset, Kind.HOST_DROPS: p.HostDrops,
    Kind.SAFETY_STATUS: p.SafetyStatus,
    Kind.FORBIDDEN_SITE: p.ForbiddenSite, Kind.TASK_HEALTH: p.TaskHealth,
    Kind.FAULT_TRACE: p.FaultTrace,
}

# One hand-picked valid payload per kind (used by example tests and mutation fuzzing).
EXAMPLES = {
    Kind.VELOCITY_CMD: (0.25, -0.5),
    Kind.ODOMETRY: (1.0, 2.0, 0.5, 0.25, 0.1, 2.5, 2.4, 12.5, -3.25,
                    p.ODOM_BRAKING | p.ODOM_CLAMPED),
    Kind.WHEEL_CMD: (512, 1023, 1),
    Kind.ENCODERS: (4095, 0, 12.5, -3.25, 0),
    Kind.IMU: (0.0, 0.0, 0.0, 1.0, 0.01, -0.02, 0.03, 0.1, -0.2, 9.81, 0),
    Kind.SONAR: (1.5, p.SONAR_OK),
    Kind.LASER_SCAN: (-2.0, 0.00613592, 0.02, 5.6, 0.1, 0.0001, 0xFFFFFF, (20, 1000, 5600, 0)),
    Kind.LED: (255, 128, 0, 200, 1),
    Kind.TASK_STATS: ('actuator', 0, 90, 1, 10_000_000, 1234, 1, 2, 3, 0,
                      (p.TaskSample(1_000, 1_050, 1_200, 1),
                       p.TaskSample(2_000, 2_040, 2_100, 2))),
    Kind.REQUEST: (7, 42),
    Kind.RT_STATUS: (1, 1, 0, 1, 0, 6, 100),
    Kind.DEVICE_STATUS: ('imu', 3, p.LEVEL_WARN, 2, 121),
    Kind.PORT_STATS: ('cmd', 1, 1, 5000, 1000, 3, 2, 1, 4, 1),
    Kind.E_STOP: (1,),
    Kind.ODOM_RESET: (0xDEADBEEF,),
    Kind.APPLIED_VELOCITY: (0.25, -0.5),
    Kind.SET_POSE: (7, 1.5, -2.0, 0.75),
    Kind.FAULT_RESET: (3, 1),
    Kind.HOST_DROPS: ('motor', 9_990, 7, 1, 0, 2, 0, 0, 2 ** 64 - 1),
    Kind.SAFETY_STATUS: (2.0, 3.2, 0.48, 1.5, 0.35, 0.49, 0.0, 0.1, 0x7, 0, 0),
    Kind.FORBIDDEN_SITE: ('led', 2, 'open', 311, 42, 400, '/x/led_body.py', 'cycle'),
    Kind.TASK_HEALTH: ('imu', 1, 3, 2, 1, 0, 4, 0, 1, 85, 17),
    Kind.FAULT_TRACE: (3, 0x200, 63, 64, 1_234_567_890,
                       0.0, 0.0, 0.2, 1.4, -0.05, 0.0,            # setpoints, speeds, outputs
                       12.5, -3.25, 0.01, 0.02, 0.0, 0.0, 0.3,    # angles, yaw, holds, bounds
                       0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.3, 0.0, 0.0,   # symptom times
                       0x7C),
}


def _f32(x):
    return struct.unpack('<f', struct.pack('<f', x))[0]


def test_every_kind_has_an_example_and_a_strategy():
    assert set(EXAMPLES) == set(Kind) == set(FIELDS) == set(PAYLOAD_TYPES)


def test_kind_table_has_unique_numbers_and_a_layout_per_kind():
    numbers = [int(k) for k in Kind]
    assert len(numbers) == len(set(numbers)) and all(0 < n < 256 for n in numbers)
    assert set(p._SPECS) == set(Kind)
    assert all(spec.kind == kind and spec.type is PAYLOAD_TYPES[kind]
               and len(spec.type._fields) == len(spec.payload.unpack(bytes(spec.payload.size)))
               for kind, spec in p._SPECS.items())


def test_forbidden_event_codes_are_distinct_and_contiguous():
    codes = sorted(p.EVENT_CODES.values())
    assert codes == list(range(1, len(p.EVENT_CODES) + 1))
    assert p.EVENT_NAMES == {c: e for e, c in p.EVENT_CODES.items()}


def test_forbidden_site_keeps_the_file_tail_and_saturates_counters():
    buf = bytearray(256)
    n = p.encode_forbidden_site_into(buf, 0, 7, 123, 'led', 2, p.EVENT_CODES['open'], 2 ** 40,
                                     42, 400, '/very/long/path/' * 5 + 'led_body.py', 'cycle')
    header, site = p.decode(bytes(buf[:n]))
    assert header == Header(Kind.FORBIDDEN_SITE, 7, 123)
    assert site.event == 'open' and site.calls == 0xFFFFFFFF and site.total == 400
    assert site.file.endswith('/path/led_body.py') and len(site.file) == p.SITE_FILE_SIZE
    with pytest.raises(ProtocolError, match='unknown forbidden event'):
        p.encode_forbidden_site_into(buf, 0, 0, 0, 'led', 2, 0, 1, 1, 1, 'f', 'g')


def test_forbidden_site_with_an_unknown_event_code_is_rejected():
    good = bytearray(p.encode(Kind.FORBIDDEN_SITE, 0, 0, *EXAMPLES[Kind.FORBIDDEN_SITE]))
    good[16 + 17] = len(p.EVENT_CODES) + 1  # the event byte after name (16) and index (1)
    assert _reason(bytes(good)) == 'range'


# ---- exact bytes, computed by hand from the table in docs/internals.md ----

def test_velocity_cmd_bytes_are_exact():
    data = p.encode(Kind.VELOCITY_CMD, 1, 2, 0.5, -0.25)
    assert data == bytes.fromhex(
        '4d4b' '01' '01' '01000000' '0200000000000000'   # magic 'MK', version, kind, seq, stamp
        '000000000000e03f'                               # 0.5  = 0x3FE0000000000000
        '000000000000d0bf')                              # -0.25 = 0xBFD0000000000000


def test_wheel_cmd_bytes_are_exact_and_seq_wraps():
    data = p.encode(Kind.WHEEL_CMD, 0x1_0102_0304, -1, 512, 1023, 1)
    assert data == bytes.fromhex(
        '4d4b0103' '04030201' 'ffffffffffffffff' '0002' 'ff03' '01')


def test_sonar_bytes_are_exact():
    data = p.encode(Kind.SONAR, 0, 1_000_000_000, 1.5, p.SONAR_TIMEOUT)
    assert data == bytes.fromhex('4d4b0106' '00000000' '00ca9a3b00000000' '0000c03f' '02')


def test_laser_scan_bytes_are_exact():
    data = p.encode(Kind.LASER_SCAN, 3, 0, -1.0, 0.5, 0.0, 2.0, 0.25, 0.0, 0x123456, (20, 0x1234))
    assert data == bytes.fromhex(
        '4d4b0107' '03000000' '0000000000000000'
        '000080bf' '0000003f' '00000000' '00000040' '0000803e' '00000000'  # six f32
        '56341200' '0200'                                                  # stamp, count
        '1400' '3412')                                                     # ranges (mm)


def test_task_stats_bytes_are_exact():
    data = p.encode(Kind.TASK_STATS, 0, 0, 'ab', 1, 2, -1, 3, 4, 5, 6, 7, 8, [(9, 10, 11, 1)])
    assert data == bytes.fromhex(
        '4d4b0109' '00000000' '0000000000000000'
        '6162' + '00' * 14 + '01' '02000000' 'ffffffff'
        '03000000' '04000000' '05000000' '06000000' '07000000' '08000000' '0100'
        '0900000000000000' '0a00000000000000' '0b00000000000000' '01000000')


def test_port_stats_bytes_are_exact():
    data = p.encode(Kind.PORT_STATS, 0, 0, 'cmd', 0x0102, 1, 1, 2, 3, 4, 5, 6, 2 ** 64 - 1)
    assert data == bytes.fromhex(
        '4d4b010d' '00000000' '0000000000000000'
        '636d64' + '00' * 29 + '0201' '01'                       # label, port, linked
        '0100000000000000' '0200000000000000' '0300000000000000' '0400000000000000'
        '0500000000000000' '0600000000000000' 'ffffffffffffffff')


def test_port_stats_label_holds_any_xddp_label():
    label = 'a' * 32                                  # XDDP labels are 1..32 characters
    data = p.encode(Kind.PORT_STATS, 0, 0, label, 7, 0, 0, 0, 0, 0, 0, 0, 0)
    assert p.decode(data)[1].label == label
    with pytest.raises(ProtocolError):
        p.encode(Kind.PORT_STATS, 0, 0, label + 'b', 7, 0, 0, 0, 0, 0, 0, 0, 0)


def test_e_stop_and_odom_reset_bytes_are_exact():
    data = p.encode(Kind.E_STOP, 5, 7, 1)
    assert data == struct.pack('<HBBIqB', 0x4B4D, 1, 14, 5, 7, 1)
    data = p.encode(Kind.ODOM_RESET, 6, 8, 0x01020304)
    assert data == struct.pack('<HBBIqI', 0x4B4D, 1, 15, 6, 8, 0x01020304)
    assert p.decode(data)[1] == p.OdomReset(0x01020304)


def test_e_stop_engage_other_than_0_or_1_is_rejected():
    data = bytearray(p.encode(Kind.E_STOP, 0, 0, 1))
    data[-1] = 2
    with pytest.raises(ProtocolError) as exc:
        p.decode(bytes(data))
    assert exc.value.reason == 'range'


def test_odometry_flag_bits_are_distinct():
    bits = [p.ODOM_BRAKING, p.ODOM_GUARD, p.ODOM_MOTOR_STALE, p.ODOM_CLAMPED, p.ODOM_E_STOP,
            p.ODOM_HOLD]
    assert all(b & (b - 1) == 0 for b in bits) and len(set(bits)) == len(bits)


def test_encoded_size_matches_layouts():
    assert p.encoded_size(Kind.VELOCITY_CMD) == 32
    assert p.encoded_size(Kind.PORT_STATS) == 16 + 32 + 2 + 1 + 7 * 8
    assert p.encoded_size(Kind.IMU) == 16 + 80 + 1
    assert p.encoded_size(Kind.LASER_SCAN, 683) == 16 + 30 + 2 * 683
    assert p.encoded_size(Kind.TASK_STATS, 2) == 16 + 51 + 2 * 28
    assert p.encoded_size(Kind.LASER_SCAN, p.MAX_SCAN_RANGES) <= p.MAX_DATAGRAM
    assert p.encoded_size(Kind.TASK_STATS, p.MAX_STATS_SAMPLES) <= p.MAX_DATAGRAM
    assert p.encoded_size(Kind.TASK_STATS, p.MAX_STATS_SAMPLES + 1) > p.MAX_DATAGRAM


def test_the_wire_limit_is_the_channels_one_declaration():
    # MAX_DATAGRAM was a second 4096 beside the channel's contract: the protocol module now
    # states no datagram limit of its own (no number bound to a *DATAGRAM* name), and the
    # schema's default is the same declaration.
    with open(p.__file__, encoding='utf-8') as f:
        tree = ast.parse(f.read())
    stated = [t.id for n in tree.body if isinstance(n, (ast.Assign, ast.AnnAssign))
              for t in (n.targets if isinstance(n, ast.Assign) else [n.target])
              if isinstance(t, ast.Name) and 'DATAGRAM' in t.id
              and any(isinstance(c, ast.Constant) for c in ast.walk(n.value))]
    assert stated == []
    assert p.MAX_DATAGRAM == contract.DEFAULT_MAX_DATAGRAM
    assert schema.RUNTIME['max_datagram'].default == contract.DEFAULT_MAX_DATAGRAM


# ---- round trips ----

@pytest.mark.parametrize('kind', list(Kind))
def test_example_round_trips_through_encode_into_at_an_offset(kind):
    fields = EXAMPLES[kind]
    buf = bytearray(p.MAX_DATAGRAM + 8)
    n = p.encode_into(buf, 8, kind, 77, 123_456_789, *fields)
    header, payload = p.decode(memoryview(buf)[8:8 + n])
    assert header == Header(kind, 77, 123_456_789)
    assert isinstance(header.kind, Kind)
    assert type(payload) is PAYLOAD_TYPES[kind]
    if kind == Kind.LASER_SCAN:  # f32 fields come back rounded to single precision
        fields = tuple(_f32(x) for x in fields[:6]) + fields[6:]
    assert payload == fields
    assert bytes(buf[8:8 + n]) == p.encode(kind, 77, 123_456_789, *fields)


@pytest.mark.parametrize('kind', list(Kind))
def test_generated_finite_values_round_trip(kind):
    @settings(max_examples=examples(60))
    @given(fields=FIELDS[kind], seq=U32, stamp=I64)
    def check(fields, seq, stamp):
        data = p.encode(kind, seq, stamp, *fields)
        assert len(data) == p.encoded_size(kind, len(fields[-1]) if kind in (
            Kind.LASER_SCAN, Kind.TASK_STATS) else 0)
        assert p.decode(data) == (Header(kind, seq, stamp), PAYLOAD_TYPES[kind](*fields))
    check()


def test_scan_from_uint16_array_matches_scan_from_list():
    ranges = list(range(20, 20 + 683))
    a = bytearray(2000)
    b = bytearray(2000)
    args = (5, 99, -2.09, 0.006, 0.02, 5.6, 0.1, 0.0001, 4242)
    na = p.encode_scan_into(a, 0, *args, array('H', ranges))
    nb = p.encode_scan_into(b, 0, *args, ranges)
    assert na == nb == p.encoded_size(Kind.LASER_SCAN, 683)
    assert a == b
    assert p.decode(bytes(a[:na]))[1].ranges == tuple(ranges)


def test_task_stats_columnar_writer_matches_row_writer():
    rows = [(i * 10, i * 10 + 1, i * 10 + 5, 1 + i % 2) for i in range(50)]
    head = (1, 2, b'imu', 1, 80, 0, 10_000_000, 50, 0, 1, 2, 0)
    a = bytearray(p.MAX_DATAGRAM)
    b = bytearray(p.MAX_DATAGRAM)
    n = p.encode_task_stats_into(a, 0, *head, rows)
    size = p.encode_task_stats_head_into(b, 0, *head, len(rows))
    for i, row in enumerate(rows):
        p.TASK_STATS_SAMPLE.pack_into(b, size + i * p.TASK_STATS_SAMPLE.size, *row)
    assert a[:n] == b[:n]
    assert p.decode(bytes(a[:n]))[1].samples == tuple(p.TaskSample(*r) for r in rows)


# ---- decode rejects bad datagrams with the right reason ----

def _raw(kind, *fields, seq=1, stamp=2):
    """Encode without value checks (as a buggy or hostile sender would)."""
    buf = bytearray(p.MAX_DATAGRAM)
    n = p.encode_into(buf, 0, kind, seq, stamp, *fields)
    return bytes(buf[:n])


def _reason(data):
    with pytest.raises(ProtocolError) as info:
        p.decode(data)
    return info.value.reason


def test_short_datagram_is_rejected():
    assert _reason(b'') == 'short'
    assert _reason(p.encode(Kind.REQUEST, 0, 0, 1, 2)[:15]) == 'short'


def test_bad_magic_version_and_kind_are_rejected():
    good = bytearray(p.encode(Kind.REQUEST, 0, 0, 1, 2))
    assert _reason(b'KM' + good[2:]) == 'magic'
    assert _reason(good[:2] + b'\x02' + good[3:]) == 'version'
    assert _reason(good[:3] + b'\x00' + good[4:]) == 'kind'
    assert _reason(good[:3] + bytes([max(Kind) + 1]) + good[4:]) == 'kind'


@pytest.mark.parametrize('kind', [k for k in Kind if k not in (Kind.LASER_SCAN, Kind.TASK_STATS)])
def test_fixed_kinds_need_their_exact_length(kind):
    good = p.encode(kind, 0, 0, *EXAMPLES[kind])
    assert _reason(good[:-1]) == 'length'
    assert _reason(good + b'\x00') == 'length'


@pytest.mark.parametrize('kind', [Kind.LASER_SCAN, Kind.TASK_STATS])
def test_variable_kinds_need_a_length_consistent_with_count(kind):
    good = p.encode(kind, 0, 0, *EXAMPLES[kind])
    item = 2 if kind == Kind.LASER_SCAN else 28
    assert _reason(good[:-1]) == 'length'
    assert _reason(good[:-item]) == 'length'
    assert _reason(good + b'\x00' * item) == 'length'
    fixed = p.encoded_size(kind)
    assert _reason(good[:fixed - 1]) == 'length'
    too_many = {Kind.LASER_SCAN: p.MAX_SCAN_RANGES, Kind.TASK_STATS: p.MAX_STATS_SAMPLES}[kind] + 1
    forged = good[:fixed - 2] + struct.pack('<H', too_many) + b'\x00' * (item * too_many)
    assert _reason(forged) == 'range'


FLOAT_FIELDS = [(kind, i) for kind, spec in p._SPECS.items()
                for i in range(*spec.floats)]


@pytest.mark.parametrize('bad', [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize(('kind', 'index'), FLOAT_FIELDS)
def test_nonfinite_float_is_rejected_per_field(kind, index, bad):
    fields = list(EXAMPLES[kind])
    fields[index] = bad
    with pytest.raises(ProtocolError) as info:
        p.encode(kind, 0, 0, *fields)
    assert info.value.reason == 'nonfinite'
    with pytest.raises(ProtocolError) as info:
        p.decode(_raw(kind, *fields))
    assert info.value.reason == 'nonfinite'
    assert PAYLOAD_TYPES[kind]._fields[index] in str(info.value)


def test_float_fields_cover_every_float_in_the_layouts():
    assert len(FLOAT_FIELDS) == 2 + 9 + 2 + 10 + 1 + 6 + 2 + 3 + 8 + 23


@pytest.mark.parametrize(('kind', 'index', 'value'), [
    (Kind.WHEEL_CMD, 0, 1024), (Kind.WHEEL_CMD, 1, 5000), (Kind.WHEEL_CMD, 2, 2),
    (Kind.ENCODERS, 0, 4096), (Kind.ENCODERS, 1, 0xFFFF),
    (Kind.SONAR, 0, -0.5), (Kind.SONAR, 1, 4),
    (Kind.LASER_SCAN, 6, 0x1000000),
    (Kind.LED, 4, 2),
    (Kind.TASK_STATS, 3, -2),
    (Kind.RT_STATUS, 0, 2), (Kind.RT_STATUS, 1, 2), (Kind.RT_STATUS, 2, 3),
    (Kind.RT_STATUS, 3, 255),
    (Kind.DEVICE_STATUS, 2, 4),
    (Kind.PORT_STATS, 2, 2),
])
def test_value_outside_layout_range_is_rejected(kind, index, value):
    fields = list(EXAMPLES[kind])
    fields[index] = value
    with pytest.raises(ProtocolError) as info:
        p.decode(_raw(kind, *fields))
    assert info.value.reason == 'range'
    assert repr(value) in str(info.value)
    with pytest.raises(ProtocolError):
        p.encode(kind, 0, 0, *fields)


@pytest.mark.parametrize('raw_name', [b'caf\xe9', b'ab\x00cd', b'\xff' * 16])
def test_names_must_be_nul_padded_ascii(raw_name):
    good = p.encode(Kind.DEVICE_STATUS, 0, 0, *EXAMPLES[Kind.DEVICE_STATUS])
    bad = good[:16] + raw_name.ljust(16, b'\x00') + good[32:]
    assert _reason(bad) == 'range'


def test_port_stats_label_must_be_nul_padded_ascii():
    good = p.encode(Kind.PORT_STATS, 0, 0, *EXAMPLES[Kind.PORT_STATS])
    assert _reason(good[:16] + b'c\xffd'.ljust(32, b'\x00') + good[48:]) == 'range'


def test_full_length_name_round_trips():
    name = 'sixteen_chars_ok'
    data = p.encode(Kind.DEVICE_STATUS, 0, 0, name, 1, 0, 0, 0)
    assert p.decode(data)[1].device == name


# ---- encode errors ----

@pytest.mark.parametrize('name', ['seventeen_chars_x', 'caf\xe9', 'a\x00b', 42])
def test_encoding_a_bad_name_fails_instead_of_truncating(name):
    with pytest.raises(ProtocolError) as info:
        p.encode(Kind.DEVICE_STATUS, 0, 0, name, 1, 0, 0, 0)
    assert info.value.reason in ('encode', 'range')


def test_encode_errors_are_protocol_errors():
    with pytest.raises(ProtocolError, match='takes 2 fields'):
        p.encode(Kind.VELOCITY_CMD, 0, 0, 1.0)
    with pytest.raises(ProtocolError) as info:
        p.encode(99, 0, 0)
    assert info.value.reason == 'kind'
    with pytest.raises(ProtocolError, match='cannot encode'):
        p.encode_into(bytearray(10), 0, Kind.VELOCITY_CMD, 0, 0, 1.0, 2.0)
    with pytest.raises(ProtocolError, match='cannot encode'):
        p.encode_into(bytearray(64), 0, Kind.REQUEST, 0, 0, -1, 0)
    with pytest.raises(ProtocolError, match='at most'):
        p.encode_scan_into(bytearray(8192), 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
                           [0] * (p.MAX_SCAN_RANGES + 1))
    with pytest.raises(ProtocolError, match='count'):
        p.encode_task_stats_into(bytearray(8192), 0, 0, 0, 'x', 0, 0, 0, 0, 0, 0, 0, 0, 0,
                                 [(0, 0, 0, 0)] * (p.MAX_STATS_SAMPLES + 1))
    with pytest.raises(ProtocolError, match='sample'):
        p.encode_task_stats_into(bytearray(4096), 0, 0, 0, 'x', 0, 0, 0, 0, 0, 0, 0, 0, 0,
                                 [(0, 0, 0, -1)])
    with pytest.raises(ProtocolError, match='sequence'):
        p.encode(Kind.LASER_SCAN, 0, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0, 5)
    with pytest.raises(ProtocolError):
        p.encode(Kind.SONAR, 0, 0, 1e39, 0)  # finite double, too large for f32


def test_protocol_error_is_a_value_error():
    assert issubclass(ProtocolError, ValueError)


# ---- fuzzing: nothing but ProtocolError escapes decode ----

def _decode_or_protocol_error(data):
    try:
        header, payload = p.decode(data)
    except ProtocolError as exc:
        assert exc.reason in ('short', 'magic', 'version', 'kind', 'length', 'nonfinite',
                              'range')
        return None
    assert isinstance(header.kind, Kind)
    return payload


@settings(max_examples=examples(400))
@given(st.binary(max_size=300))
def test_arbitrary_bytes_raise_only_protocol_error(data):
    _decode_or_protocol_error(data)


@settings(max_examples=examples(400))
@given(st.sampled_from(list(Kind) + [0, 14, 255]), st.binary(max_size=600))
def test_arbitrary_payload_after_valid_header_raises_only_protocol_error(kind, body):
    _decode_or_protocol_error(struct.pack('<HBBIq', p.MAGIC, p.VERSION, kind, 0, 0) + body)


@settings(max_examples=examples(500))
@given(kind=st.sampled_from(list(Kind)), data=st.data())
def test_mutated_valid_datagrams_raise_only_protocol_error(kind, data):
    good = bytearray(p.encode(kind, 1, 2, *EXAMPLES[kind]))
    op = data.draw(st.sampled_from(['flip', 'truncate', 'extend', 'overwrite']))
    if op == 'flip':
        for _ in range(data.draw(st.integers(1, 4))):
            bit = data.draw(st.integers(0, len(good) * 8 - 1))
            good[bit // 8] ^= 1 << (bit % 8)
    elif op == 'truncate':
        good = good[:data.draw(st.integers(0, len(good) - 1))]
    elif op == 'extend':
        good += data.draw(st.binary(min_size=1, max_size=64))
    else:
        at = data.draw(st.integers(0, len(good) - 1))
        patch = data.draw(st.binary(min_size=1, max_size=8))
        good[at:at + len(patch)] = patch
    _decode_or_protocol_error(bytes(good))


def _outcome(fn, *args):
    try:
        header, payload = fn(*args)
    except ProtocolError as exc:
        return 'error', exc.reason, str(exc)
    return 'ok', header, type(header.kind), payload, type(payload)


@settings(max_examples=examples(500))
@given(kind=st.sampled_from(list(Kind)), data=st.data())
def test_decode_from_a_receive_buffer_agrees_with_the_full_validation(kind, data):
    # decode_from's short path must accept exactly what the full validation accepts and build
    # equal tuples of the same types; the datagram sits in a larger buffer with stale bytes
    # after it, as in a task's receive buffer.
    good = bytearray(p.encode(kind, 7, -3, *EXAMPLES[kind]))
    op = data.draw(st.sampled_from(['keep', 'flip', 'truncate', 'extend', 'nonfinite']))
    if op == 'flip':
        bit = data.draw(st.integers(0, len(good) * 8 - 1))
        good[bit // 8] ^= 1 << (bit % 8)
    elif op == 'truncate':
        good = good[:data.draw(st.integers(0, len(good) - 1))]
    elif op == 'extend':
        good += data.draw(st.binary(min_size=1, max_size=16))
    elif op == 'nonfinite' and len(good) >= p.HEADER_SIZE + 8:
        at = data.draw(st.integers(p.HEADER_SIZE, len(good) - 8))
        struct.pack_into('<d', good, at, data.draw(st.sampled_from([math.nan, math.inf])))
    buf = bytearray(data.draw(st.binary(min_size=len(good) + 1, max_size=len(good) + 40)))
    buf[:len(good)] = good
    expected = _outcome(p._decode_checked, bytes(good), len(good))
    assert _outcome(p.decode_from, buf, len(good)) == expected
    assert _outcome(p.decode, bytes(good)) == expected


def test_decode_from_refuses_a_length_beyond_the_buffer():
    with pytest.raises(ProtocolError) as exc:
        p.decode_from(bytearray(8), 9)
    assert exc.value.reason == 'length'


# ---- sequence numbers ----

@pytest.mark.parametrize(('prev', 'cur', 'gap'), [
    (1, 2, 0), (1, 5, 3), (0xFFFFFFFF, 0, 0), (0xFFFFFFFE, 1, 2), (5, 5, 0), (5, 3, 0),
    (100, 0, 0),
])
def test_seq_gap_counts_lost_datagrams_across_wrap(prev, cur, gap):
    assert p.seq_gap(prev, cur) == gap


def test_seq_helpers_wrap():
    assert p.next_seq(0xFFFFFFFF) == 0
    assert p.seq_newer(0xFFFFFFFF, 0)
    assert not p.seq_newer(0, 0xFFFFFFFF)
    assert not p.seq_newer(7, 7)


@settings(max_examples=examples(200))
@given(U32, st.integers(0, 1000))
def test_seq_gap_after_losing_k_datagrams_is_k(start, lost):
    cur = start
    for _ in range(lost + 1):
        cur = p.next_seq(cur)
    assert p.seq_gap(start, cur) == lost


def test_flag_and_status_enums_own_the_wire_values():
    # The plain-int names the RT loops use are views of the one IntFlag/IntEnum definition.
    assert p.ODOM_BRAKING == p.OdomFlag.BRAKING and p.ODOM_HOLD == p.OdomFlag.HOLD
    assert p.ENC_INVALID_MASK == 0x0F and not p.ENC_INVALID_MASK & (
        p.EncoderStatus.SAFE | p.EncoderStatus.WRITE_ERROR)
    assert p.SONAR_FAULT == max(p.SonarStatus) and p.LEVEL_STALE == max(p.Level)
    for flags in (p.OdomFlag, p.RtFlag):
        bits = [int(f) for f in flags]
        assert all(b & (b - 1) == 0 for b in bits) and len(set(bits)) == len(bits)
    # Layout ranges follow the enums: one more than the largest value is rejected.
    good = EXAMPLES[Kind.SONAR]
    with pytest.raises(ProtocolError):
        p.encode(Kind.SONAR, 0, 0, good[0], max(p.SonarStatus) + 1)
    status = EXAMPLES[Kind.DEVICE_STATUS]
    with pytest.raises(ProtocolError):
        p.encode(Kind.DEVICE_STATUS, 0, 0, status[0], status[1], max(p.Level) + 1, *status[3:])
