"""The bridge's side of a latched fault's supervision trace (m4k_bridge.faulttrace; no ROS)."""

from m4k_bridge.faulttrace import TraceCollector, TraceWriter, write_csv
from m4k_rt import protocol


def _row(fault, i, rows, cause=int(protocol.FaultCause.RIGHT_STILL)):
    values = [0.0] * len(protocol.TRACE_FLOAT_FIELDS)
    values[3] = 0.1 * i                                  # meas_right
    return protocol.FaultTrace(fault, cause, i, rows, 10_000_000 * i, *values,
                               int(protocol.TraceFlag.HELD_RIGHT | protocol.TraceFlag.LEVEL))


def test_the_collector_gives_a_trace_once_all_its_rows_are_in():
    c = TraceCollector()
    assert all(c.feed(_row(1, i, 4)) is None for i in (0, 2, 1))
    rows = c.feed(_row(1, 3, 4))
    assert [r.row for r in rows] == [0, 1, 2, 3] and c.incomplete == 0


def test_a_lost_row_gives_no_trace_and_the_next_fault_starts_over():
    c = TraceCollector()
    for i in (0, 1, 3):                                  # row 2 lost on the wire
        assert c.feed(_row(1, i, 4)) is None
    assert all(c.feed(_row(2, i, 2)) is None for i in (0,))
    assert c.incomplete == 1                             # fault 1's partial trace given up
    assert [r.fault for r in c.feed(_row(2, 1, 2))] == [2, 2]
    assert c.feed(_row(3, 5, 4)) is None and c.incomplete == 2     # a row beyond its count


def test_the_csv_has_one_line_per_cycle_and_keeps_the_newest_files(tmp_path):
    rows = [_row(7, i, 3) for i in range(3)]
    paths = [write_csv(rows, str(tmp_path), wall_ns=(1_800_000_000 + k) * 10 ** 9, keep=2)
             for k in range(3)]
    assert sorted(tmp_path.iterdir()) == [tmp_path / p.rsplit('/', 1)[1] for p in paths[1:]]
    lines = (tmp_path / paths[-1].rsplit('/', 1)[1]).read_text().splitlines()
    assert lines[0] == ','.join(['t_ms', *protocol.TRACE_FLOAT_FIELDS, 'flags'])
    assert [ln.split(',')[0] for ln in lines[1:]] == ['-20.0', '-10.0', '0.0']
    assert lines[-1].split(',')[4] == '0.2' and lines[-1].endswith(',held_right|level')


def test_a_trace_that_cannot_be_written_is_said_not_raised(tmp_path):
    blocker = tmp_path / 'file'
    blocker.write_text('')
    said = []
    w = TraceWriter(str(blocker / 'dir'), said.append)
    for i in range(2):
        assert w.on_row(_row(4, i, 2))
    w.join()
    assert w.written == [] and len(said) == 1
    assert said[0].startswith('motor fault 4 (right wheel turns while commanded still): its '
                              'supervision trace not written:')
    w = TraceWriter(str(tmp_path / 'ok'), said.append)
    for i in range(2):
        w.on_row(_row(5, i, 2))
    w.join()
    assert len(w.written) == 1 and w.written[0] in said[-1]
    assert "motor fault 5 (right wheel turns while commanded still): the wheel supervision's " \
           'last 2 cycles (10 ms) are in ' in said[-1]


def test_a_second_trace_of_the_same_second_and_number_does_not_overwrite_the_first(tmp_path):
    rows = [_row(1, i, 2) for i in range(2)]
    first = write_csv(rows, str(tmp_path), wall_ns=1_800_000_000 * 10 ** 9)
    second = write_csv(rows, str(tmp_path), wall_ns=1_800_000_000 * 10 ** 9)
    assert first != second and second.endswith('_1-2.csv')
    assert len(list(tmp_path.iterdir())) == 2
