"""Tests for m4k_rt.channel: XDDP emulation over Unix sockets (RT side + NRT side).

Every test runs over both transports (``socket`` and ``shm``, the ``transport`` fixture sets
the default the RT side binds with): the same contract. Stream mode is socket-only.
"""

import errno
import os
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import textwrap
import threading
import time

import pytest
from xddp_support import open_while_polling, until, WAIT

import m4k_rt
from m4k_rt import channel, protocol
from m4k_rt.channel import transports, XddpBusyError, XddpError, XddpNotBoundError, XddpPortError

PKG_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(m4k_rt.__file__)))


@pytest.fixture(params=channel.TRANSPORTS)
def transport(request, monkeypatch):
    monkeypatch.setattr(transports, 'DEFAULT_TRANSPORT', request.param)
    return request.param


@pytest.fixture
def rundir(monkeypatch, transport):
    # A short path (AF_UNIX paths are limited to 107 bytes) whose parent any user may
    # traverse, so the permission tests exercise our own directory and socket modes.
    base = tempfile.mkdtemp(prefix='m4kx', dir='/tmp')
    os.chmod(base, 0o711)
    path = os.path.join(base, 'rt')
    monkeypatch.setenv('M4K_RUNTIME_DIR', path)
    yield path
    shutil.rmtree(base, ignore_errors=True)






def rt_recv_wait(sock, buf):
    got = []
    until(lambda: got.append(sock.recv_into(buf)) or got[-1] > 0, 'RT receive')
    return bytes(buf[:got[-1]])


class EchoRt(threading.Thread):
    """An RT side in a thread: echoes every datagram back, until stopped."""

    def __init__(self, port, label=None, **kwargs):
        super().__init__()
        self.sock = channel.rt_xddp_bind(port, label, **kwargs)
        self._quit = threading.Event()
        self.start()

    def run(self):
        buf = bytearray(self.sock.max_datagram)
        while not self._quit.is_set():
            n = self.sock.recv_into(buf)
            if n:
                self.sock.send(memoryview(buf)[:n])
            else:
                time.sleep(0.0005)

    def stop(self):
        self._quit.set()
        self.join()
        self.sock.close()


def child_env():
    env = dict(os.environ)
    env['PYTHONPATH'] = PKG_ROOT
    return env


def spawn(code, **kwargs):
    """Start a stdlib-only Python child (-S: no site, no .pth re-exec) running ``code``."""
    return subprocess.Popen([sys.executable, '-S', '-c', textwrap.dedent(code)],
                            env=child_env(), stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True, **kwargs)


def reap(proc):
    if proc.poll() is None:
        proc.kill()
    proc.communicate(timeout=WAIT)


ECHO_PEER = """
    import sys
    from m4k_rt import channel
    ep = channel.nrt_xddp_open({port!r}, wait=30.0)
    print('linked', flush=True)
    while True:
        ep.write(ep.read())
"""


# ---- data flow ----

@pytest.mark.parametrize('label', [None, 'cmd'])
def test_message_mode_carries_datagrams_both_ways_with_boundaries(rundir, label, transport):
    rt = channel.rt_xddp_bind(1, label)
    try:
        ep = open_while_polling([rt], label or 1)
        with ep:
            assert rt.connected and ep.mode == 'message' and ep.transport == transport
            sizes = [1, 2, 100, 4096, 7]
            for i, size in enumerate(sizes):
                assert rt.send(bytes([i]) * size)
            for i, size in enumerate(sizes):
                assert ep.read(WAIT) == bytes([i]) * size
            buf = bytearray(4096)
            cmd = protocol.encode(protocol.Kind.VELOCITY_CMD, 9, 1, 0.25, 0.0)
            ep.write(cmd)
            ep.write(b'second')
            assert protocol.decode(rt_recv_wait(rt, buf))[1].linear_x == 0.25
            assert rt_recv_wait(rt, buf) == b'second'
            assert rt.recv_into(buf) == 0
            assert rt.counters.sent == len(sizes) and rt.counters.received == 2
    finally:
        rt.close()


