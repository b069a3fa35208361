import math
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from m4k_drivers.lrf import scip
from m4k_testing import examples

DATA = Path(__file__).parent / 'data'

# The PP example of the SCIP 2.0 specification (C-42-03320B p.21), with its AFRT line's ':' typo
# written as the ';' every other line uses, and ARES's sum '\\' (0x5C, which the text copy of the
# PDF shows as '/'). Every other sum is the spec's, which proves the rule: sum of KEY:value.
SPEC_PP = (b'PP\n00P\n'
           b'MODL:URG-04LX(Hokuyo Automatic Co.,Ltd.);x\n'
           b'DMIN:20;4\nDMAX:5600;_\nARES:1024;\\\nAMIN:44;7\nAMAX:725;o\nAFRT:384;6\n'
           b'SCAN:600;e\n\n')


def _fix_modl_sum(raw: bytes) -> bytes:
    body = b'MODL:URG-04LX(Hokuyo Automatic Co.,Ltd.)'
    return raw.replace(body + b';x', body + b';' + bytes((scip.checksum(body),)))


# --- encoding -------------------------------------------------------------------------------

@pytest.mark.parametrize(('value', 'nchars', 'text'), [
    (1234, 2, b'CB'), (5432, 3, b'1Dh'), (16_000_000, 4, b'm2@0')])
def test_spec_encoding_examples_round_trip(value, nchars, text):
    assert scip.encode(value, nchars) == text
    assert scip.decode(text) == value


@given(st.integers(0, (1 << 18) - 1))
def test_three_char_round_trip(value):
    assert scip.decode(scip.encode(value, 3)) == value


def test_encode_rejects_values_too_big_for_width():
    with pytest.raises(ValueError, match='4096'):
        scip.encode(4096, 2)


def test_decode_rejects_non_scip_bytes():
    with pytest.raises(scip.ScipFormatError, match='0x20'):
        scip.decode(b'A ')


def test_decode_array_matches_scalar_decode():
    values = [0, 19, 20, 5432, 262143]
    assert scip.decode_array(scip.encode_array(values, 3), 3).tolist() == values


# --- sums -------------------------------------------------------------------------------------

def test_status_sums_from_the_spec():
    assert scip.with_sum(b'00') == b'00P'
    assert scip.with_sum(b'99') == b'99b'
    assert scip.verify_line(b'00P') == b'00'


def test_bad_sum_raises_checksum_error_with_the_line():
    with pytest.raises(scip.ScipChecksumError) as info:
        scip.verify_line(b'00Q')
    assert info.value.line == b'00Q'
    assert info.value.expected == ord('P')


def test_param_line_sum_excludes_separator_as_in_spec():
    assert scip.verify_param_line(b'DMIN:20;4') == b'DMIN:20'
    with pytest.raises(scip.ScipChecksumError):
        scip.verify_param_line(b'DMIN:21;4')


# --- PP and geometry ---------------------------------------------------------------------------

def _spec_pp_response():
    out = scip.ScipParser().feed(_fix_modl_sum(SPEC_PP))
    assert len(out) == 1 and isinstance(out[0], scip.Response)
    return out[0]


def test_spec_pp_parses_to_urg04lx_spec():
    params = scip.parse_params(_spec_pp_response())
    spec = scip.SensorSpec.from_params(params)
    assert (spec.dmin, spec.dmax, spec.ares, spec.amin, spec.amax, spec.afrt, spec.scan_rpm) == (
        20, 5600, 1024, 44, 725, 384, 600)
    assert spec.model.startswith('URG-04LX')


def test_full_range_geometry_is_682_values_covering_240_degrees():
    # Steps 44..725 inclusive are 682 values (the datasheet's "683 steps" is 240 deg / 0.3516 deg
    # rounded); they cover 682 * 360/1024 = 239.77 deg, the spec's figure for the URG-04LX.
    spec = scip.SensorSpec.from_params(scip.parse_params(_spec_pp_response()))
    geo = spec.geometry()
    assert geo.count == 682
    assert math.degrees(geo.count * geo.angle_increment) == pytest.approx(239.77, abs=0.01)
    assert math.degrees(geo.count * geo.angle_increment) == pytest.approx(240.0, abs=0.5)
    assert geo.angle_max - geo.angle_min == pytest.approx(681 * geo.angle_increment)
    assert geo.angle_min == pytest.approx((44 - 384) * 2 * math.pi / 1024)
    assert geo.angle_increment == pytest.approx(2 * math.pi / 1024)
    assert (geo.range_min, geo.range_max, geo.scan_time) == (0.02, 5.6, 0.1)


