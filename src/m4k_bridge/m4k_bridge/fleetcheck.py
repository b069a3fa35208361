"""Judge a live fleet: each robot's TF tree, who claims which edge, frames, clock, lifecycles.

Pure (no rclpy): ``doctor`` collects the graph's endpoints, the TF samples per topic, the
nodes' parameters and lifecycle states, and these functions return one line per problem,
each saying what to change. The layout they accept is Nav2's multi-robot one
(docs/nav2.md): robot ``r1``'s nodes in ``/r1``, its tree on ``/r1/tf`` and
``/r1/tf_static``, frames unprefixed; a single robot keeps ``/tf``.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Iterable, Mapping, Sequence

from m4k_bridge import params as bridge_params
from m4k_bridge.graphcheck import Endpoint, range_source_problems

__all__ = ['TF_TYPE', 'TfSample', 'duplicate_edges', 'frame_parameter_problems',
           'lifecycle_problems', 'sim_time_problems', 'sonar_source_problems',
           'tf_namespace', 'tree_problems', 'wrong_tree_publishers', 'PARAMS']

TF_TYPE = 'tf2_msgs/msg/TFMessage'

# Frame parameters of the stock nodes (Jazzy defaults where a node declares one): what a
# frame named here but absent from the node's tree breaks.
FRAME_PARAMS = ('odom_frame', 'base_frame', 'footprint_frame', 'map_frame', 'world_frame',
                'base_link_frame', 'global_frame_id', 'odom_frame_id', 'base_frame_id',
                'global_frame', 'robot_base_frame', 'fixed_frame', 'route_frame', 'local_frame')
# Parameters that decide whether a node broadcasts an edge on tf (messages cannot tell two
# publishers of one identical edge apart): node kind -> (switch, default, parent, child)
EDGE_PARAMS = {
    'm4k_bridge': ('publish_tf', True, 'odom_frame', 'footprint_frame'),
    'ekf': ('publish_tf', True, 'world_frame', 'base_link_frame'),
    'amcl': ('tf_broadcast', True, 'global_frame_id', 'odom_frame_id'),
    'slam_toolbox': (None, True, 'map_frame', 'odom_frame'),
}
# everything doctor asks every node for (a node answers only what it declares)
PARAMS = ('use_sim_time', 'use_stamped', 'publish_tf', 'tf_broadcast', 'sonar_no_echo',
          'sonar_field_of_view', 'observation_sources', 'polygons', 'source_timeout',
          'frame_prefix') + FRAME_PARAMS


@dataclasses.dataclass(frozen=True)
class TfSample:
    """One transform seen on a TF topic."""

    topic: str
    static: bool
    parent: str
    child: str
    stamp: float


def tf_namespace(topic: str) -> str:
    """Return the namespace whose tree a TF topic carries ('/r1/tf' -> '/r1', '/tf' -> '')."""
    return topic.rsplit('/', 1)[0]


def _kind(fqn: str, params: Mapping[str, Any]) -> str | None:
    base = fqn.rsplit('/', 1)[-1]
    if base == 'm4k_bridge':
        return 'm4k_bridge'
    if 'world_frame' in params and 'base_link_frame' in params:
        return 'ekf'
    if 'tf_broadcast' in params and 'global_frame_id' in params:
        return 'amcl'
    if base == 'slam_toolbox':
        return 'slam_toolbox'
    return None


def _edge(kind: str, params: Mapping[str, Any]) -> tuple[str, str] | None:
    switch, default, parent, child = EDGE_PARAMS[kind]
    if switch and not params.get(switch, default):
        return None
    prefix = str(params.get('frame_prefix') or '')
    p = params.get(parent)
    c = params.get(child) or (params.get('base_frame') if kind == 'm4k_bridge' else None)
    if not p or not c:
        return None
    return prefix + str(p), prefix + str(c)


def duplicate_edges(eps: Sequence[Endpoint],
                    params: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Return the TF edges two nodes both say they broadcast into one tree."""
    claims: dict[tuple[str, tuple[str, str]], list[str]] = {}
    for fqn, p in sorted(params.items()):
        kind = _kind(fqn, p)
        edge = _edge(kind, p) if kind else None
        if edge is None:
            continue
        topics = {e.topic for e in eps if e.node == fqn and e.kind == 'pub'
                  and e.type == TF_TYPE and not e.topic.endswith('tf_static')}
        for t in topics:
            claims.setdefault((t, edge), []).append(fqn)
    out = []
    for (topic, (parent, child)), nodes in sorted(claims.items()):
        if len(nodes) > 1:
            out.append('{} -> {} on {} is broadcast by {} nodes ({}): tf listeners jump '
                       "between them; keep one (with an EKF: the bridge's publish_tf: false, "
                       "the EKF recipe's m4k_bridge section)".format(
                           parent, child, topic, len(nodes), ', '.join(nodes)))
    return out