def test_stream_mode_carries_bytes_both_ways(rundir):
    rt = channel.rt_xddp_bind(2, mode='stream', transport='socket')
    try:
        with open_while_polling([rt], 2) as ep:
            assert ep.mode == 'stream'
            for chunk in (b'abc', b'def', b'x' * 3000):
                assert rt.send(chunk)
            got = b''
            while len(got) < 3006:
                got += ep.read(WAIT)
            assert got == b'abcdef' + b'x' * 3000
            ep.write(b'hello ')
            ep.write(b'world')
            buf = bytearray(64)
            got = b''
            while len(got) < 11:
                got += rt_recv_wait(rt, buf)
            assert got == b'hello world'
    finally:
        rt.close()


def test_explicit_mode_mismatch_is_a_port_error(rundir):
    rt = channel.rt_xddp_bind(2, mode='stream', transport='socket')
    try:
        with pytest.raises(XddpPortError, match='message mode'):
            channel.nrt_xddp_open(2, mode='message')
    finally:
        rt.close()


def test_paper_style_aliases_and_echo_thread(rundir):
    echo = EchoRt(5, 'led')
    try:
        ep = channel.nrt_xddp_open('led', wait=WAIT)
        led = protocol.encode(protocol.Kind.LED, 1, 2, 255, 0, 0, 100, 1)
        channel.nrt_xddp_write(ep, led)
        assert channel.nrt_xddp_read(ep, WAIT) == led
        channel.nrt_xddp_close(ep)
        assert ep.closed
        with pytest.raises(XddpError, match='closed'):
            ep.read(0)
    finally:
        echo.stop()
    rt = channel.rt_xddp_bind(5)
    assert channel.rt_xddp_send(rt, b'x') is False
    assert channel.rt_xddp_recv(rt, bytearray(8)) == 0
    channel.rt_xddp_close(rt)
    assert not os.path.exists(rt.path)


def test_fileno_selects_on_the_peer_once_linked(rundir):
    import selectors
    rt = channel.rt_xddp_bind(3)
    try:
        listener_fd = rt.fileno()
        with open_while_polling([rt], 3) as ep, selectors.DefaultSelector() as sel:
            assert rt.fileno() != listener_fd
            sel.register(ep.fileno(), selectors.EVENT_READ)
            assert sel.select(0) == []
            rt.send(b'ping')
            assert len(sel.select(WAIT)) == 1
            assert ep.read(0) == b'ping'
            with pytest.raises(TimeoutError):
                ep.read(0)
            with pytest.raises(TimeoutError):
                ep.read(0.01)
            # The RT side's fd (a waiting user's, not the tasks'): readable once the peer wrote.
            with selectors.DefaultSelector() as rsel:
                rsel.register(rt.fileno(), selectors.EVENT_READ)
                assert rsel.select(0) == []
                ep.write(b'pong')
                assert len(rsel.select(WAIT)) == 1
                assert rt_recv_wait(rt, bytearray(64)) == b'pong'
    finally:
        rt.close()


# ---- peers: busy, not bound, restarts ----

def test_second_opener_gets_busy_error_and_first_keeps_working(rundir):
    rt = channel.rt_xddp_bind(1, 'cmd')
    try:
        with open_while_polling([rt], 1) as first:
            with pytest.raises(XddpBusyError) as info:
                open_while_polling([rt], 'cmd')
            assert info.value.path.endswith('label.cmd')
            assert info.value.errno == errno.EBUSY
            assert rt.counters.busy_rejects == 1
            assert rt.send(b'still')
            assert first.read(WAIT) == b'still'
        assert rt.counters.peer_restarts == 0
    finally:
        rt.close()


