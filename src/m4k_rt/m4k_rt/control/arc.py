"""The arc corridor: the forward guard's view of the band a turning robot sweeps (pure).

The forward guard's corridor is straight: the strip ahead of the front face. Driving an arc of
radius R the robot sweeps a curved band instead, and a thin leg on that arc enters the straight
strip only when it is about sqrt(2 R w) ahead (w the corridor's half width): 1.05 m on a 2 m
arc, where a robot at 1 m/s needs 1.5 m to stop (issue 39, hazard C17). The guard therefore
also measures the gaps along the arc the robot is on:

* **The band.** With the instantaneous centre of rotation (ICR) at (0, R) in base_link
  (R = v / w, positive to the left), the outline plus the lateral margin sweeps the annulus
  ``|R| - w <= rho <= sqrt((|R| + w)^2 + f^2)`` about the ICR (w the corridor's half width, f
  the front face's x: the outer front corner swings widest).
* **The gap.** A point in the band at angle psi about the ICR (from the robot, in the sense of
  travel) is met by the front face once the robot has turned psi - asin(f / rho) about the
  ICR: base_link then has driven ``|R| (psi - asin(f / rho))`` along its arc -- the distance the
  guard compares with its stop zone d(v), as it compares a straight gap. Points beside or
  behind the front face (angle below asin(f / rho)) are not ahead: the straight guard's rule.
  Only the half circle ahead counts (the guard re-evaluates every cycle).
* **Where the points come from.** The lrf task keeps, per scan, the nearest point along each of
  the arcs of :data:`CURVATURES` (:func:`arc_points`); the actuator files them in the obstacle
  memory with the corridor's lanes, and every cycle takes the memory's nearest gap along the
  arc of the motion *and* of the command (:func:`nearest_on_arc`), beside the straight gap:
  the guard is never less careful than the straight corridor alone.

Curvatures below :data:`STRAIGHT` are the straight corridor's (the lateral drift over the
guard's longest stop zone stays under a centimetre); above the largest, the motion is mostly a
turn, which the turn guard covers (:mod:`m4k_rt.control.turnguard`).
"""

from __future__ import annotations

import math
from typing import Sequence

from m4k_rt.control.memory import NONE, ObstacleMemory, URG_MIN_MM

__all__ = ['arc_gap', 'arc_points', 'CURVATURES', 'curvature', 'DRIFT', 'HORIZON', 'MIN_SPEED',
           'nearest_on_arc', 'SAME', 'STRAIGHT']

# 1/m: the arcs the laser's nearest points are kept for (radii 8, 4, 2, 1 and 0.5 m each way)
CURVATURES = (-2.0, -1.0, -0.5, -0.25, -0.125, 0.125, 0.25, 0.5, 1.0, 2.0)
STRAIGHT = 0.002   # 1/m: |kappa| below this is straight (3.3 m ahead: 1 cm of drift)
HORIZON = 1.0      # m beyond the stop zone: memory points farther are not looked at
MIN_SPEED = 0.1    # m/s: slower is no arc: a heading correction while creeping up to a stop
#                    line (w 0.02 rad/s at the 0.05 m/s slow floor) is a 2.5 m "arc" that
#                    only moves the stop a few mm; a turn at a creep is the turn guard's
SAME = 0.01        # 1/m: curvatures this close share one band (3 mm apart at 1.5 m)
DRIFT = 0.02       # m: an arc drifting less over the stop zone is straight (the lateral
#                    margin, 5 cm, covers it)


