"""The RT base controller driving the simulated base in virtual time (no processes, no clock).

One actuator cycle every 10 ms of simulated time, as the RT actuator runs it: the motor handler
reads both AS5045 encoders over the simulated SPI bus and the controller takes the sample; the
IMU handler reads the myAHRS+ registers (the simulator's noise and bias) and the controller
takes the gyro's yaw rate; then command, step, and the WHEEL_CMD written to the two MCP4911
DACs, the enable bit feeding the heartbeat monostable as on the robot. The world is
``m4k_drivers.world.World``: the drive-train physics, faults, floor patches; its ground truth
(pose, speeds, travelled) is what a caller judges -- never the controller's own odometry.

Deterministic: the same world seed, the same run. Used by ``python -m m4k_bench.stopping``
(stopping distances) and by the closed-loop supervision tests.
"""

from __future__ import annotations

import collections
import math
import random
from typing import Any, Callable, Mapping

from m4k_drivers.drive import RobotParams
from m4k_drivers.imu import protocol as imu_p
from m4k_drivers.imu.handler import ImuHandler
from m4k_drivers.imu.real import I2cDevice
from m4k_drivers.imu.sim import FakeMyAhrsBus
from m4k_drivers.motors.handler import MotorHandler, WheelCommand
from m4k_drivers.motors.real import EnableLine, ReadbackLine
from m4k_drivers.motors.sim import EnableMonostable, EstopReadback, open_sim_bus
from m4k_drivers.world import World, WorldConfig
from m4k_rt.config import deep_merge, load_layered, shipped_period_s
from m4k_rt.control.base import BaseController
from m4k_rt.control.params import control_params
from m4k_rt.tasks.actuator import track_slope

__all__ = ['PERIOD_NS', 'VirtualBase']

# the actuator period, as the shipped configuration declares it (tasks.actuator.period_ms)
PERIOD_NS = round(shipped_period_s('actuator') * 1e9)
_NO_MOUNT = (1.0, 0.0, 0.0)      # base_link x in imu_link for an IMU mounted square in base_link


class _Clock:
    """Simulated CLOCK_MONOTONIC in ns, moved only by the loop."""

    def __init__(self) -> None:
        self.t = 0

    def __call__(self) -> int:
        return self.t


