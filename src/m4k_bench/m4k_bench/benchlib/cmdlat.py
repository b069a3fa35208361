"""cmd_vel -> motor command latency, through ROS, the bridge, XDDP and the actuator task.

Set-up: rt_core with the actuator task (monitor always runs), the ROS bridge on the ``cmd``
port, and -- instead of the driver host -- a *probe* motor peer in this process on the
``motor`` port. The probe answers every WHEEL_CMD with an ENCODERS sample (wheels at rest,
status ok) exactly like the motor handler does, so the controller sees a live motor, and it
stamps each WHEEL_CMD on arrival with CLOCK_MONOTONIC.

One trial: publish zero commands until the probe has seen the DAC codes at 512 (zero) for a
few cycles, then, at ``t0`` (monotonic, taken just before ``publish``), publish a rotation
command and find the first WHEEL_CMD whose codes left 512. rt_core runs with the collision
guard off (:data:`GUARD_OFF`): with no sonar or laser task the guard rightly holds every
command -- forward, and since the turn guard (hazard C14) turns too -- and the path measured
does not go through it. Two intervals, both on
this machine's monotonic clock:

* ``to_cycle``: t0 -> the WHEEL_CMD's header stamp, which the actuator sets to its cycle's
  ``t_start`` -- DDS + bridge + XDDP + the wait for the next 10 ms release;
* ``to_probe``: t0 -> arrival of that WHEEL_CMD at the motor peer -- adds the cycle's
  computation and the XDDP hop to the driver side.

Expect about half a period on average from the wait for the release alone. Each trial
starts after a random 0..1 period pause, so ``t0`` falls at a uniformly random phase of the
actuator's cycle (the trials' own pacing would otherwise lock it to one phase). The first
``WARMUP`` trials are not counted (DDS discovery, the controller's hold-zero after start-up).
"""

from __future__ import annotations

import os
import random
import threading
import time
from typing import Any, Callable

import yaml

from m4k_bench.benchlib.analysis import stats_dict
from m4k_rt import channel, protocol
from m4k_rt.timing import describe

__all__ = ['MotorProbe', 'run_cmd_latency']

_ZERO = 512
WARMUP = 2
_PERIOD_S = 0.01
# rt_core's overlay here: no sensor task runs, so the guard would rightly hold every command
# (forward: no sonar or laser; turns: a stale laser stops them both ways, hazard C14). The
# path measured -- DDS, the bridge, XDDP, the actuator's release -- is the same with it off.
GUARD_OFF = {'control': {'guard': {'enabled': False}}}


class MotorProbe:
    """NRT motor peer: answer WHEEL_CMD with ENCODERS, keep (rx_ns, stamp_ns, codes)."""

    def __init__(self, runtime_dir: str) -> None:
        """Prepare the link and the reply buffer; ``start()`` runs the thread."""
        self.link = channel.NrtLink('motor', runtime_dir, retry_interval=0.05)
        self.stop_event = threading.Event()
        self.lock = threading.Lock()
        self.events: list[tuple[int, int, int, int]] = []   # rx_ns, stamp_ns, left, right
        self.seq = 0
        self.thread = threading.Thread(target=self._serve, name='bench-motor-probe',
                                       daemon=True)

    def start(self) -> MotorProbe:
        """Start serving."""
        self.thread.start()
        return self

    def _serve(self) -> None:
        while not self.stop_event.is_set():
            data = self.link.read(0.1)
            if data is None:
                continue
            rx = time.monotonic_ns()
            try:
                hdr, msg = protocol.decode(data)
            except protocol.ProtocolError:
                continue
            if hdr.kind != protocol.Kind.WHEEL_CMD:
                continue
            with self.lock:
                self.events.append((rx, hdr.stamp_ns, msg.left_code, msg.right_code))
            self.link.write(protocol.encode(protocol.Kind.ENCODERS, self.seq,
                                            time.monotonic_ns(), 0, 0, 0.0, 0.0, 0))
            self.seq += 1

    def since(self, index: int) -> list[tuple[int, int, int, int]]:
        """Return events from ``index`` on."""
        with self.lock:
            return self.events[index:]

    def count(self) -> int:
        """Return how many WHEEL_CMD arrived."""
        with self.lock:
            return len(self.events)

    def close(self) -> None:
        """Stop the thread and close the link."""
        self.stop_event.set()
        self.thread.join(2.0)
        self.link.close()


METHOD = (
    'rt_core (actuator; the collision guard off: no sensor task runs, and it would hold every '
    'command) + bridge + a probe motor peer in the bench answering each WHEEL_CMD '
    'with ENCODERS. Per trial: zero commands until the DAC codes sit at 512, then a cmd_vel '
    'rotation (angular.z = 1 rad/s) is published at t0; the first WHEEL_CMD with codes off 512 '
    'ends the trial; t0 is at a random phase of the 10 ms cycle, the first {} trials are '
    'warm-up. "cycle" = its header stamp (the actuator cycle\'s t_start), "probe" = its '
    'arrival at the motor peer; both CLOCK_MONOTONIC. The 10 ms period alone adds 0..10 ms '
    '(5 ms on average) of waiting for the next release.'.format(WARMUP))


