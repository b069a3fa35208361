"""The persisted e-stop request: where it lives, how it is written, what a bad file means.

The last test runs the shipped systemd unit's own paths: it parses config/systemd/m4k.service
for its directories and environment, performs a restart as systemd does (the runtime
directory deleted, the state directory kept) and builds rt_core's actuator on the far side.
"""

import os
from types import SimpleNamespace

from fake_peers import Ports
import pytest

from m4k_rt import estop_request as er

ROOT = os.path.normpath(os.path.join(os.path.dirname(__file__), '..', '..', '..'))
UNIT = os.path.join(ROOT, 'config', 'systemd', 'm4k.service')


def test_round_trip_and_no_file_is_no_request(tmp_path):
    d = str(tmp_path / 'state')
    assert er.read_request(d) == er.Persisted(None)        # first start: nothing known
    er.write_request(d, True)                              # creates the directory, 0700
    assert oct(os.stat(d).st_mode & 0o777) == '0o700'
    assert er.read_request(d) == er.Persisted(True)
    er.write_request(d, False)
    assert er.read_request(d) == er.Persisted(False)
    assert os.listdir(d) == ['e_stop.request']             # no temporary file left


@pytest.mark.parametrize('content', [b'', b'engag', b'garbage\n', b'\xff\xfe', b'engaged' * 20,
                                     b'released extra'])
def test_a_corrupt_file_reads_as_engaged_with_a_diagnostic(tmp_path, content):
    (tmp_path / er.FILE_NAME).write_bytes(content)
    got = er.read_request(str(tmp_path))
    assert got.engaged is True
    assert 'corrupt' in got.problem and er.request_path(str(tmp_path)) in got.problem


def test_an_unreadable_file_reads_as_engaged_with_a_diagnostic(tmp_path):
    # a directory where the file should be: EISDIR (root reads through a chmod 000 file)
    (tmp_path / er.FILE_NAME).mkdir()
    got = er.read_request(str(tmp_path))
    assert got.engaged is True
    assert got.problem.startswith('cannot read ') and 'EISDIR' in got.problem


def test_the_write_is_atomic_and_durable(tmp_path, monkeypatch):
    """tmp + fsync + rename + fsync of the directory, in that order."""
    calls = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        calls.append(('fsync', os.path.isdir(f'/proc/self/fd/{fd}')))
        real_fsync(fd)

    def replace(a, b):
        calls.append(('rename', os.path.basename(a).endswith('.tmp')))
        real_replace(a, b)
    monkeypatch.setattr(er.os, 'fsync', fsync)
    monkeypatch.setattr(er.os, 'replace', replace)
    er.write_request(str(tmp_path), True)
    assert calls == [('fsync', False), ('rename', True), ('fsync', True)]


def test_a_failed_write_leaves_the_old_request_and_no_temporary(tmp_path, monkeypatch):
    d = str(tmp_path)
    er.write_request(d, True)

    def broken(fd):
        raise OSError(5, 'Input/output error')
    monkeypatch.setattr(er.os, 'fsync', broken)
    with pytest.raises(OSError):
        er.write_request(d, False)
    assert er.read_request(d) == er.Persisted(True)
    assert os.listdir(d) == ['e_stop.request']


def test_where_the_request_lives(monkeypatch):
    assert er.state_dir({'M4K_STATE_DIR': '/s', 'STATE_DIRECTORY': '/sd',
                         'M4K_RUNTIME_DIR': '/r'}) == '/s'
    assert er.state_dir({'STATE_DIRECTORY': '/var/lib/m4k:/var/lib/other',
                         'M4K_RUNTIME_DIR': '/run/m4k'}) == '/var/lib/m4k'
    # a private runtime directory (tests, benches, scenarios): its own e-stop
    assert er.state_dir({'M4K_RUNTIME_DIR': '/tmp/x'}, runtime_dir='/tmp/y') == '/tmp/x'
    assert er.state_dir({}, runtime_dir='/tmp/y') == '/tmp/y'
    # none of those: the persistent per-user state (root: /var/lib/m4k)
    monkeypatch.setattr(er.os, 'geteuid', lambda: 1000)
    assert er.state_dir({'XDG_STATE_HOME': '/h/.st'}) == '/h/.st/m4k'
    assert er.state_dir({'HOME': '/home/u'}) == '/home/u/.local/state/m4k'
    monkeypatch.setattr(er.os, 'geteuid', lambda: 0)
    assert er.state_dir({'HOME': '/root'}) == '/var/lib/m4k'


