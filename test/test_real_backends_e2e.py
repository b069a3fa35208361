"""The README's "On the real robot" overlay: real backends in the whole stack, data on ROS.

Each real backend that can reach a transport the test owns is started inside the stack
(bringup: sim_robot, rt_core, driver_host, bridge), anything not named staying simulated:

* ``lrf: {backend: real, port: <pty>}`` -- the real URG driver on a pseudo terminal served by
  :mod:`scip_device`, a SCIP 2.0 stand-in written for this test (every step 1.5 m);
* ``sonar: {backend: iio, device: <dir>}`` -- the srf04 IIO attribute files, 1.234 m;
* ``led: {backend: led_class, sysfs_root: <dir>}`` and ``{backend: pwm, ...}`` -- LED class
  and sysfs PWM files; a colour published on /led must land in them.

The motors, the IMU and the GPIO sonar reach kernel interfaces (spidev, i2c-dev, gpiochip
ioctls) that a test cannot stand in for with files; their overlay lines are checked to load
(sim_robot and driver_host do not refuse the README's overlay as written).
"""

import os
import re
import time

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import qos_profile_sensor_data
from scip_device import ScipDevice
from sensor_msgs.msg import LaserScan, Range
from std_msgs.msg import ColorRGBA
from test_bringup import start_bringup, write_overlay
from wsenv import ROOT, stack_env
import yaml

pytestmark = pytest.mark.allow_leaks('fds')  # FastDDS keeps its sockets for the process
SCAN_M, SONAR_M = 1.5, 1.234


def _iio(tmp_path):
    d = tmp_path / 'iio:device0'
    d.mkdir()
    (d / 'in_distance_scale').write_text('0.001\n')
    (d / 'in_distance_raw').write_text(f'{round(SONAR_M * 1000)}\n')
    return {'backend': 'iio', 'device': str(d)}


def _led_class(tmp_path):
    d = tmp_path / 'sys' / 'class' / 'leds' / 'rgb:status'
    d.mkdir(parents=True)
    for name, text in (('max_brightness', '255'), ('brightness', '0'),
                       ('multi_index', 'red green blue'), ('multi_intensity', '0 0 0')):
        (d / name).write_text(text + '\n')
    return {'backend': 'led_class', 'name': 'rgb:status', 'sysfs_root': str(tmp_path / 'sys')}


def _pwm(tmp_path):
    chip = tmp_path / 'sys' / 'class' / 'pwm' / 'pwmchip0'
    for ch in range(3):                   # exported already (a udev rule or a previous run)
        d = chip / f'pwm{ch}'
        d.mkdir(parents=True)
        for name, text in (('period', '0'), ('duty_cycle', '0'), ('enable', '0'),
                           ('polarity', 'normal')):
            (d / name).write_text(text + '\n')
    (chip / 'npwm').write_text('3\n')
    return {'backend': 'pwm', 'chip': 0, 'channels': [0, 1, 2], 'period_ns': 1000000,
            'sysfs_root': str(tmp_path / 'sys')}


def _led_shows_red(section):
    root = os.path.join(section['sysfs_root'], 'class')
    if section['backend'] == 'pwm':
        duty = [open(os.path.join(root, 'pwm', 'pwmchip0', f'pwm{c}', 'duty_cycle')).read()
                for c in range(3)]
        return [d.strip() for d in duty] == ['1000000', '0', '0']
    d = os.path.join(root, 'leds', 'rgb:status')
    return (open(os.path.join(d, 'multi_intensity')).read().split() == ['255', '0', '0']
            and open(os.path.join(d, 'brightness')).read().strip() == '255')


class _User:
    def __init__(self):
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('real_backends_user', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.scan, self.sonar = [], []
        self.node.create_subscription(LaserScan, 'scan', self.scan.append,
                                      qos_profile_sensor_data)
        self.node.create_subscription(Range, 'sonar', self.sonar.append, qos_profile_sensor_data)
        self.led = self.node.create_publisher(ColorRGBA, 'led', 10)

    def spin_until(self, predicate, timeout, what, proc):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.05)
            if predicate():
                return
            assert proc.poll() is None, f'the stack exited ({proc.returncode}) waiting for {what}'
        raise AssertionError(f'timed out after {timeout} s waiting for {what}')

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.mark.parametrize('real', [('lrf',), ('sonar',), ('led_class',), ('pwm',),
                                  ('lrf', 'sonar', 'led_class')])
