"""``kernel_standin``: the real backends drive sim_robot through the kernel-ABI stand-in.

The driver side is the real motor, IMU and sonar code on python-periphery and smbus2; its
device nodes are served by :func:`m4k_drivers.abi.wire.standin_for`, whose wires end in an
in-process :class:`~m4k_drivers.sim_robot.SimRobot`.  Ground truth is sim_robot's.
"""

from __future__ import annotations

import pytest

from m4k_drivers import config as dconfig
from m4k_drivers import registry, safety
from m4k_drivers.abi.wire import standin_for
from m4k_drivers.motors.handler import WheelCommand
from m4k_drivers.sim_robot import SimRobot
from m4k_drivers.sonar import protocol as sp
from m4k_rt.channel import ensure_runtime_dir
from m4k_rt.protocol import EncoderStatus

DEVICES = {
    'motor': {'backend': 'real', 'left_dac': '/dev/spidev0.0', 'right_dac': '/dev/spidev0.1',
              'left_enc': '/dev/spidev1.0', 'right_enc': '/dev/spidev1.1',
              'estop_readback_line': 26},
    'imu': {'backend': 'real', 'bus': 1},
    'sonar': {'backend': 'gpio', 'chip': '/dev/gpiochip0', 'trigger_line': 23,
              'echo_line': 24},
}


@pytest.fixture
def rig(m4k_runtime_dir):
    rd = ensure_runtime_dir(m4k_runtime_dir)
    cfg = dconfig.validate({'devices': DEVICES})
    robot = SimRobot(cfg, rd, standin=True).start()
    kernel = standin_for(cfg.devices, rd).install()
    handlers = {}
    try:
        ctx = registry.BuildContext(runtime_dir=rd)
        for kind in DEVICES:
            handlers[kind] = registry.create(kind, cfg.devices[kind], ctx)
        yield robot, kernel, handlers
    finally:
        for h in handlers.values():
            h.shutdown()
        leaked = kernel.open_fds()
        kernel.uninstall()
        robot.close()
    assert leaked == []


def test_real_backends_run_on_sim_robot_through_the_standin(rig):
    robot, kernel, h = rig
    assert sorted(robot.sims) == ['imu', 'motor', 'sonar']
    motor = h['motor']
    motor.configure()
    motor.activate()
    motor.write(WheelCommand(800, 800, 1))
    truth = robot.truth()
    assert truth['heartbeat_edges'] >= 1 and truth['motor_enabled']
    assert truth['motor_volts'][0] > 0 and truth['motor_volts'][0] == truth['motor_volts'][1]
    reading = motor.read().value
    assert not reading.status & EncoderStatus.ESTOP_OPEN     # read back through the stand-in
    assert ('/dev/gpiochip0', 26) in robot.gpio
    spi = [d for p, c, d in kernel.log if c == 'spi_xfer' and p == '/dev/spidev0.0']
    assert spi and spi[-1]['tx'] == bytes([0x30 | 800 >> 6, (800 << 2) & 0xFF])
    imu = h['imu']
    imu.configure()
    sample = imu.read().value
    assert sample.linear_acceleration[2] == pytest.approx(9.81, abs=0.5)   # at rest, z up
    sonar = h['sonar']
    sonar.configure()
    reading = sonar.read().value
    # the paper's room: the obstacle's apex about 1.5 m ahead of the sonar's mount
    assert reading.status == sp.STATUS_OK
    assert 0.5 < reading.range_m < 3.0


def test_standin_config_is_declared_and_lets_real_motors_run_on_it():
    assert dconfig.kernel_standin({'kernel_standin': {'enabled': True}}) is True
    assert dconfig.kernel_standin({}) is False
    with pytest.raises(dconfig.ConfigError, match='kernel_standin: unknown field'):
        dconfig.kernel_standin({'kernel_standin': {'enable': True}})
    raw = {'devices': {'motor': DEVICES['motor'], 'sonar': {'backend': 'sim'}}}
    assert safety.unsafe_mix(raw) is not None
    assert safety.unsafe_mix(raw | {'kernel_standin': {'enabled': True}}) is None