def test_geometry_follows_requested_steps_and_cluster():
    spec = scip.SensorSpec.from_params(scip.parse_params(_spec_pp_response()))
    geo = spec.geometry(384, 394, 3)
    assert geo.count == 4
    assert geo.angle_min == 0.0
    assert geo.angle_increment == pytest.approx(3 * 2 * math.pi / 1024)
    assert geo.angle_max == pytest.approx(9 * 2 * math.pi / 1024)
    # SCIP geometry: 1024 steps per 100 ms revolution; one value every 3 steps.
    assert geo.time_increment == pytest.approx(0.1 / 1024 * 3)
    assert spec.geometry().time_increment == pytest.approx(0.1 / 1024)


def test_geometry_outside_measurable_steps_is_rejected():
    spec = scip.SensorSpec.from_params(scip.parse_params(_spec_pp_response()))
    with pytest.raises(ValueError, match='10..725'):
        spec.geometry(10, 725)


def test_pp_missing_key_names_it():
    params = dict(scip.parse_params(_spec_pp_response()))
    del params['ARES']
    with pytest.raises(scip.ScipFormatError, match='ARES'):
        scip.SensorSpec.from_params(params)


# --- commands and scans ------------------------------------------------------------------------

def test_command_building():
    assert scip.gd_command(44, 725, 1) == b'GD0044072501\n'
    assert scip.md_command(44, 725, 1, 0, 0, tag='ab') == b'MD0044072501000;ab\n'
    with pytest.raises(ValueError, match='start=9 end=8'):
        scip.gd_command(9, 8)


def _hand_built_gd() -> bytes:
    # Built by hand from the spec's layout: echo, 00P, timestamp 16,000,000 ms ('m2@0' + sum),
    # 25 ranges (75 chars -> one 64-char block + one 11-char block), LF LF.
    ranges = [5432] * 10 + [1234, 0, 19, 20] + [5600] * 11
    payload = b''.join(scip.encode(v, 3) for v in ranges)
    return (b'GD0384040801\n00P\n' + b'm2@0' + bytes((scip.checksum(b'm2@0'),)) + b'\n'
            + payload[:64] + bytes((scip.checksum(payload[:64]),)) + b'\n'
            + payload[64:] + bytes((scip.checksum(payload[64:]),)) + b'\n\n')


def test_hand_built_gd_response_decodes_to_known_values():
    (resp,) = scip.ScipParser().feed(_hand_built_gd())
    scan = scip.parse_scan(resp)
    assert (scan.command, scan.start, scan.end, scan.cluster) == ('GD', 384, 408, 1)
    assert scan.timestamp == 16_000_000
    assert scan.ranges.tolist() == [5432] * 10 + [1234, 0, 19, 20] + [5600] * 11
    assert scan.count == 25


def test_recorded_sim_gd_response_decodes_to_the_room_geometry():
    # Recorded from lrf.sim in a 4 m x 3 m room, sensor at the centre facing +x (no noise):
    # straight ahead the wall is 2.0 m away, to the left (+90 deg) 1.5 m.
    raw = (DATA / 'urg_gd_room_4x3.bin').read_bytes()
    (resp,) = scip.ScipParser().feed(raw)
    scan = scip.parse_scan(resp)
    assert scan.count == 682
    assert scan.ranges[384 - 44] == 2000
    assert scan.ranges[384 + 256 - 44] == 1500
    assert scan.ranges[384 - 256 - 44] == 1500


def test_format_scan_round_trips_through_parser():
    values = list(range(20, 20 + 100 * 7, 7))
    raw = scip.format_scan('MD', 100, 199, 1, 123, values, interval=2, remaining=5, tag=b'x1')
    (resp,) = scip.ScipParser().feed(raw)
    scan = scip.parse_scan(resp)
    assert scan.ranges.tolist() == values
    assert (scan.interval, scan.remaining, scan.tag, scan.timestamp) == (2, 5, b'x1', 123)


def test_scan_with_wrong_value_count_is_a_format_error():
    raw = scip.format_scan('GD', 100, 199, 1, 0, [100] * 99)
    (resp,) = scip.ScipParser().feed(raw)
    with pytest.raises(scip.ScipFormatError, match='99 ranges, expected 100'):
        scip.parse_scan(resp)


