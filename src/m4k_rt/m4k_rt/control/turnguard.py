"""Turn guard: the rotation's share of the collision guard (pure).

The forward guard watches the strip the front face sweeps driving straight. A turn sweeps
something else: the outline rotates about base_link (the axle's midpoint), and its corners --
the body's at 0.265 m, the wheels' at 0.247 m -- swing through space beside and behind the
robot that no straight corridor covers. A chair leg beside the front corner is hit by a turn
toward it at any speed (issue 39, hazard C14). This module caps the yaw rate each way so the
robot can always stop turning before its outline, inflated by ``guard.lateral_margin``, meets
a point the laser saw:

* **Where the sweep can reach.** Only points within the outline's radius plus the margin can
  be met by a turn (:attr:`SweepTable.reach`). The lrf task hands the guard every laser point
  that near (:func:`near_points`, thinned along the scan); the actuator keeps them in a
  memory of their own in the odometry frame (:mod:`m4k_rt.control.memory`), freed only when
  the laser sees the place free, so a point stays known after it leaves the laser's 240 deg
  view as the robot turns away from it. A point farther than ``reach`` from the robot cannot
  be met by a turn and is dropped.
* **The free angle each way.** For a point at radius rho and bearing phi in base_link, a turn
  of theta counter-clockwise carries it to bearing phi - theta. :class:`SweepTable` tabulates
  once, per radius ring and bearing sector, whether the point is within the margin of the
  outline, and how many sectors each way the nearest such sector lies: two lookups per point
  per cycle. A point already inside the margin (a wall 3 cm beside the wheel) is measured
  against the outline itself plus ``CONTACT_MARGIN``, so the robot may still turn where the
  geometry allows -- and not at all where it does not.
* **The cap, like the forward guard's.** The angle needed to stop from yaw rate w is
  w t_react + w^2 / (2 alpha_brake), with the forward guard's t_react (a point may appear as
  late as a forward one) and alpha_brake = brake_deceleration / (track / 2) (the wheels brake
  at a_brake in opposite senses). A turn whose stop angle exceeds the free angle that way is
  stopped at once (cap 0 that way, applied after the ramp: the drive brakes). Otherwise the
  target rate is capped at the inverse of the stop angle with the angular ramp's deceleration,
  so the ramp can follow, never below ``floor`` (the rate at which the outline's farthest
  corner moves at ``guard.slow_floor``). A stop holds until the free angle exceeds the floor's
  stop angle plus ``release_margin`` at the corner.

What it does not cover: a point the laser never saw -- the rear 120 deg is blind, so a turn
sweeps the rear corners into space only the memory can vouch for, and only for what the robot
saw before (it drove past it, or faced it) -- and a black surface (error codes measure
nothing). Arcs at speed are the forward guard's: its corridor is straight (docs/safety.md).
"""

from __future__ import annotations

import math
from typing import Any, Sequence

from m4k_rt.control.footprint import outline_of
from m4k_rt.control.guard import speed_for_distance
from m4k_rt.control.memory import NONE, ObstacleMemory, URG_MIN_MM
from m4k_rt.control.params import ControlParams

__all__ = ['CONTACT_MARGIN', 'make_turn_guard', 'near_points', 'SweepTable', 'turn_outline',
           'turn_reach', 'TurnGuard']

CONTACT_MARGIN = 0.01    # m: inside the margin, the turn may go on to this near the outline
RING = 0.01              # m, the table's radial step
SECTORS = 360            # the table's bearing steps (1 deg: 4.6 mm at the body's corner)
NEAR_SPACING = 0.03      # m, the thinning of near points along the scan


def _seg_distance(px: float, py: float, ax: float, ay: float, bx: float, by: float) -> float:
    dx = bx - ax
    dy = by - ay
    den = dx * dx + dy * dy
    t = 0.0 if den == 0.0 else ((px - ax) * dx + (py - ay) * dy) / den
    t = 0.0 if t < 0.0 else 1.0 if t > 1.0 else t
    return math.hypot(px - ax - t * dx, py - ay - t * dy)


