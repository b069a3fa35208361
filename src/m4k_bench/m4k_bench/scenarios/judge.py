"""Judge one scenario run on the simulator's ground truth (never odometry, never the guard).

:func:`judge` takes the ground-truth samples the runner (:mod:`.run`) collected and the bounds
derived from config/ (:mod:`.bounds`), and fills the :class:`Result`'s failures. Every rule is
documented in docs/scenarios.md ("The verdict"); the judge reads only the configuration and the
samples, so the suite's negative controls (a weakened guard, supervision off, the guard off)
fail it for the reason they should.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any

from m4k_bench.scenarios.bounds import (
    Bounds,
    guard_params,
    MEMORY_BIAS_M,
    REST_V,
    SAMPLE_S,
    STAY_M,
    stop_line,
    STOP_MARGIN_M,
)
from m4k_bench.scenarios.geometry import Scene
from m4k_bench.scenarios.spec import BREAKAWAY, Scenario

__all__ = ['judge', 'Result', 'trigger']


@dataclass
class Result:
    """What one run measured and the verdict."""

    name: str
    expected: str
    commanded: float
    travelled: float = math.nan
    min_clearance: float = math.nan
    contacts: int = -1
    stop_s: float | None = None
    stop_bound_s: float | None = None
    stop_m: float | None = None         # m travelled from the trigger to rest
    stop_bound_m: float | None = None   # the allowed stopping distance (guard stops)
    peak_decel: float = math.nan        # m/s^2, ground truth
    max_decel: float = math.nan         # m/s^2, mu * g of the world's robot
    distance_tol: float = math.nan
    failures: list[str] = field(default_factory=list)
    samples: list[dict[str, Any]] = field(default_factory=list)
    log_tail: str = ''
    cmd_end_ns: int | None = None       # truth time the scripted commands ended
    peak_speed: float = math.nan        # m/s, body or wheel rim, ground truth

    @property
    def passed(self) -> bool:
        """Return True when every check held."""
        return not self.failures




def judge(sc: Scenario, res: Result, b: Bounds, raw: dict[str, Any]) -> None:
    """Judge ``res.samples`` against the scenario's expectations and ``b``; fill failures."""
    s = res.samples
    if not s:
        res.failures.append('no ground truth sampled')
        return
    # the front band the guard watches: the face and the guard's lateral margin each side
    scene = Scene(raw, lateral=guard_params(raw).lateral_margin)
    for x in s:                       # the judge's own geometry, on every ground-truth sample
        x['clearance'], x['front_clearance'] = scene.judge_sample(x)
    last = s[-1]
    res.travelled = float(last['travelled'])
    # the judge's exact clearance per sample, and the simulator's own 5 ms minimum
    res.min_clearance = min(min(x['clearance'] for x in s), min(_m(x['min_clearance']) for x in s))
    res.contacts = int(last['contacts'])
    touching = sum(1 for x in s if x['clearance'] <= 0.0)
    if res.contacts:
        res.failures.append(f'{res.contacts} contact(s)')
    elif touching:
        res.failures.append(f'contact: the footprint touches a surface in {touching} sample(s)')
    if not res.min_clearance > 0.0:
        res.failures.append(f'minimum clearance {res.min_clearance:.3f} m')
    res.peak_decel = _peak_decel(s)
    res.max_decel = b.max_decel
    if res.peak_decel > b.max_decel:
        res.failures.append(f'peak deceleration {res.peak_decel:.2f} m/s^2 on ground truth > '
                            f'{b.max_decel:.2f} m/s^2 (mu * g): physically impossible braking')
    if sc.distance and abs(res.travelled - res.commanded) > b.distance_tol:
        res.failures.append(f'travelled {res.travelled:.3f} m, commanded {res.commanded:.3f} m '
                            f'(tolerance {b.distance_tol:.3f} m)')
    if sc.distance_m is not None and abs(res.travelled - sc.distance_m) > b.distance_tol:
        res.failures.append(f'travelled {res.travelled:.3f} m, expected {sc.distance_m:.3f} m '
                            f'(tolerance {b.distance_tol:.3f} m)')
    radius = scene.robot.wheel_radius_m
    res.peak_speed = max(max(abs(float(x['v'])),
                             abs(float(x.get('wheel_speed_left', 0.0))) * radius,
                             abs(float(x.get('wheel_speed_right', 0.0))) * radius) for x in s)
    if sc.min_clearance is not None and not res.min_clearance >= sc.min_clearance:
        res.failures.append(f'minimum clearance {res.min_clearance:.3f} m on ground truth < '
                            f'{sc.min_clearance:g} m expected')
    cap = sc.max_speed == BREAKAWAY
    limit = b.breakaway_speed if cap else sc.max_speed
    if isinstance(limit, float) and not res.peak_speed < limit:
        res.failures.append(f'peak speed {res.peak_speed:.3f} m/s on ground truth (body or wheel '
                            f'rim) >= ' + (f'{limit:.3f} m/s, the break-away cap '
                                           f'(pi.breakaway_effort at the full-scale rim speed)'
                                           if cap else f'{limit:g} m/s'))
    if not (sc.motor_fault or sc.faults or sc.e_stop or sc.world.get('faults')
            or sc.world.get('events')):
        _judge_drive_kept(res, s)
    if sc.motor_fault:
        _judge_motor_fault(res, s)
    elif all(c.v >= 0.0 for c in sc.commands):
        back = _backed_up(s)
        if back > STAY_M:
            res.failures.append(f'backed up {back:.3f} m on ground truth with no reverse '
                                f'command: a motion nobody commanded')
    if sc.still_after_estop:
        _judge_estop_release(res, s)
    if sc.max_w_after_kill is not None:
        hit = next((i for i, x in enumerate(s) if x.get('killed')), None)
        if hit is None:
            res.failures.append('the kill never happened')
        else:
            w_max = max(abs(float(x['w'])) for x in s[hit:])
            if not w_max < sc.max_w_after_kill:
                res.failures.append(f'|w| up to {w_max:.3f} rad/s after the kill of '
                                    f'{s[hit]["killed"]} >= {sc.max_w_after_kill:g}')
    if sc.stop:
        _judge_stop(sc, res, b, raw, s)