def test_laser_off_status_raises_status_error_with_meaning():
    (resp,) = scip.ScipParser().feed(b'GD0044072501\n10Q\n\n')
    with pytest.raises(scip.ScipStatusError, match='laser is off') as info:
        scip.parse_scan(resp)
    assert info.value.status == '10'


def test_range_error_codes_are_documented():
    from m4k_rt import protocol
    assert set(protocol.SCAN_ERROR_CODES) == set(range(20))
    assert protocol.SCAN_ERROR_CODES[6] == 'others'                    # spec Table 3, not "far"
    assert 'non-measurable' in scip.range_error_meaning(19)
    with pytest.raises(ValueError, match='20'):
        scip.range_error_meaning(20)


# --- incremental parser ------------------------------------------------------------------------

def test_parser_handles_byte_by_byte_feed():
    parser = scip.ScipParser()
    raw = _hand_built_gd()
    out = []
    for b in raw:
        out += parser.feed(bytes((b,)))
    assert len(out) == 1 and scip.parse_scan(out[0]).timestamp == 16_000_000


def test_parser_skips_and_counts_stray_bytes_before_echo():
    parser = scip.ScipParser()
    out = parser.feed(b'\x00\xffjunk\nmore' + b'QT\n00P\n\n')
    assert len(out) == 1 and out[0].command == 'QT'
    assert parser.stray_bytes == len(b'\x00\xffjunk\nmore')


def test_bad_checksum_returns_error_and_next_response_survives():
    bad = bytearray(_hand_built_gd())
    i = bad.index(b'\n', bad.index(b'm2@0') + 6) - 1       # sum char of the first data line
    bad[i] = ord('0') if bad[i] != ord('0') else ord('1')
    out = scip.ScipParser().feed(bytes(bad) + _hand_built_gd())
    assert isinstance(out[0], scip.ScipChecksumError)
    assert out[0].line.startswith(scip.encode(5432, 3))
    assert isinstance(out[1], scip.Response)


def test_parser_resynchronises_on_lf_lf_after_garbage_inside_response():
    parser = scip.ScipParser()
    out = parser.feed(b'GD0044072501\n00P\n' + b'x' * 1000 + b'\n\n' + b'BM\n00P\n\n')
    assert isinstance(out[0], scip.ScipFormatError)
    assert out[-1].command == 'BM'
    assert parser.format_errors == 1


def test_switch_reply_without_sum_and_already_scip2_reply():
    out = scip.ScipParser().feed(b'SCIP2.0\n0\n\nSCIP2.0\n0Ee\n\n')
    assert [r.status for r in out] == ['0', '0E']
    assert 'undefined' in scip.status_meaning('SCIP2.0', '0E')


@settings(max_examples=examples(300))
@given(st.lists(st.one_of(
    st.binary(max_size=80),
    st.sampled_from([b'\n', b'\n\n', b'GD0044072501\n', b'00P\n', b'99b\n', b'MD0044072501000\n',
                     b'PP\n', b'DMIN:20;4\n', b'SCIP2.0\n0\n']),
), max_size=40))
def test_fuzz_parser_only_raises_documented_errors(chunks):
    parser = scip.ScipParser()
    for chunk in chunks:
        for item in parser.feed(chunk):
            assert isinstance(item, (scip.Response, scip.ScipError))
            if isinstance(item, scip.Response) and item.command in scip.SCAN_COMMANDS:
                try:
                    scip.parse_scan(item)
                except scip.ScipError:
                    pass
            if isinstance(item, scip.Response) and item.command in scip.PARAM_COMMANDS:
                try:
                    scip.SensorSpec.from_params(scip.parse_params(item))
                except scip.ScipError:
                    pass


# --- timestamps --------------------------------------------------------------------------------

def test_timestamp_unwrap_across_24_bit_wrap():
    unwrap = scip.TimestampUnwrapper()
    assert unwrap.update(scip.TIMESTAMP_MODULO - 150) == 0
    assert unwrap.update(scip.TIMESTAMP_MODULO - 50) == 100
    assert unwrap.update(50) == 200
    assert unwrap.update(150) == 300
    assert unwrap.wraps == 1


def test_timestamp_rejects_out_of_range():
    with pytest.raises(ValueError, match='24-bit'):
        scip.TimestampUnwrapper().update(1 << 24)


def test_decode_array_is_numpy_uint32():
    assert scip.decode_array(b'1Dh', 3).dtype == np.uint32