def _inside(px: float, py: float, poly: Sequence[tuple[float, float]]) -> bool:
    inside = False
    n = len(poly)
    for i in range(n):
        ax, ay = poly[i]
        bx, by = poly[(i + 1) % n]
        if (ay > py) != (by > py) and px < ax + (py - ay) * (bx - ax) / (by - ay):
            inside = not inside
    return inside


def _clearance(px: float, py: float, poly: Sequence[tuple[float, float]]) -> float:
    """Return the distance from the point to the outline, 0 inside it."""
    if _inside(px, py, poly):
        return 0.0
    n = len(poly)
    return min(_seg_distance(px, py, *poly[i], *poly[(i + 1) % n]) for i in range(n))


class SweepTable:
    """Free turn angles of a point near the outline, tabulated by radius ring and bearing.

    ``ccw[k][j]``: how far (rad) the robot can turn counter-clockwise before a point in ring k
    (radius k RING .. (k + 1) RING) and sector j (bearing -pi + j 2 pi / SECTORS ..) comes
    within ``margin`` of the outline, over every position in the cell (so the cell's worst);
    ``math.inf`` when no turn brings it that near. ``cw`` likewise clockwise. A cell already
    within the margin has 0 both ways.
    """

    __slots__ = ('margin', 'reach', 'rings', 'ccw', 'cw', 'blocked')

    def __init__(self, outline: Sequence[tuple[float, float]], margin: float) -> None:
        if not (math.isfinite(margin) and margin >= 0.0) or len(outline) < 3:
            raise ValueError(f'sweep table needs an outline and a margin >= 0, got {margin!r}')
        self.margin = margin
        radius = max(math.hypot(x, y) for x, y in outline)
        self.reach = radius + margin
        self.rings = int(math.ceil(self.reach / RING)) + 1
        step = 2.0 * math.pi / SECTORS
        self.blocked: list[list[bool]] = []
        for k in range(self.rings):
            rho = (k + 0.5) * RING
            # half the cell's diagonal: a cell is within the margin when any of it may be
            slack = math.hypot(RING / 2.0, (k + 1) * RING * step / 2.0)
            row = []
            for j in range(SECTORS):
                phi = -math.pi + (j + 0.5) * step
                row.append(_clearance(rho * math.cos(phi), rho * math.sin(phi), outline)
                           < margin + slack)
            self.blocked.append(row)
        self.ccw = [self._free(row, -1) for row in self.blocked]
        self.cw = [self._free(row, 1) for row in self.blocked]

    @staticmethod
    def _free(row: list[bool], sense: int) -> list[float]:
        """Return, per sector, the turn before a blocked sector (a ccw turn walks j down)."""
        step = 2.0 * math.pi / SECTORS
        n = len(row)
        if not any(row):
            return [math.inf] * n
        # m(j): sectors from j to the nearest blocked one walking in ``sense``; one pass the
        # other way round the ring, starting at a blocked sector
        start = row.index(True)
        out = [0.0] * n
        m = 0
        for step_no in range(n):
            j = (start - sense * step_no) % n
            m = 0 if row[j] else m + 1
            # the point may sit anywhere in its sector and the blocked one may begin at its
            # near edge: m sectors apart is at least (m - 1) sectors of turn
            out[j] = (m - 1) * step if m > 1 else 0.0
        return out

    def cell(self, rho: float, phi: float) -> tuple[int, int]:
        """Return the (ring, sector) of a point at ``rho``, bearing ``phi`` (ring -1: beyond)."""
        k = int(rho / RING)
        if k >= self.rings:
            return -1, 0
        j = int((phi + math.pi) * SECTORS / (2.0 * math.pi))
        if j >= SECTORS:
            j = SECTORS - 1
        elif j < 0:
            j = 0
        return k, j


