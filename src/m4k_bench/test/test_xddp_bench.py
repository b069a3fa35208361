"""xddp_bench runs both transports (counts only: timing is reported, never asserted)."""

import os
import shutil
import tempfile

import pytest

from m4k_bench import xddp_bench


@pytest.fixture
def rundir(monkeypatch):
    # A short path: AF_UNIX socket paths are limited to 107 bytes.
    base = tempfile.mkdtemp(prefix='m4kb', dir='/tmp')
    path = os.path.join(base, 'rt')
    monkeypatch.setenv('M4K_RUNTIME_DIR', path)
    yield path
    shutil.rmtree(base, ignore_errors=True)


@pytest.mark.parametrize('transport', ['socket', 'shm'])
def test_rtt_benchmark_runs_both_transports(rundir, transport):
    result = xddp_bench.run_rtt(20, rundir, transport=transport)
    assert result['transport'] == transport
    for name in ('xddp', 'raw'):
        r = result[name]
        assert r['n'] == 20
        assert 0 < r['min_us'] <= r['p50_us'] <= r['p99_us'] <= r['max_us']
    assert isinstance(result['sched_fifo'], bool)
    assert sorted(os.listdir(rundir)) == []  # both transports cleaned up their sockets


def test_loop_parts_times_every_part_on_real_objects():
    from m4k_bench.benchlib import loopparts
    parts = loopparts.measure_parts(50)
    assert set(parts) == {'clock', 'drain_decode', 'drain_empty', 'encode_send',
                          'timing_record', 'rusage'}
    assert all(v > 0 for v in parts.values()), parts   # measured, never judged here
