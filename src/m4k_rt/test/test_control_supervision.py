"""Wheel supervision against a simulated plant, in simulated time (no clocks, no processes).

The plant: two wheels answering DAC codes through the motor's first-order lag (80 ms), with
the drive's acceleration bounded (the amplifier's current limit / tyre traction), sampled by
12-bit encoders. Faults are injected between the wheels and the controller as the real ones
sit: an encoder that counts the wrong way, swapped encoder channels, a frozen frame (valid,
unchanging), a wheel that is blocked. Each must latch MOTOR_FAULT within 0.3 s of simulated
time from the moment the wheel is supervised (|setpoint| above the threshold) and the fault
acts; normal ramps, hard stops, slip and crawling must not trip it.
"""

import math

import pytest

from m4k_rt.control.base import BaseController, MODE_FAULT
from m4k_rt.control.dac import code_to_command
from m4k_rt.control.params import control_params
from m4k_rt.control.supervision import cause_text
from m4k_rt.control.trace import SupervisionTrace, TRACE_ROWS
from m4k_rt.protocol import (
    ENC_ESTOP_OPEN,
    FaultCause,
    ODOM_E_STOP,
    ODOM_ESTOP_OPEN,
    ODOM_HOLD,
    ODOM_MOTOR_FAULT,
    TRACE_FLOAT_FIELDS,
    TraceFlag,
)

MS = 1_000_000
PERIOD_NS = 10 * MS
R_WHEEL = 0.1016
COUNT = 2 * math.pi / 4096          # one 12-bit encoder count, rad
FF = 1.0 / 19.685                   # the PI's feed-forward gain (1 / full scale)


class Plant:
    """Wheels with a first-order lag and an acceleration bound; encoders with faults."""

    def __init__(self, full_scale: float, tau: float = 0.08, max_accel: float = 6.9,
                 slip: float = 0.0) -> None:
        self.full_scale = full_scale
        self.tau = tau
        self.max_dw = max_accel / R_WHEEL        # wheel rad/s^2 the drive can give
        self.slip = slip                         # extra wheel speed fraction (spinning tyre)
        self.speed = [0.0, 0.0]
        self.angle = [0.0, 0.0]
        self.flip = [False, False]
        self.swap = False
        self.frozen = [None, None]
        self.blocked = [False, False]
        self.peak = 0.0                          # peak rim speed, m/s

    def run(self, codes, dt: float, substeps: int = 10) -> None:
        h = dt / substeps
        for _ in range(substeps):
            for i in (0, 1):
                if self.blocked[i]:
                    self.speed[i] = 0.0
                    continue
                target = code_to_command(codes[i]) * self.full_scale * (1.0 + self.slip)
                dw = (target - self.speed[i]) * (h / self.tau)
                dw = max(-self.max_dw * h, min(self.max_dw * h, dw))
                self.speed[i] += dw
                self.angle[i] += self.speed[i] * h
                self.peak = max(self.peak, abs(self.speed[i]) * R_WHEEL)

    def read(self):
        out = []
        for i in (0, 1):
            a = math.floor(self.angle[i] / COUNT) * COUNT       # 12-bit quantization
            if self.flip[i]:
                a = -a
            if self.frozen[i] is not None:
                a = self.frozen[i]
            out.append(a)
        if self.swap:
            out.reverse()
        return out

    def freeze(self, i):
        self.frozen[i] = self.read()[i]


def make(**section):
    p = control_params(section or None)
    return BaseController(p, 0.01), p