def near_points(angle_min: float, angle_increment: float, range_min: float, range_max: float,
                ranges_mm: Sequence[int], radius: float, laser_x: float) -> tuple[float, ...]:
    """Return the scan's valid points within ``radius`` of base_link (x0, y0, ...; robot frame).

    Consecutive points closer than ``NEAR_SPACING`` to the last one kept are left out (a wall
    beside the robot is a row of points, not a hundred); error codes are not points. The
    laser sits at (``laser_x``, 0) looking along x.
    """
    lo = max(range_min * 1000.0, URG_MIN_MM)
    hi = range_max * 1000.0
    # a beam can reach the disc only if its range is below radius + |laser_x|
    limit = min(hi, (radius + abs(laser_x)) * 1000.0)
    r2 = radius * radius
    sp2 = NEAR_SPACING * NEAR_SPACING
    out: list[float] = []
    last_x = last_y = math.inf
    for i, r in enumerate(ranges_mm):
        if r < lo or r > limit:
            continue
        a = angle_min + i * angle_increment
        x = laser_x + r * 0.001 * math.cos(a)
        y = r * 0.001 * math.sin(a)
        if x * x + y * y > r2:
            continue
        if (x - last_x) ** 2 + (y - last_y) ** 2 < sp2:
            continue
        out.append(x)
        out.append(y)
        last_x = x
        last_y = y
    return tuple(out)


class TurnGuard:
    """Cap the yaw rate each way from the near points (see the module notes)."""

    __slots__ = ('enabled', 'keep', 'contact', 'reaction_time', 'brake', 'slow', 'floor',
                 'release', 'ccw_free', 'cw_free', 'ccw_cap', 'cw_cap', 'ccw_held', 'cw_held',
                 'stops', 'slowing', 'reach')

    def __init__(self, outline: Sequence[tuple[float, float]], *, enabled: bool,
                 margin: float, reaction_time: float, angular_brake: float,
                 angular_slow: float, floor: float, release: float) -> None:
        """Take the outline, the margin and the stop law's figures (rad, rad/s, rad/s^2)."""
        for name, value in (('reaction_time', reaction_time), ('floor', floor),
                            ('release', release)):
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'turn guard {name} must be a finite number >= 0, got {value!r}')
        for name, value in (('angular_brake', angular_brake), ('angular_slow', angular_slow)):
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f'turn guard {name} must be a finite number > 0, got {value!r}')
        self.enabled = bool(enabled)
        self.keep = SweepTable(outline, margin)
        self.contact = SweepTable(outline, min(CONTACT_MARGIN, margin))
        self.reach = self.keep.reach
        self.reaction_time = reaction_time
        self.brake = angular_brake
        self.slow = angular_slow
        self.floor = floor
        self.release = release
        self.stops = 0            # turns stopped (either way)
        self.reset()

    def reset(self) -> None:
        """Forget the free angles and the holds."""
        self.ccw_free = self.cw_free = math.inf
        self.ccw_cap = self.cw_cap = math.inf
        self.ccw_held = self.cw_held = False
        self.slowing = False

    def stop_angle(self, w: float) -> float:
        """Return the turn (rad) needed to stop from yaw rate ``w`` at alpha_brake."""
        w = abs(w)
        return w * self.reaction_time + w * w / (2.0 * self.brake)

    def free_angles(self, memories: Sequence[ObstacleMemory], x: float, y: float,
                    yaw: float) -> tuple[float, float]:
        """Return the free turn (ccw, cw) in rad at pose (x, y, yaw) from the memories' points."""
        ccw = cw = math.inf
        c = math.cos(yaw)
        s = math.sin(yaw)
        reach2 = self.reach * self.reach
        keep = self.keep
        contact = self.contact
        for mem in memories:
            if mem.used == 0:
                continue
            kinds = mem.src
            xs = mem.x
            ys = mem.y
            for i in range(mem.capacity):
                if kinds[i] == NONE:
                    continue
                dx = xs[i] - x
                dy = ys[i] - y
                if dx * dx + dy * dy > reach2:
                    continue
                fx = c * dx + s * dy
                fy = -s * dx + c * dy
                rho = math.hypot(fx, fy)
                k, j = keep.cell(rho, math.atan2(fy, fx))
                if k < 0:
                    continue
                if keep.blocked[k][j]:
                    # inside the margin already: as far as the outline itself allows (a ring
                    # beyond the contact table's reach is never met within CONTACT_MARGIN)
                    if k < contact.rings:
                        a = contact.ccw[k][j]
                        b = contact.cw[k][j]
                    else:
                        a = b = math.inf
                else:
                    a = keep.ccw[k][j]
                    b = keep.cw[k][j]
                if a < ccw:
                    ccw = a
                if b < cw:
                    cw = b
        return ccw, cw

    def evaluate(self, memories: Sequence[ObstacleMemory], x: float, y: float, yaw: float,
                 w_now: float, blind: bool = False) -> None:
        """Set ``ccw_cap`` / ``cw_cap`` (rad/s, >= 0; inf: none) for the yaw rate ``w_now``.

        ``blind``: the laser is stale under the fail-safe policy (no scan yet, or too old): no
        turn either way, as the forward guard stops forward motion then -- the memory alone
        cannot say what came near since.
        """
        if not self.enabled:
            self.ccw_cap = self.cw_cap = math.inf
            self.slowing = False
            return
        if blind:
            self.ccw_cap = self.cw_cap = 0.0
            self.slowing = True
            return
        ccw, cw = self.free_angles(memories, x, y, yaw)
        self.ccw_free = ccw
        self.cw_free = cw
        self.ccw_cap, self.ccw_held = self._cap(ccw, w_now if w_now > 0.0 else 0.0,
                                                self.ccw_held)
        self.cw_cap, self.cw_held = self._cap(cw, -w_now if w_now < 0.0 else 0.0,
                                              self.cw_held)
        self.slowing = (self.ccw_cap != math.inf or self.cw_cap != math.inf)

    def _cap(self, free: float, w: float, held: bool) -> tuple[float, bool]:
        if free == math.inf:
            return math.inf, False
        if held:
            if free > self.stop_angle(self.floor) + self.release:
                held = False
        elif w > 0.0 and self.stop_angle(w) > free:
            held = True
            self.stops += 1
        if held:
            return 0.0, True
        cap = speed_for_distance(free, self.reaction_time, self.slow, 0.0)
        if cap < self.floor:
            cap = self.floor if free > self.stop_angle(self.floor) else 0.0
        return cap, False


