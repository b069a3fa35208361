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

__all__ = ['NO_ECHO_MARGIN_S', 'SonarHandler', 'SonarReading', 'check_no_echo']

NO_ECHO_MARGIN_S = 0.01     # the wait beyond the no-echo width: edge latency, scheduling


def check_no_echo(params: dict[str, Any], name: str = 'sonar') -> None:
    """Raise ValueError unless the echo wait outlasts the no-echo pulse."""
    need = params['no_echo_s'] + NO_ECHO_MARGIN_S
    if params['timeout_s'] < need:
        raise ValueError(f"devices.{name}.timeout_s: {params['timeout_s']!r} s is shorter than "
                         f"no_echo_s {params['no_echo_s']!r} s + {NO_ECHO_MARGIN_S} s: open "
                         'space would read as a timeout (stale sonar: the guard stops); set '
                         f'timeout_s >= {need:.3f}')

_COMMON = {
    'temperature_c': Param(float, 20.0, 'air temperature for the speed of sound, degC'),
    'timeout_s': Param(float, 0.06, 'longest wait for the echo, s; must exceed no_echo_s by '
                       f'{NO_ECHO_MARGIN_S * 1000:.0f} ms (refused otherwise), else open space '
                       'reads as a timeout (stale: the guard stops)'),
    'no_echo_s': Param(float, 0.038, 'echo width the sensor holds with nothing in range, s. '
                       "The default is the HC-SR04's documented 38 ms; no US-100 document "
                       'gives its width, so it is measured on the part (bringup_check sonar '
                       "step, or sonar_echo_width). sim: the simulated part's width; "
                       'control.guard.sonar_timeout must exceed it',
                       lambda v: None if 0.02 <= v <= 0.2 else 'must be 0.02..0.2 s'),
}
_GPIO = _COMMON | {
    'chip': Param(str, doc='gpiochip character device, e.g. /dev/gpiochip0'),
    'trigger_line': Param(int, doc='line offset of TRIG'),
    'echo_line': Param(int, doc='line offset of ECHO'),
}


def _handler(name: str, params: dict[str, Any], opener: Any) -> SonarHandler:
    check_no_echo(params, name)
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
