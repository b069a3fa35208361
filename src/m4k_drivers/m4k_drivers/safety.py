"""Refuse configurations that would drive the real motors unprotected (pure, no I/O).

Checked when a process loads its configuration (driver_host serving the stack, sim_robot), so
a bad mix exits 2 with one line naming the field and its value before anything moves:

* real motors with a *simulated* guard sensor (``sonar``, ``lrf``) or IMU: the collision guard
  (and the odometry fusion) would watch a virtual room while the real robot drives.  Configure
  the real sensor, or switch the simulated one off (``enabled: false``: a guard sensor that is
  absent is stale, and a stale guard sensor stops forward motion);
* real motors with ``devices.motor.heartbeat: false`` (the enable strapped on: a dead driver
  host leaves the motors driven at the last DAC word) or ``control.cmd_vel_timeout: 0`` (the
  RT loop drives on the last ``cmd_vel`` forever when its sender dies).

The override is ``devices.motor.external_stop: true`` (real backend): the hardware stops the
motors by itself when commands stop -- an operator's hold-to-run switch in series with the
enable, or an amplifier with its own command timeout.  It accepts the heartbeat and the
timeout being off; it never accepts a simulated sensor on a real robot.
"""

from __future__ import annotations

from typing import Any, Mapping

__all__ = ['GUARD_SENSORS', 'unsafe_mix']

GUARD_SENSORS = ('sonar', 'lrf', 'imu')


def _section(devices: Mapping[str, Any], kind: str) -> Mapping[str, Any]:
    s = devices.get(kind)
    return s if isinstance(s, Mapping) else {}


def _enabled(s: Mapping[str, Any]) -> bool:
    return s.get('enabled', True) is not False


def unsafe_mix(raw: Mapping[str, Any]) -> str | None:
    """Return the first refusal for the merged config document ``raw``, or None when safe."""
    devices = raw.get('devices')
    if not isinstance(devices, Mapping):
        return None
    motor = _section(devices, 'motor')
    if motor.get('backend') != 'real' or not _enabled(motor):
        return None
    standin = raw.get('kernel_standin')
    if isinstance(standin, Mapping) and standin.get('enabled') is True:
        return None      # the motors' nodes are served by the stand-in: no real motor moves
    for kind in GUARD_SENSORS:
        s = _section(devices, kind)
        if s.get('backend') == 'sim' and _enabled(s):
            return (f"devices.{kind}.backend: 'sim' refused with real motors "
                    f"(devices.motor.backend: 'real'): the robot would drive on a simulated "
                    f"{kind}; configure the real one or set devices.{kind}.enabled: false")
    if motor.get('external_stop') is True:
        return None
    if motor.get('heartbeat', True) is False:
        return ('devices.motor.heartbeat: False refused with real motors: a dead driver host '
                'would leave them driven at the last DAC word; set heartbeat: true, or '
                'devices.motor.external_stop: true if the hardware stops them on its own')
    control = raw.get('control')
    timeout = control.get('cmd_vel_timeout') if isinstance(control, Mapping) else None
    if isinstance(timeout, (int, float)) and not isinstance(timeout, bool) and timeout <= 0:
        return (f'control.cmd_vel_timeout: {timeout!r} refused with real motors: the robot '
                'would drive on the last cmd_vel forever when its sender dies; set a timeout '
                '> 0, or devices.motor.external_stop: true if the hardware stops the motors '
                'on its own')
    return None