class VirtualBase:
    """World + motor and IMU handlers + the RT controller, stepped one actuator cycle at a time.

    ``world``: a ``world:`` overlay (robot, faults, floor, seed...); ``control``: a
    ``control:`` overlay over ``config/`` (e.g. supervision settings). ``imu``: feed the gyro
    to the controller (False: as with the IMU unplugged). ``imu_lag_s``: each gyro sample
    reaches the controller this long after it was taken, plus up to ``imu_jitter_s`` more
    (uniform, from the world's seed; in order): on the robot the gyro arrives one hop after
    the encoders (the IMU task's period, the driver host's I2C read), and under load tens
    of ms later. ``encoder_every``: the controller gets an encoder sample only every this many
    cycles (a driver host or RT process short of CPU, a stalled bus: samples every 3-10 cycles
    in starved test stacks); the DACs are written every cycle.
    """

    def __init__(self, world: Mapping[str, Any] | None = None,
                 control: Mapping[str, Any] | None = None, imu: bool = True,
                 heartbeat_hold_s: float = 0.05, imu_lag_s: float = 0.0,
                 imu_jitter_s: float = 0.0, encoder_every: int = 1) -> None:
        if encoder_every < 1:
            raise ValueError(f'encoder_every must be >= 1, got {encoder_every!r}')
        self._encoder_every = encoder_every
        self._cycles = 0
        cfg = load_layered()
        self.control = deep_merge(cfg.get('control') or {}, dict(control or {}))
        body = (cfg.get('robot') or {}).get('body')
        base = RobotParams.from_control(self.control, body)
        wcfg = deep_merge({'obstacles': [], 'walls': {'rectangle': [-30, -30, 30, 30]}},
                          dict(world or {}))
        self.clock = _Clock()
        self.world = World(WorldConfig.from_dict(wcfg, robot=base), clock=self.clock, t0_ns=0)
        self.mono = EnableMonostable(self.world, heartbeat_hold_s)

        def motor_bus() -> Any:
            bus = open_sim_bus(self.world)
            bus.enable = EnableLine(self.mono, 'sim:heartbeat')
            bus.readback = ReadbackLine(EstopReadback(self.world), 'sim:estop_readback')
            return bus
        self.motor = MotorHandler(motor_bus, clock=self.clock, period_s=PERIOD_NS * 1e-9,
                                  enable_hold_s=heartbeat_hold_s)
        self.motor.configure()
        self.motor.activate()
        self.imu: ImuHandler | None = None
        if imu:
            self.imu = ImuHandler(lambda: I2cDevice(FakeMyAhrsBus(self.world), imu_p.ADDRESS,
                                                    'sim:imu'))
            self.imu.configure()
            self.imu.activate()
        self.params = control_params(self.control)
        self._imu_lag_ns = round(imu_lag_s * 1e9)
        self._imu_jitter_ns = round(imu_jitter_s * 1e9)
        self._rng = random.Random(int((world or {}).get('seed', 0)))
        self._imu_queue: collections.deque[tuple[int, int, float, float]] = collections.deque()
        self._imu_last: tuple[int, float, int, float] | None = None   # (stamp, rate, rx, slope)
        self.ctl = BaseController(self.params, PERIOD_NS * 1e-9)

    @property
    def t(self) -> float:
        """Return the simulated time in seconds."""
        return self.clock.t * 1e-9

    def cycle(self, v: float | None, w: float = 0.0, forward_cap: float = math.inf,
              guard_active: bool = False) -> None:
        """Run one actuator cycle; ``v``/``w`` a fresh command (None: none this cycle)."""
        ctl, now = self.ctl, self.clock.t
        r = self.motor.read()
        self._cycles += 1
        if r.value is not None and self._cycles % self._encoder_every == 0:
            e = r.value
            ctl.encoders(e.left_angle, e.right_angle, e.t_ns, now, e.status)
        if self.imu is not None:
            s = self.imu.read()
            if s.value is not None and s.value.status == 0:
                stamp = self.imu.sample_ns or now
                due = stamp + self._imu_lag_ns + (
                    self._rng.randrange(self._imu_jitter_ns + 1) if self._imu_jitter_ns else 0)
                if self._imu_queue:
                    due = max(due, self._imu_queue[-1][0])
                # the simulated IMU sits in base_link: no mount to turn it by
                qx, qy, qz, qw = s.value.orientation
                self._imu_queue.append((due, stamp, s.value.angular_velocity[2],
                                        track_slope(qx, qy, qz, qw, _NO_MOUNT)))
            q = self._imu_queue
            while q and q[0][0] <= now:
                _, stamp, rate, slope = q.popleft()
                self._imu_last = (stamp, rate, now, slope)
            if self._imu_last is not None:
                # as the actuator: the newest sample arrived by now, once per cycle (an older
                # one delivered in the same cycle is overwritten, as in the IMU task's state)
                stamp, rate, rx, slope = self._imu_last
                ctl.imu(rate, rx, stamp, slope)
        if v is not None:
            ctl.command(v, w, now)
        ctl.step(now, forward_cap, guard_active)
        self.motor.write(WheelCommand(ctl.left_code, ctl.right_code, ctl.enable))
        self.clock.t += PERIOD_NS
        self.world.now()

    def run(self, seconds: float, v: float | None, w: float = 0.0,
            until: Callable[[], bool] | None = None, **kw: Any) -> float | None:
        """Run ``seconds``; return the time into the run at which ``until()`` first held."""
        for k in range(round(seconds * 1e9 / PERIOD_NS)):
            self.cycle(v, w, **kw)
            if until is not None and until():
                return (k + 1) * PERIOD_NS * 1e-9
        return None

    def at_rest(self) -> bool:
        """Return True when the ground truth says the body is at rest (|v| < 1 cm/s, |w|)."""
        st = self.world.state()
        return abs(st.v) < 0.01 and abs(st.w) < 0.01 and self.world.rest_since_ns is not None

    def faulted(self) -> bool:
        """Return True while the wheel supervision holds a latched fault."""
        return self.ctl.supervisor.latched

    def close(self) -> None:
        """Shut the handlers down (outputs safe)."""
        self.motor.shutdown()
        if self.imu is not None:
            self.imu.shutdown()