def turn_outline(params: ControlParams, robot: Any) -> tuple[tuple[float, float], ...] | None:
    """Return the robot's outline (``m4k_rt.control.footprint``), None without a body.

    A bare test config without a ``robot.body`` has no outline: no turn guard (stated by the
    start-up plan).
    """
    try:
        return outline_of(robot, params.track_width, params.wheel_radius)
    except ValueError:
        return None


def turn_reach(params: ControlParams, robot: Any) -> float:
    """Return how near base_link a point must be for a turn to meet it (m; 0: no outline)."""
    shape = turn_outline(params, robot)
    if shape is None:
        return 0.0
    return max(math.hypot(x, y) for x, y in shape) + params.guard.lateral_margin


def make_turn_guard(params: ControlParams, robot: Any, reaction_time: float) -> TurnGuard:
    """Build the turn guard from ``control:`` and the robot's outline (the forward t_react).

    alpha_brake: the wheels brake at ``guard.brake_deceleration`` in opposite senses, so the
    yaw rate falls at a_brake / (track / 2). The ramp's deceleration is the angular axis's.
    The floor and the release are the forward guard's, taken at the outline's farthest corner.
    """
    g = params.guard
    shape = turn_outline(params, robot)
    if shape is None:     # no body declared: nothing to sweep
        shape = ((0.0, 0.0), (0.0, 0.0), (0.0, 0.0))
    corner = max(math.hypot(x, y) for x, y in shape)
    per_m = 1.0 / corner if corner > 0.0 else 0.0
    slow = params.angular.max_deceleration
    if slow is None:
        slow = params.angular.max_acceleration
    return TurnGuard(shape, enabled=g.enabled and g.use_laser and corner > 0.0,
                     margin=g.lateral_margin,
                     reaction_time=reaction_time,
                     angular_brake=g.brake_deceleration / (params.track_width / 2.0),
                     angular_slow=slow, floor=g.slow_floor * per_m,
                     release=g.release_margin * per_m)
