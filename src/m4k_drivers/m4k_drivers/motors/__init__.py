"""Drive motors: MCP4911 DACs and AS5045 wheel encoders on SPI; backends ``real`` and ``sim``.

``sim`` is the same handler on sim-bus transports to the ``sim_robot`` process; the sim's own
parameters (``vref``, ``noise_lsb``) configure the simulated chips inside sim_robot.
"""

from __future__ import annotations

from typing import Any

from m4k_drivers.motors.amplifier import AMP_PARAMS, check_amplifier
from m4k_drivers.motors.handler import (
    EncoderReading,
    HANDLER_PARAMS,
    MotorHandler,
    WheelCommand,
)
from m4k_drivers.motors.service import SERVICE
from m4k_drivers.registry import BuildContext, Param, register, register_service

__all__ = ['EncoderReading', 'MotorHandler', 'RealMotorHandler', 'WheelCommand']


def _check_active(value: object) -> str | None:
    return None if value in ('high', 'low') else "must be 'high' or 'low'"


def _check_line(value: object) -> str | None:
    return None if value is None or (isinstance(value, int) and value >= 0) else \
        'must be a line offset >= 0 or null'


_HEARTBEAT = {
    'heartbeat': Param(bool, True, 'toggle the amplifier-enable line on every fresh command; '
                       'false = enable strapped on (a dead driver host leaves the motors '
                       'driven at the last DAC word)'),
    'heartbeat_chip': Param(str, '/dev/gpiochip0', 'gpiochip of the heartbeat line'),
    'heartbeat_line': Param(int, 25, 'line offset of the heartbeat output'),
    'heartbeat_hold_s': Param(float, 0.05, 'hold time of the enable monostable, s (hardware: '
                              'the RC of the retriggerable monostable; sim: modelled)'),
    'estop_readback_chip': Param(str, '/dev/gpiochip0', 'gpiochip of the e-stop read-back '
                                 'input'),
    'estop_readback_line': Param((int, type(None)), None, 'line offset of the input that reads '
                                 "the monostable's output 1Q through a dedicated safety-relay "
                                 'contact at 3.3 V (docs/real-robot.md, section 5): not asserted '
                                 'while the handler drives the enable -> relay open, ENCODERS '
                                 'status ESTOP_OPEN; asserted with the heartbeat silent -> '
                                 'latched READBACK_FAULT; null = not wired, the software cannot '
                                 'see the '
                                 'relay (logged at configure)', _check_line),
    'estop_readback_active': Param(str, 'high', "the read-back's level while the enable passes "
                                   "the contact: 'high' (1Q through the contact, 10 kOhm "
                                   "pull-down) or 'low' (an inverting stage: an optocoupler or "
                                   'NPN pulling the line to GND against a pull-up); requested '
                                   "with the kernel's ACTIVE_LOW flag when low. Independent of "
                                   "amp_enable: the tap is on the 3.3 V side, before the "
                                   'driver stage. Wrong = every reading an e-stop, then a latched '
                                   'read-back fault', _check_active),
    'sched_priority': Param(int, 50, 'SCHED_FIFO priority of the motor service thread (0: '
                            'SCHED_OTHER); below every RT task, above ordinary load, so the '
                            'heartbeat keeps its period on a busy machine'),
}
_COMMON = HANDLER_PARAMS | _HEARTBEAT


class RealMotorHandler(MotorHandler):
    """The real backend's handler: also knows the amplifier as configured (the DAC hold)."""

    amplifier: dict[str, Any] = {}


LDAC_MODES = ('tied_low', 'gpio')


def _check_ldac(value: object) -> str | None:
    return None if value in LDAC_MODES else f'must be one of {", ".join(LDAC_MODES)}'


def _handler_kw(params: dict[str, Any], ctx: BuildContext) -> dict[str, Any]:
    hold, period = params['heartbeat_hold_s'], params['period_s']
    if params['heartbeat'] and not hold >= 3.0 * period:
        # The monostable retriggers on rising edges, every second command: one late command
        # must not drop the enable, so the hold spans at least three periods.
        raise ValueError(f'devices.motor.heartbeat_hold_s: must be >= 3 * period_s '
                         f'({3.0 * period!r} s), got {hold!r}')
    if params['estop_readback_line'] is not None and params['heartbeat'] and (
            params['estop_readback_chip'], params['estop_readback_line']) == (
            params['heartbeat_chip'], params['heartbeat_line']):
        raise ValueError(f"devices.motor.estop_readback_line: {params['estop_readback_line']!r} "
                         f"is the heartbeat output on {params['heartbeat_chip']!r}; the "
                         'read-back is a separate input after the e-stop contact')
    return {k: params[k] for k in HANDLER_PARAMS} | {
        'clock': ctx.clock, 'enable_hold_s': hold if params['heartbeat'] else None}