def _wait_zero(probe: MotorProbe, publish: Callable[[float], None], timeout_s: float,
               streak: int = 5) -> bool:
    end = time.monotonic() + timeout_s
    start = probe.count()
    while time.monotonic() < end:
        publish(0.0)
        time.sleep(0.05)
        ev = probe.since(start)
        if len(ev) >= streak and all(e[2] == _ZERO and e[3] == _ZERO for e in ev[-streak:]):
            return True
    return False


def run_cmd_latency(trials: int, runtime_dir: str, log_dir: str, *,
                    env: dict[str, str] | None = None,
                    progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Measure ``trials`` cmd_vel -> WHEEL_CMD latencies; return stats and the method text."""
    from geometry_msgs.msg import Twist
    import rclpy
    from rclpy.context import Context

    from m4k_bench.benchlib.stack import entry_argv, start_child

    env = dict(env or os.environ, M4K_RUNTIME_DIR=runtime_dir)
    channel.ensure_runtime_dir(runtime_dir)
    overlay = os.path.join(runtime_dir, 'cmdlat.overlay.yaml')
    with open(overlay, 'w', encoding='utf-8') as f:
        yaml.safe_dump(GUARD_OFF, f)
    rt = start_child('cmdlat.rt_core', entry_argv('m4k_rt.rt_core', '--tasks', 'actuator',
                                                  '--config', overlay), log_dir, env)
    bridge = start_child('cmdlat.bridge', entry_argv('m4k_bridge.node'), log_dir, env)
    probe = MotorProbe(runtime_dir).start()
    ctx = Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node('m4k_bench_cmdlat', context=ctx)
    pub = node.create_publisher(Twist, 'cmd_vel', 10)
    msg = Twist()

    def publish(w: float) -> None:
        msg.angular.z = w
        pub.publish(msg)

    to_cycle: list[int] = []
    to_probe: list[int] = []
    lost = 0
    error = None
    try:
        # Wait for the bridge to match our publisher and the controller to settle at zero.
        end = time.monotonic() + 30.0
        while pub.get_subscription_count() < 1 and time.monotonic() < end:
            time.sleep(0.05)
        if not _wait_zero(probe, publish, max(end - time.monotonic(), 1.0)):
            error = 'no zero WHEEL_CMD stream within 30 s (rt_core: {}; bridge: {})'.format(
                ' | '.join(rt.tail(2)), ' | '.join(bridge.tail(2)))
        else:
            for i in range(trials + WARMUP):
                if not _wait_zero(probe, publish, 3.0):
                    lost += 1
                    continue
                time.sleep(random.uniform(0.0, _PERIOD_S))
                mark = probe.count()
                t0 = time.monotonic_ns()
                publish(1.0)
                end = time.monotonic() + 0.5
                hit = None
                next_pub = time.monotonic() + 0.05
                while hit is None and time.monotonic() < end:
                    time.sleep(0.001)
                    for e in probe.since(mark):
                        if e[0] > t0 and (e[2] != _ZERO or e[3] != _ZERO):
                            hit = e
                            break
                    if time.monotonic() >= next_pub:  # keep it alive like a 20 Hz planner
                        publish(1.0)
                        next_pub += 0.05
                if i < WARMUP:
                    pass
                elif hit is None:
                    lost += 1
                else:
                    to_cycle.append(hit[1] - t0)
                    to_probe.append(hit[0] - t0)
                if progress is not None:
                    progress('trial {}/{}'.format(max(i + 1 - WARMUP, 0), trials))
                publish(0.0)
    finally:
        node.destroy_node()
        ctx.try_shutdown()
        bridge.stop()
        rt.stop()
        probe.close()
    out: dict[str, Any] = {
        'trials': len(to_probe), 'lost': lost,
        'method': METHOD,
        'to_cycle_us': stats_dict(describe(to_cycle), 1e-3) if to_cycle else None,
        'to_probe_us': stats_dict(describe(to_probe), 1e-3) if to_probe else None,
        'samples_ns': {'to_cycle': to_cycle, 'to_probe': to_probe},
    }
    if error is None and lost and not to_probe:
        # Never "skipped": a phase that ran and saw nothing says so (a guard or an e-stop
        # holding every command looks exactly like this).
        error = ('every trial lost: no WHEEL_CMD left zero within 0.5 s of a command '
                 '(rt_core: {})'.format(' | '.join(rt.tail(2))))
    if error:
        out['error'] = error
    return out