TURNING_W = 0.02     # rad/s: the judge's own "at rest" for the yaw rate


def _backed_up(s: list[dict[str, Any]]) -> float:
    """Return the largest retreat along the body's own heading (m, ground truth).

    The path is summed along the heading, step by step, over the steps the body is not
    turning (|w| < ``TURNING_W``); the retreat is how far it fell back from the furthest point
    it had reached (a drawdown). While it turns, the heading the steps are projected on sweeps
    round, and the centre's small wobble of a turn on the spot projects as metres of forth and
    back: estop.slow.in_place summed 1.1 cm "backed up" from a centre that never left a
    2.7 mm circle (every backward step while turning; 3 um while not).
    """
    path = peak = worst = 0.0
    for a, c in zip(s, s[1:], strict=False):
        if abs(float(a['w'])) >= TURNING_W:
            continue
        th = float(a['theta'])
        path += ((float(c['x']) - float(a['x'])) * math.cos(th) +
                 (float(c['y']) - float(a['y'])) * math.sin(th))
        if path > peak:
            peak = path
        elif peak - path > worst:
            worst = peak - path
    return worst


def _judge_drive_kept(res: Result, s: list[dict[str, Any]]) -> None:
    """Judge a world with nothing declared to fail: the drive stays powered while commanded.

    With no fault, kill, e-stop or sensor event in the world, only a false stop can drop the
    amplifier enable while the commands are live (a motor fault latched on a healthy wheel, a
    link or a sensor going stale under load); a guard stop brakes with the enable on. Judged
    on ground truth from the first powered sample to the end of the commands.
    """
    end = res.cmd_end_ns
    first = next((i for i, x in enumerate(s) if x.get('motor_enabled')), None)
    if end is None or first is None:
        return
    cut = [x for x in s[first:] if int(x['t_ns']) <= end and not x.get('motor_enabled', True)]
    if cut:
        at = (int(cut[0]['t_ns']) - int(s[first]['t_ns'])) * 1e-9
        res.failures.append(f'the drive lost power {at:.2f} s into the run with no fault '
                            f'declared ({len(cut)} sample(s) unpowered while commanded): a '
                            f'false motor fault or a stale link')


FAULT_HOLD_S = 1.0   # a latched fault: outputs zero and at rest this long before the commands end


