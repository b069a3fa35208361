"""Access control of the XDDP emulation and the m4k processes, tested as another user.

Model: Xenomai's ``/dev/rtpN`` -- only who may open the device node may talk to the RT side.
Here: the runtime directory is 0700 (0770 with a configured group), sockets 0600 (0660), no
world-writable file, no abstract-namespace socket (those bypass file permissions) and no
TCP/UDP socket of m4k's own. "Another user" is ``nobody``: a forked child drops to its uid
and reports what it could do.
"""

import errno
import grp
import json
import os
import pwd
import re
import shutil
import socket
import stat
import tempfile
import time

import pytest
from wsenv import start_sim_robot

from m4k_rt import channel, protocol

pytestmark = pytest.mark.needs_root('to impersonate another user')

NOBODY = pwd.getpwnam('nobody')


def _other_group() -> grp.struct_group:
    """Return a group nobody is not in (for the configured-group case)."""
    for name in ('users', 'staff', 'adm', 'daemon'):
        try:
            g = grp.getgrnam(name)
        except KeyError:
            continue
        if g.gr_gid != NOBODY.pw_gid and 'nobody' not in g.gr_mem:
            return g
    pytest.fail("no group other than nobody's found to test the group mode")


def as_user(fn, uid=NOBODY.pw_uid, gid=NOBODY.pw_gid, groups=()):
    """Run ``fn()`` in a forked child with the given identity; return its JSON-able result."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: drop privileges, run, report, never return into pytest
        code = 0
        try:
            os.close(r)
            os.setgroups(list(groups))
            os.setgid(gid)
            os.setuid(uid)
            out = json.dumps(fn()).encode()
        except BaseException as exc:  # noqa: BLE001 -- reported to the parent
            out = json.dumps({'child_error': repr(exc)}).encode()
            code = 1
        os.write(w, out)
        os._exit(code)
    os.close(w)
    chunks = []
    while True:
        b = os.read(r, 65536)
        if not b:
            break
        chunks.append(b)
    os.close(r)
    os.waitpid(pid, 0)
    res = json.loads(b''.join(chunks))
    assert not (isinstance(res, dict) and 'child_error' in res), res
    return res


def _errno_of(call):
    try:
        call()
    except OSError as exc:
        return exc.errno
    return 0


def _probe(rd: str, label: str, port: int) -> dict:
    """Everything another user might try against a port: list, connect, open, send, read."""
    def connect(path):
        s = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            s.settimeout(2.0)
            s.connect(path)
            s.send(protocol.encode(protocol.Kind.VELOCITY_CMD, 0, 0, 1.0, 0.0))
            s.recv(64)
        finally:
            s.close()

    def m4k_open():
        with channel.nrt_xddp_open(label, runtime_dir=rd, wait=0.5) as ep:
            ep.write(protocol.encode(protocol.Kind.VELOCITY_CMD, 0, 0, 1.0, 0.0))
            ep.read(0.5)
    return {
        'listdir': _errno_of(lambda: os.listdir(rd)),
        'connect_port': _errno_of(lambda: connect(channel.port_path(port, rd))),
        'connect_label': _errno_of(lambda: connect(channel.port_path(label, rd))),
        'nrt_open': _errno_of(m4k_open),
        'create_file': _errno_of(lambda: open(os.path.join(rd, 'probe'), 'w').close()),
    }


@pytest.fixture
def public_parent():
    """A directory every user can traverse, so only m4k's own modes can stop ``nobody``."""
    parent = tempfile.mkdtemp(prefix='m4kacc', dir='/tmp')
    os.chmod(parent, 0o755)
    try:
        yield parent
    finally:
        shutil.rmtree(parent, ignore_errors=True)


def _world_writable(rd: str) -> list[str]:
    bad = []
    for root, dirs, files in os.walk(rd):
        for name in dirs + files + ['.']:
            p = os.path.join(root, name)
            st = os.lstat(p)
            if not stat.S_ISLNK(st.st_mode) and st.st_mode & stat.S_IWOTH:
                bad.append(p)
    return bad


