"""The guard's obstacle memory: what a sensor saw ahead, kept until a sensor sees it gone (pure).

The guard used to act on the latest readings only, so an obstacle that left every sensor's view
was forgotten: a black chair leg the sonar had stopped the robot for left the narrow near end
of the 15 deg cone, the laser got error codes from it, and the guard released and drove into it
(issue 39). The memory keeps what the sensors reported inside the front corridor as points in
the odometry frame, so they stay where they are in the world while the robot moves (the
actuator's own odometry carries them), and the guard takes their nearest gap ahead of the front
face like a reading.

**Forgotten only when seen free**, by a sensor that can see that place: the sonar when its
cone covers the point and the echo is farther than it (or there is none); the
laser when every beam through the point's disc returns a valid longer range or code 0 (nothing
within range). Never because nobody reports it, and never by a laser error code (1-19: the
step measured nothing, so it cannot say the place is free; docs/sensor-outcomes.md).

**A sonar echo has no bearing**: it is the nearest surface anywhere in the cone. It is kept as
the part of the echo's arc that lies in the corridor, a row of points at most ``2 SONAR_RADIUS``
apart with both ends on the cone's edge (or the corridor's), so the object lies between two
neighbouring points. As the robot closes in, points leave the narrowing cone outermost first:
the point outward of the object leaves before the object does and can no longer be freed by
the sonar, the one inward of it is freed once the object is out of the cone. The laser frees a
sonar point only when every beam within ``2 SONAR_RADIUS`` of it (the whole gap to its
neighbour, so the object is within it) returns a valid longer range: a black leg returns
codes, so the point beside it stays. (A thin glass object that left the cone is forgotten that
way: the laser sees through it -- the one case the memory cannot hold; sensor-outcomes.md.)

**Bounded**: ``capacity`` points in preallocated lists; no allocation per call. A point seen
again within ``MERGE`` of a kept point of the same sensor is already known: it takes no slot, and
the kept point stays where it is.
When full, the point farthest from the robot is replaced (the least urgent to the forward
guard; counted in ``evicted``). No age limit: a still obstacle is no less there for being
old, and no age is safe for one the sensors cannot see again.
"""

from __future__ import annotations

import math

__all__ = ['LASER', 'LASER_RADIUS', 'MERGE', 'NONE', 'ObstacleMemory', 'SONAR', 'SONAR_RADIUS',
           'scan_frees', 'URG_FAR_CODE', 'URG_MIN_MM']

NONE = 0
SONAR = 1
LASER = 2
SONAR_RADIUS = 0.05   # m, a sonar arc point's disc: points 0.1 m apart along the arc
LASER_RADIUS = 0.03   # m, a laser point's disc: odometry drift over a stop, a beam's width
MERGE = 0.05          # m, a new point this close to a kept one of the same sensor is known
FREE_TOLERANCE = 0.02  # m, a reading must be this much beyond a point to call it free (the
#                       US-100's and the URG's few cm of noise); the disc is *across* the
#                       point, so it does not lengthen this
URG_MIN_MM = 20       # SCIP 2.0: values below 20 are error codes, not ranges
URG_FAR_CODE = 0      # "possibly at 22 m": no echo within the URG's range, so free to its max


def scan_frees(value: int, beyond_mm: float, lo_mm: float, hi_mm: float) -> bool:
    """Return whether a URG step value says its beam is free out to ``beyond_mm``.

    Code 0 (nothing within range) is free; the other codes (1-19: low intensity, strong
    reflection, errors on neighbouring steps, non-measurable) measured nothing: not free. A
    range is free beyond ``beyond_mm`` when it is a measurement (``lo_mm``..``hi_mm``) past it.
    """
    if value == URG_FAR_CODE:
        return True
    if value < URG_MIN_MM or value < lo_mm or value > hi_mm:
        return False
    return value > beyond_mm


