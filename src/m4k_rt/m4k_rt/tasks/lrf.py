"""LRF task body (200 ms): request a scan, forward it to the bridge, feed the guard.

Ports: ``lrf`` (driver host: REQUEST out, LASER_SCAN and DEVICE_STATUS in) and ``lrf_out``
(bridge: LASER_SCAN out). Pipeline like the other device tasks: each cycle drains the scan
replying to the previous REQUEST (the URG-04LX takes 100 ms per scan, well inside the 200 ms
period), forwards it unchanged (its stamp and device stamp are the measurement's), computes
the smallest gap between the body's front face and a point in its swept corridor
(``control.guard.FrontCorridor``: the outline's half width -- the wheels stand outside the
body, ``control.footprint`` -- + ``control.guard.lateral_margin``) for the
actuator's collision guard, then sends this cycle's
REQUEST. A scan whose sector holds no valid point reports ``inf`` (nothing seen) but still
refreshes ``laser_rx_ns``: the laser is alive. ``laser_rx_ns`` is the scan's own stamp (the
URG stamps the start of its sweep: the oldest step; the driver host maps it onto
CLOCK_MONOTONIC), never later than now: the guard ages the scan from when it was taken, not
from when it arrived. The whole scan also goes to the guard as one
:class:`~m4k_rt.control.sightings.LaserSighting` in ``laser_sighting`` (its steps free memory
points, its nearest point per corridor lane is kept, and an error code in the corridor is
``unknown``), with the scan's points within a turn's reach of base_link for the turn guard
(``control.turnguard.near_points``).
"""

from __future__ import annotations

import time
from typing import Any, Callable, Mapping

from m4k_rt.config import TaskConfig
from m4k_rt.control.arc import arc_points
from m4k_rt.control.guard import body_front, front_offset, FrontCorridor, sensor_x
from m4k_rt.control.params import control_params
from m4k_rt.control.sightings import LaserSighting
from m4k_rt.control.turnguard import near_points, turn_reach
from m4k_rt.protocol import Kind
from m4k_rt.tasks.actuator import control_section, corridor_half_width, raw_section
from m4k_rt.tasks.interfaces import CycleContext, RtPort
from m4k_rt.tasks.portio import DeviceTaskBody
from m4k_rt.tasks.state import robot_state, RobotState

__all__ = ['LrfBody', 'make_lrf', 'SCAN_REQUEST']

SCAN_REQUEST = 1   # REQUEST.arg asking the lrf handler for one scan
_SCAN = Kind.LASER_SCAN


class LrfBody(DeviceTaskBody):
    """Per-cycle body of the LRF task."""

    def __init__(self, dev_sock: RtPort, out_sock: RtPort, state: RobotState,
                 half_width: float = 0.19,
                 clock: Callable[[], int] = time.monotonic_ns, front: float = 0.0,
                 laser_x: float = 0.0, near_reach: float = 0.0,
                 face_x: float = 0.0) -> None:
        super().__init__(dev_sock, out_sock, state, clock)
        self.sector = FrontCorridor(half_width, front)
        self.half_width = half_width
        self.face_x = face_x        # m, the front face's x on the robot (arc gaps)
        self.laser_x = laser_x      # m, the laser's x on the robot (lane points' frame)
        self.near_reach = near_reach  # m from base_link: points a turn can meet (0: none)
        self.scans = 0

    @property
    def counters(self) -> Mapping[str, int]:
        """Return a snapshot of the body's counters (NRT use)."""
        return {'cycles': self.cycles, 'scans': self.scans, 'unexpected': self.unexpected,
                'forwarded': self._out.sent, 'forward_dropped': self._out.dropped,
                'requests': self._dev_out.sent}

    def __call__(self, ctx: CycleContext | None = None) -> None:
        """Run one LRF cycle."""
        self._poll_device(ctx, _SCAN, 'lrf', SCAN_REQUEST)

    def _on_reading(self, hdr: Any, msg: Any, now: int) -> None:
        """Forward one scan and give the guard its front corridor's nearest point."""
        state = self.state
        sector = self.sector
        self._out.forward(self._dev_in.raw())
        gap = sector.minimum(msg.angle_min, msg.angle_increment, msg.range_min,
                             msg.range_max, msg.ranges)
        # the corridor's beams are measured some way into the sweep: date them by the middle
        # of their window (step i at stamp + i x time_increment)
        i0, i1 = sector.window(msg.angle_min, msg.angle_increment, len(msg.ranges))
        acq = hdr.stamp_ns + int((i0 + i1) * 0.5 * msg.time_increment * 1e9)
        if acq > now:
            acq = now
        self.scans += 1
        state.laser_sighting = LaserSighting(
            self.scans, acq, gap, sector.unknown, sector.lanes(self.laser_x),
            msg.angle_min, msg.angle_increment, msg.range_min, msg.range_max, msg.ranges,
            near_points(msg.angle_min, msg.angle_increment, msg.range_min, msg.range_max,
                        msg.ranges, self.near_reach, self.laser_x) if self.near_reach else (),
            arc_points(msg.angle_min, msg.angle_increment, msg.range_min, msg.range_max,
                       msg.ranges, self.laser_x, self.half_width, self.face_x))
        state.laser_front_min = gap
        # staleness from the sweep's start: the oldest step of the scan
        state.laser_rx_ns = hdr.stamp_ns if hdr.stamp_ns < now else now


def make_lrf(task: TaskConfig, ports: Mapping[str, RtPort], shared: Any) -> LrfBody:
    """Build the LRF body from its ``lrf``/``lrf_out`` ports and the guard's corridor."""
    params = control_params(control_section(task, shared))
    robot = raw_section(task, shared, 'robot')
    return LrfBody(ports['lrf'], ports['lrf_out'], robot_state(shared),
                   corridor_half_width(params, robot),
                   front=front_offset(robot, 'laser'), laser_x=sensor_x(robot, 'laser'),
                   near_reach=turn_reach(params, robot), face_x=body_front(robot))
