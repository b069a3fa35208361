"""Every real backend end to end through the kernel stand-in (spidev, i2c-dev, GPIO v2).

python-periphery and smbus2 run unchanged: their os.open / fcntl.ioctl / os.read calls reach
:class:`m4k_drivers.abi.kernel.KernelStandIn`, which decodes the uapi structures from the
bytes and drives the datasheet models of :mod:`m4k_drivers.abi.devices`.  Ground truth is the
models' state (the DAC's output register and volts, the encoder's magnet angle, the IMU's
measurement, the sonar's distance), never the driver's own bookkeeping.
"""

from __future__ import annotations

import math

from fakeclock import FakeClock
import pytest

from m4k_drivers.abi import uapi as u
from m4k_drivers.abi.devices import (
    As5045,
    ImuState,
    LdacPin,
    Mcp4911,
    Monostable,
    MyAhrsPlus,
    Us100,
)
from m4k_drivers.abi.kernel import GpioChip, I2cAdapter, KernelStandIn, SpiNode
from m4k_drivers.handler import DeviceNotFoundError, DriverError
from m4k_drivers.imu.handler import ImuHandler
from m4k_drivers.imu.protocol import GRAVITY
from m4k_drivers.imu.real import open_real_i2c
from m4k_drivers.motors.handler import MotorHandler, WheelCommand
from m4k_drivers.motors.real import open_real_bus, open_real_enable
from m4k_drivers.sonar import protocol as sp
from m4k_drivers.sonar.real import open_gpio_sonar
from m4k_rt.config import shipped_period_s

PERIOD_S = shipped_period_s('actuator')   # the actuator task's, as shipped

CHIP = '/dev/gpiochip0'


@pytest.fixture
def kernel():
    k = KernelStandIn().install()
    yield k
    leaked = k.open_fds()
    k.uninstall()
    assert leaked == [], f'descriptors left open by the backend: {leaked}'


# -- motors: MCP4911 + AS5045 on spidev, /LDAC and the heartbeat on GPIO ---------------------

# The handler's clock: 10 ms per reading (FakeClock(step_ns=...)), so the jump filter sees a
# wheel speed.


class _Rig:
    def __init__(self, kernel: KernelStandIn, ldac: bool) -> None:
        self.dacs = [Mcp4911(), Mcp4911()]
        self.angles = [1234, 4000]
        self.encs = [As5045(lambda: self.angles[0]), As5045(lambda: self.angles[1])]
        self.enable = Monostable(0.05)
        for path, dev in zip(('/dev/spidev0.0', '/dev/spidev0.1', '/dev/spidev1.0',
                              '/dev/spidev1.1'), self.dacs + self.encs, strict=True):
            kernel.spi[path] = SpiNode(dev)
        lines = {25: self.enable}
        if ldac:
            lines[22] = LdacPin(self.dacs)
        kernel.gpio[CHIP] = GpioChip(lines=lines)
        self.kernel = kernel

    def handler(self, ldac: bool) -> MotorHandler:
        def opener():
            return open_real_bus('/dev/spidev0.0', '/dev/spidev0.1', '/dev/spidev1.0',
                                 '/dev/spidev1.1', ldac_chip=CHIP if ldac else None,
                                 ldac_line=22 if ldac else None,
                                 enable=lambda: open_real_enable(CHIP, 25))
        # 10 ms per reading, so the jump filter sees a wheel speed
        return MotorHandler(opener, name='motor', clock=FakeClock(step_ns=10_000_000),
                            period_s=PERIOD_S)