def _unit_service_section(path):
    """Return the unit's [Service] settings: repeated keys (Environment=) as lists."""
    out, section = {}, None
    with open(path, encoding='utf-8') as f:
        for line in f:
            line = line.strip()
            if not line or line.startswith(('#', ';')):
                continue
            if line.startswith('['):
                section = line.strip('[]')
                continue
            if section == 'Service':
                key, _, value = line.partition('=')
                out.setdefault(key, []).append(value)
    return out


def test_a_service_restart_keeps_the_e_stop_through_the_shipped_units_paths(
        tmp_path, monkeypatch, capsys):
    """Parse config/systemd/m4k.service, restart as systemd does, and build rt_core's actuator.

    systemd creates ``/run/<RuntimeDirectory>`` and ``/var/lib/<StateDirectory>`` at start
    and deletes the runtime directory at stop (no RuntimeDirectoryPreserve=); both roots are
    moved under tmp_path. The unit's environment is what bringup and its children see.
    """
    svc = _unit_service_section(UNIT)
    env = dict(e.split('=', 1) for e in svc['Environment'])
    (runtime_name,), (state_name,) = svc['RuntimeDirectory'], svc['StateDirectory']
    assert 'RuntimeDirectoryPreserve' not in svc       # systemd deletes it on every stop
    run_root, lib_root = tmp_path / 'run', tmp_path / 'var' / 'lib'

    def host(path):
        """Map an absolute path of the unit into the test's roots."""
        for real, here in (('/run/', run_root), ('/var/lib/', lib_root)):
            if path.startswith(real):
                return str(here / path[len(real):])
        raise AssertionError(f'the unit names {path!r} outside /run and /var/lib')
    runtime = host(env['M4K_RUNTIME_DIR'])
    assert runtime == host(f'/run/{runtime_name}')
    state_env = dict(env, STATE_DIRECTORY=f'/var/lib/{state_name}')
    for k in ('M4K_RUNTIME_DIR', 'M4K_STATE_DIR', 'STATE_DIRECTORY'):
        if k in state_env:
            state_env[k] = host(state_env[k])
    state = er.state_dir(state_env)          # as bringup resolves it for its children
    assert state == host(f'/var/lib/{state_name}')
    assert not state.startswith(runtime + os.sep) and state != runtime

    def start():                             # systemd: both directories exist, 0700
        os.makedirs(runtime, mode=0o700, exist_ok=True)
        os.makedirs(state, mode=0o700, exist_ok=True)
        for k, v in state_env.items():
            monkeypatch.setenv(k, v)

    def stop():                              # systemd: the runtime directory goes
        import shutil
        shutil.rmtree(runtime)

    from m4k_rt import config
    from m4k_rt.tasks.actuator import make_actuator

    def actuator():
        shared = SimpleNamespace(config=config.load(None, None), runtime_dir=runtime,
                                 robot=None)
        task = shared.config.task('actuator')
        ports = Ports(runtime, 'cmd', 'motor')
        try:
            return make_actuator(task, ports.rt, shared)
        finally:
            ports.close()

    start()
    er.write_request(er.state_dir(), True)   # the bridge persists the operator's e-stop
    stop()
    start()                                  # systemctl restart m4k (or a reboot)
    assert actuator().ctl.estop.engaged
    assert 'e-stop latch ENGAGED at start-up' in capsys.readouterr().err
    # a corrupt state after a crash: still engaged, and said so
    with open(er.request_path(state), 'wb') as f:
        f.write(b'\x00\x00')
    stop()
    start()
    assert actuator().ctl.estop.engaged
    assert 'corrupt' in capsys.readouterr().err
    er.write_request(state, False)
    stop()
    start()
    assert not actuator().ctl.estop.engaged