@register('motor', 'real', params=_COMMON | AMP_PARAMS | {
    'left_dac': Param(str, doc='spidev path of the left MCP4911'),
    'right_dac': Param(str, doc='spidev path of the right MCP4911'),
    'left_enc': Param(str, doc='spidev path of the left AS5045'),
    'right_enc': Param(str, doc='spidev path of the right AS5045'),
    'dac_mode': Param(int, 0, 'SPI mode of the DACs'),
    'dac_speed_hz': Param(int, 1_000_000, 'SPI clock of the DACs'),
    'enc_mode': Param(int, 2, 'SPI mode of the encoders'),
    'enc_speed_hz': Param(int, 500_000, 'SPI clock of the encoders (AS5045 max 1 MHz)'),
    'ldac': Param(str, 'tied_low', "MCP4911 /LDAC: 'tied_low' (wired to GND) or 'gpio' "
                  '(driven: both outputs latch together)', _check_ldac),
    'ldac_chip': Param((str, type(None)), None, "gpiochip of /LDAC when ldac is 'gpio'"),
    'ldac_line': Param((int, type(None)), None, "line offset of /LDAC when ldac is 'gpio'"),
    'external_stop': Param(bool, False, 'true: the hardware stops the motors by itself when '
                           'commands stop (hold-to-run switch in series with the enable, or '
                           "the amplifier's own command timeout); only then are heartbeat: "
                           'false and control.cmd_vel_timeout: 0 accepted (m4k_drivers.safety)'),
})
def _build_real(name: str, params: dict[str, Any], ctx: BuildContext) -> MotorHandler:
    from m4k_drivers.motors.real import open_real_bus, open_real_enable, open_real_readback
    check_amplifier(params, f'devices.{name}')
    kw = _handler_kw(params, ctx)
    driven = params['ldac'] == 'gpio'
    if driven and (params['ldac_chip'] is None or params['ldac_line'] is None
                   or params['ldac_line'] < 0):
        raise ValueError(f"devices.{name}.ldac: 'gpio' needs ldac_chip and ldac_line (>= 0), "
                         f"got chip={params['ldac_chip']!r} line={params['ldac_line']!r}")
    if driven and params['heartbeat'] and (params['ldac_chip'], params['ldac_line']) == (
            params['heartbeat_chip'], params['heartbeat_line']):
        # One line cannot be both: every heartbeat toggle would latch the DACs mid-update.
        raise ValueError(f"devices.{name}.ldac_line: {params['ldac_line']!r} is also the "
                         f"heartbeat line on {params['heartbeat_chip']!r}; wire /LDAC to "
                         'another line (or tie it low)')

    def opener() -> Any:
        return open_real_bus(params['left_dac'], params['right_dac'], params['left_enc'],
                             params['right_enc'], dac_mode=params['dac_mode'],
                             dac_speed_hz=params['dac_speed_hz'], enc_mode=params['enc_mode'],
                             enc_speed_hz=params['enc_speed_hz'],
                             ldac_chip=params['ldac_chip'] if driven else None,
                             ldac_line=params['ldac_line'] if driven else None,
                             enable=enable if params['heartbeat'] else None,
                             readback=readback if params['estop_readback_line'] is not None
                             else None)

    def enable() -> Any:
        return open_real_enable(params['heartbeat_chip'], params['heartbeat_line'])

    def readback() -> Any:
        return open_real_readback(params['estop_readback_chip'], params['estop_readback_line'],
                                  active_low=params['estop_readback_active'] == 'low')
    handler = RealMotorHandler(opener, name=name, **kw)
    handler.amplifier = {k: params[k] for k in AMP_PARAMS}
    return handler


@register('motor', 'sim', params=_COMMON | {
    'vref': Param(float, 3.3, 'DAC reference voltage, V'),
    'noise_lsb': Param(float, 0.5, 'encoder noise, standard deviation in counts'),
})
def _build_sim(name: str, params: dict[str, Any], ctx: BuildContext) -> MotorHandler:
    from m4k_drivers.motors.sim import open_simbus_bus
    kw = _handler_kw(params, ctx)
    runtime_dir = ctx.sim_runtime_dir()
    line = (params['heartbeat_chip'], params['heartbeat_line']) if params['heartbeat'] else None
    back = (None if params['estop_readback_line'] is None
            else (params['estop_readback_chip'], params['estop_readback_line']))
    low = params['estop_readback_active'] == 'low'
    return MotorHandler(lambda: open_simbus_bus(runtime_dir, line, back, readback_low=low),
                        name=name, **kw)


# How the driver host answers the RT side for this kind (m4k_drivers.motors.service).
register_service('motor', SERVICE)
