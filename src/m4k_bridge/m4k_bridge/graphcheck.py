"""Check a ROS graph's endpoints against each other: names, types and QoS (pure, no rclpy).

The graph is a list of :class:`Endpoint` -- a publisher or a subscription with its resolved
topic name, message type and the two QoS policies that decide whether DDS matches them
(reliability, durability). The same check runs on the graph the recipes *describe*
(``test/test_recipes.py`` resolves every name as its consumer node would) and on the *live*
graph (``doctor``). Each problem is one line that names what is wrong and how to fix it.

QoS compatibility follows the ROS 2 rules ("QoS compatibilities", docs.ros.org): a best-effort
publisher cannot serve a reliable subscription, and a volatile publisher cannot serve a
transient-local subscription; every other pairing matches.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Iterable, Sequence

__all__ = ['Endpoint', 'check', 'qos_mismatch', 'base_name', 'range_points',
           'range_source_problems']


@dataclasses.dataclass(frozen=True)
class Endpoint:
    """One publisher ('pub') or subscription ('sub') of a node, its name fully resolved."""

    node: str                    # fully qualified node name, e.g. /local_costmap/local_costmap
    kind: str                    # 'pub' or 'sub'
    topic: str                   # absolute, after expansion and remapping
    type: str                    # e.g. 'sensor_msgs/msg/LaserScan'
    reliable: bool = True
    transient_local: bool = False
    m4k: bool = False            # an endpoint of the m4k base (the bridge)
    external: bool = False       # fed or read by something outside the checked graph


def base_name(topic: str) -> str:
    """Return the last token of a topic name ('/local_costmap/scan' -> 'scan')."""
    return topic.rstrip('/').rsplit('/', 1)[-1]


def qos_mismatch(pub: Endpoint, sub: Endpoint) -> str | None:
    """Return why pub cannot serve sub (reliability, durability), or None when they match."""
    if sub.reliable and not pub.reliable:
        return 'the publisher is best effort, the subscription reliable'
    if sub.transient_local and not pub.transient_local:
        return 'the publisher is volatile, the subscription transient local'
    return None


def _short(t: str) -> str:
    return t.replace('/msg/', '/')


def check(endpoints: Iterable[Endpoint], unfed: str = 'all') -> list[str]:
    """Return one line per problem of the graph, with its fix; [] for a healthy graph.

    * a subscription nobody publishes -- named with the m4k topic it probably meant when one
      has the same last token (the costmap case: /local_costmap/scan against m4k's /scan);
    * a publisher and a subscription of one name with different types;
    * a publisher that cannot serve a subscription of its name (QoS);
    * an m4k subscription (cmd_vel, e_stop, led) fed by a publisher of another type;
    * a publisher nobody reads whose name matches an m4k subscription up to the namespace;
    * more than one writer on an m4k input (cmd_vel, e_stop);
    * two types on one topic, even with nobody subscribing to one of them.

    ``unfed``: 'all' reports every subscription without a publisher (a described graph, where
    each input must be fed unless marked external); 'm4k' only those whose name matches an m4k
    topic up to the namespace (a live graph, where idle inputs are normal).
    """
    eps = list(endpoints)
    pubs: dict[str, list[Endpoint]] = {}
    for e in eps:
        if e.kind == 'pub':
            pubs.setdefault(e.topic, []).append(e)
    m4k_names = {e.topic: e for e in eps if e.m4k}
    out: list[str] = []
    seen: set[str] = set()

    def add(line: str) -> None:
        if line not in seen:
            seen.add(line)
            out.append(line)

    for sub in (e for e in eps if e.kind == 'sub'):
        here = pubs.get(sub.topic, [])
        if not here:
            if sub.external:
                continue
            meant = sorted(t for t in m4k_names if base_name(t) == base_name(sub.topic)
                           and t != sub.topic)
            if unfed != 'all' and not meant:
                continue
            if meant:
                add('{} subscribes {} ({}), which nobody publishes; m4k publishes {}: give '
                    "the node the absolute name {} (a relative name resolves in the node's "
                    'namespace)'.format(sub.node, sub.topic, _short(sub.type), meant[0],
                                        meant[0]))
            else:
                add('{} subscribes {} ({}), which nobody publishes: start its publisher or '
                    'point the node at an existing topic'.format(sub.node, sub.topic,
                                                                 _short(sub.type)))
            continue
        for pub in here:
            if pub.type != sub.type:
                if sub.m4k:
                    add("{} publishes {} as {}, the m4k bridge subscribes {}: set the bridge's "
                        'enable_stamped_cmd_vel to {} (or auto), or make the publisher send {}'
                        .format(pub.node, sub.topic, _short(pub.type), _short(sub.type),
                                'true' if pub.type.endswith('TwistStamped') else 'false',
                                _short(sub.type))
                        if base_name(sub.topic).startswith('cmd_vel') else
                        '{} publishes {} as {}, the m4k bridge subscribes {}: publish {}'.format(
                            pub.node, sub.topic, _short(pub.type), _short(sub.type),
                            _short(sub.type)))
                else:
                    add('{} publishes {} as {}, {} subscribes {}: one type per topic (check '
                        'stamped/unstamped settings on both)'.format(
                            pub.node, sub.topic, _short(pub.type), sub.node, _short(sub.type)))
                continue
            why = qos_mismatch(pub, sub)
            if why:
                add('{} -> {} on {}: QoS incompatible, {}: subscribe {} (e.g. the sensor-data '
                    'QoS) or publish {}'.format(
                        pub.node, sub.node, sub.topic, why,
                        'best effort' if 'best effort' in why else 'volatile',
                        'reliable' if 'best effort' in why else 'transient local'))
    subs = {e.topic for e in eps if e.kind == 'sub'}
    m4k_subs = {e.topic: e for e in eps if e.m4k and e.kind == 'sub'}
    for topic in sorted(m4k_subs):
        writers = sorted({p.node for p in pubs.get(topic, [])})
        if len(writers) > 1:
            add('{} has {} writers ({}), an m4k input takes one: the last message wins, so one '
                'writer undoes another (a stop, a lock); put twist_mux in front for cmd_vel, '
                "or remap the extra writer into Nav2's chain (docking_server: "
                '-r cmd_vel:=cmd_vel_nav, as m4k_nav2.launch.py does)'.format(
                    topic, len(writers), ', '.join(writers)))
    types: dict[str, set[str]] = {}
    for e in eps:
        types.setdefault(e.topic, set()).add(e.type)
    for topic, ts in sorted(types.items()):
        if len(ts) > 1 and not any(topic in line for line in out):
            add('{} carries {} types ({}): a subscriber of one never hears the other; one '
                'type per topic (rename or convert one side)'.format(
                    topic, len(ts), ', '.join(sorted(_short(t) for t in ts))))
    for pub in (e for e in eps if e.kind == 'pub' and not e.m4k and e.topic not in subs):
        meant = sorted(t for t in m4k_subs if base_name(t) == base_name(pub.topic))
        if meant:
            add('{} publishes {} ({}), which nobody reads; the m4k bridge subscribes {}: '
                'publish on {} (or remap)'.format(pub.node, pub.topic, _short(pub.type),
                                                  meant[0], meant[0]))
    return out


def subscriptions_meaning(endpoints: Sequence[Endpoint], m4k_topic: str) -> list[Endpoint]:
    """Return the subscriptions that name m4k_topic up to the namespace but not exactly."""
    return [e for e in endpoints if e.kind == 'sub' and e.topic != m4k_topic
            and base_name(e.topic) == base_name(m4k_topic)]


def range_points(field_of_view: float, obstacles_angle: float) -> int:
    """Return how many points Nav2's collision monitor makes of one Range reading.

    Jazzy's ``nav2_collision_monitor/src/range.cpp``: one point per ``obstacles_angle`` step
    from -fov/2 while below +fov/2, then one more at +fov/2.
    """
    if obstacles_angle <= 0.0 or not math.isfinite(obstacles_angle):
        raise ValueError('obstacles_angle must be a positive number, got {!r}'.format(
            obstacles_angle))
    n, angle = 0, -field_of_view / 2.0
    while angle < field_of_view / 2.0:
        n += 1
        angle += obstacles_angle
    return n + 1


def range_source_problems(node: str, source: str, *, no_echo: str, field_of_view: float,
                          obstacles_angle: float, min_points: int,
                          source_timeout: float) -> list[str]:
    """Return why a collision-monitor Range source on the m4k sonar cannot work.

    * "no echo" published as +inf (the bridge's ``sonar_no_echo: positive_infinity``) is
      ``range > max_range`` for Jazzy's Range source, which then reports the source invalid;
      with a ``source_timeout`` other than 0 the monitor turns an invalid source into a STOP,
      so Nav2's output is zeroed whenever the sonar sees nothing;
    * fewer points per reading than the polygon's ``min_points``: the sonar can only stop the
      robot through invalidity, never trigger the polygon by what it sees.
    """
    out = []
    if no_echo != 'max_range' and source_timeout != 0.0:
        out.append('{} takes the sonar as Range source {} but the bridge publishes "no echo" '
                   "as +inf, which Jazzy's Range source reads as invalid, and with "
                   'source_timeout {:g} an invalid source is a STOP: Nav2 stops whenever the '
                   "sonar sees nothing; remove {} from the monitor's observation_sources (the "
                   "RT guard and the costmap's range layer use the sonar), or set the bridge's "
                   'sonar_no_echo: max_range'.format(node, source, source_timeout, source))
    pts = range_points(field_of_view, obstacles_angle)
    if pts < min_points:
        out.append('{}: Range source {} makes {} points per reading (field of view {:g} rad, '
                   'obstacles_angle {:g}), below the polygon min_points {}: the sonar can never '
                   'trigger the monitor; set {}.obstacles_angle <= {:.4f} or remove the source'
                   .format(node, source, pts, field_of_view, obstacles_angle, min_points,
                           source, field_of_view / max(min_points - 1, 1)))
    return out