def wrong_tree_publishers(eps: Sequence[Endpoint]) -> list[str]:
    """Return nodes of a robot's namespace that publish TF into another robot's tree.

    A node in ``/r1`` publishing on ``/tf`` while ``/r1/tf`` exists was started without the
    ``/tf:=tf`` remaps: its transforms miss its robot's tree.
    """
    trees = {tf_namespace(e.topic) for e in eps if e.type == TF_TYPE and e.kind == 'pub'}
    out = []
    for e in sorted(eps, key=lambda e: (e.node, e.topic)):
        if e.type != TF_TYPE or e.kind != 'pub':
            continue
        ns = e.node.rsplit('/', 1)[0]
        home = max((t for t in trees if t and (ns + '/').startswith(t + '/')), key=len,
                   default='')
        if home and tf_namespace(e.topic) != home:
            out.append("{} publishes {} but its robot's tree is {}/{}: start it with -r "
                       '/tf:=tf -r /tf_static:=tf_static (as m4k_nav2.launch.py does)'.format(
                           e.node, e.topic, home, e.topic.rsplit('/', 1)[-1]))
    return out


def tree_problems(samples: Iterable[TfSample], eps: Sequence[Endpoint], now: float,
                  stale_s: float) -> list[str]:
    """Return each robot's tree problems, one tree per namespace (``/r1/tf``, ``/r1/tf_static``).

    Two parents, two static publishers of one frame, a split tree, stale dynamic transforms.
    """
    by_ns: dict[str, list[TfSample]] = {}
    for s in samples:
        by_ns.setdefault(tf_namespace(s.topic), []).append(s)
    out = []
    for ns, ss in sorted(by_ns.items()):
        where = (ns or '') + '/tf'
        parents: dict[str, set[str]] = {}
        static_n: dict[str, int] = {}
        latest: dict[str, float] = {}
        for s in ss:
            parents.setdefault(s.child, set()).add(s.parent)
            if s.static:
                static_n[s.child] = static_n.get(s.child, 0) + 1
            else:
                latest[s.child] = max(latest.get(s.child, 0.0), s.stamp)
        for child, ps in sorted(parents.items()):
            if len(ps) > 1:
                out.append('frame {} has {} parents ({}) on {}: two publishers disagree; keep '
                           "one (the bridge's publish_tf / publish_robot_state, the EKF's "
                           'publish_tf, robot_state_publisher)'.format(
                               child, len(ps), ', '.join(sorted(ps)), where))
        static_topic = (ns or '') + '/tf_static'
        static_pubs = sorted({e.node for e in eps if e.topic == static_topic
                              and e.kind == 'pub'})
        if len(static_pubs) > 1:
            for child, n in sorted(static_n.items()):
                if n > 1:
                    out.append('frame {} is published on {} by more than one of {}: turn one '
                               "off (robot_state_publisher:=true turns the bridge's "
                               'publish_robot_state off)'.format(child, static_topic,
                                                                 ', '.join(static_pubs)))
        frames = set(parents) | {p for ps in parents.values() for p in ps}
        roots = sorted(f for f in frames if f not in parents)
        if len(roots) > 1:
            out.append('the TF tree on {} is split into {} trees with roots {}: a transform '
                       'between them is missing or published elsewhere (another tf topic, a '
                       'frame_prefix, a node not running)'.format(where, len(roots),
                                                                  ', '.join(roots)))
        for child, stamp in sorted(latest.items()):
            if now - stamp > stale_s:
                out.append('transform to {} on {} is stamped {:.1f} s behind this clock: its '
                           'publisher is stalled or on another clock (use_sim_time, NTP)'
                           .format(child, where, now - stamp))
    return out