def test_runtime_dir_0700_socket_0600_nobody_cannot_list_connect_send_or_read(public_parent):
    rd = os.path.join(public_parent, 'm4k')
    with channel.rt_xddp_bind(1, 'cmd', runtime_dir=rd) as rt:
        assert stat.S_IMODE(os.stat(rd).st_mode) == 0o700
        assert stat.S_IMODE(os.stat(rt.path).st_mode) == 0o600
        assert _world_writable(rd) == []
        res = as_user(lambda: _probe(rd, 'cmd', 1))
        assert res == dict.fromkeys(res, errno.EACCES), res
        # Defence in depth: even if the directory were opened up by mistake, the 0600 socket
        # still refuses another user's connect().
        os.chmod(rd, 0o711)
        try:
            res = as_user(lambda: _probe(rd, 'cmd', 1))
        finally:
            os.chmod(rd, 0o700)
        assert res['connect_port'] == errno.EACCES and res['connect_label'] == errno.EACCES
        # m4k's own NRT side refuses the widened directory before it tries the socket
        # (check_runtime_dir: mode wider than 0700), so it never reaches the kernel's EACCES.
        assert res['nrt_open'] == errno.EPERM
        rt.poll_peer()
        assert not rt.connected and rt.counters.received == 0


def test_configured_group_admits_its_members_only(public_parent):
    g = _other_group()
    rd = os.path.join(public_parent, 'm4k')
    with channel.rt_xddp_bind(1, 'cmd', runtime_dir=rd, group=g.gr_gid) as rt:
        st = os.stat(rd)
        assert stat.S_IMODE(st.st_mode) == 0o770 and st.st_gid == g.gr_gid
        sst = os.stat(rt.path)
        assert stat.S_IMODE(sst.st_mode) == 0o660 and sst.st_gid == g.gr_gid
        assert _world_writable(rd) == []
        outsider = as_user(lambda: _probe(rd, 'cmd', 1))
        # m4k's NRT side, not given the group, refuses a 0770 directory itself (EPERM from
        # channel.check_runtime_dir) before the kernel would (EACCES); everything else: the kernel.
        assert outsider.pop('nrt_open') == errno.EPERM
        assert outsider == dict.fromkeys(outsider, errno.EACCES), outsider

        def member():
            with channel.nrt_xddp_open('cmd', runtime_dir=rd, wait=2.0, group=g.gr_gid) as ep:
                ep.write(protocol.encode(protocol.Kind.VELOCITY_CMD, 5, 0, 0.5, 0.0))
                data = ep.read(5.0)
            return protocol.decode(data)[0].kind

        # The member's datagram reaches the RT side; the RT side's reply reaches the member.
        import threading
        stop = threading.Event()

        def serve():
            buf = bytearray(4096)
            while not stop.is_set():
                if rt.recv_into(buf):
                    rt.send(protocol.encode(protocol.Kind.ODOMETRY, 1, 0, *[0.0] * 9, 0))
                time.sleep(0.005)
        t = threading.Thread(target=serve)
        t.start()
        try:
            kind = as_user(member, groups=(g.gr_gid,))
        finally:
            stop.set()
            t.join()
        assert kind == protocol.Kind.ODOMETRY
        assert rt.counters.received == 1


def test_runtime_dir_of_another_user_or_too_open_is_refused(public_parent):
    rd = os.path.join(public_parent, 'm4k')
    os.mkdir(rd, 0o700)
    os.chown(rd, NOBODY.pw_uid, NOBODY.pw_gid)
    with pytest.raises(channel.XddpError, match='owned by uid {}'.format(NOBODY.pw_uid)):
        channel.rt_xddp_bind(1, runtime_dir=rd)
    os.chown(rd, 0, 0)
    os.chmod(rd, 0o777)
    with pytest.raises(channel.XddpError, match='mode 0777, wider than 0700'):
        channel.rt_xddp_bind(1, runtime_dir=rd)
    os.rmdir(rd)
    os.symlink(public_parent, rd)
    with pytest.raises(channel.XddpError, match='symlinks are refused'):
        channel.rt_xddp_bind(1, runtime_dir=rd)


