"""Parameters of the live view node ``m4k_foxglove``: one table of schema Fields (no rclpy).

The node declares each with a ParameterDescriptor built from its Field
(:func:`m4k_bridge.foxglove.node.descriptor`), and ``docs/configuration.md`` documents them
from the same table (``m4k_bringup.configdoc``). Every one is read-only: the server is set up
once, at start.
"""

from __future__ import annotations

import re
from typing import Any, Mapping

from m4k_bridge.foxglove.access import AccessError, DEFAULT_ORIGINS, OriginPolicy
from m4k_rt.schema import Field

__all__ = ['NAV_TOPICS', 'NODE_NAME', 'SPECS', 'check_param_file', 'validate']

NODE_NAME = 'm4k_foxglove'
# What the 3D panel's publish tool advertises as soon as a layout opens (Foxglove and
# Lichtblick: ThreeDeeRender advertises all three whatever the chosen click type), as the
# shipped layout names them: Nav2's goal, RViz's clicked point, AMCL's initial pose.
NAV_TOPICS = {'goal_pose': 'geometry_msgs/msg/PoseStamped',
              'clicked_point': 'geometry_msgs/msg/PointStamped',
              'initialpose': 'geometry_msgs/msg/PoseWithCovarianceStamped'}


def _origins(v: Any) -> str | None:
    try:
        OriginPolicy(v)
    except AccessError as exc:
        return str(exc).split(': ', 1)[1]
    return None


def _regexes(v: Any) -> str | None:
    for p in v:
        try:
            re.compile(p)
        except re.error as exc:
            return 'not a regular expression: {!r} ({})'.format(p, exc)
    return None


def _f(name: str, type_: str, default: Any, description: str, **kw: Any) -> Field:
    return Field(type_, default, description, name=name, read_only=True, **kw)