def _judge_motor_fault(res: Result, s: list[dict[str, Any]]) -> None:
    """Judge a latched motor fault on ground truth: the commands drive on, the robot does not.

    Over the last ``FAULT_HOLD_S`` of the scripted commands both armatures get 0 V or the
    amplifiers are disabled, and the robot is at rest -- although the command source never
    stopped asking for motion.
    """
    end = res.cmd_end_ns
    if end is None:
        res.failures.append('motor fault: no samples while commanded')
        return
    # the commands reached the wheels before the latch (a stack that never drove is no test)
    if not any(abs(float(u)) > 0.5 for x in s for u in x.get('motor_volts') or []):
        res.failures.append('motor fault: the motors were never driven (no armature voltage '
                            'above 0.5 V on ground truth): nothing was supervised')
        return
    tail = [x for x in s if end - FAULT_HOLD_S * 1e9 <= int(x['t_ns']) <= end]
    if len(tail) < 3:
        res.failures.append('motor fault: too few samples at the end of the commands')
        return
    driven = [x for x in tail if x.get('motor_enabled', True) and
              any(abs(float(u)) > 1e-6 for u in x.get('motor_volts') or [])]
    moving = [x for x in tail if abs(float(x['v'])) >= REST_V or abs(float(x['w'])) >= 0.02]
    if driven or moving:
        res.failures.append(f'motor fault not latched: in the last {FAULT_HOLD_S:g} s of the '
                            f'commands {len(driven)} sample(s) drive the motors, {len(moving)} '
                            f'move')


TURNED_RAD = 0.1     # rad of heading: a robot turning in place has been driven (the rim of a
#                     wheel 0.2 m from the centre has moved 2 cm, as ``travelled`` asks)


def turned(s: list[dict[str, Any]]) -> float:
    """Return the heading change summed over the samples ``s`` (rad, each step wrapped)."""
    total = 0.0
    for a, b in zip(s, s[1:], strict=False):
        d = float(b['theta']) - float(a['theta'])
        total += abs(math.atan2(math.sin(d), math.cos(d)))
    return total


def _judge_estop_release(res: Result, s: list[dict[str, Any]]) -> None:
    """Judge the e-stop release: no motion once the contact closes (no reset, command live).

    The contact (``estop_open`` on ground truth) must have opened while the robot was being
    driven (it had moved, or turned: a turn in place travels nowhere), then closed; from the
    closing sample on, the robot stays at rest.
    """
    i_open = next((i for i, x in enumerate(s) if x.get('estop_open')), None)
    if i_open is None:
        res.failures.append('e-stop: the contact never opened during the drive')
        return
    if float(s[i_open]['travelled']) < 0.02 and turned(s[:i_open + 1]) < TURNED_RAD:
        res.failures.append('e-stop: the contact opened before the robot moved or turned (the '
                            'stack came up late): the release under a live command was not '
                            'exercised')
        return
    i_close = next((i for i in range(i_open, len(s)) if not s[i].get('estop_open')), None)
    if i_close is None:
        res.failures.append('e-stop: the contact never closed again during the drive')
        return
    end = res.cmd_end_ns
    if end is not None and int(s[i_close]['t_ns']) > end:
        res.failures.append('e-stop: the contact closed after the commands ended: the release '
                            'under a live command was not exercised')
        return
    # the robot may still be coasting when the contact closes: from its rest on
    i_rest = next((i for i in range(i_close, len(s)) if abs(float(s[i]['v'])) < REST_V
                   and abs(float(s[i]['w'])) < TURNING_W), None)
    if i_rest is None:
        res.failures.append('e-stop: never at rest after the release')
        return
    after = s[i_rest:]
    moved = float(after[-1]['travelled']) - float(after[0]['travelled'])
    v_max = max(abs(float(x['v'])) for x in after)
    w_max = max(abs(float(x['w'])) for x in after)
    held = (int(after[-1]['t_ns']) - int(s[i_close]['t_ns'])) / 1e9
    if moved > STAY_M or v_max >= REST_V or w_max >= TURNING_W:
        res.failures.append(f'e-stop release restarted motion: {moved:.3f} m, up to '
                            f'{v_max:.3f} m/s, {w_max:.3f} rad/s with no reset')
    elif held < 1.0:
        res.failures.append(f'e-stop: only {held:.2f} s observed after the release')


