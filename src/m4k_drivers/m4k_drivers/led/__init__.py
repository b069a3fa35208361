"""LED strip NS-LED-02: backends led_class (= real), led_class_rgb, pwm, pixel_spi, sim.

``pixel_spi`` drives a WS2811/WS2812 pixel strip (the NS-LED-02 is one) with its bit timing
encoded on SPI MOSI (:mod:`m4k_drivers.led.pixel`): no root, no DMA, no PWM block.

``led_class_rgb`` drives a strip wired as three single-colour LED class devices.  ``sim`` runs
the ``led_class`` (or, with ``interface: pwm``, the ``pwm``) code unchanged on the sysfs files
``sim_robot`` keeps in ``<runtime_dir>/sim-sysfs`` (their ``sysfs_root``).
"""

from __future__ import annotations

from typing import Any

from m4k_drivers.led.handler import LedHandler
from m4k_drivers.led.protocol import LedColor
from m4k_drivers.led.service import SERVICE
from m4k_drivers.registry import BuildContext, Param, register, register_service

__all__ = ['LedColor', 'LedHandler']

_ROOT = {'sysfs_root': Param(str, '/sys', 'where sysfs is mounted (sim_robot: its own tree)')}
_LED_CLASS = {'name': Param(str, doc='LED class device name under /sys/class/leds')} | _ROOT


def _leds(params: dict[str, Any]) -> str:
    import os
    return os.path.join(params['sysfs_root'], 'class', 'leds')


def _build_led_class(name: str, params: dict[str, Any], ctx: BuildContext) -> LedHandler:
    from m4k_drivers.led.real import LedClassOutput
    return LedHandler(lambda: LedClassOutput(params['name'], _leds(params)), name=name)


register('led', 'led_class', params=_LED_CLASS)(_build_led_class)
register('led', 'real', params=_LED_CLASS)(_build_led_class)


def _check_names(value: object) -> str | None:
    if not (isinstance(value, list) and len(value) == 3
            and all(isinstance(v, str) and v and '/' not in v for v in value)):
        return 'expected [red, green, blue] LED class device names'
    return None


def _check_channels(value: object) -> str | None:
    if not (isinstance(value, list) and len(value) == 3 and len(set(value)) == 3
            and all(isinstance(v, int) and not isinstance(v, bool) and v >= 0
                    for v in value)):
        return 'expected three distinct channel numbers >= 0 for [r, g, b]'
    return None


@register('led', 'led_class_rgb', params={
    'names': Param(list, doc='[red, green, blue] single-colour LED class names under '
                   '/sys/class/leds', check=_check_names),
} | _ROOT)
def _build_led_class_rgb(name: str, params: dict[str, Any], ctx: BuildContext) -> LedHandler:
    from m4k_drivers.led.real import LedClassRgbOutput
    return LedHandler(lambda: LedClassRgbOutput(params['names'], _leds(params)), name=name)


_PWM = {
    'chip': Param(int, doc='PWM chip number N of /sys/class/pwm/pwmchipN'),
    'channels': Param(list, [0, 1, 2], 'PWM channels for r, g, b', _check_channels),
    'period_ns': Param(int, 1_000_000, 'PWM period, ns (> 0)',
                       lambda v: None if v > 0 else 'must be > 0'),
    'polarity': Param(str, 'normal', "'normal' or 'inversed' (active-low wiring, e.g. a "
                      'common-anode strip)',
                      lambda v: None if v in ('normal', 'inversed')
                      else "must be 'normal' or 'inversed'"),
}


@register('led', 'pwm', params=_PWM | _ROOT)
def _build_pwm(name: str, params: dict[str, Any], ctx: BuildContext) -> LedHandler:
    import os

    from m4k_drivers.led.real import PwmOutput
    root = os.path.join(params['sysfs_root'], 'class', 'pwm')
    write = params.get('_write')
    return LedHandler(lambda: PwmOutput(params['chip'], params['channels'], params['period_ns'],
                                        params['polarity'], root,
                                        **({'write': write()} if write else {})), name=name)