class Sim:
    def __init__(self, **section):
        self.ctl, self.p = make(**section)
        self.plant = Plant(self.p.full_scale_wheel_speed)
        self.t = 0
        self.status = 0
        self.step()

    def step(self, cmd=None):
        self.t += PERIOD_NS
        left, right = self.plant.read()
        self.ctl.encoders(left, right, self.t, self.t, self.status)
        if cmd is not None:
            self.ctl.command(cmd[0], cmd[1], self.t)
        self.ctl.step(self.t)
        self.plant.run((self.ctl.left_code, self.ctl.right_code), 0.01)

    def run(self, seconds, cmd=None, until=None):
        """Step ``seconds`` of sim time (command every cycle); return the time ``until`` held."""
        for k in range(round(seconds / 0.01)):
            self.step(cmd)
            if until is not None and until():
                return (k + 1) * 0.01
        return None

    def supervised(self):
        th = self.p.supervision.speed_threshold
        return abs(self.ctl.left_setpoint) > th or abs(self.ctl.right_setpoint) > th

    def faulted(self):
        return bool(self.ctl.flags & ODOM_MOTOR_FAULT)


def _latch_time(sim, cmd, seconds=2.0):
    """Run until the wheel is supervised, then return the sim time to the fault latch."""
    if not sim.supervised():
        assert sim.run(2.0, cmd, sim.supervised) is not None
    return sim.run(seconds, cmd, sim.faulted)


def _assert_fault_outputs(sim):
    # a category-1 stop: the zero word with the enable on (the drive brakes), then off
    ctl = sim.ctl
    assert ctl.flags & ODOM_MOTOR_FAULT and ctl.mode == MODE_FAULT
    assert (ctl.left_code, ctl.right_code, ctl.enable) == (512, 512, 1)
    bound = sim.p.linear.max_velocity / sim.p.guard.brake_deceleration
    sim.run(bound + 0.02)
    assert ctl.flags & ODOM_MOTOR_FAULT and ctl.mode == MODE_FAULT
    assert (ctl.left_code, ctl.right_code, ctl.enable) == (512, 512, 0)


@pytest.mark.parametrize('wheel', [0, 1])
def test_sign_flipped_encoder_latches_within_0_3_s_while_cruising(wheel):
    sim = Sim()
    sim.run(2.0, (0.5, 0.0))
    assert not sim.faulted()
    sim.plant.flip[wheel] = True
    dt = _latch_time(sim, (0.5, 0.0))
    assert dt is not None and dt < 0.3, dt
    _assert_fault_outputs(sim)
    bit = FaultCause.LEFT_WRONG_WAY if wheel == 0 else FaultCause.RIGHT_WRONG_WAY
    assert sim.ctl.supervisor.cause & bit, cause_text(sim.ctl.supervisor.cause)


def test_sign_flipped_encoder_from_rest_never_runs_away():
    sim = Sim()
    sim.plant.flip[0] = True
    dt = _latch_time(sim, (0.5, 0.0))
    assert dt is not None and dt < 0.3, dt
    assert sim.plant.peak < 0.5, sim.plant.peak
    # latched: the outputs stay zero and disabled whatever is commanded
    sim.run(1.0, (0.5, 0.0))
    _assert_fault_outputs(sim)


def test_sign_flip_with_supervision_off_runs_away():
    # the negative control's premise: without supervision the PI turns positive feedback
    sim = Sim(supervision={'enabled': False})
    sim.plant.flip[0] = True
    sim.run(3.0, (0.5, 0.0))
    assert not sim.faulted()
    assert sim.plant.peak > 1.0, sim.plant.peak


def test_swapped_channels_latch_in_a_turn():
    sim = Sim()
    sim.run(2.0, (0.3, 0.6))
    assert not sim.faulted()
    sim.plant.swap = True
    dt = _latch_time(sim, (0.3, 0.6))
    assert dt is not None and dt < 0.3, dt
    _assert_fault_outputs(sim)


def test_swapped_channels_latch_turning_in_place():
    sim = Sim()
    sim.plant.swap = True
    dt = _latch_time(sim, (0.0, 1.0))
    assert dt is not None and dt < 0.3, dt
    _assert_fault_outputs(sim)


@pytest.mark.parametrize('wheel', [0, 1])
def test_frozen_encoder_latches(wheel):
    sim = Sim()
    sim.run(2.0, (0.5, 0.0))
    sim.plant.freeze(wheel)
    dt = _latch_time(sim, (0.5, 0.0))
    assert dt is not None and dt < 0.3, dt
    _assert_fault_outputs(sim)
    bit = FaultCause.LEFT_FROZEN if wheel == 0 else FaultCause.RIGHT_FROZEN
    assert sim.ctl.supervisor.cause & bit


