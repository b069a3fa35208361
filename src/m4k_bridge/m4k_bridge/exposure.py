"""Whether the DDS graph is open to the network: a doctor check (pure but for reading /proc).

Who may publish ``cmd_vel`` or ``e_stop`` false over DDS is decided by discovery and by DDS
Security, not by the live view's rights. The installed middleware (the ``ros-fastrtps``
2.14.5 wheel) is built without DDS Security -- its library has none of the builtin
``PKI-DH`` / ``Access-Permissions`` / ``AES-GCM-GMAC`` plugins, and rmw_fastrtps then refuses
``ROS_SECURITY_ENABLE=true`` ("Please compile Fast DDS using the -DSECURITY=ON CMake option")
-- so what is left is the discovery range and the firewall:

* ``ROS_AUTOMATIC_DISCOVERY_RANGE`` unset (rcl's default is ``SUBNET``), ``SUBNET`` or
  ``SYSTEM_DEFAULT``: the stack announces itself by multicast and any host of the subnet on
  the same ``ROS_DOMAIN_ID`` joins the graph and can drive -- reported as open.
* ``LOCALHOST`` (with ``ROS_STATIC_PEERS`` naming the laptop) or ``OFF``: no multicast; the
  stack is found only by the peers it names. rmw_fastrtps still listens for unicast on every
  interface, so a host that names the robot as *its* static peer can still join: only a
  firewall (or DDS Security) closes that; the docs say so (docs/live-view.md, "The DDS graph").
"""

from __future__ import annotations

import os
from typing import Mapping

__all__ = ['OPEN_RANGES', 'bridge_environments', 'graph_problems', 'range_problem']

OPEN_RANGES = ('', 'SUBNET', 'SYSTEM_DEFAULT')


def _domain(env: Mapping[str, str]) -> str:
    return env.get('ROS_DOMAIN_ID', '').strip() or '0'


def range_problem(env: Mapping[str, str], who: str) -> str | None:
    """Return a problem line when ``env`` puts its process in a graph open to the subnet."""
    rng = env.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '').strip()
    if rng not in OPEN_RANGES:
        return None
    if env.get('ROS_LOCALHOST_ONLY', '') == '1' and not rng:
        return None          # the deprecated switch: rcl maps it to LOCALHOST when unset
    return ('the DDS graph of {} is open to the subnet (ROS_AUTOMATIC_DISCOVERY_RANGE={}): '
            'any host there on ROS_DOMAIN_ID {} can publish cmd_vel and e_stop false, and the '
            'installed Fast DDS has no DDS Security; set ROS_AUTOMATIC_DISCOVERY_RANGE='
            'LOCALHOST with ROS_STATIC_PEERS=<laptop address> and firewall the RTPS ports '
            '(docs/live-view.md, "The DDS graph")'.format(
                who, rng or 'unset, i.e. SUBNET', _domain(env)))


def bridge_environments(proc: str = '/proc') -> dict[int, dict[str, str]]:
    """Return {pid: environment} of the m4k bridge processes this user may read."""
    out: dict[int, dict[str, str]] = {}
    for name in os.listdir(proc):
        if not name.isdigit():
            continue
        try:
            with open(os.path.join(proc, name, 'cmdline'), 'rb') as f:
                argv = f.read().split(b'\0')
            if not any(a.endswith((b'm4k_bridge.node', b'm4k_bridge/node.py')) for a in argv):
                continue
            with open(os.path.join(proc, name, 'environ'), 'rb') as f:
                raw = f.read().split(b'\0')
        except OSError:
            continue             # gone, or another user's
        env = {}
        for item in raw:
            key, sep, value = item.decode(errors='replace').partition('=')
            if sep:
                env[key] = value
        out[int(name)] = env
    return out


def graph_problems(env: Mapping[str, str] | None = None, proc: str = '/proc') -> list[str]:
    """Return the open-graph problems of this process's environment and of local bridges.

    Only the bridges on this environment's ``ROS_DOMAIN_ID`` are in the graph the doctor
    checks; one on another domain is another graph (two stacks side by side on one host --
    ``make test``'s streams -- each on a domain of its own).
    """
    here = os.environ if env is None else env
    out = []
    own = range_problem(here, 'this shell')
    if own is not None:
        out.append(own)
    domain = _domain(here)
    for pid, benv in sorted(bridge_environments(proc).items()):
        if _domain(benv) != domain:
            continue
        line = range_problem(benv, 'the bridge (pid {})'.format(pid))
        if line is not None:
            out.append(line)
    return out
