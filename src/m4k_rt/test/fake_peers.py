"""In-process fake NRT peers for task-body tests: real protocol over real XDDP sockets.

Everything is synchronous and driven by the test's simulated clock: the test calls a body
(RT side), then ``peer.serve(now)``; no threads run while the bodies do.
"""

from __future__ import annotations

import math
import threading
from types import SimpleNamespace

from m4k_rt import protocol as p
from m4k_rt.channel import nrt_xddp_open, rt_xddp_bind
from m4k_rt.control.dac import code_to_command

MS = 1_000_000


def ctx(t_ns: int) -> SimpleNamespace:
    """Return a stand-in for the RtTask the runtime passes to bodies."""
    return SimpleNamespace(t_start=t_ns)


class NrtPeers:
    """NRT endpoints by label, opened against an RT side that runs elsewhere (rt_core)."""

    def __init__(self, runtime_dir: str, *labels: str, wait: float = 10.0) -> None:
        self.rt = {}
        self.nrt = {}
        try:
            for label in labels:
                self.nrt[label] = nrt_xddp_open(label, wait=wait, runtime_dir=runtime_dir)
        except BaseException:
            self.close()
            raise

    def read_all(self, label: str) -> list:
        """Return every decoded datagram pending on the NRT side of ``label``."""
        out = []
        ep = self.nrt[label]
        while True:
            try:
                data = ep.read(timeout=0.0)
            except TimeoutError:
                return out
            out.append(p.decode(data))

    def write(self, label: str, kind: int, *fields, seq: int = 0, stamp: int = 0) -> None:
        """Encode and write one datagram from the NRT side of ``label``."""
        self.nrt[label].write(p.encode(kind, seq, stamp, *fields))

    def close(self) -> None:
        """Close every endpoint and RT socket."""
        for ep in self.nrt.values():
            ep.close()
        for sock in self.rt.values():
            sock.close()


class Ports(NrtPeers):
    """RT sockets bound by label, each linked to an NRT endpoint; closes all of them."""

    NUMBERS = {'cmd': 1, 'motor': 2, 'imu': 3, 'imu_out': 4, 'led': 5, 'led_in': 6,
               'sonar': 7, 'sonar_out': 8, 'lrf': 9, 'lrf_out': 10}

    def __init__(self, runtime_dir: str, *labels: str) -> None:
        self.rt = {}
        self.nrt = {}
        try:
            for label in labels:
                self.rt[label] = rt_xddp_bind(self.NUMBERS[label], label,
                                              runtime_dir=runtime_dir)
                self.nrt[label] = self._open(label, runtime_dir)
        except BaseException:
            self.close()
            raise

    def _open(self, label: str, runtime_dir: str):
        box = {}

        def opener() -> None:
            try:
                box['ep'] = nrt_xddp_open(label, wait=2.0, runtime_dir=runtime_dir)
            except Exception as exc:  # noqa: BLE001 -- re-raised in the test thread
                box['err'] = exc

        t = threading.Thread(target=opener)
        t.start()
        sock = self.rt[label]
        while t.is_alive():
            sock.poll_peer()
            t.join(0.001)
        if 'err' in box:
            raise box['err']
        return box['ep']



class FakeMotor:
    """Motor handler: wheels with a first-order lag answering each WHEEL_CMD with ENCODERS."""

    def __init__(self, ports: Ports, full_scale: float, tau: float = 0.08) -> None:
        self.ports = ports
        self.full_scale = full_scale
        self.tau = tau
        self.code = [512, 512]
        self.enable = 0
        self.speed = [0.0, 0.0]
        self.angle = [0.0, 0.0]
        self.t_ns = None
        self.commands = []
        self.status = 0
        self.alive = True
        self.frozen: list[float] | None = None   # report these angles (a frozen valid frame)

    def _advance(self, t_ns: int) -> None:
        if self.t_ns is None:
            self.t_ns = t_ns
            return
        steps = max(1, (t_ns - self.t_ns) // MS)
        h = (t_ns - self.t_ns) * 1e-9 / steps
        for _ in range(steps):
            for i in (0, 1):
                u = code_to_command(self.code[i]) if self.enable else 0.0
                self.speed[i] += (u * self.full_scale - self.speed[i]) * (h / self.tau)
                self.angle[i] += self.speed[i] * h
        self.t_ns = t_ns

    def serve(self, t_ns: int) -> int:
        """Advance the wheels to ``t_ns``, apply pending commands, reply; return #replies."""
        self._advance(t_ns)
        replies = 0
        for hdr, msg in self.ports.read_all('motor'):
            assert hdr.kind == p.Kind.WHEEL_CMD
            self.commands.append(msg)
            self.code = [msg.left_code, msg.right_code]
            self.enable = msg.enable
            if not self.alive:
                continue
            angle = self.angle if self.frozen is None else self.frozen
            raw = [int(a / (2 * math.pi) * 4096) % 4096 for a in angle]
            self.ports.write('motor', p.Kind.ENCODERS, raw[0], raw[1], angle[0],
                             angle[1], self.status, seq=len(self.commands), stamp=t_ns)
            replies += 1
        return replies