def test_blocked_wheel_latches():
    sim = Sim()
    sim.run(2.0, (0.5, 0.0))
    sim.plant.blocked[1] = True
    dt = _latch_time(sim, (0.5, 0.0))
    assert dt is not None and dt < 0.3, dt
    _assert_fault_outputs(sim)


def test_stall_at_saturation_latches_even_when_the_encoder_flickers():
    # a blocked wheel whose encoder flickers one count, stalled at full output
    from m4k_rt.control.params import SupervisionParams
    from m4k_rt.control.supervision import WheelSupervisor
    sup = WheelSupervisor(SupervisionParams(), R_WHEEL, 0.40, FF)
    t = 0.0
    k = 0
    while not sup.latched and t < 1.0:
        k += 1
        sup.encoders(COUNT * (k % 2), 10.0 * k, k * 10_000_000)
        sup.step(0.01, 10.0, 10.0, 0.1, 10.0, 1.0, 10.0 * FF, True, False)
        t += 0.01
    # one count of flicker is no motion (FROZEN_COUNTS): the frozen test sees it first
    assert sup.cause in (FaultCause.LEFT_STALL, FaultCause.LEFT_FROZEN) and t < 0.3, \
        (sup.cause, t)


@pytest.mark.parametrize('cmd', [(0.5, 0.0), (2.0, 0.0), (-0.1, 0.0), (0.0, 1.5), (0.4, -0.8),
                                 (0.03, 0.0), (0.0, 0.12)])
def test_no_false_trip_on_ramps_stops_and_reversals(cmd):
    sim = Sim()
    sim.run(4.0, cmd)                        # accelerate and cruise
    sim.run(0.5, (0.0, 0.0))                 # ramp down
    sim.run(3.0, (-cmd[0], -cmd[1]))         # reverse through zero
    sim.run(1.0, None)                       # no command: timeout brake
    assert not sim.faulted(), cause_text(sim.ctl.supervisor.last_cause)
    assert sim.ctl.supervisor.faults == 0


def test_no_false_trip_on_a_hard_guard_stop_and_restart():
    sim = Sim()
    sim.run(6.0, (2.0, 0.0))
    for _ in range(50):                      # guard stop: zero cap, the ramp bypassed
        sim.t += PERIOD_NS
        left, right = sim.plant.read()
        sim.ctl.encoders(left, right, sim.t, sim.t)
        sim.ctl.command(2.0, 0.0, sim.t)
        sim.ctl.step(sim.t, 0.0, True)
        sim.plant.run((sim.ctl.left_code, sim.ctl.right_code), 0.01)
    sim.run(3.0, (2.0, 0.0))
    assert not sim.faulted(), cause_text(sim.ctl.supervisor.last_cause)


def test_no_false_trip_on_wheel_slip():
    sim = Sim()
    sim.plant.slip = 0.3                     # the tyres spin 30 % faster than the drive asks
    sim.plant.max_dw = 2.0 / R_WHEEL         # on a slippery floor, gently
    sim.run(4.0, (1.0, 0.3))
    sim.run(2.0, (0.2, -0.3))
    assert not sim.faulted(), cause_text(sim.ctl.supervisor.last_cause)


def test_reset_clears_the_fault_and_needs_a_fresh_command():
    sim = Sim()
    sim.plant.flip[0] = True
    assert _latch_time(sim, (0.5, 0.0)) is not None
    sim.plant.flip[0] = False
    sim.run(1.0, None)
    assert sim.faulted()                     # latched: nothing clears it by itself
    assert sim.ctl.reset_fault()
    sim.run(0.3, None)                       # the old command must not restart the robot
    assert not sim.faulted() and sim.ctl.flags & ODOM_HOLD
    assert sim.ctl.left_code == 512 and sim.ctl.v == 0.0
    sim.run(1.0, (0.3, 0.0))
    assert sim.ctl.v > 0.2 and not sim.faulted()
    assert not sim.ctl.reset_fault()         # nothing latched: reported as such