def _judge_stop(sc: Scenario, res: Result, b: Bounds, raw: dict[str, Any],
                s: list[dict[str, Any]]) -> None:
    trig = trigger(sc, s, raw, b.t_react)
    if trig is None:
        early = _stopped_before_the_line(sc, s, raw)
        if early is None:
            res.failures.append(f'stop ({sc.stop}): its trigger never happened')
        elif early:
            res.failures.append(f'stop ({sc.stop}): its trigger never happened; {early}')
        return
    t0, travelled0, _ = trig       # its speed: the guard judge uses each sample's own
    # The simulator stamps when the robot came to rest (1 ms steps): the first sample
    # after the trigger that reports rest says since when, whatever the sampling jitter.
    i_rest = next((i for i, x in enumerate(s)
                   if x['t_ns'] >= t0 and x.get('rest_since_ns') is not None), None)
    if i_rest is None:
        res.failures.append(f'stop ({sc.stop}): never at rest after the trigger')
        return
    rest = s[i_rest]
    res.stop_s = max(int(rest['rest_since_ns']) - t0, 0) / 1e9
    res.stop_m = max(float(rest['travelled']) - travelled0, 0.0)
    if b.t_react is not None:
        _judge_guard_stop(res, b, raw, s, i_rest, t0)
    if b.stop_s is not None and res.stop_s > b.stop_s:
        res.failures.append(f'stop took {res.stop_s:.3f} s > bound {b.stop_s:.3f} s')
    if b.stays_stopped:
        after = s[i_rest:]
        moved = float(after[-1]['travelled']) - float(rest['travelled'])
        v_max = max(abs(float(x['v'])) for x in after)
        held_s = (int(after[-1]['t_ns']) - int(rest['t_ns'])) / 1e9
        if moved > STAY_M or v_max >= REST_V:
            res.failures.append(f'stop ({sc.stop}): moved again after the stop ({moved:.3f} m, '
                                f'up to {v_max:.3f} m/s)')
        elif held_s < 1.0:
            res.failures.append(f'stop ({sc.stop}): at rest only {held_s:.2f} s before the run '
                                f'ended: staying stopped not shown')


def _stopped_before_the_line(sc: Scenario, s: list[dict[str, Any]],
                             raw: dict[str, Any]) -> str | None:
    """Judge a guard stop that never crossed its line: the robot stood still short of it.

    The guard sizes its line from its own readings, which the obstacle memory keeps at the
    nearest a sensor reported (noise, the sonar's arc, a pose from the reading's acquisition),
    so at the slow floor it may stop a few cm before the judge's exact line: safe, and the
    promise at rest holds. Accepted when the robot stood still (forward speed below
    ``REST_V``) inside the guard's own release band -- d(``slow_floor``) + ``release_margin``
    + the judge's margin + ``MEMORY_BIAS_M`` -- and never stood inside ``stop_distance``;
    None when it never stood still after the start (the plain "never happened"), else what is
    wrong, e.g. a stop for nothing far before the line. '' when accepted.

    Standing still, not the last pose: a command that turns goes on in place after the stop,
    the face swings away, and the guard may release a creep along the arc
    (wall.cruise.turning stood at 0.452 m and ended 0.489 m from the wall; wall.slow.turning
    stood at 0.43 m, turned, and was creeping on when the run ended).
    """
    if sc.stop not in ('sonar', 'laser') or not s:
        return None
    first = next((i for i, x in enumerate(s) if float(x['travelled']) > STAY_M), None)
    if first is None:
        return None
    still = [float(x['front_clearance']) for x in s[first:] if abs(float(x['v'])) < REST_V]
    if not still:
        return None
    g = guard_params(raw)
    band = stop_line(raw, g.slow_floor) + g.release_margin + STOP_MARGIN_M + MEMORY_BIAS_M
    nearest = min(still)
    if nearest < g.stop_distance:
        return (f'stood {nearest:.3f} m from the obstacle, inside stop_distance '
                f'{g.stop_distance:.3f} m')
    if nearest > band:
        return (f'stood still {nearest:.3f} m from the obstacle at its nearest, before the '
                f"guard's release band (<= {band:.3f} m): a stop short of its line")
    return ''


INTRUSION_M = 0.01   # m the gap may close beyond the robot's travel in one sample (noise)


