"""``calibrate``: identify the M4K's geometry and motors and write a config overlay.

``ros2 run m4k_drivers calibrate --overlay my_robot.yaml --output calibrated.yaml`` walks the
steps below with the motor device of the configuration (real spidev DACs/encoders, or the
simulated ones of ``sim_robot``).  It asks before every run that moves the robot, and asks
for what only a person can measure; answers come from stdin, one per line.

1. ``zero``: hold code 512 with the amplifier *enabled* and report each wheel's creep.
2. ``sweep``: turn in place through a staircase of codes, both ways: the code-to-speed lines
   give ``dac_zero_trim`` (mid of the dead band), the dead band, ``full_scale_wheel_speed``
   and the in-place lag; the new trims are used from here on and checked by a second zero hold.
3. ``lag``: drive straight through three plateaus of ``--speed`` (half, three quarters, all of
   it; about 0.8 m): the straight-line lag of the wheel speed, from small steps in the linear
   region, and the suggested PI gains (lambda tuning on it).
4. ``straight``: drive straight about ``--distance`` m; you measure the distance travelled:
   ``wheel_radius``.
5. ``turn``: turn in place ``--turns`` full turns counter-clockwise, then clockwise; you
   measure each angle: ``track_width``.
6. ``brake``: drive straight at ``--brake-speed``, then
   command zero (amplifier on, as the guard's stop does) and fit the encoders' speed:
   ``control.guard.brake_deceleration`` (m/s^2) and ``control.guard.amplifier_lag`` (s,
   from the host's zero command to the wheels' deceleration: t_react's actuation part only;
   the sensor and RT parts stay, m4k_rt.control.reaction); the robot travels about 1.5 m.

The output is your overlay (``--overlay``) with the identified values merged in, so it can
replace it; a comment block states every value's method and the numbers behind it, and
``--report`` writes them as JSON.  Bounded: every command within ``--max-speed`` /
``--speed`` (<= 0.3 of full scale), every run time-limited, motors at zero and the handler
shut down at the end, on any error and on Ctrl-C/SIGTERM.  Exit 0 done, 1 a run failed or
was cancelled (nothing written), 2 bad arguments or configuration.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import sys
import threading
from typing import Any, TextIO

from m4k_drivers.calibrate import fit, runs
from m4k_drivers.handler import DriverError
from m4k_drivers.motors.handler import MotorHandler

__all__ = ['STEPS', 'Operator', 'main']

ACTUATION_FLOOR_S = 0.001   # s, the smallest actuation time the overlay writes

STEPS = ('zero', 'sweep', 'lag', 'straight', 'turn', 'brake')
DEFAULT_STEPS = STEPS


class Operator:
    """The person at the robot: confirmations and measurements, one line each from stdin."""

    def __init__(self, stdin: TextIO, out: TextIO, assume_yes: bool = False) -> None:
        self.stdin, self.out, self.assume_yes = stdin, out, assume_yes

    def say(self, text: str) -> None:
        """Print one line of guidance."""
        print(text, file=self.out, flush=True)

    def _line(self, prompt: str) -> str:
        print(prompt, end='', file=self.out, flush=True)
        line = self.stdin.readline()
        if not line:
            raise runs.Aborted('no answer (end of input)')
        return line.strip()

    def confirm(self, text: str) -> None:
        """Ask before a run; anything but yes cancels."""
        if self.assume_yes:
            self.say(f'{text} (--yes)')
            return
        if self._line(f'{text} [y/N] ').lower() not in ('y', 'yes'):
            raise runs.Aborted('cancelled')

    def number(self, text: str, default: float) -> float:
        """Ask for a measured value; empty keeps ``default``; asks again on a bad value."""
        for _ in range(5):
            ans = self._line(f'{text} [{default:.4g}]: ')
            if not ans:
                return default
            try:
                v = float(ans)
            except ValueError:
                self.say(f'not a number: {ans!r}')
                continue
            if math.isfinite(v) and v > 0:
                return v
            self.say(f'must be a positive number, got {ans!r}')
        raise runs.Aborted(f'no valid answer to: {text}')


def _parser() -> argparse.ArgumentParser:
    doc = __doc__.split('\n\n')
    summary = doc[0].split(': ', 1)[1]
    ap = argparse.ArgumentParser(prog='calibrate', description=summary[0].upper() + summary[1:],
                                 epilog='\n\n'.join(doc[1:]),
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--config', help='devices YAML file (default: the layered m4k config)')
    ap.add_argument('--overlay', help='your robot overlay (merged into the output)')
    ap.add_argument('--runtime-dir', help='runtime directory (sim backends: the sim_robot)')
    ap.add_argument('--output', required=True, help='overlay YAML to write')
    ap.add_argument('--report', help='also write the numbers behind it as JSON')
    ap.add_argument('--steps', default=','.join(DEFAULT_STEPS),
                    help=f'comma-separated subset of {",".join(STEPS)} (default: '
                    f'{",".join(DEFAULT_STEPS)})')
    ap.add_argument('--hold', type=float, default=3.0, help='zero hold, s (1..10)')
    ap.add_argument('--max-speed', type=float, default=0.25,
                    help=f'sweep top, fraction of full scale (<= {runs.MAX_SPEED})')
    ap.add_argument('--levels', type=int, default=6, help='sweep levels per direction (3..10)')
    ap.add_argument('--settle', type=float, default=0.6,
                    help='sweep and lag run: s to settle per level')
    ap.add_argument('--measure', type=float, default=0.6,
                    help='sweep and lag run: s measured per level')
    ap.add_argument('--speed', type=float, default=0.15,
                    help='lag run (its top), straight run and turns, fraction of full '
                    'scale (<= 0.25)')
    ap.add_argument('--distance', type=float, default=1.0, help='straight run, m (0.2..3)')
    ap.add_argument('--turns', type=int, default=1, help='full turns each way (1..3)')
    ap.add_argument('--brake-speed', type=float, default=0.25,
                    help='brake: straight speed before the stop, fraction of full scale '
                    f'(0.05..{runs.MAX_SPEED})')
    ap.add_argument('--brake-settle', type=float, default=1.5,
                    help='brake: s at that speed before the stop (0.5..5)')
    ap.add_argument('--lambda', dest='lam', type=float, default=0.15,
                    help='closed-loop lag for the suggested PI gains, s (0.05..1)')
    ap.add_argument('--yes', action='store_true', help='do not ask before moving')
    ap.add_argument('-v', '--verbose', action='store_true')
    return ap


def _check(args: argparse.Namespace) -> list[str]:
    steps = [s for s in args.steps.split(',') if s]
    bad = [s for s in steps if s not in STEPS]
    if bad or not steps:
        raise ValueError(f'--steps: unknown {bad!r}; valid: {",".join(STEPS)}')
    for name, v, lo, hi in (('--hold', args.hold, 1.0, 10.0),
                            ('--max-speed', args.max_speed, 0.02, runs.MAX_SPEED),
                            ('--levels', args.levels, 3, 10),
                            ('--brake-speed', args.brake_speed, 0.05, runs.MAX_SPEED),
                            ('--brake-settle', args.brake_settle, 0.5, 5.0),
                            ('--settle', args.settle, 0.2, 5.0),
                            ('--measure', args.measure, 0.2, 5.0),
                            ('--speed', args.speed, 0.02, 0.25),
                            ('--distance', args.distance, 0.2, 3.0),
                            ('--turns', args.turns, 1, 3),
                            ('--lambda', args.lam, 0.05, 1.0)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and lo <= v <= hi):
            raise ValueError(f'{name}: must be in [{lo}, {hi}], got {v!r}')
    for name, path in (('--output', args.output), ('--report', args.report)):
        where = os.path.dirname(os.path.abspath(path)) if path else None
        if where is not None and not os.path.isdir(where):
            # Found out before the robot moves, not after a quarter of an hour of runs.
            raise ValueError(f'{name}: directory {where!r} does not exist')
    return [s for s in STEPS if s in steps]


def main(argv: list[str] | None = None) -> int:
    """Run the calibration; return the exit code."""
    from m4k_rt import rosargs
    from m4k_rt.stopsignals import run_stoppable
    return run_stoppable('calibrate', lambda signals: _main(
        rosargs.parse_args(_parser(), argv), signals.event), when_stopped='; motors at zero')


def _main(args: argparse.Namespace, stop: threading.Event) -> int:
    from m4k_drivers import config as dconfig
    from m4k_drivers import registry
    from m4k_drivers.host import load_raw_config
    from m4k_rt import rosargs
    from m4k_rt.control.params import control_params
    rosargs.configure_logging(args.ros_args, args.verbose)
    try:
        steps = _check(args)
        raw = load_raw_config(args.config, args.overlay)
        cfg = dconfig.validate({'devices': {'motor': (raw.get('devices') or {}).get('motor')
                                            or {'backend': 'sim'}}})
        motor = cfg.devices['motor']
        if motor['backend'] == 'real' and not motor['heartbeat'] \
                and not motor.get('external_stop'):
            # A crash mid-run would leave the DACs latched at a run's code, the enable on.
            raise ValueError('devices.motor.heartbeat: False refused with real motors: '
                             'calibrate drives them, and a dead process would leave them '
                             'driven; set heartbeat: true, or devices.motor.external_stop: true '
                             'if the hardware stops them on its own')
        ctl = control_params(raw.get('control'))
        ctx = registry.BuildContext(runtime_dir=args.runtime_dir or (
            raw.get('runtime') or {}).get('runtime_dir'))
        handler = registry.create('motor', cfg.devices['motor'], ctx)
        if not isinstance(handler, MotorHandler):
            raise ValueError(f'devices.motor: backend {cfg.devices["motor"]["backend"]!r} '
                             'has no motor handler to calibrate')
    except (ValueError, DriverError) as exc:
        print(f'calibrate: {exc}', file=sys.stderr)
        return 2
    op = Operator(sys.stdin, sys.stdout, args.yes)
    res: dict[str, Any] = {'configured': {
        'wheel_radius': ctl.wheel_radius, 'track_width': ctl.track_width,
        'full_scale_wheel_speed': ctl.full_scale_wheel_speed,
        'dac_zero_trim': list(handler.dac_zero_trim), 'dac_sign': list(handler.dac_sign)}}
    try:
        op.say(f'calibrate: steps {", ".join(steps)}; Ctrl-C stops the motors at any time')
        op.confirm('Robot on blocks or on a clear floor (1 m around it), e-stop in reach, '
                   'motors may turn now?')
        with runs.MotorRig(handler, stop) as rig:
            identify(rig, steps, args, ctl, op, res)
        res['encoder_readings_skipped'] = rig.bad_samples
    except (runs.Aborted, fit.FitError, DriverError) as exc:
        print(f'calibrate: {exc}; motors at zero, nothing written', file=sys.stderr)
        return 1
    write_overlay(args.output, args.overlay, res)
    if args.report:
        with open(args.report, 'w', encoding='utf-8') as f:
            json.dump(res, f, indent=1)
    op.say(f'calibrate: wrote {args.output}')
    return 0


def identify(rig: runs.MotorRig, steps: list[str], args: argparse.Namespace, ctl: Any,
             op: Operator, res: dict[str, Any]) -> None:
    """Run the chosen steps in order, filling ``res``."""
    handler = rig.handler
    if 'zero' in steps:
        res['zero_hold_before'] = _hold(rig, args.hold, op, 'before')
    if 'sweep' in steps:
        op.confirm('Sweep: the robot turns in place both ways (about 15 s). Go?')
        sw = runs.sweep(rig, args.max_speed, args.levels, args.settle, args.measure, op.say)
        res.update(_sweep_result(sw, handler.dac_sign, handler.dac_zero_trim))
        handler.dac_zero_trim = tuple(res['dac_zero_trim'])
        op.say(f'sweep: dac_zero_trim {res["dac_zero_trim"]} (exact '
               f'{[round(v, 2) for v in res["dac_zero_trim_exact"]]}), dead band '
               f'{[round(v, 1) for v in res["deadband_codes"]]} codes, full_scale_wheel_speed '
               f'{res["full_scale_wheel_speed"]:.4f} rad/s, in-place lag '
               f'{res["tau_turn_s"] * 1e3:.1f} ms; using the new trims from now on')
        res['zero_hold_after'] = _hold(rig, args.hold, op, 'with the new trims')
    radius = ctl.wheel_radius
    if 'lag' in steps:
        full = res.get('full_scale_wheel_speed', ctl.full_scale_wheel_speed)
        travel = (sum(runs.LAG_LEVELS) * args.speed * full * radius
                  * (args.settle + args.measure))
        op.confirm(f'Lag run: the robot drives straight about {travel:.1f} m at up to '
                   f'{args.speed:.2f} of full scale (clear path, 0.5 m beyond). Go?')
        band = res.get('deadband_codes')
        pls = runs.lag(rig, args.speed, args.settle, args.measure, op.say,
                       sum(band) / len(band) if band else 0.0)
        top = max(abs(pl.speed) for pl in pls)
        tau = fit.tau_from_plateaus(pls, 0.1 * top)
        if not tau > 0:
            raise fit.FitError(f'lag run: the wheels led the command by {-tau * 1e3:.1f} ms '
                               '(an encoder or drive fault?)')
        kp, ki = fit.pi_gains(full, tau, args.lam)
        res['tau_s'] = tau
        res['lag'] = {'speeds_rad_s': [pl.speed for pl in pls], 'codes': [pl.x for pl in pls]}
        res['pi'] = {'kp': kp, 'ki': ki, 'lambda_s': args.lam, 'full_scale': full}
        op.say(f'lag: straight-line wheel lag {tau * 1e3:.1f} ms; PI kp {kp:.5f}, ki {ki:.5f} '
               f'(lambda {args.lam} s)')
    if 'straight' in steps:
        op.confirm(f'Straight run: mark the axle centre on the floor; the robot drives forward '
                   f'about {args.distance:.2f} m (clear path, 0.5 m beyond). Go?')
        dl, dr = runs.straight(rig, args.distance, radius, args.speed,
                               limit_s=_time_limit(args.distance, radius, args.speed, ctl))
        enc = 0.5 * (dl + dr) * radius
        d = op.number(f'Measured distance travelled by the axle centre, m (encoders with the '
                      f'configured radius say {enc:.4f})', enc)
        radius = fit.radius_from_run(d, dl, dr)
        res['straight'] = {'distance_m': d, 'left_rad': dl, 'right_rad': dr}
        res['wheel_radius'] = radius
        op.say(f'straight: wheel_radius {radius:.5f} m (configured {ctl.wheel_radius:.5f})')
    if 'turn' in steps:
        tracks = []
        res['turns'] = []
        for sign, name in ((1, 'counter-clockwise'), (-1, 'clockwise')):
            plan = sign * args.turns * 2.0 * math.pi
            op.confirm(f'Turn: mark the heading on the floor; the robot turns in place '
                       f'{args.turns} full turn(s) {name}. Go?')
            arc = abs(plan) * ctl.track_width / 2.0             # m each wheel rolls
            dl, dr = runs.turn(rig, plan, radius, ctl.track_width, args.speed,
                               limit_s=_time_limit(arc, radius, args.speed, ctl))
            enc = math.degrees((dr - dl) * radius / ctl.track_width) * sign
            deg = op.number(f'Measured angle turned {name}, degrees (360 per full turn; '
                            f'encoders with the configured track say {enc:.1f})', enc)
            heading = sign * math.radians(deg)
            tracks.append(fit.track_from_turn(radius, dl, dr, heading))
            res['turns'].append({'heading_deg': sign * deg, 'left_rad': dl, 'right_rad': dr,
                                 'track_width': tracks[-1]})
        res['track_width'] = sum(tracks) / len(tracks)
        op.say(f'turn: track_width {res["track_width"]:.5f} m (ccw {tracks[0]:.5f}, cw '
               f'{tracks[1]:.5f}; configured {ctl.track_width:.5f})')
    if 'brake' in steps:
        op.confirm(f'Brake: the robot drives straight at {args.brake_speed:.2f} of full scale '
                   f'for {args.brake_settle:.1f} s, then stops with a zero command (clear path '
                   'of about 2 m ahead). Go?')
        t_zero, before, after = runs.brake(rig, args.brake_speed, args.brake_settle)
        b = fit.braking(t_zero, [(s.t, 0.5 * (s.left + s.right)) for s in before],
                        [(s.t, 0.5 * (s.left + s.right)) for s in after], radius)
        res['brake'] = {'decel_mps2': b.decel_mps2, 'reaction_s': b.reaction_s,
                        'speed_mps': b.speed_mps, 'points': b.points, 'radius_m': radius}
        op.say(f'brake: from {b.speed_mps:.3f} m/s the wheels decelerate at '
               f'{b.decel_mps2:.3f} m/s^2, {b.reaction_s * 1e3:.1f} ms after the zero command')


def _time_limit(distance_m: float, radius_m: float, speed: float, ctl: Any) -> float:
    """Return a run's time limit: 3x the time at the configured full scale, plus 3 s."""
    rim = speed * ctl.full_scale_wheel_speed * radius_m         # m/s, by the configuration
    return 3.0 + 3.0 * distance_m / rim