def _socket_inodes(pid: int) -> set[str]:
    out = set()
    for fd in os.listdir('/proc/{}/fd'.format(pid)):
        try:
            t = os.readlink('/proc/{}/fd/{}'.format(pid, fd))
        except OSError:
            continue
        if t.startswith('socket:['):
            out.add(t[8:-1])
    return out


def _net_inodes(kind: str) -> dict[str, str]:
    """Return inode -> local address line for /proc/net/<kind>."""
    rows = {}
    try:
        with open('/proc/net/' + kind) as f:
            lines = f.read().splitlines()[1:]
    except FileNotFoundError:
        return rows
    for line in lines:
        cols = line.split()
        if kind == 'unix':
            path = cols[7] if len(cols) > 7 else ''
            rows[cols[6]] = path
        else:
            rows[cols[9]] = cols[1]
    return rows


def _wait_bound(rd: str, n: int, timeout: float = 20.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if os.path.isdir(rd) and sum(e.startswith('xddp') for e in os.listdir(rd)) >= n:
            return
        time.sleep(0.05)
    pytest.fail('rt_core did not bind its ports in {}'.format(rd))


def _and_children(pid: int) -> list[int]:
    """Return ``pid`` and its child processes (the driver host's device processes)."""
    out = [pid]
    for task in os.listdir('/proc/{}/task'.format(pid)):
        with open('/proc/{}/task/{}/children'.format(pid, task)) as f:
            out += [int(c) for c in f.read().split()]
    return out


def _wait_host_linked(log, timeout):
    """Wait until the driver host says it serves N devices and N of them linked to rt_core."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        text = log.read_text()
        # one line per host process (the motors serve from their own, m4k_drivers.hostproc)
        lines = re.findall(r'serving (.+?)(?: \(pid \d+\))?$', text, re.M)
        n = sum(len(m.split(', ')) for m in lines)
        if 'motor@' in text and n and text.count('linked to the RT side (link 1)') >= n:
            return
        time.sleep(0.05)
    pytest.fail('driver_host did not link its ports in {} s:\n{}'.format(
        timeout, log.read_text()[-2000:]))


def test_rt_core_and_driver_host_have_no_inet_or_abstract_sockets(procs, tmp_path,
                                                                   m4k_runtime_dir):
    overlay = tmp_path / 'fast.yaml'
    overlay.write_text('runtime: {mlockall: false, cpu_dma_latency: false}\n')
    sim = start_sim_robot(procs, dict(os.environ), m4k_runtime_dir, '--overlay', str(overlay))
    core = procs.start(['python', '-m', 'm4k_rt.rt_core', '--config', str(overlay)])
    _wait_bound(m4k_runtime_dir, 12)
    with open(tmp_path / 'host.err', 'w') as err:
        host = procs.start(['python', '-m', 'm4k_drivers.host', '--overlay', str(overlay)],
                           stderr=err)
    _wait_host_linked(tmp_path / 'host.err', 60)  # every service's port linked: sockets open
    assert core.poll() is None and host.poll() is None and sim.poll() is None
    inet = {}
    for kind in ('tcp', 'tcp6', 'udp', 'udp6', 'raw', 'raw6', 'udplite', 'udplite6'):
        inet.update(_net_inodes(kind))
    unix = _net_inodes('unix')
    for name, p in (('rt_core', core), ('driver_host', host), ('sim_robot', sim)):
        inodes = set().union(*(_socket_inodes(pid) for pid in _and_children(p.pid)))
        assert inodes, name
        assert not inodes & set(inet), '{} has TCP/UDP/raw sockets: {}'.format(
            name, {i: inet[i] for i in inodes & set(inet)})
        abstract = [unix[i] for i in inodes if unix.get(i, '').startswith('@')]
        assert not abstract, '{} has abstract unix sockets {}'.format(name, abstract)
    bad = _world_writable(m4k_runtime_dir)
    assert bad == [], bad
    modes = {e: stat.S_IMODE(os.lstat(os.path.join(m4k_runtime_dir, e)).st_mode)
             for e in os.listdir(m4k_runtime_dir)
             if not os.path.islink(os.path.join(m4k_runtime_dir, e))}    # labels, sim-urg
    assert all(m & 0o077 == 0 for m in modes.values()), modes