SPECS: tuple[Field, ...] = (
    _f('address', 'str', '127.0.0.1', 'Listen address. 0.0.0.0 serves every interface: '
       'anyone who reaches the port sees the robot and, with client_topics, drives it (set '
       'token_file and firewall the port).'),
    _f('port', 'int', 8765, 'TCP port (0: any free port, logged). Taken: the node exits 1.',
       lo=0, hi=65535),
    _f('allowed_origins', 'str[]', list(DEFAULT_ORIGINS),
       'Origin headers a handshake may carry (scheme://host[:port], scheme://host:* for any '
       'port, file://, null); a handshake without Origin (a native client) is always '
       'admitted, any other gets HTTP 403 before serverInfo. Too wide: a web page in the '
       "operator's browser can drive the robot through the SSH tunnel; too narrow: the app "
       'cannot connect (a self-hosted Lichtblick on another host needs its origin here).',
       check=_origins),
    _f('token_file', 'str', '', 'File (mode 0600, this user) holding a shared token of at '
       'least 16 URL-safe characters; clients then connect to ws://host:port/?token=TOKEN '
       '(or Authorization: Bearer TOKEN, or subprotocol m4k-token.TOKEN) and any other '
       'handshake gets HTTP 401. Empty: no token (localhost behind SSH).'),
    _f('rights', 'str', 'drive', 'The right of an admitted client that presents no right '
       'token: view (subscribe only: no publish or service capability is offered), drive '
       '(also cmd_vel, led, e-stop engage, reset_odometry), safety (also e-stop release, '
       'reset_motor_fault, set_pose, other allowed services). safety here lets anyone '
       'admitted release the e-stop.', choices=('view', 'drive', 'safety')),
    _f('drive_token_file', 'str', '', 'Token file (as token_file) whose token gives the drive '
       'right. Empty: none.'),
    _f('safety_token_file', 'str', '', 'Token file (as token_file) whose token gives the '
       'safety right. Empty: nobody releases the e-stop through the live view (unless rights '
       'is safety).'),
    _f('driver_idle_timeout', 'float', 2.0, 'The single-driver lock: the client that drives '
       '(publishes cmd_vel, led or goals) keeps the lock while it publishes at least this '
       'often; after it another drive client may take over. A safety client takes over at '
       'any time.', unit='s', lo=0.1, hi=60.0),
    _f('max_publish_rate', 'float', 30.0, "Token bucket of each client's channel (burst: one "
       'second of it); a message beyond it is dropped, counted and the client told with a '
       'warning status. An e-stop engage is never limited.', unit='Hz', lo=1.0, hi=1000.0),
    _f('max_service_rate', 'float', 2.0, "Token bucket of each client's service calls "
       '(burst: one second of it, at least 1); beyond it the call fails with the reason. An '
       'e-stop engage is never limited.', unit='Hz', lo=0.1, hi=100.0),
    _f('service_timeout', 'float', 5.0, 'A service call with no response by then fails '
       '(serviceCallFailure) and is forgotten.', unit='s', lo=0.1, hi=300.0),
    _f('tls_cert_file', 'str', '', 'PEM certificate (chain) for wss://; with tls_key_file. '
       'Empty: plain ws://.'),
    _f('tls_key_file', 'str', '', 'PEM private key of tls_cert_file (mode 0600).'),
    _f('max_clients', 'int', 4, 'Connections served at once; one more is refused (HTTP 503) '
       'before serverInfo. Each client costs queues of up to max_queue_bytes.', lo=1, hi=64),
    _f('max_client_channels', 'int', 16, 'Channels one client may advertise for publishing '
       '(each is an rclpy publisher); beyond it the advertisement is refused with a status '
       'naming this parameter. The shipped layout advertises 5.', lo=1, hi=256),
    _f('topic_whitelist', 'str[]', ['.*'], 'Regular expressions (full match) of the topics '
       'served.', check=_regexes),
    _f('service_whitelist', 'str[]', ['m4k_bridge/[a-z_]+'], 'Regular expressions (full '
       'match) of the services served; a pattern without a leading / matches the name '
       "relative to this node's namespace. Default: the bridge's own services. A service "
       'not of the bridge needs the safety right.', check=_regexes),
    _f('client_topics', 'str[]', ['cmd_vel', 'e_stop', 'led'], 'The only topics clients may '
       'publish on (relative: the namespace applies), checked before anything of the '
       "client's advertisement is imported. [] serves a view-only live view."),
    _f('nav_goals', 'bool', False, 'true: clients may also publish goal_pose '
       '(PoseStamped), clicked_point (PointStamped) and initialpose '
       "(PoseWithCovarianceStamped) -- the 3D panel's publish tool -- for a nav stack (Nav2, "
       'AMCL). false: the 3D panel may advertise them (no alert on connect) but a click '
       'publishes nothing and gets an error status naming this parameter.'),
    _f('bridge_node', 'str', 'm4k_bridge', 'Whose parameters getParameters reads.'),
    _f('max_queue_messages', 'int', 200, "Each client's message data queue bound (the oldest "
       'frame is dropped and counted beyond it).', lo=1, hi=100000),
    _f('max_queue_bytes', 'int', 8 << 20, "Each client's message data queue bound.",
       unit='bytes', lo=65536, hi=1 << 30),
    _f('graph_period', 'float', 1.0, 'How often the ROS graph is polled for new topics and '
       'services.', unit='s', lo=0.05, hi=60.0),
    _f('diagnostics_period', 'float', 1.0, 'Period of the server status on diagnostics.',
       unit='s', lo=0.1, hi=60.0),
)

_BY_NAME = {s.name: s for s in SPECS}


def check_param_file(doc: Any, path: str) -> None:
    """Refuse a ROS parameter file whose ``m4k_foxglove`` section has an unknown or bad value.

    rclpy ignores a value for a parameter the node does not declare: a misspelt
    ``token_fle`` would start the live view without its token. ValueError names the key.
    """
    if doc is None:
        return
    if not isinstance(doc, Mapping):
        raise ValueError('{}: top level must be a mapping'.format(path))
    for key, section in doc.items():
        name = str(key).rsplit('/', 1)[-1]
        if name not in (NODE_NAME, '**'):
            continue
        values = section.get('ros__parameters') if isinstance(section, Mapping) else None
        if not isinstance(values, Mapping):
            raise ValueError("{}: {}: expected a mapping with 'ros__parameters'".format(
                path, key))
        for pname, value in values.items():
            if pname == 'use_sim_time' or (name == '**' and pname not in _BY_NAME):
                continue        # a wildcard section also feeds other nodes
            if pname not in _BY_NAME:
                raise ValueError('{}: {}: unknown parameter {!r} (known: {})'.format(
                    path, key, pname, ', '.join(sorted(_BY_NAME))))
            validate({pname: value})


def validate(values: Mapping[str, Any]) -> dict[str, Any]:
    """Return the values checked against :data:`SPECS` (ValueError naming the parameter)."""
    out = {}
    for name, value in values.items():
        f = _BY_NAME[name]
        why = f.problem(value)
        if why is not None:
            raise ValueError('parameter {!r}: {}'.format(name, why))
        out[name] = value
    return out
