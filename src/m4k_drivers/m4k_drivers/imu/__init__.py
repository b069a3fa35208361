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
})
def _build_real(name: str, params: dict[str, Any], ctx: BuildContext) -> ImuHandler:
    from m4k_drivers.imu.real import open_real_i2c
    return ImuHandler(lambda: open_real_i2c(params['bus'], params['address']), name=name)


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