class ObstacleMemory:
    """Up to ``capacity`` obstacle points in the odometry frame (see the module notes)."""

    __slots__ = ('capacity', 'x', 'y', 'r', 'src', 'used', 'added', 'merged', 'evicted',
                 'freed', 'left')

    def __init__(self, capacity: int) -> None:
        if isinstance(capacity, bool) or not isinstance(capacity, int) or capacity < 1:
            raise ValueError(f'memory capacity must be an int >= 1, got {capacity!r}')
        self.capacity = capacity
        self.x = [0.0] * capacity
        self.y = [0.0] * capacity
        self.r = [0.0] * capacity
        self.src = [NONE] * capacity
        self.used = 0        # points kept now
        self.added = 0       # points taken into a free or evicted slot
        self.merged = 0      # readings that refreshed a kept point
        self.evicted = 0     # points replaced because the memory was full
        self.freed = 0       # points a sensor saw free
        self.left = 0        # points dropped as out of reach (forget_beyond)

    def clear(self) -> None:
        """Forget every point (a pose reset moves the odometry frame under them)."""
        for i in range(self.capacity):
            self.src[i] = NONE
        self.used = 0

    def add(self, x: float, y: float, radius: float, src: int, px: float, py: float) -> None:
        """Keep the point (``x``, ``y``) (odometry frame) seen by ``src``; robot at (px, py)."""
        cap = self.capacity
        sx = self.x
        sy = self.y
        kinds = self.src
        free = -1
        far = -1
        far_d = -1.0
        for i in range(cap):
            k = kinds[i]
            if k == NONE:
                if free < 0:
                    free = i
                continue
            dx = sx[i] - x
            dy = sy[i] - y
            if k == src and dx * dx + dy * dy <= MERGE * MERGE:
                # already known within the disc: kept where it is (moving it would let a row
                # of sightings walk a point away from the object it stands for)
                self.merged += 1
                return
            dx = sx[i] - px
            dy = sy[i] - py
            d = dx * dx + dy * dy
            if d > far_d:
                far_d = d
                far = i
        if free < 0:
            free = far
            self.evicted += 1
        else:
            self.used += 1
        sx[free] = x
        sy[free] = y
        self.r[free] = radius
        kinds[free] = src
        self.added += 1

    def _forget(self, i: int) -> None:
        self.src[i] = NONE
        self.used -= 1
        self.freed += 1

    def forget_beyond(self, px: float, py: float, radius: float) -> None:
        """Drop the points farther than ``radius`` from (px, py): out of a user's reach.

        For a memory whose user can only meet points that near (the turn guard's sweep): the
        points are not seen free, so they count in ``left``, not ``freed``.
        """
        if self.used == 0:
            return
        r2 = radius * radius
        kinds = self.src
        for i in range(self.capacity):
            if kinds[i] == NONE:
                continue
            dx = self.x[i] - px
            dy = self.y[i] - py
            if dx * dx + dy * dy > r2:
                kinds[i] = NONE
                self.used -= 1
                self.left += 1

    def add_sonar_arc(self, rng: float, sensor_x: float, half_angle: float, half_width: float,
                      pose_x: float, pose_y: float, pose_yaw: float) -> None:
        """Keep the corridor's part of a sonar echo at ``rng`` from the sonar (robot frame x).

        The sonar looks along the robot's x axis from (``sensor_x``, 0); the arc spans the
        cone (``half_angle``) clipped to the corridor (|y| <= ``half_width``), sampled at most
        ``2 SONAR_RADIUS`` apart with both ends included. Each point is ``rng`` ahead of the
        sonar, the gap the guard takes from a sonar reading itself (off the axis the true x
        is shorter by r - sqrt(r^2 - y^2): 2.3 cm for a leg 0.13 m off the axis 0.39 m away).
        """
        if not (rng > 0.0) or rng == math.inf:
            return
        ymax = rng * math.sin(half_angle)
        if ymax > half_width:
            ymax = half_width
        n = int(math.ceil(ymax / (2.0 * SONAR_RADIUS)))   # segments each side of the axis
        c = math.cos(pose_yaw)
        s = math.sin(pose_yaw)
        for j in range(-n, n + 1):
            ly = ymax * j / n if n else 0.0
            lx = sensor_x + rng   # the range ahead, as the guard reads the sonar itself
            self.add(pose_x + c * lx - s * ly, pose_y + s * lx + c * ly, SONAR_RADIUS, SONAR,
                     pose_x, pose_y)

    def add_robot_point(self, lx: float, ly: float, src: int, radius: float, pose_x: float,
                        pose_y: float, pose_yaw: float) -> None:
        """Keep a point given in the robot frame at the pose it was seen from."""
        c = math.cos(pose_yaw)
        s = math.sin(pose_yaw)
        self.add(pose_x + c * lx - s * ly, pose_y + s * lx + c * ly, radius, src, pose_x,
                 pose_y)

    def free_by_sonar(self, rng: float, sensor_x: float, half_angle: float, pose_x: float,
                      pose_y: float, pose_yaw: float) -> None:
        """Forget points in the cone nearer than the echo ``rng`` by more than their disc.

        ``rng`` inf: no echo within range (every covered point nearer than the sonar's reach
        is free; the caller passes the reach as ``rng`` then).
        """
        if self.used == 0:
            return
        c = math.cos(pose_yaw)
        s = math.sin(pose_yaw)
        sx0 = pose_x + c * sensor_x
        sy0 = pose_y + s * sensor_x
        kinds = self.src
        for i in range(self.capacity):
            if kinds[i] == NONE:
                continue
            dx = self.x[i] - sx0
            dy = self.y[i] - sy0
            fx = c * dx + s * dy           # in the sonar's frame
            fy = -s * dx + c * dy
            d = math.hypot(fx, fy)
            if d + FREE_TOLERANCE >= rng or fx <= 0.0:
                continue
            if abs(math.atan2(fy, fx)) <= half_angle:
                self._forget(i)

    def free_by_scan(self, sensor_x: float, angle_min: float, angle_increment: float,
                     range_min: float, range_max: float, ranges_mm: tuple[int, ...] | list[int],
                     pose_x: float, pose_y: float, pose_yaw: float) -> None:
        """Forget points every beam through whose disc is free beyond it (sonar points: 2 x)."""
        n = len(ranges_mm)
        if self.used == 0 or n == 0 or angle_increment <= 0.0:
            return
        c = math.cos(pose_yaw)
        s = math.sin(pose_yaw)
        lx0 = pose_x + c * sensor_x
        ly0 = pose_y + s * sensor_x
        lo = range_min * 1000.0
        hi = range_max * 1000.0
        kinds = self.src
        for i in range(self.capacity):
            k = kinds[i]
            if k == NONE:
                continue
            dx = self.x[i] - lx0
            dy = self.y[i] - ly0
            fx = c * dx + s * dy
            fy = -s * dx + c * dy
            d = math.hypot(fx, fy)
            rad = self.r[i] if k == LASER else 2.0 * self.r[i]
            if d <= rad:
                continue
            a = math.atan2(fy, fx)
            w = math.asin(rad / d)
            j0 = math.ceil((a - w - angle_min) / angle_increment)
            j1 = math.floor((a + w - angle_min) / angle_increment)
            if j0 < 0 or j1 >= n or j1 < j0:
                continue      # not (wholly) in the scan: the laser cannot see it free
            beyond = (d + FREE_TOLERANCE) * 1000.0
            for j in range(j0, j1 + 1):
                if not scan_frees(ranges_mm[j], beyond, lo, hi):
                    break
            else:
                self._forget(i)

    def nearest(self, front_x: float, half_width: float, pose_x: float, pose_y: float,
                pose_yaw: float) -> float:
        """Return the smallest gap (m) ahead of the front face to a kept point, inf if none.

        A point counts when its disc reaches into the corridor (|y| - radius <= half_width)
        and is not behind the front face; the gap is measured to the point itself, as the
        readings' gaps are: the disc stands for where *across* the point the object may be (a
        sonar echo's bearing; a beam's width), not for a shorter range.
        """
        if self.used == 0:
            return math.inf
        c = math.cos(pose_yaw)
        s = math.sin(pose_yaw)
        best = math.inf
        kinds = self.src
        xs = self.x
        ys = self.y
        rs = self.r
        for i in range(self.capacity):
            if kinds[i] == NONE:
                continue
            dx = xs[i] - pose_x
            dy = ys[i] - pose_y
            fy = -s * dx + c * dy
            rad = rs[i]
            if abs(fy) - rad > half_width:
                continue
            gap = c * dx + s * dy - front_x
            if gap + rad < 0.0:
                continue      # behind the front face: not in the way of forward motion
            if gap < best:
                best = gap
        if best == math.inf:
            return best
        return best if best > 0.0 else 0.0
