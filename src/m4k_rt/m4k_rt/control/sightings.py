"""What the sensor tasks hand the guard, and how the actuator files it in the memory (pure).

The sonar and lrf tasks each publish one immutable record per reading in the shared state (one
reference store, atomic under the GIL: the actuator never sees half of one reading and half of
the next), stamped with the reading's *acquisition* time on CLOCK_MONOTONIC:

* :class:`SonarSighting` -- the echo range ahead of the front face (inf: no echo within range)
  and the time of the ping (the reply's stamp less the echo's flight time);
* :class:`LaserSighting` -- the scan's stamp (the URG stamps the start of its sweep, the
  oldest step: m4k_drivers.lrf.stamp), its geometry and raw steps (for freeing memory points),
  the nearest corridor gap, the nearest point per lane of the corridor (robot frame) and
  whether a step inside the corridor carried an error code (unknown).

:class:`SightingFeed` (owned by the actuator, the memory's only writer) takes each new record
once: it looks up where the robot was when the reading was taken (:class:`PoseHistory`, the
actuator's own odometry of the last ``POSE_HISTORY`` cycles), frees the memory points the
reading sees free, then keeps what it saw. Per call it allocates nothing: the records are
built by the sensor tasks, the memory and the history are preallocated.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from m4k_rt.control.arc import curvature, HORIZON, nearest_on_arc, SAME
from m4k_rt.control.memory import LASER, LASER_RADIUS, ObstacleMemory

__all__ = ['LaserSighting', 'POSE_HISTORY', 'PoseHistory', 'SightingFeed', 'SonarSighting',
           'SPEED_OF_SOUND']

POSE_HISTORY = 128        # actuator cycles of pose kept (1.28 s at 10 ms: > the oldest scan used)
SPEED_OF_SOUND = 343.0    # m/s at 20 C: the echo's flight time dates the ping


class SonarSighting(NamedTuple):
    """One sonar reading as the guard takes it."""

    seq: int          # the sonar task's reading count (a new record has a new seq)
    acquired_ns: int  # CLOCK_MONOTONIC of the ping
    gap: float        # m ahead of the front face (inf: no echo within range)
    range_m: float    # m from the sonar (inf: no echo)


class LaserSighting(NamedTuple):
    """One laser scan as the guard takes it."""

    seq: int
    acquired_ns: int                # when its corridor beams were measured (mid window)
    gap: float                      # nearest corridor point ahead of the front face (inf: none)
    unknown: bool                   # a corridor step carried an error code 1-19
    lanes: tuple[float, ...]        # x0, y0, x1, y1, ...: nearest point per lane, robot frame
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: tuple[int, ...]         # the raw steps (mm; < 20: error codes)
    near: tuple[float, ...] = ()    # x0, y0, ...: points a turn can meet (robot frame,
    #                                 m4k_rt.control.turnguard.near_points)
    arcs: tuple[float, ...] = ()    # x0, y0, ...: the nearest point along each arc
    #                                 (robot frame, m4k_rt.control.arc.arc_points)


class PoseHistory:
    """The actuator's odometry pose of the last ``size`` cycles, looked up by time."""

    __slots__ = ('size', 't', 'x', 'y', 'yaw', 'head', 'count')

    def __init__(self, size: int = POSE_HISTORY) -> None:
        self.size = size
        self.t = [0] * size
        self.x = [0.0] * size
        self.y = [0.0] * size
        self.yaw = [0.0] * size
        self.head = -1
        self.count = 0

    def record(self, t_ns: int, x: float, y: float, yaw: float) -> None:
        """Keep the pose at ``t_ns`` (called once per actuator cycle)."""
        h = self.head + 1
        if h == self.size:
            h = 0
        self.head = h
        self.t[h] = t_ns
        self.x[h] = x
        self.y[h] = y
        self.yaw[h] = yaw
        if self.count < self.size:
            self.count += 1

    def at(self, t_ns: int) -> int:
        """Return the slot of the newest pose no later than ``t_ns`` (the oldest if none).

        Earlier, not nearer: driving forward, an earlier pose is further back, so a point
        placed from it lands nearer the robot than it is -- never further.
        """
        i = self.head
        n = self.count
        size = self.size
        ts = self.t
        while n > 1 and ts[i] > t_ns:
            i = i - 1 if i > 0 else size - 1
            n -= 1
        return i

    def rebase(self, c: float, s: float, tx: float, ty: float, dyaw: float) -> None:
        """Re-express every kept pose after the odometry frame moved (pose reset)."""
        for i in range(self.size):
            x = self.x[i]
            y = self.y[i]
            self.x[i] = c * x - s * y + tx
            self.y[i] = s * x + c * y + ty
            self.yaw[i] += dyaw