def _deepest(s: list[dict[str, Any]], raw: dict[str, Any], b: Bounds,
             i_rest: int) -> tuple[tuple[float, float, float, str] | None, bool]:
    """Return the worst passage past the stop line and whether any was an intrusion.

    The worst is ``(measure m, v m/s, allowed m, kind)``. The depth of a ground-truth sample is
    how far the exact front clearance is inside the stop line at the true speed of that moment.
    A passage is a run of samples inside the line. One the robot drove into: its measure is its
    deepest depth, allowed ``v t_react + STOP_MARGIN_M`` at that sample's speed (kind
    ``'reach'``). One entered by the gap closing more than ``INTRUSION_M`` beyond the robot's
    own travel since the previous sample is an *intrusion* -- an obstacle that stepped in
    inside the line (a person at 1 m/s) or walks towards the robot fast; the guard sizes its
    line by its own speed only, so it is held to the straight-approach stopping distance from
    that moment: its measure is the travel to rest, allowed :meth:`Bounds.stop_distance` (kind
    ``'intrusion'``). The worst is None when the robot never got past the line.
    """
    worst: tuple[float, float, float, str] | None = None

    def keep(c: tuple[float, float, float, str]) -> None:
        nonlocal worst
        if worst is None or c[0] - c[2] > worst[0] - worst[2]:
            worst = c

    entry: tuple[float, float, bool] | None = None     # (travelled, v, intrusion)
    prev: dict[str, Any] | None = None
    intruded = False
    for x in s[:i_rest + 1]:
        v = abs(float(x['v']))
        depth = stop_line(raw, v) - float(x['front_clearance'])
        if entry is not None and entry[2]:
            continue           # an intrusion is held from its moment to rest (below)
        if depth <= 0.0:
            entry, prev = None, x
            continue
        if entry is None:
            # the gap closed by more than the robot drove since the last sample: the
            # obstacle moved in (stepped into the band, or walks towards the robot)
            moved_in = prev is not None and (
                float(prev['front_clearance']) - float(x['front_clearance']) >
                float(x['travelled']) - float(prev['travelled']) + INTRUSION_M)
            entry = (float(x['travelled']), v, moved_in)
            intruded = intruded or moved_in
        prev = x
        if not entry[2]:
            keep((depth, v, b.reach(v), 'reach'))
    if entry is not None and entry[2]:
        keep((float(s[i_rest]['travelled']) - entry[0], entry[1],
              b.stop_distance(entry[1]) or 0.0, 'intrusion'))
    return worst, intruded


def _judge_guard_stop(res: Result, b: Bounds, raw: dict[str, Any], s: list[dict[str, Any]],
                      i_rest: int, t0: int) -> None:
    """Judge a guard stop (sonar / laser) on ground truth: two obligations.

    1. **In time.** The robot never gets further past the stop line at its true speed ``v``
       of the moment than its sensors' reaction lets it: ``v t_react + STOP_MARGIN_M``
       (:meth:`Bounds.reach`, t_react the guard's own: no slack it does not take); where an
       obstacle stepped in past the line, it stops within the straight-approach stopping
       distance from then (:func:`_deepest`). Once the guard sees the line crossed it brakes,
       the speed falls and the line with it faster than the gap closes. The speed is the
       instantaneous one: with the slow-down zone the robot comes in on a falling speed riding
       the line, and a line sized by an earlier, higher speed would hold that approach to a
       stopping distance it never had to keep.
    2. **The promise.** It comes to rest no nearer than the guard's ``stop_distance`` less
       ``STOP_MARGIN_M`` -- static and moving obstacles alike. A moving obstacle is taken
       where it was at the trigger (``t0``) as well as where it is at rest, and the larger of
       the two gaps counts: what the obstacle itself walked towards the robot after the guard
       had to act is not the guard's, but the robot's own travel is. Waived only after an
       intrusion (an obstacle stepped in inside the line: nobody can keep stop_distance from
       it; the intrusion rule above applies instead).
    """
    worst, intruded = _deepest(s, raw, b, i_rest)
    if worst is not None:
        measure, v_at, allowed, kind = worst
        res.stop_m, res.stop_bound_m = measure, allowed
        if measure > allowed and kind == 'reach':
            res.failures.append(f'went {measure:.3f} m past the stop line at {v_at:.2f} m/s > '
                                f'{allowed:.3f} m (v t_react + margin: t_react '
                                f'{b.t_react:.3f} s)')
        elif measure > allowed:
            res.failures.append(f'an obstacle stepped in past the stop line at {v_at:.2f} m/s '
                                f'and the robot went {measure:.3f} m on > {allowed:.3f} m '
                                f'(v t_react + v^2 / 2a + margin: t_react '
                                f'{b.t_react:.3f} s, a {b.a_brake:.2f} m/s^2)')
    else:
        res.stop_m, res.stop_bound_m = 0.0, b.reach(res.peak_speed)
    if intruded:
        return
    g = guard_params(raw)
    rest = s[i_rest]
    at_rest = float(rest['front_clearance'])
    at_trigger = next((x for x in s if int(x['t_ns']) >= t0), rest)
    if at_trigger.get('obstacle_offsets') != rest.get('obstacle_offsets'):
        scene = Scene(raw, lateral=g.lateral_margin)
        at_rest = max(at_rest, scene.front_clearance(
            float(rest['x']), float(rest['y']), float(rest['theta']),
            at_trigger.get('obstacle_offsets') or []))
    if at_rest < g.stop_distance - STOP_MARGIN_M:
        res.failures.append(f'came to rest {at_rest:.3f} m from the obstacle ahead: inside the '
                            f"guard's stop_distance {g.stop_distance:.3f} m (less the judge's "
                            f'{STOP_MARGIN_M:.3f} m margin)')


