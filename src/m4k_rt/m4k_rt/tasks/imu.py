"""IMU task body (10 ms): request a sample from the imu handler, forward the latest to the bridge.

Ports: ``imu`` (driver host: REQUEST out, IMU and DEVICE_STATUS in) and ``imu_out`` (bridge:
IMU out). Same one-cycle pipeline as the actuator: each cycle first drains the reply to the
previous cycle's REQUEST, forwards the newest valid IMU datagram unchanged (the handler's
stamp is the measurement time), then sends this cycle's REQUEST. Samples older than the
newest one in the same drain are skipped (counted in ``superseded``): the bridge wants the
freshest orientation, not a backlog.
"""

from __future__ import annotations

import math
import time
from typing import Any, Callable, Mapping

from m4k_rt.config import TaskConfig
from m4k_rt.protocol import ImuStatus, Kind
from m4k_rt.tasks.interfaces import CycleContext, RtPort
from m4k_rt.tasks.portio import DeviceTaskBody
from m4k_rt.tasks.state import robot_state, RobotState

__all__ = ['ImuBody', 'make_imu']

_IMU = Kind.IMU
_DEVICE_STATUS = Kind.DEVICE_STATUS
_HOST_DROPS = Kind.HOST_DROPS
_REQUEST = Kind.REQUEST
_IMU_OK = int(ImuStatus.OK)


class ImuBody(DeviceTaskBody):
    """Per-cycle body of the IMU task."""

    def __init__(self, dev_sock: RtPort, out_sock: RtPort, state: RobotState,
                 clock: Callable[[], int] = time.monotonic_ns) -> None:
        super().__init__(dev_sock, out_sock, state, clock)
        self._latest = bytearray(len(self._dev_in.buf))
        self._latest_view = memoryview(self._latest)
        self.samples = 0
        self.superseded = 0

    @property
    def counters(self) -> Mapping[str, int]:
        """Return a snapshot of the body's counters (NRT use)."""
        return {'cycles': self.cycles, 'samples': self.samples, 'superseded': self.superseded,
                'unexpected': self.unexpected, 'forwarded': self._out.sent,
                'forward_dropped': self._out.dropped, 'requests': self._dev_out.sent}

    def __call__(self, ctx: CycleContext | None = None) -> None:
        """Run one IMU cycle."""
        now = ctx.t_start if ctx is not None else self._clock()
        reader = self._dev_in
        reader.start_cycle()
        n = 0
        gz = qx = qy = qz = qw = math.nan
        stamp = 0
        while (got := reader.next()) is not None:
            kind = got[0].kind
            if kind == _IMU:
                if n:
                    self.superseded += 1
                n = reader.length
                self._latest_view[:n] = reader.view[:n]
                self.samples += 1
                msg = got[1]
                stamp = got[0].stamp_ns
                if msg.status == _IMU_OK:
                    gz, qx, qy, qz, qw = msg.gz, msg.qx, msg.qy, msg.qz, msg.qw
                else:
                    # a sample the driver flags: no yaw rate or tilt for the supervision
                    gz = qx = qy = qz = qw = math.nan
            elif kind == _DEVICE_STATUS:
                self.state.record_device_status('imu', got[1], now)
            elif kind == _HOST_DROPS:
                self.state.record_host_drops('imu', got[1], now)
            else:
                self.unexpected += 1
        if n:
            self._out.forward(self._latest_view[:n])
            st = self.state
            st.imu_gz = gz    # the wheel supervision's yaw cross-check (actuator)
            st.imu_qx, st.imu_qy, st.imu_qz, st.imu_qw = qx, qy, qz, qw   # its level test
            st.imu_rx_ns = now
            st.imu_stamp_ns = stamp   # when the driver took it (the supervision aligns)
        self.unexpected += self._out_in.discard()   # the bridge only reads this port
        self._dev_out.send(_REQUEST, now, self.cycles & 0xFFFFFFFF, 0)
        self.cycles += 1


def make_imu(task: TaskConfig, ports: Mapping[str, RtPort], shared: Any) -> ImuBody:
    """Build the IMU body from its ``imu``/``imu_out`` ports."""
    return ImuBody(ports['imu'], ports['imu_out'], robot_state(shared))