@pytest.mark.parametrize('ldac', [False, True])
def test_motor_real_backend_writes_mcp4911_words_and_reads_as5045_frames(kernel, ldac):
    rig = _Rig(kernel, ldac)
    h = rig.handler(ldac)
    h.configure()
    h.activate()
    # configure zeroed both DACs: code 512 = 1.65 V at Vref 3.3 V, gain 1, output active
    assert [d.code for d in rig.dacs] == [512, 512]
    h.write(WheelCommand(700, 300, 1))
    assert [d.code for d in rig.dacs] == [700, 300]
    assert rig.dacs[0].volts == pytest.approx(3.3 * 700 / 1024)
    assert all(not d.ignored for d in rig.dacs), [d.ignored for d in rig.dacs]
    reading = h.read()
    assert (reading.value.left_raw, reading.value.right_raw) == (1234, 4000)
    rig.angles = [1300, 10]          # forward on both wheels, the right one wrapping
    reading = h.read()
    assert (reading.value.left_raw, reading.value.right_raw) == (1300, 10)
    # what went over the wires: the DACs in mode 0 at 1 MHz, the encoders in mode 2 at 500 kHz
    xfers = [(p, d) for p, c, d in kernel.log if c == 'spi_xfer']
    assert {(d['mode'], d['speed_hz']) for p, d in xfers if p.startswith('/dev/spidev0')} == {
        (0, 1_000_000)}
    assert {(d['mode'], d['speed_hz']) for p, d in xfers if p.startswith('/dev/spidev1')} == {
        (2, 500_000)}
    # the heartbeat: a rising edge on the monostable's input -> the amplifier is enabled
    h.write(WheelCommand(700, 300, 1))
    assert rig.enable.rising_edges >= 1
    assert rig.enable.enabled(rig.enable.last_rise_ns or 0)
    h.deactivate()
    assert [d.code for d in rig.dacs] == [512, 512]
    h.cleanup()


def test_ldac_driven_holds_both_outputs_until_the_pulse(kernel):
    rig = _Rig(kernel, ldac=True)
    bus = open_real_bus('/dev/spidev0.0', '/dev/spidev0.1', '/dev/spidev1.0', '/dev/spidev1.1',
                        ldac_chip=CHIP, ldac_line=22)
    try:
        bus.dacs[0].transfer(bytes([0x30 | (800 >> 6), (800 << 2) & 0xFF]))
        assert rig.dacs[0].input_word is not None and rig.dacs[0].code is None
        bus.latch()
        assert rig.dacs[0].code == 800
    finally:
        bus.close()


def test_encoder_in_the_wrong_spi_mode_is_refused_at_configure(kernel):
    rig = _Rig(kernel, ldac=False)
    h = MotorHandler(lambda: open_real_bus('/dev/spidev0.0', '/dev/spidev0.1', '/dev/spidev1.0',
                                           '/dev/spidev1.1', enc_mode=0), name='motor',
                     period_s=PERIOD_S)
    with pytest.raises(DriverError, match='AS5045'):
        h.configure()
    h.cleanup()
    assert rig.encs[0].reads >= 1


def test_missing_spidev_node_names_its_path(kernel):
    with pytest.raises(DriverError, match='/dev/spidev9.9'):
        open_real_bus('/dev/spidev9.9', '/dev/spidev0.1', '/dev/spidev1.0', '/dev/spidev1.1')


def test_dac_word_outside_the_datasheet_is_ignored_by_the_chip(kernel):
    _Rig(kernel, ldac=False)
    bus = open_real_bus('/dev/spidev0.0', '/dev/spidev0.1', '/dev/spidev1.0', '/dev/spidev1.1')
    try:
        dac = kernel.spi['/dev/spidev0.0'].device
        bus.dacs[0].transfer(b'\x30\x00\x00')     # 24 clocks: not a write
        assert dac.code is None and '24 clocks' in dac.ignored[-1]
    finally:
        bus.close()