def _m(v: float | None) -> float:
    """Return a truth clearance in m (null: nothing there, inf)."""
    return math.inf if v is None else float(v)


def _peak_decel(s: list[dict[str, Any]]) -> float:
    """Return the peak braking deceleration (m/s^2, >= 0) on ground truth.

    The simulator's own peak since the previous sample when it reports one, else the
    difference of the true speed between consecutive samples.
    """
    peaks = [float(x['peak_decel']) for x in s if x.get('peak_decel') is not None]
    if peaks:
        return max(0.0, max(peaks))
    best = 0.0
    for a, c in zip(s, s[1:], strict=False):
        dt = (int(c['t_ns']) - int(a['t_ns'])) / 1e9
        if dt <= 0:
            continue
        va, vc = float(a['v']), float(c['v'])
        if abs(vc) < abs(va) and va * vc >= 0:     # slowing down, not reversing
            best = max(best, (abs(va) - abs(vc)) / dt)
    return best


def trigger(sc: Scenario, s: list[dict[str, Any]], raw: dict[str, Any],
             t_react: float | None = None) -> tuple[int, float, float] | None:
    """Return (ns, travelled m, v m/s) when the robot had to start stopping (ground truth).

    Guard stops: the sample where the judge's exact front clearance first falls below the
    guard's stop line, interpolated (linear in travelled) back to the crossing between that
    sample and the one before. The line is sized by the highest true speed over the preceding
    reaction time (``t_react``, the cause's), not the instantaneous one: once a guard brakes,
    its speed -- and with it the instantaneous d(v) -- shrinks faster than the gap, so a guard
    that tripped a few mm early (its sensors read a little short, it sizes d(v) by the larger
    of commanded and measured speed) would never "cross" an instantaneous line at all. The
    obligation is: within d(v) of the obstacle at the speed it was driving, the robot must be
    braking; a guard acting late still crosses the line at full speed and is held to it.
    """
    if sc.stop in ('sonar', 'laser'):
        prev = None
        window_ns = int(max(t_react or 0.0, SAMPLE_S) * 1e9)
        recent: list[tuple[int, float]] = []
        for x in s:
            v = abs(float(x['v']))
            t_x = int(x['t_ns'])
            recent.append((t_x, v))
            while recent and recent[0][0] < t_x - window_ns:
                recent.pop(0)
            v = max(u for _, u in recent)
            line = stop_line(raw, v)
            fc = x['front_clearance']
            if fc < line:
                if prev is None or not prev['front_clearance'] > fc:
                    return int(x['t_ns']), float(x['travelled']), v
                k = (prev['front_clearance'] - line) / (prev['front_clearance'] - fc)
                k = min(max(k, 0.0), 1.0)
                t = int(prev['t_ns'] + k * (int(x['t_ns']) - int(prev['t_ns'])))
                tr = float(prev['travelled']) + k * (float(x['travelled']) -
                                                      float(prev['travelled']))
                vv = max(abs(float(prev['v'])), v)
                return t, tr, vv
            prev = x
        return None
    if sc.stop in ('sonar_unplugged', 'laser_unplugged'):
        want = 'sonar' if sc.stop == 'sonar_unplugged' else 'lrf'
        for x in s:
            for e in x.get('events', []):
                if e['unplug'] == want:
                    return int(e['t_ns']), float(x['travelled']), abs(float(x['v']))
        return None
    want = 'bridge' if sc.stop == 'bridge_killed' else 'driver_host'
    hit = next((x for x in s if x.get('killed') == want), None)
    return None if hit is None else (int(hit['kill_ns']), float(hit['travelled']),
                                     abs(float(hit['v'])))