def test_open_fails_fast_when_nothing_is_bound(rundir):
    channel.ensure_runtime_dir()
    with pytest.raises(XddpNotBoundError) as info:
        channel.nrt_xddp_open(4)
    assert info.value.path == os.path.join(rundir, 'xddp4')
    with pytest.raises(XddpNotBoundError):
        channel.nrt_xddp_open('nolabel', wait=0.05)


def test_open_with_wait_succeeds_when_bound_later(rundir):
    channel.ensure_runtime_dir()
    result = {}

    def opener():
        try:
            result['ep'] = channel.nrt_xddp_open(6, wait=WAIT)
        except Exception as exc:
            result['exc'] = exc

    thread = threading.Thread(target=opener)
    thread.start()
    time.sleep(0.1)  # let the opener find nothing bound first
    rt = channel.rt_xddp_bind(6)
    try:
        until(lambda: not thread.is_alive(), 'waiting opener', step=rt.poll_peer)
        thread.join()
        assert 'exc' not in result, result.get('exc')
        with result['ep'] as ep:
            assert rt.connected
            rt.send(b'late')
            assert ep.read(WAIT) == b'late'
    finally:
        thread.join()
        rt.close()


def test_rt_close_makes_nrt_read_and_write_raise_broken_pipe(rundir):
    rt = channel.rt_xddp_bind(7)
    ep = open_while_polling([rt], 7)
    try:
        rt.send(b'last words')
        rt.close()
        assert ep.read(WAIT) == b'last words'  # queued data is still delivered first
        with pytest.raises(BrokenPipeError):
            ep.read(WAIT)
        with pytest.raises(BrokenPipeError):
            ep.write(b'anyone?')
    finally:
        ep.close()


def test_killed_nrt_peer_is_dropped_and_a_restarted_one_relinks(rundir):
    rt = channel.rt_xddp_bind(2, 'motor')
    buf = bytearray(4096)
    procs = []
    try:
        for generation in range(2):
            proc = spawn(ECHO_PEER.format(port='motor'))
            procs.append(proc)
            until(rt.poll_peer, 'peer link')
            assert proc.stdout.readline().strip() == 'linked'
            msg = protocol.encode(protocol.Kind.WHEEL_CMD, generation, 0, 512, 600, 1)
            assert rt.send(msg)
            assert rt_recv_wait(rt, buf) == msg
            assert rt.counters.peer_restarts == generation
            proc.send_signal(signal.SIGKILL)
            proc.wait(WAIT)
            until(lambda: rt.recv_into(buf) == 0 and not rt.connected, 'peer loss')
            assert rt.counters.peer_lost == generation + 1
            assert not rt.send(b'nobody there')
        assert rt.counters.dropped_no_peer == 2
    finally:
        for proc in procs:
            reap(proc)
        rt.close()


def test_killed_rt_process_breaks_the_pipe_and_its_stale_socket_is_replaced(rundir, transport):
    proc = spawn("""
        import time
        from m4k_rt import channel
        rt = channel.rt_xddp_bind(8, 'sonar', transport={!r})
        print('bound', flush=True)
        while True:
            rt.poll_peer()
            time.sleep(0.001)
    """.format(transport))
    try:
        assert proc.stdout.readline().strip() == 'bound'
        ep = channel.nrt_xddp_open('sonar', wait=WAIT)
        proc.send_signal(signal.SIGKILL)
        proc.wait(WAIT)
        assert ep.transport == transport
        with ep, pytest.raises(BrokenPipeError):
            ep.read(WAIT)
    finally:
        reap(proc)
    path = os.path.join(rundir, 'xddp8')
    assert stat.S_ISSOCK(os.lstat(path).st_mode)  # left behind by the dead process
    with pytest.raises(XddpNotBoundError):
        channel.nrt_xddp_open(8)
    with channel.rt_xddp_bind(8, 'sonar') as rt:
        with open_while_polling([rt], 'sonar') as ep:
            rt.send(b'new')
            assert ep.read(WAIT) == b'new'