def test_open_e_stop_contact_resets_the_pi_and_latches_until_release_and_fresh_command():
    sim = Sim()
    sim.run(2.0, (0.5, 0.0))
    sim.status = ENC_ESTOP_OPEN              # contact open: the amplifier is cut, wheels coast
    sim.run(0.04, (0.5, 0.0))                # e_stop.contact_samples (5) in a row first
    for _ in range(100):
        sim.step((0.5, 0.0))
        ctl = sim.ctl
        assert ctl.flags & ODOM_ESTOP_OPEN and ctl.flags & ODOM_E_STOP
        assert ctl.left_code == ctl.right_code == 512 and ctl.enable == 1
        assert ctl.pi_left.integral == 0.0 and ctl.pi_right.integral == 0.0
    assert not sim.faulted()                 # not a motor fault: the wheels were cut off
    sim.status = 0                           # contact closed again: still latched
    sim.run(1.0, (0.5, 0.0))
    assert sim.ctl.flags & ODOM_E_STOP and sim.ctl.v == 0.0
    sim.ctl.e_stop(False)                    # the explicit release
    sim.run(0.5, None)
    assert sim.ctl.flags & ODOM_HOLD and sim.ctl.v == 0.0
    sim.run(1.0, (0.5, 0.0))                 # a fresh command drives again
    assert sim.ctl.v > 0.3


def test_a_short_estop_open_glitch_is_filtered():
    # fewer than e_stop.contact_samples samples: contact bounce, or the read-back glitch when
    # the heartbeat restarts -- not an e-stop
    sim = Sim()
    sim.run(2.0, (0.5, 0.0))
    sim.status = ENC_ESTOP_OPEN
    sim.run(0.04, (0.5, 0.0))
    sim.status = 0
    sim.run(0.5, (0.5, 0.0))
    assert not sim.ctl.flags & ODOM_E_STOP and sim.ctl.v == pytest.approx(0.5)


def test_no_false_trip_when_encoder_samples_come_late_and_bunched():
    """One reverse reading (a hard stop's rebound) then a ~90 ms gap of the driver host.

    The gap is shorter than motor_timeout (0.1 s), so the controller keeps stepping on the
    last reading; counting those repeats as time latched "wrong way" on healthy wheels under
    load (seen in make scenarios: low_obstacle, sonar_only_glass). Symptom time is encoder
    time now: the repeats stand still, the next samples (forward) clear it.
    """
    from m4k_rt.control.params import SupervisionParams
    from m4k_rt.control.supervision import WheelSupervisor
    sup = WheelSupervisor(SupervisionParams(), R_WHEEL, 0.40, FF)
    angle = [0.0, 0.0]
    stamp = [0]

    def sample(speed):
        for i in (0, 1):
            angle[i] += speed * 0.01
        stamp[0] += 10_000_000
        sup.encoders(angle[0], angle[1], stamp[0])

    sample(-0.6)                                   # the rebound, beyond min_speed (0.3)
    assert not sup.step(0.01, 2.0, 2.0, -0.6, -0.6, 2.0 * FF, 2.0 * FF, False, False)
    for _ in range(9):                             # 90 ms, no sample: the same old reading
        assert not sup.step(0.01, 2.0, 2.0, -0.6, -0.6, 2.0 * FF, 2.0 * FF, False, False)
    for _ in range(20):                            # samples again: the wheels go forward
        sample(1.0)
        assert not sup.step(0.01, 2.0, 2.0, 1.0, 1.0, 2.0 * FF, 2.0 * FF, False, False)
    assert sup.faults == 0 and not sup.latched