def _check_color_order(value: object) -> str | None:
    from m4k_drivers.led.pixel import COLOR_ORDERS
    return None if value in COLOR_ORDERS else f'must be one of {", ".join(COLOR_ORDERS)}'


@register('led', 'pixel_spi', params={
    'device': Param(str, '/dev/spidev1.2', "spidev node whose MOSI drives the strip's DIN: "
                    'SPI1 MOSI (GPIO20, pin 38, through a 3.3 V -> 5 V buffer) with '
                    'dtoverlay=spi1-3cs; not SPI0, whose MOSI carries the DAC words '
                    '(docs/real-robot.md)'),
    'pixels': Param(int, 1, 'pixels on the strip (all show the LED colour); the frame must '
                    "fit spidev's 4096-byte bufsiz", lambda v: None if v >= 1 else 'must be >= 1'),
    'spi_hz': Param(int, 7_000_000, 'SPI clock asked of the controller, Hz; the aux SPI '
                    'runs core_clock_hz / (2 ceil(core_clock_hz / (2 spi_hz))): 6.944 MHz at a '
                    '250 or 500 MHz core. The frame is planned for that real clock; a clock '
                    'with no encoding inside the WS2812B windows is refused',
                    lambda v: None if 100_000 <= v <= 50_000_000 else 'must be 1e5..5e7'),
    'core_clock_hz': Param(int, 250_000_000, "the Pi's fixed core clock, Hz (config.txt: Pi 3 "
                           'core_freq=250 -> 250e6; Pi 4 core_freq_min=500 -> 500e6; '
                           'docs/real-robot.md); wrong = every bit off by the ratio',
                           lambda v: None if 50_000_000 <= v <= 1_000_000_000
                           else 'must be 5e7..1e9'),
    'color_order': Param(str, 'GRB', 'byte order the strip expects: GRB for WS2812/WS2812B '
                         '(NS-LED-02), often RGB for WS2811 strips; wrong = swapped colours',
                         _check_color_order),
    'reset_us': Param(float, 300.0, 'low time that latches a frame, us: >= 50 for WS2811/'
                      'WS2812, >= 280 for WS2812B V5 and WS2813 (too short: nothing latches)',
                      lambda v: None if 50.0 <= v <= 1000.0 else 'must be 50..1000'),
})
def _build_pixel_spi(name: str, params: dict[str, Any], ctx: BuildContext) -> LedHandler:
    from m4k_drivers.led.real import PixelSpiOutput
    return LedHandler(lambda: PixelSpiOutput(params['device'], params['pixels'],
                                             spi_hz=params['spi_hz'],
                                             core_clock_hz=params['core_clock_hz'],
                                             order=params['color_order'],
                                             reset_us=params['reset_us']), name=name)


@register('led', 'sim', params={
    'interface': Param(str, 'led_class', "'led_class' (multicolor LED) or 'pwm' (3 channels)",
                       lambda v: None if v in ('led_class', 'pwm')
                       else "must be 'led_class' or 'pwm'"),
    'name': Param(str, 'rgb:status', 'simulated LED class device name'),
    'chip': Param(int, 0, 'simulated PWM chip'),
    'channels': _PWM['channels'],
    'period_ns': _PWM['period_ns'],
    'polarity': _PWM['polarity'],
    'multi_index': Param(list, ['red', 'green', 'blue'], 'sim: the channel order the '
                         'simulated multicolor LED reports in multi_index'),
})
def _build_sim(name: str, params: dict[str, Any], ctx: BuildContext) -> LedHandler:
    import os
    runtime_dir = ctx.sim_runtime_dir()
    root = os.path.join(runtime_dir, 'sim-sysfs')
    if params['interface'] == 'pwm':
        # PWM attribute writes go to sim_robot's simulated kernel, which refuses them as a
        # strict kernel does (a plain file cannot fail a write): m4k_drivers.led.simfs.
        from m4k_drivers.simbus import SysfsWriter
        return _build_pwm(name, params | {'sysfs_root': root,
                                          '_write': lambda: SysfsWriter(runtime_dir)}, ctx)
    return _build_led_class(name, params | {'sysfs_root': root}, ctx)


# How the driver host answers the RT side for this kind (m4k_drivers.led.service).
register_service('led', SERVICE)
