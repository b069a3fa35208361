"""The shm transport of m4k_rt.channel: what test_xddp.py (run on both transports) cannot see.

The region and its fds as a raw peer receives them, the negotiation, torn and corrupt slots,
a peer writing its socket instead of its ring, garbage rings, fresh rings per link.
"""

import fcntl
import mmap
import os
import random
import selectors
import shutil
import socket
import struct
import tempfile
import zlib

import pytest
from xddp_support import open_while_polling, until, WAIT

from m4k_rt import channel, schema
from m4k_rt.channel import shmring, XddpPortError


@pytest.fixture
def rundir(monkeypatch):
    base = tempfile.mkdtemp(prefix='m4ks', dir='/tmp')
    path = os.path.join(base, 'rt')
    monkeypatch.setenv('M4K_RUNTIME_DIR', path)
    yield path
    shutil.rmtree(base, ignore_errors=True)






def raw_link(rt, path):
    """Connect as a raw peer would; return (socket, handshake bytes, fds) once accepted."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    sock.settimeout(WAIT)
    sock.connect(path)
    until(rt.poll_peer, 'accept')
    msg, fds, flags, _ = socket.recv_fds(sock, 64, 4)
    assert not flags & socket.MSG_CTRUNC
    return sock, msg, fds


def publish(ring, seq, payload, crc=None, seq_field=None):
    """Write the datagram at absolute slot ``seq`` of ``ring`` by hand, as the producer does."""
    mv = ring.mv
    slot = ring.slots + (seq % ring.nslots) * 128
    mv[slot + 16:slot + 16 + len(payload)] = payload
    seed = (seq * 0x9E3779B1 + len(payload)) & 0xFFFFFFFF
    struct.pack_into('<II', mv, slot + 4, len(payload),
                     zlib.crc32(payload, seed) if crc is None else crc)
    if seq_field is not False:
        struct.pack_into('<I', mv, slot, seq if seq_field is None else seq_field)


def test_the_region_and_the_wake_fd_reach_the_peer_sealed_and_private(rundir):
    with channel.rt_xddp_bind(3, 'imu', transport='shm', poolsz=8192, max_datagram=1000) as rt:
        sock, msg, fds = raw_link(rt, rt.path)
        try:
            assert msg[:1] == channel.HANDSHAKE_SHM and len(fds) == 3
            magic, version, _, nslots, slot, size = struct.unpack_from('<4sHHIII', msg, 1)
            assert (magic, version, slot) == (b'M4KS', 1, 128)
            # poolsz bytes of 128-byte slots per direction, plus one u32 ack per slot
            assert (nslots, slot * nslots + 4 * nslots) == shmring.shm_geometry(8192, 1000) \
                == (64, 8448)
            mfd, efd, efd_rt = fds
            st = os.fstat(mfd)
            assert st.st_size == size >= 2 * 8448 and size % mmap.PAGESIZE == 0
            assert st.st_mode & 0o777 == 0o600
            assert os.readlink('/proc/self/fd/{}'.format(mfd)).startswith('/memfd:m4k-xddp3')
            for fd in (efd, efd_rt):
                assert os.readlink('/proc/self/fd/{}'.format(fd)) == 'anon_inode:[eventfd]'
            seals = fcntl.fcntl(mfd, fcntl.F_GET_SEALS)
            want = fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_GROW | fcntl.F_SEAL_SEAL
            assert seals & want == want
            with pytest.raises(PermissionError):
                os.ftruncate(mfd, 0)  # a peer cannot pull the pages from under the RT side
            with pytest.raises(PermissionError):
                os.ftruncate(mfd, size * 2)
            # Nothing of the link is in the file system: the runtime dir holds the socket
            # and the label only.
            assert sorted(os.listdir(rundir)) == ['label.imu', 'xddp3']
            # A datagram the RT side sends is in ring 0 and wakes the eventfd.
            assert rt.send(b'hello')
            assert os.eventfd_read(efd) == 1
            ring = shmring.ShmRing(memoryview(mmap.mmap(mfd, size)), 0, nslots)
            buf = bytearray(64)
            assert ring.get_into(buf) == 5 and buf[:5] == b'hello'
            ring.mv.release()
        finally:
            for fd in fds:
                os.close(fd)
            sock.close()


def test_a_raw_peer_is_told_shm_and_a_peer_asking_the_other_transport_is_refused(rundir):
    with channel.rt_xddp_bind(1, 'cmd', transport='shm') as rt:
        with pytest.raises(XddpPortError, match='served over the shm transport'):
            open_while_polling(rt, 'cmd', transport='socket')
        until(lambda: rt.recv_into(bytearray(8)) == 0 and not rt.connected, 'refused peer')
        with open_while_polling(rt, 'cmd', transport='shm') as ep:
            assert ep.transport == 'shm'
    with channel.rt_xddp_bind(1, 'cmd', transport='socket') as rt:
        with pytest.raises(XddpPortError, match='served over the socket transport'):
            open_while_polling(rt, 'cmd', transport='shm')
        with pytest.raises(XddpPortError, match='transport'):
            channel.nrt_xddp_open('cmd', transport='udp')


def test_shm_is_message_mode_only_and_transport_is_validated(rundir):
    with pytest.raises(XddpPortError, match='message mode'):
        channel.rt_xddp_bind(2, mode='stream', transport='shm')
    with pytest.raises(XddpPortError, match='transport'):
        channel.rt_xddp_bind(2, transport='pipe')
    field = schema.RUNTIME['transport']
    assert field.default == 'socket' and set(field.choices) == set(channel.TRANSPORTS)
    assert field.validate('runtime.transport', 'shm') == 'shm'
    with pytest.raises(Exception, match='runtime.transport'):
        field.validate('runtime.transport', 'pipe')


def test_unpublished_torn_and_stale_slots_are_never_delivered(rundir, monkeypatch):
    buf = bytearray(256)
    with channel.rt_xddp_bind(4, transport='shm', poolsz=4096, max_datagram=100) as rt, \
            open_while_polling(rt, 4) as ep:
        ring = ep._region.to_rt
        c = rt.counters
        first = ring.wseq
        # Payload, length and CRC written, seq not yet: "not published".
        publish(ring, first, b'first', seq_field=False)
        assert rt.recv_into(buf) == 0 and c.received == 0 and c.torn == 0
        # Seq visible before the CRC (weakly ordered stores): detected, counted once, retried.
        publish(ring, first, b'first', crc=0x12345678)
        assert rt.recv_into(buf) == 0 and rt.recv_into(buf) == 0
        assert c.torn == 1 and c.received == 0
        # The late store lands: delivered.
        publish(ring, first, b'first')
        assert rt.recv_into(buf) == 5 and buf[:5] == b'first' and c.received == 1
        ring.wseq = first + 1  # the endpoint's own writes go on from here
        # A new lap's seq over the previous lap's payload and CRC: the CRC is seeded with
        # seq and length, so the stale slot does not pass.
        for j in range(1, ring.nslots):
            ep.write(bytes([j]))
            assert rt.recv_into(buf) == 1 and buf[0] == j
        stale = first + ring.nslots  # the slot of b'first', one lap later
        struct.pack_into('<I', ring.mv, ring.slots + (stale % ring.nslots) * 128, stale)
        assert rt.recv_into(buf) == 0 and c.torn == 2
        # A slot that stays bad is corrupt, not late: skipped after the give-up time and
        # counted malformed; the next datagram is delivered.
        monkeypatch.setattr(shmring, 'SHM_TORN_GIVEUP_NS', 0)
        ring.wseq = stale + 1
        ep.write(b'after')
        assert rt.recv_into(buf) == 5 and buf[:5] == b'after'
        assert c.malformed == 1 and c.torn == 2 and c.received == ring.nslots + 1


def test_ring_full_and_oversize_are_counted_and_the_ring_recovers(rundir):
    buf = bytearray(128)
    with channel.rt_xddp_bind(5, transport='shm', poolsz=4096, max_datagram=100) as rt, \
            open_while_polling(rt, 5) as ep:
        nslots = ep._region.to_nrt.nslots
        results = [rt.send(bytes([i]) * 10) for i in range(nslots + 5)]
        assert results == [True] * nslots + [False] * 5
        assert rt.counters.dropped_full == 5 and rt.counters.sent == nslots
        assert [ep.read(0) for _ in range(nslots)] == [bytes([i]) * 10 for i in range(nslots)]
        with pytest.raises(TimeoutError):
            ep.read(0)
        assert rt.send(b'again') and ep.read(WAIT) == b'again'
        # NRT -> RT: a full ring makes a write wait, then time out (the RT side is not reading)
        for i in range(nslots):
            ep.write(bytes([i]))
        with pytest.raises(TimeoutError):
            ep.write(b'no room', 0.01)
        # larger than a slot: published as a marker the RT side counts as oversize
        got = [rt.recv_into(buf) for _ in range(nslots)]
        assert got == [1] * nslots
        ep.write(b'x' * 5000)
        ep.write(b'y' * 100)
        assert rt.recv_into(bytearray(50)) == 0  # 5000 > the ring, 100 > the buffer: dropped
        assert rt.counters.dropped_oversize == 2
        ep.write(b'z')
        assert rt.recv_into(buf) == 1 and buf[0] == ord('z')


def test_garbage_in_the_rings_never_breaks_the_rt_side(rundir, monkeypatch):
    monkeypatch.setattr(shmring, 'SHM_TORN_GIVEUP_NS', 0)
    buf = bytearray(4096)
    rng = random.Random(33)
    with channel.rt_xddp_bind(6, transport='shm', poolsz=8192) as rt, \
            open_while_polling(rt, 6) as ep:
        region = ep._region
        for _ in range(200):
            start = rng.randrange(len(region.mv))
            chunk = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64)))
            chunk = chunk[:len(region.mv) - start]
            region.mv[start:start + len(chunk)] = chunk
            for _ in range(4):
                assert 0 <= rt.recv_into(buf) <= len(buf)
            rt.send(b'still alive')  # full or not: counted, never raised
        c = rt.counters
        assert c.sent + c.dropped_full == 200


def test_bytes_written_on_the_socket_of_an_shm_link_are_counted_malformed(rundir):
    with channel.rt_xddp_bind(7, transport='shm') as rt, open_while_polling(rt, 7) as ep:
        ep._sock.send(b'not through the ring')
        until(lambda: rt.recv_into(bytearray(64)) == 0 and rt.counters.malformed == 1,
              'socket look')
        assert rt.connected
        ep.write(b'ring')
        until(lambda: rt.recv() == b'ring', 'ring datagram')


def test_a_new_peer_gets_fresh_rings_never_the_old_peers_data(rundir):
    with channel.rt_xddp_bind(8, transport='shm') as rt:
        first = open_while_polling(rt, 8)
        assert rt.send(b'for the first peer only')
        first.close()
        until(lambda: rt.recv_into(bytearray(64)) == 0 and not rt.connected, 'peer loss')
        assert rt.counters.peer_lost == 1
        with open_while_polling(rt, 8) as second:
            with pytest.raises(TimeoutError):
                second.read(0.05)
            assert rt.send(b'for the second')
            assert second.read(WAIT) == b'for the second'
        assert rt.counters.peer_restarts == 1


def test_the_nrt_fileno_wakes_on_data_and_on_rt_death(rundir):
    rt = channel.rt_xddp_bind(9, transport='shm')
    ep = open_while_polling(rt, 9)
    try:
        with selectors.DefaultSelector() as sel:
            sel.register(ep.fileno(), selectors.EVENT_READ)
            assert sel.select(0) == []
            rt.send(b'one')
            assert len(sel.select(WAIT)) == 1
            assert ep.read(0) == b'one'
            rt.close()
            assert len(sel.select(WAIT)) == 1
            with pytest.raises(BrokenPipeError):
                ep.read(WAIT)
            with pytest.raises(BrokenPipeError):
                ep.write(b'x')
    finally:
        ep.close()
        rt.close()


@pytest.mark.parametrize('seed', range(5))
def test_random_sizes_wrap_in_order_with_boundaries_and_exact_full_drops(seed):
    # Producer and consumer as two ring objects over one buffer, as the two processes have.
    rng = random.Random(seed)
    nslots, size = shmring.shm_geometry(4096, 1000)
    mem = memoryview(bytearray(size))
    prod, cons = shmring.ShmRing(mem, 0, nslots), shmring.ShmRing(mem, 0, nslots)
    prod.init_acks()
    sent, got, full = [], [], 0
    buf = bytearray(1000)
    for i in range(3000):
        if rng.random() < 0.55:
            data = bytes([i & 0xFF]) * rng.choice([1, 20, 111, 112, 113, 500, 1000])
            if prod.put(data):
                sent.append(data)
            else:
                full += 1
                # full means: the slots this one needs (wrap included) are not acked yet
                assert len(sent) > len(got)
        else:
            n = cons.get_into(buf)
            assert n >= 0
            if n:
                got.append(bytes(buf[:n]))
    while (n := cons.get_into(buf)) > 0:
        got.append(bytes(buf[:n]))
    assert got == sent and full > 0 and prod.wseq == cons.rseq


def test_a_burst_of_small_datagrams_fits_as_in_a_socket_buffer(rundir):
    # The monitor ships ~25 small datagrams per batch: poolsz holds them all, as the socket
    # buffer does.
    with channel.rt_xddp_bind(10, transport='shm') as rt, open_while_polling(rt, 10) as ep:
        assert all(rt.send(bytes([i]) * 60) for i in range(200))
        assert [ep.read(0) for _ in range(200)] == [bytes([i]) * 60 for i in range(200)]
        assert rt.counters.dropped_full == 0