def test_a_flipped_encoder_still_latches_when_samples_are_bunched():
    """Samples every third cycle only (the driver host late): still latched within 0.3 s."""
    from m4k_rt.control.params import SupervisionParams
    from m4k_rt.control.supervision import WheelSupervisor
    sup = WheelSupervisor(SupervisionParams(), R_WHEEL, 0.40, FF)
    angle = 0.0
    for k in range(30):                            # 0.3 s of cycles, 10 samples
        if k % 3 == 0:
            angle -= 1.0 * 0.03                    # the left wheel reads backwards
            sup.encoders(angle, -angle, k * 10_000_000)
        if sup.step(0.01, 2.0, 2.0, -1.0, 1.0, 2.0 * FF, 2.0 * FF, False, False):
            break
    assert sup.latched and sup.cause & FaultCause.LEFT_WRONG_WAY


def test_the_supervisor_takes_its_settings_from_supervision_params():
    """The settings are SupervisionParams' own (declared once): nothing restated or copied."""
    from m4k_rt.control.params import SupervisionParams
    from m4k_rt.control.supervision import WheelSupervisor
    own = SupervisionParams(enabled=False, speed_threshold=1.5, swap_time=0.2)
    sup = WheelSupervisor(own, R_WHEEL, 0.40, FF)
    assert sup.p is own and not sup.enabled
    assert WheelSupervisor(SupervisionParams(), R_WHEEL, 0.40, FF).enabled == \
        SupervisionParams().enabled


def test_a_latch_freezes_the_supervisions_last_cycles_oldest_first():
    # What the supervision saw before a latch, for whoever has to explain it: the frozen
    # table ends with the latching cycle, its rows are the controller's own values.
    sim = Sim()
    sim.run(2.0, (0.5, 0.0))
    trace = sim.ctl.supervisor.trace
    assert trace.fault == 0 and trace.rows == 0          # nothing frozen before a fault
    sim.plant.flip[0] = True
    assert _latch_time(sim, (0.5, 0.0)) is not None
    ctl = sim.ctl
    assert (trace.fault, trace.cause) == (1, ctl.supervisor.cause)
    assert trace.rows == TRACE_ROWS                       # the ring was full: all of it
    rows = [trace.row(i) for i in range(trace.rows)]
    stamps = [t for t, _, _ in rows]
    assert stamps == sorted(stamps) and stamps[-1] == sim.t       # oldest first, ends at latch
    assert all(b - a == PERIOD_NS for a, b in zip(stamps, stamps[1:], strict=False))
    names = TRACE_FLOAT_FIELDS
    _, flags, last = rows[-1]
    value = dict(zip(names, last, strict=True))
    assert value['sp_left'] == pytest.approx(0.5 / R_WHEEL)       # the cruise's setpoint
    assert value['meas_left'] == ctl.left_speed
    assert value['angle_left'] == ctl.wheel_angles[0]
    assert value['t_wrong_left'] >= sim.p.supervision.wrong_way_time - 1e-9
    assert flags & TraceFlag.ENCODERS
    # the flipped wheel read against its setpoint in the cycles before
    assert sum(1 for _, _, v in rows if v[names.index('meas_left')] < 0) >= 3
    sim.run(0.5, (0.5, 0.0))                              # latched: no more rows, same table
    assert trace.row(trace.rows - 1)[0] == stamps[-1]


def test_the_trace_ring_keeps_its_newest_rows_across_the_wrap():
    trace = SupervisionTrace(capacity=5)
    times = [0.0] * 10
    for n in range(13):
        trace.record(n, n & 0x7F, (float(n),) + (0.0,) * 12, times)
    trace.freeze(7, 0x1)
    assert trace.rows == 5 and (trace.fault, trace.cause) == (7, 0x1)
    assert [trace.row(i)[0] for i in range(5)] == [8, 9, 10, 11, 12]
    assert [trace.row(i)[2][0] for i in range(5)] == [8.0, 9.0, 10.0, 11.0, 12.0]
    short = SupervisionTrace(capacity=5)
    for n in range(3):
        short.record(n, 0, (float(n),) + (0.0,) * 12, times)
    short.freeze(1, 0x2)
    assert short.rows == 3 and [short.row(i)[0] for i in range(3)] == [0, 1, 2]
    with pytest.raises(IndexError):
        short.row(3)