def test_bind_refuses_a_port_held_by_a_live_process_without_disturbing_it(rundir, transport):
    proc = spawn("""
        import sys
        from m4k_rt import channel
        rt = channel.rt_xddp_bind(9, 'lrf', transport={!r})
        print('bound', flush=True)
        sys.stdin.readline()
        print(rt.poll_peer(), rt.counters.busy_rejects, rt.counters.peer_lost, flush=True)
        rt.close()
    """.format(transport))
    try:
        assert proc.stdout.readline().strip() == 'bound'
        with pytest.raises(XddpBusyError) as info:
            channel.rt_xddp_bind(9)
        assert 'xddp9' in str(info.value) and info.value.path.endswith('xddp9')
        with pytest.raises(XddpBusyError, match="label 'lrf'"):
            channel.rt_xddp_bind(10, 'lrf')
        assert not os.path.exists(os.path.join(rundir, 'xddp10'))
        out, _ = proc.communicate('go\n', timeout=WAIT)
        assert out.split() == ['False', '0', '0']  # the probes never reached its listener
        assert proc.returncode == 0
    finally:
        reap(proc)


def test_bind_refuses_to_replace_a_non_socket_file(rundir):
    channel.ensure_runtime_dir()
    path = os.path.join(rundir, 'xddp3')
    with open(path, 'w') as f:
        f.write('not a socket')
    with pytest.raises(XddpError, match='not a socket') as info:
        channel.rt_xddp_bind(3)
    assert info.value.path == path
    assert os.path.exists(path)


# ---- drops: oversize, full, no peer ----

def test_oversize_and_empty_sends_are_dropped_and_counted(rundir):
    rt = channel.rt_xddp_bind(4, max_datagram=1024)
    try:
        with open_while_polling([rt], 4) as ep:
            assert not rt.send(b'x' * 1025)
            assert not rt.send(b'')
            assert rt.send(b'x' * 1024)
            assert ep.read(WAIT) == b'x' * 1024
            assert rt.counters.dropped_oversize == 2 and rt.counters.sent == 1
            ep.write(b'y' * 2000)  # larger than the RT receive buffer: discarded, counted
            ep.write(b'ok')
            assert rt_recv_wait(rt, bytearray(1024)) == b'ok'
            assert rt.counters.dropped_oversize == 3 and rt.counters.received == 1
    finally:
        rt.close()


@pytest.mark.parametrize('mode', ['message', 'stream'])
def test_full_queue_drops_without_blocking_and_every_accepted_datagram_arrives(rundir, mode):
    rt = channel.rt_xddp_bind(5, mode=mode, poolsz=16384, max_datagram=1000,
                           transport='socket' if mode == 'stream' else None)
    try:
        with open_while_polling([rt], 5) as ep:
            results = [rt.send(b'z' * 1000) for _ in range(2000)]  # peer is not reading
            accepted = results.count(True)
            assert 0 < accepted < 2000
            assert rt.counters.dropped_full == results.count(False)
            assert rt.counters.sent == accepted
            got = 0
            while True:
                try:
                    got += len(ep.read(0.2))
                except TimeoutError:
                    break
            assert got == accepted * 1000
            assert rt.send(b'z' * 1000)  # space again
    finally:
        rt.close()


def test_send_without_peer_is_dropped_and_counted(rundir):
    with channel.rt_xddp_bind(6) as rt:
        assert not rt.connected
        assert [rt.send(b'a') for _ in range(3)] == [False] * 3
        assert rt.recv() is None
        counters = rt.counters.as_dict()
        assert counters['dropped_no_peer'] == 3 and counters['sent'] == 0
        assert set(counters) == {
            'sent', 'received', 'dropped_no_peer', 'dropped_full', 'dropped_oversize',
            'malformed', 'torn', 'peer_restarts', 'peer_lost', 'busy_rejects'}
        rt.count_malformed()
        assert rt.counters.malformed == 1


