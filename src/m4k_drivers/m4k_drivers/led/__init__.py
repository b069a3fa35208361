"""LED strip NS-LED-02; backends ``led_class`` (alias ``real``), ``pwm`` and ``sim``."""

from __future__ import annotations

from typing import Any

from m4k_drivers.led.handler import LedHandler
from m4k_drivers.led.protocol import LedColor
from m4k_drivers.registry import BuildContext, Param, register

__all__ = ['LedColor', 'LedHandler']

_LED_CLASS = {'name': Param(str, doc='LED class device name under /sys/class/leds')}


def _build_led_class(name: str, params: dict[str, Any], ctx: BuildContext) -> LedHandler:
    from m4k_drivers.led.real import LedClassOutput
    return LedHandler(lambda: LedClassOutput(params['name']), name=name)


register('led', 'led_class', params=_LED_CLASS)(_build_led_class)
register('led', 'real', params=_LED_CLASS)(_build_led_class)


@register('led', 'pwm', params={
    'chip': Param(int, doc='PWM chip number N of /sys/class/pwm/pwmchipN'),
    'channels': Param(list, [0, 1, 2], 'PWM channels for r, g, b'),
    'period_ns': Param(int, 1_000_000, 'PWM period, ns'),
})
def _build_pwm(name: str, params: dict[str, Any], ctx: BuildContext) -> LedHandler:
    from m4k_drivers.led.real import PwmOutput
    return LedHandler(lambda: PwmOutput(params['chip'], params['channels'], params['period_ns']),
                      name=name)


@register('led', 'sim', params={'history': Param(int, 1000, 'colours remembered')})
def _build_sim(name: str, params: dict[str, Any], ctx: BuildContext) -> LedHandler:
    from m4k_drivers.led.sim import SimLed
    return LedHandler(lambda: SimLed(ctx.clock, params['history']), name=name)
