"""Tests of the mode-switch analogue: forbidden calls caught with their call site."""

import os
import sys
import threading

import pytest

from m4k_rt import modeswitch, task

MS = 1_000_000


@pytest.fixture(autouse=True)
def _hook():
    modeswitch.install()
    yield
    modeswitch.uninstall_console_guard()


def _run(body, seconds=0.1):
    t = task.RtTask('ms', 20, 5 * MS, body)
    t.start()
    threading.Event().wait(seconds)
    t.stop()
    assert t.join(2.0)
    return t


def test_open_inside_body_is_reported_with_this_file_and_line():
    def body(ctx):
        with open(os.devnull, 'rb'):  # deliberate forbidden call
            pass
    line = body.__code__.co_firstlineno + 1
    t = _run(body)
    sites = t.sites.sites()
    assert t.sites.total >= t.cycles >= 1
    assert t.sites.by_event[modeswitch.EVENT_CODES['open']] == t.sites.total
    assert [(s.event, s.file, s.line, s.func) for s in sites] == [
        ('open', __file__, line, 'body')]
    assert sites[0].calls == t.sites.total


def test_sleep_subprocess_socket_and_console_are_distinct_sites():
    import socket
    import time

    def body(ctx):
        if ctx.cycles == 0:
            time.sleep(0)
            socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM).close()
            print('from the loop')

    modeswitch.install_console_guard()
    t = _run(body)
    modeswitch.uninstall_console_guard()
    events = [s.event for s in t.sites.sites()]
    assert events == ['time.sleep', 'socket.__new__', 'console']
    assert all(s.file == __file__ for s in t.sites.sites())


def test_calls_outside_rt_loop_are_not_counted():
    table = modeswitch.SiteTable()
    with open(os.devnull, 'rb'):
        pass
    modeswitch.enter_rt(table)
    modeswitch.leave_rt()
    with open(os.devnull, 'rb'):
        pass
    assert table.total == 0


def test_import_inside_loop_is_caught():
    table = modeswitch.SiteTable()
    sys.modules.pop('colorsys', None)
    modeswitch.enter_rt(table)
    try:
        import colorsys  # noqa: F401 -- deliberate import in an "RT loop"
    finally:
        modeswitch.leave_rt()
    assert table.by_event[modeswitch.EVENT_CODES['import']] >= 1
    assert table.sites()[0].file == __file__


def test_site_table_keeps_last_n_distinct_sites():
    table = modeswitch.SiteTable(capacity=2)
    for line in (1, 2, 2, 3):
        table.record(1, 'f.py', line, 'fn')
    assert table.total == 4
    assert [(s.line, s.calls) for s in table.sites()] == [(2, 2), (3, 1)]