# -- IMU: myAHRS+ on i2c-dev ------------------------------------------------------------------
def test_imu_real_backend_reads_the_myahrs_registers_over_i2c_rdwr(kernel):
    state = ImuState(acc_g=(0.1, -0.2, -1.0), gyro_dps=(10.0, -20.0, 30.0), temp_c=31.5,
                     euler_deg=(1.0, 2.0, 90.0), quat=(0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)))
    dev = MyAhrsPlus(lambda: state)
    kernel.i2c['/dev/i2c-1'] = I2cAdapter({0x20: dev})
    h = ImuHandler(lambda: open_real_i2c(1, 0x20), name='imu')
    h.configure()
    assert h.revision == (1, 5)
    r = h.read()
    s = r.value
    # REP-103: board y and z flip; 16 g / 2000 dps full scale in 16 bits
    g = GRAVITY
    assert s.linear_acceleration == pytest.approx((0.1 * g, 0.2 * g, 1.0 * g),
                                                  abs=16 / 32767 * g)
    assert s.temperature == pytest.approx(31.5, abs=200 / 32767)
    assert s.orientation == pytest.approx((0.0, 0.0, -math.sqrt(0.5), math.sqrt(0.5)),
                                          abs=1 / 32767)
    assert s.angular_velocity == pytest.approx(tuple(math.radians(v) for v in (10.0, 20.0, -30.0)),
                                   abs=math.radians(2000 / 32767))
    # one I2C_RDWR transaction carried the 34-byte sample: a pointer write, then the read
    burst = [d for p, c, d in kernel.log if c == 'i2c' and len(d['msgs']) == 2
             and d['msgs'][1] == (True, 34)]
    assert burst and burst[-1]['msgs'][0] == (False, b'\x22')
    h.cleanup()


def test_imu_at_the_wrong_address_is_a_missing_device(kernel):
    kernel.i2c['/dev/i2c-1'] = I2cAdapter({0x20: MyAhrsPlus(ImuState)})
    h = ImuHandler(lambda: open_real_i2c(1, 0x21), name='imu')
    with pytest.raises(DriverError, match='0x21'):
        h.configure()
    h.cleanup()


# -- sonar: US-100 on GPIO v2 with kernel edge stamps ---------------------------------------
def _sonar(kernel, rng, no_echo_s=0.038):
    part = Us100(lambda: rng, no_echo_s=no_echo_s)
    kernel.gpio[CHIP] = GpioChip(lines={23: part.trigger, 24: part.echo})
    return part


def test_sonar_real_backend_times_the_echo_on_monotonic_edges(kernel):
    part = _sonar(kernel, 1.25)
    sonar = open_gpio_sonar(CHIP, 23, 24)
    try:
        assert sonar.line_clock == 'monotonic'
        # periphery asked for realtime stamps; the SET_CONFIG ioctl took that flag away
        cfgs = [d['flags'][0] for p, c, d in kernel.log if c == 'line_config'
                and d['offsets'] == [24]]
        assert cfgs[0] & u.GPIO_V2_LINE_FLAG_EVENT_CLOCK_REALTIME
        assert not cfgs[-1] & u.GPIO_V2_LINE_FLAG_EVENT_CLOCK_REALTIME
        reading = sonar.measure(20.0)
        assert reading.status == sp.STATUS_OK
        assert reading.range_m == pytest.approx(1.25, abs=0.01)
        assert sonar.edge_clock == 'monotonic'
        assert part.pings == 1 and part.short_triggers == 0
    finally:
        sonar.close()


def test_sonar_no_echo_within_the_timeout_is_nothing_in_range(kernel):
    _sonar(kernel, None, no_echo_s=0.038)
    sonar = open_gpio_sonar(CHIP, 23, 24)
    try:
        assert sonar.measure(20.0).status == sp.STATUS_NO_ECHO
    finally:
        sonar.close()


def test_line_already_requested_is_busy(kernel):
    _sonar(kernel, 1.0)
    sonar = open_gpio_sonar(CHIP, 23, 24)
    try:
        with pytest.raises(DriverError, match='line 23'):
            open_gpio_sonar(CHIP, 23, 24)
    finally:
        sonar.close()


def test_an_unserved_path_still_reaches_the_real_kernel(kernel, tmp_path):
    with pytest.raises(DeviceNotFoundError, match='No such file'):
        open_real_enable(str(tmp_path / 'gpiochip7'), 1)
