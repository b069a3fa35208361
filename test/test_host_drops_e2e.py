"""End to end: wheel commands the driver host drops after a real stall reach /diagnostics.

The whole stack runs under ``bringup`` (sim_robot + rt_core + driver_host + bridge). The test
stops the motor's own process (SIGSTOP) for half a second while the RT actuator keeps sending
a WHEEL_CMD every period, then lets it go on (SIGCONT): the commands queued meanwhile are older
than two periods, so the host drops them as stale -- the real cause the issue measured under
load, forced.  The drop counts travel as the host's HOST_DROPS, forwarded by rt_core's
monitor, and the bridge publishes them as ``m4k_drivers: motor host drops``.  Judged: OK with
no drops before the stall, WARN naming a stale reason after it, and the count published is
the host's own (its exit line), not more.  No timing figure is asserted.
"""

import os
import re
import signal
import subprocess
import time

import pytest
from wsenv import stack_env
import yaml

from m4k_bringup.bringup import bringup_argv

rclpy = pytest.importorskip('rclpy')

STATUS = 'm4k_drivers: motor host drops'


def _values(status):
    return {kv.key: kv.value for kv in status.values}


@pytest.mark.allow_leaks('fds')  # in-process DDS transports outlive the node
def test_commands_dropped_after_a_host_stall_appear_in_diagnostics_by_reason(
        procs, tmp_path, m4k_runtime_dir):
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor

    from m4k_msgs.msg import RtStatus
    overlay = tmp_path / 'overlay.yaml'
    overlay.write_text(yaml.safe_dump({'runtime': {'mlockall': False, 'cpu_dma_latency': False,
                                                   'start_delay_ms': 10}}))
    log_path = tmp_path / 'bringup.log'
    with open(log_path, 'w') as log:
        bu = procs.start(bringup_argv(str(overlay)) + ['--status-interval', '1'],
                         env=stack_env(m4k_runtime_dir), stdout=log, stderr=subprocess.STDOUT)
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node('m4k_host_drops_probe', context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    seen = []
    node.create_subscription(DiagnosticArray, 'diagnostics', lambda m: seen.extend(
        s for s in m.status if s.name == STATUS), 10)
    motor_port = {}          # the RT side's own counters of the motor port (for the printout)
    node.create_subscription(RtStatus, 'rt_status', lambda m: motor_port.update(
        (p.label, (p.sent, p.dropped_full, p.dropped_no_peer)) for p in m.ports), 10)

    def until(pred, timeout, what):
        deadline = time.monotonic() + timeout
        while not pred():
            assert time.monotonic() < deadline, 'timed out: {}\n{}'.format(
                what, log_path.read_text()[-3000:])
            ex.spin_once(timeout_sec=0.05)

    motor_pid = None
    try:
        until(lambda: seen and seen[-1].level == b'\x00'
              and int(_values(seen[-1])['served']) > 100, 90,
              'the motor served and no drop in the window')
        before = _values(seen[-1])
        port_before = motor_port.get('motor')
        m = re.search(r'serving motor@\S+ \(pid (\d+)\)', log_path.read_text())
        assert m, log_path.read_text()[-3000:]
        motor_pid = int(m.group(1))
        n = len(seen)
        os.kill(motor_pid, signal.SIGSTOP)
        time.sleep(0.5)
        os.kill(motor_pid, signal.SIGCONT)
        motor_pid = None
        until(lambda: any(s.level == b'\x01' for s in seen[n:]), 30, 'WARN after the stall')
        warn = next(s for s in seen[n:] if s.level == b'\x01')
        port_after = motor_port.get('motor')
    finally:
        if motor_pid is not None:
            os.kill(motor_pid, signal.SIGCONT)
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        bu.send_signal(signal.SIGINT)
        bu.wait(40)
    text = log_path.read_text()
    assert bu.returncode == 0, text[-3000:]
    values = _values(warn)
    print('motor host stalled 0.5 s:', warn.message, '| RT motor port (sent, dropped_full, '
          'dropped_no_peer) before/after:', port_before, port_after)
    stale = int(values['stale_host']) + int(values['stale_device'])
    before_stale = int(before['stale_host']) + int(before['stale_device'])
    # The commands queued during the stall were dropped as stale, and said so by reason.
    assert stale > before_stale and int(values['window_drops']) >= stale - before_stale
    assert 'stale_' in warn.message and warn.hardware_id == 'driver_host'
    # Nothing the RT side sends is malformed or of a kind the motor does not take.
    assert values['malformed'] == values['unexpected'] == '0'
    # What /diagnostics said is the host's own count (its exit line has it or, after later
    # stalls, more).
    m = re.search(r'motor: drops served=\d+ stale_host=(\d+) stale_device=(\d+) .* at exit',
                  text)
    assert m, text[-3000:]
    assert int(m.group(1)) + int(m.group(2)) >= stale