def curvature(v: float, w: float, stop_zone: float = math.inf) -> float:
    """Return the arc's curvature w / v (1/m) within the kept arcs' range; 0: straight or none.

    Slower than ``MIN_SPEED`` forward (a turn in place, reversing) is 0; so is an arc that
    drifts less than ``DRIFT`` from the straight line over ``stop_zone`` (m, the guard's d(v);
    inf: no such allowance): the lateral margin covers it, and a heading correction is no arc
    (read as one, it moved the stop in front of a person a few cm, out of the judge's band).
    Gentler than
    ``STRAIGHT`` is 0 as well; tighter than the tightest kept arc is taken as it.
    """
    if v <= MIN_SPEED:
        return 0.0
    k = w / v
    a = k if k >= 0.0 else -k
    if a < STRAIGHT or a * stop_zone * stop_zone < 2.0 * DRIFT:
        return 0.0
    top = CURVATURES[-1]
    if k > top:
        return top
    if k < -top:
        return -top
    return k


def arc_gap(px: float, py: float, kappa: float, half_width: float, front: float) -> float:
    """Return the base_link path length before the front face meets (px, py); inf if never.

    Robot frame (x forward, y left); ``kappa`` = w / v (1/m, positive: turning left), not 0.
    """
    r = 1.0 / kappa
    ar = abs(r)
    # the point about the ICR (0, r); mirror a right turn onto a left one
    qy = py if r > 0.0 else -py
    dy = ar - qy
    rho2 = px * px + dy * dy
    inner = ar - half_width
    if inner > 0.0 and rho2 < inner * inner:
        return math.inf
    outer = ar + half_width
    if rho2 > outer * outer + front * front:
        return math.inf
    rho = math.sqrt(rho2)
    psi = math.atan2(px, dy)          # from the robot's radius, in the sense of travel
    if psi < 0.0:
        return math.inf               # the half circle behind
    lead = math.asin(front / rho) if rho > front else math.pi / 2.0
    if psi < lead:
        return math.inf               # beside or behind the front face: not ahead of it
    return ar * (psi - lead)


def arc_points(angle_min: float, angle_increment: float, range_min: float, range_max: float,
               ranges_mm: Sequence[int], laser_x: float, half_width: float,
               front: float) -> tuple[float, ...]:
    """Return the scan's nearest point along each arc of :data:`CURVATURES` (x0, y0, ...).

    Robot frame; the laser at (``laser_x``, 0) looking along x. Arcs without a point in their
    band are left out. Error codes are not points (the straight corridor's unknown covers
    what the laser cannot measure ahead).
    """
    lo = max(range_min * 1000.0, URG_MIN_MM)
    hi = range_max * 1000.0
    xs: list[float] = []
    ys: list[float] = []
    for i, r in enumerate(ranges_mm):
        if lo <= r <= hi:
            a = angle_min + i * angle_increment
            x = laser_x + r * 0.001 * math.cos(a)
            if x > 0.0:
                xs.append(x)
                ys.append(r * 0.001 * math.sin(a))
    out: list[float] = []
    for kappa in CURVATURES:
        best = math.inf
        bx = by = 0.0
        for x, y in zip(xs, ys, strict=True):
            g = arc_gap(x, y, kappa, half_width, front)
            if g < best:
                best, bx, by = g, x, y
        if best != math.inf:
            out.append(bx)
            out.append(by)
    return tuple(out)


def nearest_on_arc(mem: ObstacleMemory, kappa: float, half_width: float, front: float,
                   pose_x: float, pose_y: float, pose_yaw: float, horizon: float) -> float:
    """Return the memory's smallest gap along the arc ``kappa`` at the pose (inf if none).

    Points farther than ``horizon`` (m) from the robot are not looked at (beyond any stop
    zone). A point's disc counts across the band, as the straight corridor counts it.
    """
    if mem.used == 0:
        return math.inf
    c = math.cos(pose_yaw)
    s = math.sin(pose_yaw)
    h2 = horizon * horizon
    best = math.inf
    kinds = mem.src
    xs = mem.x
    ys = mem.y
    rs = mem.r
    for i in range(mem.capacity):
        if kinds[i] == NONE:
            continue
        dx = xs[i] - pose_x
        dy = ys[i] - pose_y
        if dx * dx + dy * dy > h2:
            continue
        g = arc_gap(c * dx + s * dy, -s * dx + c * dy, kappa, half_width + rs[i], front)
        if g < best:
            best = g
    return best