def frame_parameter_problems(eps: Sequence[Endpoint], params: Mapping[str, Mapping[str, Any]],
                             samples: Iterable[TfSample]) -> list[str]:
    """Return frame parameters naming a frame the node's own tree does not have."""
    frames: dict[str, set[str]] = {}
    for s in samples:
        frames.setdefault(tf_namespace(s.topic), set()).update((s.parent, s.child))
    out = []
    for fqn, p in sorted(params.items()):
        reads = {tf_namespace(e.topic) for e in eps if e.node == fqn and e.type == TF_TYPE}
        if not reads and fqn.rsplit('/', 1)[-1] != bridge_params.NODE_NAME:
            # a node whose listener is a node of its own (Nav2's costmaps: tf2_ros'
            # TransformListener without a node) reads its robot's tree: the tree of the
            # longest namespace above it. The bridge publishes its frames, reads none.
            ns = fqn.rsplit('/', 1)[0]
            home = max((t for t in frames if (ns + '/').startswith(t + '/') or t == ''),
                       key=len, default=None)
            reads = {home} if home is not None else set()
        for ns in sorted(reads):
            have = frames.get(ns)
            if not have:
                continue
            for key in FRAME_PARAMS:
                v = p.get(key)
                if isinstance(v, str) and v and v not in have:
                    out.append('{} {}: {!r} is not a frame of the tree on {}/tf (it has {}): '
                               'name one of them, or start what publishes {}'.format(
                                   fqn, key, v, ns, ', '.join(sorted(have)), v))
    return out


def sim_time_problems(eps: Sequence[Endpoint],
                      params: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Return use_sim_time disagreements and nodes on sim time with no /clock."""
    sim = {k: bool(v['use_sim_time']) for k, v in params.items()
           if isinstance(v.get('use_sim_time'), bool)}
    out = []
    if len(set(sim.values())) > 1:
        on = sorted(k for k, v in sim.items() if v)
        off = sorted(k for k, v in sim.items() if not v)
        few, many, state = (on, off, 'true') if len(on) <= len(off) else (off, on, 'false')
        out.append('use_sim_time is {} on {} but {} on {}: one clock for all nodes (set it the '
                   'same everywhere; with a simulator, true; with the robot, false)'.format(
                       state, ', '.join(few), 'false' if state == 'true' else 'true',
                       ', '.join(many)))
    clocks = [e for e in eps if e.kind == 'pub' and e.topic == '/clock']
    on = sorted(k for k, v in sim.items() if v)
    if on and not clocks:
        out.append('use_sim_time is true on {} but nothing publishes /clock: their time stands '
                   'at 0 (no timer fires, every transform is in the future); set use_sim_time '
                   'false, or start the simulator'.format(', '.join(on)))
    return out


def lifecycle_problems(states: Mapping[str, str]) -> list[str]:
    """Return lifecycle nodes that are not active (state label by node)."""
    return ['{} is {}, not active: its lifecycle manager did not bring it up (a configure '
            "failure aborts the manager's bringup; read the node's log, then restart the "
            "stack or call its manager's startup)".format(fqn, label)
            for fqn, label in sorted(states.items()) if label != 'active']


def sonar_source_problems(eps: Sequence[Endpoint], params: Mapping[str, Mapping[str, Any]],
                          sources: Mapping[str, Mapping[str, Any]],
                          default_timeout: float = 2.0) -> list[str]:
    """Return collision-monitor Range sources on an m4k sonar that cannot work.

    ``sources``: monitor fqn -> its parameters '<source>.type', '<source>.topic',
    '<source>.obstacles_angle', '<source>.source_timeout', '<polygon>.min_points' (as read).
    """
    out = []
    pubs = {e.topic: e.node for e in eps if e.kind == 'pub' and e.m4k}
    for fqn, p in sorted(params.items()):
        src = p.get('observation_sources')
        if not isinstance(src, list):
            continue
        q = sources.get(fqn, {})
        min_points = min([int(q.get(poly + '.min_points', 4)) for poly in
                          (p.get('polygons') or [])] or [4])
        ns = fqn.rsplit('/', 1)[0]
        for s in src:
            if q.get(s + '.type') != 'range':
                continue
            topic = str(q.get(s + '.topic', 'scan'))
            topic = topic if topic.startswith('/') else ns + '/' + topic
            bridge = params.get(pubs.get(topic, ''), None)
            if bridge is None:
                continue
            timeout = q.get(s + '.source_timeout', p.get('source_timeout', default_timeout))
            out += range_source_problems(
                fqn, s, no_echo=str(bridge.get('sonar_no_echo',
                                               bridge_params.spec('sonar_no_echo').default)),
                field_of_view=float(bridge.get(
                    'sonar_field_of_view', bridge_params.spec('sonar_field_of_view').default)),
                obstacles_angle=float(q.get(s + '.obstacles_angle', 3.141592653589793 / 180)),
                min_points=min_points, source_timeout=float(timeout))
    return out
