"""The driver host counts every datagram it does not serve by reason, and splits its processes.

Pure: the service's dispatch is fed crafted datagrams (real protocol bytes) with a handler that
records what reaches the "device", and a link that takes or refuses the replies; no thread, no
socket, no clock dependence (stamps are either now or a second old against a 20 ms max age).
"""

import threading
import time

from m4k_drivers import config as dconfig
from m4k_drivers import hostproc
from m4k_drivers.handler import DeviceHandler
from m4k_drivers.host import DeviceService, DROP_REASONS
from m4k_drivers.hostproc import groups, own_process
from m4k_drivers.motors.handler import EncoderReading
from m4k_rt import protocol

K = protocol.Kind


class _Motor(DeviceHandler):
    """Records the written commands; reads a fixed encoder pair."""

    kind = 'motor'

    def __init__(self) -> None:
        super().__init__('motor')
        self.written: list[object] = []

    def on_write(self, command: object) -> None:
        self.written.append(command)

    def on_read(self) -> EncoderReading:
        return EncoderReading(100, 200, 0.1, 0.2, 0, time.monotonic_ns())


class _Link:
    def __init__(self) -> None:
        self.accept = True
        self.linked = True          # a peer that refuses (a full socket), not no peer
        self.sent: list[bytes] = []

    def write(self, data: bytes) -> bool:
        if self.accept:
            self.sent.append(data)
        return self.accept


def _service():
    section = dconfig.validate({'devices': {'motor': {'backend': 'sim'}}}).devices['motor']
    h = _Motor()
    svc = DeviceService('motor', h, section, 2, threading.Event())
    svc.link = _Link()
    return svc, h


def _cmd(age_s: float = 0.0, kind: int = K.WHEEL_CMD) -> bytes:
    stamp = time.monotonic_ns() - int(age_s * 1e9)
    if kind == K.WHEEL_CMD:
        return protocol.encode(kind, 1, stamp, 600, 600, 1)
    return protocol.encode(kind, 1, stamp, 0.1, 0.0)


def test_every_unserved_datagram_is_counted_under_its_reason():
    svc, h = _service()
    assert set(svc.drops) == set(DROP_REASONS) and not any(svc.drops.values())
    svc._dispatch(_cmd())                        # INACTIVE: not served, counted
    assert svc.drops['inactive'] == 1 and svc.served == 0
    h.configure()
    h.activate()
    svc._dispatch(_cmd())                        # served: one write, one ENCODERS reply
    assert svc.served == 1 and len(h.written) == 1 and len(svc.link.sent) == 1
    svc._dispatch(b'\x00garbage')
    svc._dispatch(_cmd(kind=K.VELOCITY_CMD))     # the motors do not take a VELOCITY_CMD
    svc._dispatch(_cmd(age_s=1.0))               # older than two periods (20 ms)
    svc.link.accept = False
    svc._dispatch(_cmd())                        # served, but the reply is refused
    assert svc.drops == {'stale_host': 1, 'stale_device': 0, 'malformed': 1, 'unexpected': 1,
                         'inactive': 1, 'encode': 0, 'reply_lost': 1}
    assert svc.served == 2 and len(h.written) == 2
    assert (svc.stale, svc.malformed, svc.unexpected) == (1, 1, 1)
    assert svc.drop_line() == ('motor: drops served=2 stale_host=1 stale_device=0 malformed=1 '
                               'unexpected=1 inactive=1 encode=0 reply_lost=1')


def test_a_stale_command_right_after_a_long_device_transaction_is_the_devices():
    svc, h = _service()
    h.configure()
    h.activate()
    svc._busy_ns = int(0.05e9)           # the last serve took 50 ms (> the 20 ms max age)
    svc._dispatch(_cmd(age_s=1.0))
    svc._dispatch(_cmd(age_s=1.0))       # the rest of the burst: the same cause
    assert svc.drops['stale_device'] == 2 and svc.drops['stale_host'] == 0
    svc._dispatch(_cmd())                # a short serve resets the attribution
    svc._dispatch(_cmd(age_s=1.0))
    assert svc.drops['stale_host'] == 1 and svc.served == 1


def test_rt_facing_devices_get_a_process_of_their_own():
    rt, nrt = {'sched_priority': 50}, {'sched_priority': 0}
    assert own_process(rt) and not own_process(nrt) and not own_process({})
    sections = {'motor': rt, 'imu': nrt, 'led': {}, 'other': rt}
    assert groups(['motor', 'imu', 'led'], sections) == [['motor'], ['imu', 'led']]
    assert groups(['imu', 'led'], sections) == [['imu', 'led']]          # no child at all
    assert groups(['motor'], sections) == [['motor']]                    # served inline
    assert groups(['motor', 'other'], sections) == [['motor'], ['other'], []]


def _child(code):
    """Fork a child that exits with ``code`` at once, or (None) waits for a signal with the
    default SIGTERM disposition (a process still starting: it dies -15)."""
    import os
    import signal
    pid = os.fork()
    if pid == 0:                               # pragma: no cover - the child
        if code is None:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            time.sleep(30)
        os._exit(code or 0)
    return pid


def test_a_child_ended_by_the_stop_itself_stopped_cleanly():
    """A stop that reaches a device process before its own handler (still starting) ends it
    by the SIGTERM: it stopped as asked, the host exits 0."""
    children = hostproc.Children({_child(None): 'motor'})
    assert children.stop(timeout_s=10.0)
    assert children.codes == {'motor': -15}


def test_a_child_that_exited_non_zero_before_the_stop_is_not_clean():
    children = hostproc.Children({_child(3): 'motor'})
    time.sleep(0.2)
    assert children.poll() is not None
    assert not children.stop(timeout_s=10.0)
