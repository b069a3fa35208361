"""sim-bus: framing, the three transports, errors as errno, against the in-process SimRobot."""

import errno
import math
import socket
import struct
import time

import pytest

from m4k_drivers.imu import protocol as ip
from m4k_drivers.motors import protocol as mp
from m4k_drivers.simbus import GpioClient, I2cClient, read_truth, socket_path, SpiClient


def test_spi_dac_word_latches_and_encoder_frame_decodes(sim_robot, m4k_runtime_dir):
    dac = SpiClient(m4k_runtime_dir, 'left_dac')
    enc = SpiClient(m4k_runtime_dir, 'left_enc')
    try:
        assert dac.transfer(mp.encode_dac(800)) == b'\x00\x00'
        assert sim_robot.world.motor_voltage(0) > 0
        dac.close()                               # the SPI master goes away ...
        time.sleep(0.05)
        assert sim_robot.world.motor_voltage(0) > 0   # ... the MCP4911 holds its word
        frame = mp.decode_encoder(enc.transfer(bytes(3)))
        assert 0 <= frame.raw < 4096 and frame.ocf
    finally:
        enc.close()


def test_i2c_burst_of_any_length_and_a_missing_address(sim_robot, m4k_runtime_dir):
    bus = I2cClient(m4k_runtime_dir, 1)
    try:
        assert bus.read_byte_data(ip.ADDRESS, ip.REG_WHO_AM_I) == ip.WHO_AM_I_VALUE
        burst = bus.read_burst(ip.ADDRESS, ip.BLOCK1, ip.BLOCK1_LEN + ip.BLOCK2_LEN)
        assert len(burst) == ip.BLOCK1_LEN + ip.BLOCK2_LEN > 32
        with pytest.raises(OSError) as exc:
            bus.read_byte_data(0x55, 0)
        assert exc.value.errno == errno.EREMOTEIO
    finally:
        bus.close()


def test_unknown_devices_are_enoent(sim_robot, m4k_runtime_dir):
    for make in (lambda: SpiClient(m4k_runtime_dir, 'nope'),
                 lambda: I2cClient(m4k_runtime_dir, 7),
                 lambda: GpioClient(m4k_runtime_dir, '/dev/gpiochip9', 1, 'in')):
        with pytest.raises(OSError) as exc:
            make()
        assert exc.value.errno == errno.ENOENT


@pytest.mark.parametrize('clock', ['monotonic', 'realtime'])
def test_sonar_edges_carry_timestamps_on_the_requested_clock(sim_robot, m4k_runtime_dir, clock):
    trig = GpioClient(m4k_runtime_dir, '/dev/gpiochip0', 23, 'low')
    echo = GpioClient(m4k_runtime_dir, '/dev/gpiochip0', 24, 'in', 'both', event_clock=clock)
    now = time.monotonic_ns if clock == 'monotonic' else time.time_ns
    try:
        t0 = now()
        trig.write(True)
        time.sleep(0.001)
        trig.write(False)
        assert echo.poll(1.0)
        rise = echo.read_event()
        assert echo.poll(1.0)
        fall = echo.read_event()
        assert (rise.edge, fall.edge) == ('rising', 'falling')
        assert t0 < rise.timestamp < fall.timestamp < now() + 1_000_000_000
        assert not echo.poll(0.0)
    finally:
        trig.close()
        echo.close()


def test_truth_and_a_garbage_frame_length(sim_robot, m4k_runtime_dir):
    doc = read_truth(m4k_runtime_dir)
    assert doc['pose'] == [0.0, 0.0, 0.0] and doc['motor_enabled'] is False
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.connect(socket_path(m4k_runtime_dir))
    s.sendall(struct.pack('>I', 1 << 30))            # impossible length: connection dropped
    s.settimeout(5.0)
    assert s.recv(16) == b''
    s.close()
    assert read_truth(m4k_runtime_dir)['t_ns'] >= doc['t_ns']     # the simulator lives on


def test_an_encoder_read_answers_with_the_angle_latched_when_chip_select_fell(
        sim_robot, m4k_runtime_dir):
    # An AS5045 latches at CSn's falling edge: a read the simulator handles 60 ms late (here:
    # the world moved on in between) still reads the angle of the moment it started.
    from m4k_drivers import simbus
    world = sim_robot.world
    world.set_enable_until(None)                      # no heartbeat needed: always enabled
    world.set_motor_voltage(0, 12.0)
    time.sleep(0.3)                                   # the wheel turns at a few rad/s
    enc = SpiClient(m4k_runtime_dir, 'left_enc')
    stamp = time.monotonic_ns() - 60_000_000          # CS fell 60 ms ago
    try:
        raw = mp.decode_encoder(enc._conn.call(simbus.Op.SPI_TRANSFER_AT,
                                               struct.pack('>Q', stamp) + bytes(3))).raw
        plain = mp.decode_encoder(enc.transfer(bytes(3))).raw     # stamped now
    finally:
        enc.close()
    counts = mp.ENC_COUNTS / (2 * math.pi)
    then = world.encoder_angle(0, stamp)[0] * counts
    now = world.encoder_angle(0)[0] * counts
    assert now - then > 20                            # 60 ms is many counts at this speed

    def off(a, b):
        return abs((a - b + 2048) % 4096 - 2048)
    assert off(raw, then) <= 3                        # noise 0.5 LSB sd
    assert off(plain, then) > 15                      # the client's own read: of its moment


def test_a_simulator_without_the_timed_transfer_gets_plain_ones(sim_robot, m4k_runtime_dir,
                                                                monkeypatch):
    # An older or independent simulator answers SPI_TRANSFER_AT with EOPNOTSUPP: the client
    # falls back to SPI_TRANSFER for good on that connection, and the read still works.
    from m4k_drivers import simbus
    real = simbus.SimBusServer._device_op
    seen = []

    def older(device, op, payload, realtime=False):
        seen.append(op)
        if op == simbus.Op.SPI_TRANSFER_AT:
            raise OSError(errno.EOPNOTSUPP, 'unknown sim-bus op 0x0a')
        return real(device, op, payload, realtime)
    monkeypatch.setattr(simbus.SimBusServer, '_device_op', staticmethod(older))
    enc = SpiClient(m4k_runtime_dir, 'left_enc')
    try:
        for _ in range(3):
            assert 0 <= mp.decode_encoder(enc.transfer(bytes(3))).raw < 4096
    finally:
        enc.close()
    assert seen == [simbus.Op.SPI_TRANSFER_AT] + [simbus.Op.SPI_TRANSFER] * 3
