"""LED strip NS-LED-02; backends ``led_class`` (alias ``real``), ``pwm`` and ``sim``.

``sim`` runs the ``led_class`` (or, with ``interface: pwm``, the ``pwm``) code unchanged on the
sysfs files ``sim_robot`` keeps in ``<runtime_dir>/sim-sysfs`` (``sysfs_root``).
"""

from __future__ import annotations

from typing import Any

from m4k_drivers.led.handler import LedHandler
from m4k_drivers.led.protocol import LedColor
from m4k_drivers.registry import BuildContext, Param, register

__all__ = ['LedColor', 'LedHandler']

_ROOT = {'sysfs_root': Param(str, '/sys', 'where sysfs is mounted (a simulated tree in tests)')}
_LED_CLASS = {'name': Param(str, doc='LED class device name under /sys/class/leds')} | _ROOT


def _led_class(params: dict[str, Any], name: str) -> LedHandler:
    import os

    from m4k_drivers.led.real import LedClassOutput
    root = os.path.join(params['sysfs_root'], 'class', 'leds')
    return LedHandler(lambda: LedClassOutput(params['name'], root), name=name)


def _pwm(params: dict[str, Any], name: str) -> LedHandler:
    import os

    from m4k_drivers.led.real import PwmOutput
    root = os.path.join(params['sysfs_root'], 'class', 'pwm')
    return LedHandler(lambda: PwmOutput(params['chip'], params['channels'], params['period_ns'],
                                        root=root), name=name)


def _build_led_class(name: str, params: dict[str, Any], ctx: BuildContext) -> LedHandler:
    return _led_class(params, name)


register('led', 'led_class', params=_LED_CLASS)(_build_led_class)
register('led', 'real', params=_LED_CLASS)(_build_led_class)


_PWM = {
    'chip': Param(int, doc='PWM chip number N of /sys/class/pwm/pwmchipN'),
    'channels': Param(list, [0, 1, 2], 'PWM channels for r, g, b'),
    'period_ns': Param(int, 1_000_000, 'PWM period, ns'),
}


@register('led', 'pwm', params=_PWM | _ROOT)
def _build_pwm(name: str, params: dict[str, Any], ctx: BuildContext) -> LedHandler:
    return _pwm(params, name)


@register('led', 'sim', params={
    'interface': Param(str, 'led_class', "'led_class' (multicolor LED) or 'pwm' (3 channels)"),
    'name': Param(str, 'rgb:status', 'simulated LED class device name'),
    'chip': Param(int, 0, 'simulated PWM chip'),
    'channels': _PWM['channels'],
    'period_ns': _PWM['period_ns'],
    'multi_index': Param(list, ['red', 'green', 'blue'], 'sim: the channel order the '
                         'simulated multicolor LED reports in multi_index'),
})
def _build_sim(name: str, params: dict[str, Any], ctx: BuildContext) -> LedHandler:
    import os
    if params['interface'] not in ('led_class', 'pwm'):
        raise ValueError(f"devices.{name}.interface: expected 'led_class' or 'pwm', "
                         f"got {params['interface']!r}")
    root = os.path.join(ctx.sim_runtime_dir(), 'sim-sysfs')
    build = _pwm if params['interface'] == 'pwm' else _led_class
    return build(params | {'sysfs_root': root}, name)