def test_closed_rt_socket_stays_harmless(rundir):
    rt = channel.rt_xddp_bind(2)
    ep = open_while_polling([rt], 2)
    rt.close()
    ep.close()
    assert rt.closed and not rt.connected and rt.fileno() == -1
    assert rt.send(b'late') is False and rt.counters.dropped_no_peer == 1
    assert rt.recv_into(bytearray(16)) == 0 and not rt.poll_peer()


def test_receiver_counts_malformed_datagrams(rundir):
    with channel.rt_xddp_bind(1) as rt, open_while_polling([rt], 1) as ep:
        ep.write(b'garbage!' * 3)
        ep.write(protocol.encode(protocol.Kind.VELOCITY_CMD, 1, 1, 0.1, 0.2))
        decoded = []
        until(lambda: len(decoded) + rt.counters.malformed == 2, 'two datagrams',
              step=lambda: _drain(rt, decoded))
        assert rt.counters.malformed == 1 and decoded == [protocol.VelocityCmd(0.1, 0.2)]


def _drain(rt, decoded):
    data = rt.recv()
    if data is None:
        return
    try:
        decoded.append(protocol.decode(data)[1])
    except protocol.ProtocolError:
        rt.count_malformed()


# ---- ports, labels, validation ----

@pytest.mark.parametrize('port', [-1, 32, 1.0, True, '3', None])
def test_bad_port_is_a_port_error(rundir, port):
    with pytest.raises(XddpPortError, match='port'):
        channel.rt_xddp_bind(port)


@pytest.mark.parametrize('label', ['', '../evil', 'a/b', '.hidden', 'x' * 33, 'sp ace'])
def test_bad_labels_are_refused(rundir, label):
    with pytest.raises(XddpPortError, match='label'):
        channel.nrt_xddp_open(label)


@pytest.mark.parametrize('kwargs', [
    {'mode': 'datagram'}, {'poolsz': 100}, {'max_datagram': 0},
    {'poolsz': 8192, 'max_datagram': 8192}])
def test_bad_bind_options_are_port_errors(rundir, kwargs):
    with pytest.raises(XddpPortError):
        channel.rt_xddp_bind(1, **kwargs)


def test_port_limit_is_configurable(rundir):
    with pytest.raises(XddpPortError):
        channel.rt_xddp_bind(40)
    with channel.rt_xddp_bind(40, max_ports=64) as rt:
        assert rt.path.endswith('xddp40')
        with pytest.raises(XddpPortError):
            channel.nrt_xddp_open(40)
        with open_while_polling([rt], 40, max_ports=64):
            assert rt.connected


def test_labels_are_symlinks_removed_on_close(rundir):
    rt = channel.rt_xddp_bind(4, 'imu_out')
    link = os.path.join(rundir, 'label.imu_out')
    try:
        assert os.readlink(link) == 'xddp4'
        with open_while_polling([rt], 'imu_out') as ep:
            assert ep.path == link
    finally:
        rt.close()
    assert not os.path.lexists(link) and not os.path.exists(rt.path)
    rt.close()  # idempotent


def test_relabelling_a_dead_port_moves_the_label(rundir):
    with channel.rt_xddp_bind(3, 'imu'):
        pass
    channel.ensure_runtime_dir()
    os.symlink('xddp9', os.path.join(rundir, 'label.imu'))  # dangling, from a dead config
    with channel.rt_xddp_bind(3, 'imu'):
        assert os.readlink(os.path.join(rundir, 'label.imu')) == 'xddp3'


# ---- runtime directory and permissions ----