def _hold(rig: runs.MotorRig, seconds: float, op: Operator, when: str) -> dict[str, Any]:
    op.confirm(f'Zero hold {when}: code 512, amplifier enabled, {seconds:.0f} s. Go?')
    creep = runs.hold(rig, seconds)
    moving = [name for name, c in zip(('left', 'right'), creep, strict=True)
              if abs(c) > runs.STOP_SPEED]
    op.say(f'zero hold {when}: creep left {creep[0]:+.3f} rad/s, right {creep[1]:+.3f} rad/s: '
           + (f'{" and ".join(moving)} creeps' if moving else 'both still'))
    return {'creep_rad_s': list(creep), 'creeping': moving}


def _sweep_result(sw: runs.Sweep, sign: tuple[int, ...],
                  trim: tuple[int, ...]) -> dict[str, Any]:
    models, taus = [], []
    for side in (0, 1):
        pls = sw.plateaus[side]
        top = max(abs(pl.speed) for pl in pls)
        models.append(fit.wheel_model([(pl.x, pl.speed) for pl in pls], 0.2 * top))
        # The plateaus follow each other without a gap (the second staircase's zero plateau
        # comes right after the first one's top): every step between them times the lag.
        taus.append(fit.tau_from_plateaus(pls, 0.1 * top))
    exact = [fit.new_trim(m.zero_offset, sign[i], trim[i]) for i, m in enumerate(models)]
    trims = [round(v) for v in exact]
    from m4k_drivers.motors import protocol as p
    reason = p.check_trim_pair(trims)
    if reason:
        raise fit.FitError(f'identified dac_zero_trim {trims}: {reason}; the amplifier zero '
                           'is too far off: adjust it in hardware first')
    full = sum(m.full_scale for m in models) / 2
    return {
        'dac_zero_trim': trims, 'dac_zero_trim_exact': exact,
        'deadband_codes': [m.deadband_codes for m in models],
        'full_scale_wheel_speed': full,
        'full_scale_per_wheel': [m.full_scale for m in models],
        'lines': [{'forward': vars(m.forward), 'backward': vars(m.backward)} for m in models],
        # The lag of turning in place (the wheels move the yaw inertia only): reported, not
        # tuned on; the PI comes from the straight-line lag of the ``lag`` step.
        'tau_turn_s': sorted(taus)[len(taus) // 2],
    }


def overlay_doc(res: dict[str, Any]) -> dict[str, Any]:
    """Return the config keys the results identify (nothing for a step not run)."""
    control: dict[str, Any] = {}
    for key in ('wheel_radius', 'track_width', 'full_scale_wheel_speed'):
        if key in res:
            control[key] = round(float(res[key]), 6)
    if 'pi' in res:
        control['pi'] = {'kp': round(res['pi']['kp'], 5), 'ki': round(res['pi']['ki'], 5)}
    if 'brake' in res:
        # The guard's physics (issue 28): its stop distance v t_react + v^2 / (2 a_brake).
        # t_react's actuation part only: the command path it measures starts at the host's
        # DAC write, so the sensor and RT parts (m4k_rt.control.reaction) are not in it and
        # stay in t_react. A reaction measured at or below 0 (noise; no command path latency
        # in simulated time) is written as the 1 ms floor.
        control['guard'] = {'brake_deceleration': round(res['brake']['decel_mps2'], 4),
                            'amplifier_lag': round(max(res['brake']['reaction_s'],
                                                       ACTUATION_FLOOR_S), 4)}
    doc: dict[str, Any] = {'control': control} if control else {}
    if 'dac_zero_trim' in res:
        doc['devices'] = {'motor': {'dac_zero_trim': list(res['dac_zero_trim'])}}
    return doc


def _comments(res: dict[str, Any]) -> list[str]:
    now = datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')
    c = [f'm4k calibration overlay, written by `calibrate` {now} (docs/real-robot.md).',
         'Your --overlay with the identified values merged in. Methods '
         '(m4k_drivers.calibrate.fit):']
    if 'straight' in res:
        s = res['straight']
        c.append(f'  wheel_radius = measured {s["distance_m"]:.4f} m / mean wheel angle '
                 f'{0.5 * (s["left_rad"] + s["right_rad"]):.4f} rad (straight run)')
    if 'turns' in res:
        c.append('  track_width = radius * (right - left wheel angle) / measured heading, mean '
                 'of ' + ', '.join(f'{t["heading_deg"]:+.1f} deg -> {t["track_width"]:.5f} m'
                                   for t in res['turns']))
    if 'full_scale_wheel_speed' in res:
        c += ['  full_scale_wheel_speed = slope of the code-to-speed lines * 511 (rad/s per unit '
              'command, dead band excluded), per wheel '
              + ', '.join(f'{v:.4f}' for v in res['full_scale_per_wheel']),
              "  dac_zero_trim = middle of each wheel's dead band (codes, exact "
              + ', '.join(f'{v:+.2f}' for v in res['dac_zero_trim_exact']) + '); dead band '
              + ', '.join(f'+/-{v:.1f}' for v in res['deadband_codes'])
              + ' codes (the PI integrator covers it); lag turning in place '
              f'{res["tau_turn_s"]:.4f} s (not used for the PI)']
    if 'pi' in res:
        pi = res['pi']
        c.append(f'  pi: lambda tuning of K/(tau s + 1), K = full scale {pi["full_scale"]:.4f}, '
                 f'tau = {res["tau_s"]:.4f} s (straight-line lag: gap of the mean wheel angle '
                 f'asymptotes over small steps): kp = tau/(K lambda), ki = 1/(K lambda), '
                 f'lambda = {pi["lambda_s"]} s')
    if 'brake' in res:
        b = res['brake']
        c.append(f'  guard.brake_deceleration / amplifier_lag (the actuation part of t_react; '
                 f'the sensor and RT parts are kept): zero command from a steady '
                 f'{b["speed_mps"]:.3f} m/s; the wheel speed line (85..40 % of it, {b["points"]} '
                 f'samples) falls at {b["decel_mps2"]:.4f} m/s^2 and starts '
                 f'{b["reaction_s"] * 1e3:.1f} ms after the write (radius {b["radius_m"]:.5f} m)')
    return c


def write_overlay(path: str, overlay: str | None, res: dict[str, Any]) -> None:
    """Write ``overlay`` (if any) merged with the identified values, with the method comments."""
    import yaml

    from m4k_drivers import config as dconfig
    doc = dconfig.load_file(overlay) if overlay else {}
    doc = dconfig.merge(doc, overlay_doc(res))
    text = ''.join(f'# {line}\n' for line in _comments(res))
    text += yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)
    tmp = path + '.tmp'
    with open(tmp, 'w', encoding='utf-8') as f:
        f.write(text)
    os.replace(tmp, path)


if __name__ == '__main__':
    sys.exit(main())
