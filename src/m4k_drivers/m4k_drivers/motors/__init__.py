"""Drive motors: MCP4911 DACs and AS5045 wheel encoders on SPI; backends ``real`` and ``sim``."""

from __future__ import annotations

from typing import Any

from m4k_drivers.motors.handler import EncoderReading, MotorHandler, WheelCommand
from m4k_drivers.registry import BuildContext, Param, register

__all__ = ['EncoderReading', 'MotorHandler', 'WheelCommand']

_COMMON = {
    'period_s': Param(float, 0.01, 'actuator period, s'),
    'watchdog_periods': Param(int, 10, 'periods without WHEEL_CMD before outputs go safe'),
    'max_wheel_rad_s': Param(float, 30.0, 'fastest plausible wheel speed for jump rejection'),
    'lead_bits': Param(int, 1, 'dummy bits before the AS5045 frame in an SPI read'),
}


def _handler_kw(params: dict[str, Any], ctx: BuildContext) -> dict[str, Any]:
    return {k: params[k] for k in _COMMON} | {'clock': ctx.clock}


@register('motor', 'real', params=_COMMON | {
    'left_dac': Param(str, doc='spidev path of the left MCP4911'),
    'right_dac': Param(str, doc='spidev path of the right MCP4911'),
    'left_enc': Param(str, doc='spidev path of the left AS5045'),
    'right_enc': Param(str, doc='spidev path of the right AS5045'),
    'dac_mode': Param(int, 0, 'SPI mode of the DACs'),
    'dac_speed_hz': Param(int, 1_000_000, 'SPI clock of the DACs'),
    'enc_mode': Param(int, 2, 'SPI mode of the encoders'),
    'enc_speed_hz': Param(int, 500_000, 'SPI clock of the encoders (AS5045 max 1 MHz)'),
})
def _build_real(name: str, params: dict[str, Any], ctx: BuildContext) -> MotorHandler:
    from m4k_drivers.motors.real import open_real_bus

    def opener() -> Any:
        return open_real_bus(params['left_dac'], params['right_dac'], params['left_enc'],
                             params['right_enc'], dac_mode=params['dac_mode'],
                             dac_speed_hz=params['dac_speed_hz'], enc_mode=params['enc_mode'],
                             enc_speed_hz=params['enc_speed_hz'])
    return MotorHandler(opener, name=name, **_handler_kw(params, ctx))


@register('motor', 'sim', params=_COMMON | {
    'vref': Param(float, 3.3, 'DAC reference voltage, V'),
    'noise_lsb': Param(float, 0.5, 'encoder noise, standard deviation in counts'),
})
def _build_sim(name: str, params: dict[str, Any], ctx: BuildContext) -> MotorHandler:
    from m4k_drivers.motors.sim import open_sim_bus
    world = ctx.world
    return MotorHandler(lambda: open_sim_bus(world, vref=params['vref'],
                                             noise_lsb=params['noise_lsb'],
                                             lead_bits=params['lead_bits']),
                        name=name, **_handler_kw(params, ctx))
