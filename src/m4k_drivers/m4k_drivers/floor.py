"""Floor patches: the tyre-floor friction under each drive wheel (a wet patch under one wheel).

``world.floor`` is a list of rectangles, each with its own friction; a wheel whose contact point
(on the axle, half the track to its side) is inside a patch grips with that patch's ``mu`` and
slides with its ``mu_kinetic``; elsewhere the robot's (``world.robot.mu``, ``mu_kinetic``). The
last patch listed wins where patches overlap::

    floor:
      - {rectangle: [1.0, -0.5, 2.0, 0.0], mu: 0.15, mu_kinetic: 0.1}   # water on tiles
      - {rectangle: [0.0, -2.0, 6.0, 2.0], mu: 0.6, grade_deg: 4.8, downhill_deg: 0.0}  # a ramp

Wet smooth tiles: mu 0.1-0.3; polished concrete: 0.4-0.5 (docs/sim-physics.md). A patch may
slope: ``grade_deg`` (a wheelchair ramp is at most 4.8 deg, 1:12) falling toward the world
direction ``downhill_deg``. Where base_link is on it, gravity pulls the body along its heading
with ``m g sin(grade) cos(yaw - downhill)`` (:func:`grade_force`), and the body stands tilted
on it (:func:`tilt`: what the simulated IMU reports); the pull across the heading (the tyres
hold it) and the load's cos(grade) are not modelled. Each key is declared once, in
:data:`PATCH`.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any

from m4k_rt.schema import ConfigError, Field, REQUIRED, validate_tree

__all__ = ['FloorError', 'grade_force', 'PATCH', 'Patch', 'parse_floor', 'tilt', 'wheel_mu']


class FloorError(ConfigError):
    """Raise for a bad ``world.floor`` entry; the message names the field."""


PATCH: dict[str, Field] = {
    'rectangle': Field('float[]', REQUIRED, 'The patch [xmin, ymin, xmax, ymax] in the world '
                       'frame.', unit='m', length=4),
    'mu': Field('float', REQUIRED, 'Static tyre friction on the patch.', lo=0, lo_open=True,
                hi=1.5),
    'mu_kinetic': Field('float', None, 'Sliding friction on the patch (<= mu); null: mu.',
                        lo=0, lo_open=True, hi=1.5, nullable=True),
    'grade_deg': Field('float', 0.0, 'The patch slopes this steeply (0: level).', unit='deg',
                       lo=0, hi=15.0),
    'downhill_deg': Field('float', 0.0, 'The world-frame direction the slope falls toward '
                          '(0: +x).', unit='deg', lo=-360.0, hi=360.0),
}


@dataclass(frozen=True)
class Patch:
    """One floor patch: an axis-aligned rectangle and its friction."""

    xmin: float
    ymin: float
    xmax: float
    ymax: float
    mu: float
    mu_kinetic: float
    grade: float = 0.0           # rad
    downhill: float = 0.0        # rad, world frame

    def contains(self, x: float, y: float) -> bool:
        """Return True when (x, y) is on the patch."""
        return self.xmin <= x <= self.xmax and self.ymin <= y <= self.ymax


def parse_floor(data: Any, where: str = 'world.floor') -> tuple[Patch, ...]:
    """Return the patches of a ``floor:`` list (errors name the entry and field)."""
    if data is None:
        return ()
    if not isinstance(data, list):
        raise FloorError(where, f'expected a list of patches, got {data!r}')
    out = []
    for i, entry in enumerate(data):
        at = f'{where}[{i}]'
        v = validate_tree(PATCH, entry, at, FloorError)
        x0, y0, x1, y1 = (float(c) for c in v['rectangle'])
        if not (x1 > x0 and y1 > y0):
            raise FloorError(f'{at}.rectangle', f'expected xmin < xmax and ymin < ymax, got '
                             f'{v["rectangle"]!r}')
        mu = float(v['mu'])
        mk = mu if v['mu_kinetic'] is None else float(v['mu_kinetic'])
        if mk > mu:
            raise FloorError(f'{at}.mu_kinetic', f'must be <= mu ({mu!r}), got {mk!r}')
        out.append(Patch(x0, y0, x1, y1, mu, mk, math.radians(float(v['grade_deg'])),
                         math.radians(float(v['downhill_deg']))))
    return tuple(out)


def wheel_mu(patches: tuple[Patch, ...], x: float, y: float, yaw: float, half_track: float,
             mu: float, mu_kinetic: float) -> tuple[float, float, float, float]:
    """Return (static left, static right, kinetic left, kinetic right) under the two wheels.

    ``x, y, yaw``: the robot's pose (base_link on the axle); ``mu``/``mu_kinetic`` off the
    patches.
    """
    out = [mu, mu, mu_kinetic, mu_kinetic]
    s, c = math.sin(yaw), math.cos(yaw)
    for side, sign in ((0, 1.0), (1, -1.0)):         # the left wheel is at +y in base_link
        wx, wy = x - sign * half_track * s, y + sign * half_track * c
        for patch in patches:
            if patch.contains(wx, wy):
                out[side], out[2 + side] = patch.mu, patch.mu_kinetic
    return out[0], out[1], out[2], out[3]


def grade_force(patches: tuple[Patch, ...], x: float, y: float, yaw: float,
                weight_n: float) -> float:
    """Return gravity's pull along the heading (N, + forward) where base_link is at (x, y).

    Off every slope: 0.
    """
    patch = _slope_at(patches, x, y)
    if patch is None:
        return 0.0
    return weight_n * math.sin(patch.grade) * math.cos(yaw - patch.downhill)


def _slope_at(patches: tuple[Patch, ...], x: float, y: float) -> Patch | None:
    """Return the sloping patch under (x, y): the last one listed that holds it (None: level)."""
    for patch in reversed(patches):
        if patch.grade and patch.contains(x, y):
            return patch
    return None


def tilt(patches: tuple[Patch, ...], x: float, y: float, yaw: float) -> tuple[float, float]:
    """Return base_link's (roll, pitch) in rad where it stands at (x, y) heading ``yaw``.

    REP-103 angles (fixed axes x, y, z; roll positive with the left side up, pitch positive
    with the nose down), of a body whose z axis is the slope's normal and whose heading is
    ``yaw``: with ``a = yaw - downhill``, ``roll = asin(sin(grade) sin(a))`` and ``pitch =
    atan2(sin(grade) cos(a), cos(grade))`` -- facing downhill the nose is down by the grade,
    across the slope the uphill side is up by it. The same patch as :func:`grade_force`;
    off every slope: level.
    """
    patch = _slope_at(patches, x, y)
    if patch is None:
        return 0.0, 0.0
    a = yaw - patch.downhill
    sg = math.sin(patch.grade)
    return math.asin(sg * math.sin(a)), math.atan2(sg * math.cos(a), math.cos(patch.grade))