def test_default_runtime_dir_follows_the_documented_order(monkeypatch):
    monkeypatch.setenv('M4K_RUNTIME_DIR', '/x/m4k')
    assert channel.default_runtime_dir() == '/x/m4k'
    monkeypatch.delenv('M4K_RUNTIME_DIR')
    monkeypatch.setenv('XDG_RUNTIME_DIR', '/run/user/7')
    assert channel.default_runtime_dir() == '/run/user/7/m4k'
    monkeypatch.delenv('XDG_RUNTIME_DIR')
    expected = '/run/m4k' if os.geteuid() == 0 else '/tmp/m4k-{}'.format(os.getuid())
    assert channel.default_runtime_dir() == expected


def test_runtime_dir_and_sockets_are_private(rundir):
    with channel.rt_xddp_bind(1):
        assert stat.S_IMODE(os.stat(rundir).st_mode) == 0o700
        assert stat.S_IMODE(os.stat(os.path.join(rundir, 'xddp1')).st_mode) == 0o600


def test_runtime_dir_with_group_is_group_accessible(rundir):
    gid = os.getgid() if os.geteuid() != 0 else 65534
    with channel.rt_xddp_bind(1, group=gid) as rt:
        st_dir = os.stat(rundir)
        st_sock = os.stat(rt.path)
        assert stat.S_IMODE(st_dir.st_mode) == 0o770 and st_dir.st_gid == gid
        assert stat.S_IMODE(st_sock.st_mode) == 0o660 and st_sock.st_gid == gid


def test_runtime_dir_narrower_than_configured_is_widened(rundir):
    os.mkdir(rundir, 0o700)
    gid = os.getgid()
    os.chown(rundir, -1, gid)
    channel.ensure_runtime_dir(rundir, group=gid)
    assert stat.S_IMODE(os.stat(rundir).st_mode) == 0o770


@pytest.mark.parametrize('mode', [0o755, 0o750, 0o701, 0o777])
def test_runtime_dir_wider_than_configured_is_refused(rundir, mode):
    os.mkdir(rundir)
    os.chmod(rundir, mode)
    with pytest.raises(XddpError, match='wider than 0700') as info:
        channel.rt_xddp_bind(1)
    assert info.value.path == rundir and info.value.errno == errno.EPERM
    assert os.listdir(rundir) == []


def test_runtime_dir_that_is_a_symlink_is_refused(rundir):
    real = rundir + '.real'
    os.mkdir(real, 0o700)
    os.symlink(real, rundir)
    with pytest.raises(XddpError, match='not a directory'):
        channel.ensure_runtime_dir()


def test_unknown_group_is_refused(rundir):
    with pytest.raises(XddpError, match='unknown group'):
        channel.ensure_runtime_dir(group='no-such-group-m4k')


# ---- the NRT side checks the runtime directory too, before it links ----

def test_nrt_side_accepts_what_the_rt_side_made_and_a_missing_directory(rundir):
    assert channel.check_runtime_dir() == rundir            # absent: nothing bound yet
    with channel.rt_xddp_bind(1, 'imu') as rt:
        assert channel.check_runtime_dir() == rundir
        with open_while_polling([rt], 'imu', wait=5.0) as ep:
            assert ep.path.endswith('label.imu')


def test_nrt_side_accepts_a_group_directory_with_its_group(rundir):
    gid = os.getgid() if os.geteuid() != 0 else 65534
    with channel.rt_xddp_bind(1, group=gid) as rt:
        assert channel.check_runtime_dir(group=gid) == rundir
        with open_while_polling([rt], 1, wait=5.0, group=gid):
            pass
        with pytest.raises(XddpError, match='wider than 0700'):   # a peer not told the group
            channel.nrt_xddp_open(1, wait=0.0)
        other = 65533 if gid != 65533 else 65532
        with pytest.raises(XddpError, match='has group {}, expected {}'.format(gid, other)):
            channel.check_runtime_dir(group=other)


