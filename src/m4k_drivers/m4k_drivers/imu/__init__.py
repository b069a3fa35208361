"""IMU: WithRobot myAHRS+ on I2C; backends ``real`` (smbus2) and ``sim`` (register-level fake).

``sim`` reads the register-level myAHRS+ inside ``sim_robot`` through a sim-bus I2C client with
smbus2's methods; ``gyro_bias_sd`` configures that simulated chip.
"""

from __future__ import annotations

from typing import Any

from m4k_drivers.imu.handler import ImuHandler
from m4k_drivers.imu.protocol import ADDRESS, ImuSample
from m4k_drivers.imu.service import SERVICE
from m4k_drivers.registry import BuildContext, Param, register, register_service

__all__ = ['ImuHandler', 'ImuSample']

_COMMON = {
    'address': Param(int, ADDRESS, '7-bit I2C address'),
    'rate_hz': Param(float, 100.0, 'sample rate when streaming, Hz (device max 100)'),
    'stream': Param(bool, False, 'push samples at rate_hz instead of answering REQUESTs'),
}


@register('imu', 'real', params=_COMMON | {
    'bus': Param((int, str), doc='I2C bus number (/dev/i2c-N) or device path'),
    'drdy_chip': Param(str, '/dev/gpiochip0', 'gpiochip of the DATA READY line (J3-1)'),
    'drdy_line': Param((int, type(None)), None, 'line offset wired to the myAHRS+ J3-1 DATA '
                       'READY output (measure its high level first: a Pi pin takes 3.3 V at '
                       'most); each sample is then stamped at its edge. null = not wired: '
                       'STATUS is polled and the sample timed on arrival',
                       lambda v: None if v is None or v >= 0 else 'must be >= 0 or null'),
    'drdy_edge': Param(str, 'rising', "the edge that announces a sample: 'rising' or 'falling' "
                       '(WithRobot does not document it: check it with the bring-up; wrong = '
                       'every read falls back to polling, counted)',
                       lambda v: None if v in ('rising', 'falling')
                       else "must be 'rising' or 'falling'"),
    'drdy_timeout_s': Param(float, 0.02, 'longest wait for a data-ready edge per read, s '
                            '(then STATUS is polled); two samples at 100 Hz',
                            lambda v: None if 0.0 < v <= 0.5 else 'must be in (0, 0.5]'),
})
def _build_real(name: str, params: dict[str, Any], ctx: BuildContext) -> ImuHandler:
    from m4k_drivers.imu.drdy import open_drdy
    from m4k_drivers.imu.real import open_real_i2c
    line = params['drdy_line']
    drdy = None if line is None else (
        lambda: open_drdy(params['drdy_chip'], line, params['drdy_edge']))
    return ImuHandler(lambda: open_real_i2c(params['bus'], params['address']), name=name,
                      drdy=drdy, drdy_timeout_s=params['drdy_timeout_s'])


@register('imu', 'sim', params=_COMMON | {
    'bus': Param((int, str), 1, 'simulated I2C bus number'),
    'gyro_bias_sd': Param(float, 0.002, 'sd of the constant gyro bias per axis, rad/s'),
})
def _build_sim(name: str, params: dict[str, Any], ctx: BuildContext) -> ImuHandler:
    from m4k_drivers.handler import wrap_os_error
    from m4k_drivers.imu.real import I2cDevice
    from m4k_drivers.simbus import I2cClient
    runtime_dir = ctx.sim_runtime_dir()

    def opener() -> I2cDevice:
        where = f'sim-bus:i2c-{params["bus"]}'
        try:
            return I2cDevice(I2cClient(runtime_dir, params['bus']), params['address'], where)
        except OSError as exc:
            raise wrap_os_error(exc, where) from exc
    return ImuHandler(opener, name=name)


# How the driver host answers the RT side for this kind (m4k_drivers.imu.service).
register_service('imu', SERVICE)