def test_real_backends_deliver_to_ros(procs, tmp_path, m4k_runtime_dir, real):
    devices = {}
    if 'sonar' in real:
        devices['sonar'] = _iio(tmp_path)
    if 'led_class' in real:
        devices['led'] = _led_class(tmp_path)
    if 'pwm' in real:
        devices['led'] = _pwm(tmp_path)
    with ScipDevice(range_mm=round(SCAN_M * 1000)) as urg:
        if 'lrf' in real:
            devices['lrf'] = {'backend': 'real', 'port': urg.path}
        overlay = write_overlay(tmp_path, {'devices': devices})
        proc = start_bringup(procs, tmp_path, m4k_runtime_dir, overlay, extra=['--no-status'])
        user = _User()
        try:
            def scan_ok():
                return any(abs(r - SCAN_M) < 0.002 for m in user.scan[-1:] for r in m.ranges)

            def sonar_ok():
                return any(abs(m.range - SONAR_M) < 0.002 for m in user.sonar[-1:])
            if 'lrf' in real:
                user.spin_until(scan_ok, 60, '/scan from the real URG backend', proc)
                assert urg.scans > 0 and b'TM1' in urg.commands
                assert all(abs(r - SCAN_M) < 0.002 for r in user.scan[-1].ranges)
            else:                      # the simulated laser still publishes (not 1.5 m flat)
                user.spin_until(lambda: user.scan, 60, '/scan from the simulated URG', proc)
            if 'sonar' in real:
                user.spin_until(sonar_ok, 60, '/sonar from the IIO backend', proc)
            if 'led' in devices:
                def red():
                    user.led.publish(ColorRGBA(r=1.0, g=0.0, b=0.0, a=1.0))
                    return _led_shows_red(devices['led'])
                user.spin_until(red, 60, 'red in the LED files', proc)
        finally:
            user.close()
            err = (tmp_path / 'bringup.err').read_text()
            assert procs.stop(proc, timeout=40) == 0, err[-3000:]
    assert 'unknown field' not in err


def _readme_overlay():
    text = open(os.path.join(ROOT, 'README.md'), encoding='utf-8').read()
    block = re.search(r'```yaml\n# my_robot\.yaml\n(.*?)```', text, re.S)
    assert block, 'README: the "On the real robot" overlay block'
    return yaml.safe_load(block.group(1))


def test_the_readme_overlay_as_written_is_accepted(procs, tmp_path, m4k_runtime_dir):
    # Every device real: sim_robot has nothing to simulate and starts; driver_host validates
    # every section (the old 'unknown field mount' exit 2) and keeps retrying the devices
    # that are not there.
    path = tmp_path / 'my_robot.yaml'
    path.write_text(yaml.safe_dump(_readme_overlay()))
    env = stack_env(m4k_runtime_dir)
    sim = procs.start(['python', '-m', 'm4k_drivers.sim_robot', '--runtime-dir', m4k_runtime_dir,
                       '--overlay', str(path)], env=env)
    from m4k_drivers.sim_robot import wait_ready
    assert wait_ready(m4k_runtime_dir, 30.0), sim.stderr.read() if sim.poll() else ''
    host = procs.start(['python', '-m', 'm4k_drivers.host', '--runtime-dir', m4k_runtime_dir,
                        '--overlay', str(path), '-v'], env=env)
    deadline = time.monotonic() + 60
    seen = ''
    while 'serving' not in seen and time.monotonic() < deadline and host.poll() is None:
        seen += host.stderr.readline()
    assert host.poll() is None and 'serving' in seen, seen + (host.stderr.read()
                                                              if host.poll() is not None else '')
    assert procs.stop(host) == 0
    assert procs.stop(sim) == 0
