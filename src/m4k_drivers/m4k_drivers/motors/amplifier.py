"""The motor amplifier as configured: input range, zero, enable polarity, current limit.

The stack commands the amplifier through an MCP4911 with its mid-scale (code 512) as zero
speed (:mod:`m4k_drivers.motors.protocol`).  That is only right for an amplifier whose command
input spans the DAC's output (0 .. Vref * 1023/1024 at gain 1) and reads zero at Vref / 2
within the per-wheel zero trims (+/-``DAC_TRIM_MAX`` codes).  :func:`check_amplifier` refuses
a configuration where it does not -- before anything is opened -- instead of driving an
amplifier whose zero the DAC cannot produce (a +/-10 V input reads 1.65 V as a third of full
forward).  Measure the values with the DAC hold (``driver_host --device motor --dac CODE``:
docs/real-robot.md, "Before first power").
"""

from __future__ import annotations

from typing import Any

from m4k_drivers.motors import protocol as p
from m4k_drivers.registry import Param

__all__ = ['AMP_PARAMS', 'ENABLE_POLARITIES', 'check_amplifier', 'zero_code']

ENABLE_POLARITIES = ('active_high', 'active_low')


def _check_range(value: object) -> str | None:
    if not (isinstance(value, list) and len(value) == 2
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
            and value[0] < value[1]):
        return 'expected [min, max] volts with min < max'
    return None


AMP_PARAMS = {
    'vref': Param(float, 3.3, 'MCP4911 reference voltage, V (its VREF pin; gain 1x: the DAC '
                  'outputs 0 .. vref * 1023/1024)',
                  lambda v: None if 0.5 <= v <= 5.5 else 'must be 0.5..5.5 V (MCP4911)'),
    'amp_input_range_v': Param(list, [0.0, 3.3], "[min, max] of the amplifier's command input, "
                               "V; must contain the DAC's whole output range (else codes near "
                               'the ends overdrive it: refused)', _check_range),
    'amp_zero_v': Param(float, 1.65, 'command input at which the amplifier drives zero, V; must '
                        f'be the DAC mid-scale within the zero trims (+/-{p.DAC_TRIM_MAX} codes), '
                        'else the robot could not stop: refused'),
    'amp_enable': Param(str, 'active_high', "level of the amplifier's ENABLE input that "
                        "enables it: 'active_high' or 'active_low'; selects the driver stage "
                        'of docs/real-robot.md section 5 (both fail safe: unpowered = off)',
                        lambda v: None if v in ENABLE_POLARITIES
                        else f'must be one of {", ".join(ENABLE_POLARITIES)}'),
    'amp_current_limit_a': Param(float, 3.0, "the amplifier's current limit per motor as set on "
                                 'it (pot or DIP), A: bounds the torque, so the braking the '
                                 'guard may assume (control.brake_decel) must be measured with '
                                 'it; the simulated robot has its own (world.robot)',
                                 lambda v: None if 0.0 < v <= 100.0 else 'must be in (0, 100] A'),
}


def zero_code(params: dict[str, Any]) -> float:
    """Return the DAC code (fractional) that puts ``amp_zero_v`` on the amplifier input."""
    return params['amp_zero_v'] / params['vref'] * (p.DAC_MAX + 1)


def check_amplifier(params: dict[str, Any], where: str = 'devices.motor') -> None:
    """Raise ValueError naming the field when the amplifier does not fit the DAC."""
    vref = params['vref']
    lo, hi = params['amp_input_range_v']
    dac_hi = p.code_to_volts(p.DAC_MAX, vref)
    if lo > 0.0 or hi < dac_hi:
        raise ValueError(f'{where}.amp_input_range_v: [{lo!r}, {hi!r}] V does not contain the '
                         f"DAC's output 0..{dac_hi:.3f} V (vref {vref!r} V): codes beyond "
                         'it would overdrive the amplifier input (lower vref, or add a divider)')
    zc = zero_code(params)
    if abs(zc - p.DAC_ZERO) > p.DAC_TRIM_MAX:
        raise ValueError(f"{where}.amp_zero_v: {params['amp_zero_v']!r} V is DAC code "
                         f'{zc:.0f}, beyond {p.DAC_ZERO} +/- {p.DAC_TRIM_MAX} that the zero trims '
                         'reach: the mid-scale command mapping could not stop this amplifier '
                         '(an offset/scaling stage must put its zero at vref/2)')