@pytest.mark.parametrize('mode', [0o755, 0o777, 0o707])
def test_nrt_side_refuses_a_directory_others_may_write_or_read(rundir, mode):
    os.mkdir(rundir)
    os.chmod(rundir, mode)
    with pytest.raises(XddpError, match='wider than 0700') as info:
        channel.nrt_xddp_open(1, wait=0.0)
    assert info.value.errno == errno.EPERM
    link = channel.NrtLink(1, retry_interval=0.01)
    assert link.write(b'x') is False and 'wider than' in str(link.last_error)
    assert stat.S_IMODE(os.stat(rundir).st_mode) == mode     # checked, never changed


def test_nrt_side_refuses_a_symlinked_runtime_directory(rundir):
    real = rundir + '.real'
    os.mkdir(real, 0o700)
    os.symlink(real, rundir)
    with pytest.raises(XddpError, match='symlinks are refused'):
        channel.nrt_xddp_open(1, wait=0.0)


@pytest.mark.needs_root('to chown the directory to another user')
def test_nrt_side_refuses_a_runtime_directory_of_another_user(rundir):
    os.mkdir(rundir, 0o700)
    os.chown(rundir, 54321, -1)
    with pytest.raises(XddpError, match='owned by uid 54321'):
        channel.nrt_xddp_open(1, wait=0.0)


needs_root = pytest.mark.needs_root('to chown and to run a child as nobody')

CONNECT_AS_NOBODY = """
import errno, socket, sys
s = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
try:
    s.connect(sys.argv[1])
except OSError as exc:
    print(errno.errorcode.get(exc.errno, exc.errno))
else:
    print('connected')
"""


def connect_as_nobody(path):
    out = subprocess.run(
        ['setpriv', '--reuid=nobody', '--regid=nogroup', '--clear-groups',
         '/usr/bin/python3', '-I', '-c', CONNECT_AS_NOBODY, path],
        capture_output=True, text=True, timeout=WAIT, check=True)
    return out.stdout.strip()


@needs_root
def test_runtime_dir_owned_by_another_user_is_refused(rundir):
    os.mkdir(rundir, 0o700)
    os.chown(rundir, 65534, -1)
    with pytest.raises(XddpError, match='owned by uid 65534'):
        channel.rt_xddp_bind(1)


@needs_root
def test_another_user_cannot_connect(rundir):
    with channel.rt_xddp_bind(1, 'cmd') as rt:
        assert connect_as_nobody(rt.path) == 'EACCES'
        assert connect_as_nobody(rt.label_path) == 'EACCES'
        os.chmod(rundir, 0o711)  # even with a traversable directory the 0600 socket holds
        assert connect_as_nobody(rt.path) == 'EACCES'
        assert not rt.poll_peer()


@needs_root
def test_configured_group_member_can_connect(rundir):
    with channel.rt_xddp_bind(1, group='nogroup') as rt:
        assert connect_as_nobody(rt.path) == 'connected'  # the harness itself can connect


# ---- NrtLink ----

def test_nrt_link_is_quiet_while_unbound_and_relinks_after_rt_restart(rundir):
    channel.ensure_runtime_dir()
    link = channel.NrtLink('cmd', retry_interval=0.02)
    echo = None
    try:
        assert link.read(0.05) is None
        assert link.write(b'x') is False
        assert not link.linked and link.fileno() == -1
        assert isinstance(link.last_error, XddpNotBoundError)
        for generation in range(2):
            echo = EchoRt(1, 'cmd')
            msg = b'gen%d' % generation
            until(lambda msg=msg: link.write(msg), 'link')
            assert link.linked and link.fileno() >= 0
            assert link.read(WAIT) == msg
            assert link.relinks == generation
            echo.stop()
            echo = None
            assert link.read(0.05) is None  # lost: returns None, does not raise
        assert link.lost == 2 and link.links == 2
        assert isinstance(link.last_error, (BrokenPipeError, XddpNotBoundError))
    finally:
        link.close()
        if echo is not None:
            echo.stop()


def test_nrt_link_validates_port_up_front(rundir):
    with pytest.raises(XddpPortError):
        channel.NrtLink(99)
