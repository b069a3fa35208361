"""Sonar: US-100 in pulse mode; backends ``gpio`` (alias ``real``), ``iio`` (srf04) and ``sim``.

``sim`` runs the ``gpio`` code on sim-bus GPIO lines of ``sim_robot`` (same chip/line fields);
``mount``, ``noise_sd`` and ``fov_deg`` configure the simulated sensor there.
"""

from __future__ import annotations

from typing import Any

from m4k_drivers.registry import BuildContext, Param, register, register_service
from m4k_drivers.sonar.handler import SonarHandler
from m4k_drivers.sonar.protocol import SonarReading
from m4k_drivers.sonar.service import SERVICE

__all__ = ['SonarHandler', 'SonarReading']

_COMMON = {
    'temperature_c': Param(float, 20.0, 'air temperature for the speed of sound, degC'),
    'timeout_s': Param(float, 0.06, 'longest wait for the echo, s'),
}
_GPIO = _COMMON | {
    'chip': Param(str, doc='gpiochip character device, e.g. /dev/gpiochip0'),
    'trigger_line': Param(int, doc='line offset of TRIG'),
    'echo_line': Param(int, doc='line offset of ECHO'),
}


def _handler(name: str, params: dict[str, Any], opener: Any) -> SonarHandler:
    return SonarHandler(opener, name=name, temperature_c=params['temperature_c'],
                        timeout_s=params['timeout_s'])


def _build_gpio(name: str, params: dict[str, Any], ctx: BuildContext) -> SonarHandler:
    from m4k_drivers.sonar.real import open_gpio_sonar
    return _handler(name, params, lambda: open_gpio_sonar(params['chip'], params['trigger_line'],
                                                          params['echo_line']))


register('sonar', 'gpio', params=_GPIO)(_build_gpio)
register('sonar', 'real', params=_GPIO)(_build_gpio)


@register('sonar', 'iio', params=_COMMON | {
    'device': Param(str, doc='IIO device dir, e.g. /sys/bus/iio/devices/iio:device0'),
})
def _build_iio(name: str, params: dict[str, Any], ctx: BuildContext) -> SonarHandler:
    from m4k_drivers.sonar.real import IioSonar
    return _handler(name, params, lambda: IioSonar(params['device']))


@register('sonar', 'sim', params=_COMMON | {
    'chip': Param(str, '/dev/gpiochip0', 'simulated gpiochip'),
    'trigger_line': Param(int, 23, 'line offset of TRIG'),
    'echo_line': Param(int, 24, 'line offset of ECHO'),
    'mount': Param(list, [0.225, 0.0, 0.0], 'sensor pose in base_link: [x, y, yaw]'),
    'noise_sd': Param(float, 0.003, 'range noise sd, m'),
    'fov_deg': Param(float, 15.0, 'beam width, deg'),
})
def _build_sim(name: str, params: dict[str, Any], ctx: BuildContext) -> SonarHandler:
    from m4k_drivers.sonar.real import open_simbus_sonar
    mount = params['mount']
    if len(mount) != 3 or not all(isinstance(v, (int, float)) for v in mount):
        raise ValueError(f'devices.{name}.mount: expected [x, y, yaw] numbers, got {mount!r}')
    runtime_dir = ctx.sim_runtime_dir()
    return _handler(name, params, lambda: open_simbus_sonar(
        runtime_dir, params['chip'], params['trigger_line'], params['echo_line']))


# How the driver host answers the RT side for this kind (m4k_drivers.sonar.service).
register_service('sonar', SERVICE)