class SightingFeed:
    """File each new sonar / laser record in the obstacle memory (the actuator's helper)."""

    __slots__ = ('memory', 'history', 'sonar_x', 'laser_x', 'front_x', 'half_width',
                 'half_angle', 'sonar_reach', '_sonar_seq', '_laser_seq', 'sonar_taken',
                 'laser_taken', 'near', 'near_reach')

    def __init__(self, memory: ObstacleMemory, *, sonar_x: float, laser_x: float,
                 front_x: float, half_width: float, sonar_half_angle: float,
                 sonar_reach: float, near: ObstacleMemory | None = None,
                 near_reach: float = 0.0) -> None:
        self.memory = memory
        # the turn guard's points: what the laser saw within a turn's reach (own memory, so a
        # wall beside the robot never pushes the corridor's points out)
        self.near = near if near is not None else ObstacleMemory(1)
        self.near_reach = near_reach
        self.history = PoseHistory()
        self.sonar_x = sonar_x            # m, robot frame
        self.laser_x = laser_x
        self.front_x = front_x            # m, the front face
        self.half_width = half_width      # m, the corridor's half width
        self.half_angle = sonar_half_angle
        self.sonar_reach = sonar_reach    # m from the sonar: a no echo is free this far
        self._sonar_seq = -1
        self._laser_seq = -1
        self.sonar_taken = 0
        self.laser_taken = 0

    def take_sonar(self, rec: SonarSighting | None) -> None:
        """File a sonar record not taken before."""
        if rec is None or rec.seq == self._sonar_seq:
            return
        self._sonar_seq = rec.seq
        self.sonar_taken += 1
        h = self.history
        i = h.at(rec.acquired_ns)
        px = h.x[i]
        py = h.y[i]
        pyaw = h.yaw[i]
        rng = rec.range_m
        mem = self.memory
        mem.free_by_sonar(self.sonar_reach if rng == math.inf else rng, self.sonar_x,
                          self.half_angle, px, py, pyaw)
        if rng != math.inf:
            mem.add_sonar_arc(rng, self.sonar_x, self.half_angle, self.half_width, px, py,
                              pyaw)

    def take_laser(self, rec: LaserSighting | None) -> None:
        """File a laser record not taken before."""
        if rec is None or rec.seq == self._laser_seq:
            return
        self._laser_seq = rec.seq
        self.laser_taken += 1
        h = self.history
        i = h.at(rec.acquired_ns)
        px = h.x[i]
        py = h.y[i]
        pyaw = h.yaw[i]
        mem = self.memory
        mem.free_by_scan(self.laser_x, rec.angle_min, rec.angle_increment, rec.range_min,
                         rec.range_max, rec.ranges, px, py, pyaw)
        lanes = rec.lanes
        for k in range(0, len(lanes), 2):
            mem.add_robot_point(lanes[k], lanes[k + 1], LASER, LASER_RADIUS, px, py, pyaw)
        arcs = rec.arcs
        for k in range(0, len(arcs), 2):
            mem.add_robot_point(arcs[k], arcs[k + 1], LASER, LASER_RADIUS, px, py, pyaw)
        near = self.near
        pts = rec.near
        if pts or near.used:
            near.free_by_scan(self.laser_x, rec.angle_min, rec.angle_increment, rec.range_min,
                              rec.range_max, rec.ranges, px, py, pyaw)
            for k in range(0, len(pts), 2):
                near.add_robot_point(pts[k], pts[k + 1], LASER, LASER_RADIUS, px, py, pyaw)
            # out of a turn's reach now (the robot drove on): a turn cannot meet them
            h_now = h.head
            near.forget_beyond(h.x[h_now], h.y[h_now], self.near_reach + LASER_RADIUS)

    def nearest(self, x: float, y: float, yaw: float) -> float:
        """Return the memory's nearest gap ahead of the front face at pose (x, y, yaw)."""
        return self.memory.nearest(self.front_x, self.half_width, x, y, yaw)

    def nearest_on_arcs(self, v: float, w: float, cmd_v: float, cmd_w: float, x: float,
                        y: float, yaw: float, stop_zone: float) -> float:
        """Return the memory's nearest gap along the arc of the motion and of the command.

        (m4k_rt.control.arc) ``stop_zone``: d(v) now; points beyond it + ``HORIZON`` are not
        looked at. The command's arc is measured only when it bends differently from the
        motion's (one pass on a steady arc); inf when neither is an arc.
        """
        best = math.inf
        done = math.nan
        for k in (curvature(v, w, stop_zone), curvature(cmd_v, cmd_w, stop_zone)):
            if k != 0.0 and not abs(k - done) < SAME:
                done = k
                g = nearest_on_arc(self.memory, k, self.half_width, self.front_x, x, y, yaw,
                                   stop_zone + HORIZON)
                if g < best:
                    best = g
        return best

    def rebase(self, old: tuple[float, float, float], new: tuple[float, float, float]) -> None:
        """Carry the memory and the history into the odometry frame after a pose reset.

        The robot did not move: a world point that was at ``p`` in the old frame is at
        T_new T_old^-1 p in the new one.
        """
        dyaw = new[2] - old[2]
        c = math.cos(dyaw)
        s = math.sin(dyaw)
        tx = new[0] - (c * old[0] - s * old[1])
        ty = new[1] - (s * old[0] + c * old[1])
        self.history.rebase(c, s, tx, ty, dyaw)
        for m in (self.memory, self.near):
            for i in range(m.capacity):
                x = m.x[i]
                y = m.y[i]
                m.x[i] = c * x - s * y + tx
                m.y[i] = s * x + c * y + ty
