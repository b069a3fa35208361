"""Foxglove WebSocket protocol v1 (subprotocol ``foxglove.websocket.v1``): the wire format.

Pure functions and constants, written from the published specification (ws-protocol
``docs/spec.md``): JSON text messages carry an ``op`` field, binary messages start with a
one-byte opcode and use little-endian integers. Only what m4k serves is here: server info,
status, advertise/unadvertise (channels and services), message data, parameter values and
service call responses; and the parsing of what a client sends (client message data,
service call requests). Parsing raises :class:`ProtocolError` with a specific reason.
"""

from __future__ import annotations

import json
import math
import os
import re
import struct
from typing import Any, Callable, Mapping, Sequence

from m4k_bridge.bag.msgdef import dependencies, SEPARATOR, split_type

__all__ = [
    'BIN_MESSAGE_DATA', 'BIN_SERVICE_CALL_RESPONSE', 'CLIENT_MESSAGE_DATA',
    'CLIENT_SERVICE_CALL_REQUEST', 'ProtocolError', 'SUBPROTOCOL', 'advertise',
    'advertise_services', 'message_data', 'service', 'parameter_value', 'parameter_values',
    'parse_client_message_data', 'parse_service_call_request', 'server_info',
    'service_call_failure', 'service_call_response', 'service_definitions', 'status',
    'unadvertise',
]

SUBPROTOCOL = 'foxglove.websocket.v1'
# Server -> client binary opcodes.
BIN_MESSAGE_DATA = 0x01
BIN_SERVICE_CALL_RESPONSE = 0x03
# Client -> server binary opcodes.
CLIENT_MESSAGE_DATA = 0x01
CLIENT_SERVICE_CALL_REQUEST = 0x02

_MSG_HEADER = struct.Struct('<BIQ')      # opcode, subscription id, receive time (ns)
_CLIENT_MSG = struct.Struct('<BI')       # opcode, client channel id
_CALL_HEADER = struct.Struct('<BIII')    # opcode, service id, call id, encoding length
_U32 = 0xFFFFFFFF


class ProtocolError(ValueError):
    """A client message that does not follow the protocol."""


def _json(doc: Mapping[str, Any]) -> str:
    return json.dumps(doc, separators=(',', ':'), allow_nan=False)


def server_info(name: str, capabilities: Sequence[str], encodings: Sequence[str],
                session_id: str, metadata: Mapping[str, str] | None = None) -> str:
    """Return the ``serverInfo`` text message (always the first message to a client)."""
    return _json({'op': 'serverInfo', 'name': name, 'capabilities': list(capabilities),
                  'supportedEncodings': list(encodings), 'metadata': dict(metadata or {}),
                  'sessionId': session_id})


def status(level: int, message: str) -> str:
    """Return a ``status`` text message: level 0 info, 1 warning, 2 error."""
    return _json({'op': 'status', 'level': int(level), 'message': message})


def advertise(channels: Sequence[Mapping[str, Any]]) -> str:
    """Return an ``advertise`` message (channels: id, topic, encoding, schemaName, schema...)."""
    return _json({'op': 'advertise', 'channels': [dict(c) for c in channels]})


def unadvertise(channel_ids: Sequence[int]) -> str:
    """Return an ``unadvertise`` message."""
    return _json({'op': 'unadvertise', 'channelIds': [int(i) for i in channel_ids]})


def advertise_services(services: Sequence[Mapping[str, Any]]) -> str:
    """Return an ``advertiseServices`` message (each service from :func:`service`)."""
    return _json({'op': 'advertiseServices', 'services': [dict(s) for s in services]})


def service(service_id: int, name: str, type_name: str, request_schema: str,
            response_schema: str, encoding: str = 'cdr') -> dict[str, Any]:
    """Return one service of ``advertiseServices`` in the current form of the spec.

    ``request`` and ``response`` objects (encoding, schemaName, schemaEncoding, schema), not
    the deprecated ``requestSchema``/``responseSchema`` strings that Lichtblick warns about.
    The schema names follow the convention the spec and the clients use to derive them from
    the type: ``pkg/srv/Name_Request``, ``pkg/srv/Name_Response``.
    """
    def half(suffix: str, schema: str) -> dict[str, str]:
        return {'encoding': encoding, 'schemaName': type_name + suffix,
                'schemaEncoding': 'ros2msg', 'schema': schema}

    return {'id': int(service_id), 'name': name, 'type': type_name,
            'request': half('_Request', request_schema),
            'response': half('_Response', response_schema)}


def service_call_failure(service_id: int, call_id: int, message: str) -> str:
    """Return a ``serviceCallFailure`` message (a call that got no response, and why)."""
    return _json({'op': 'serviceCallFailure', 'serviceId': int(service_id),
                  'callId': int(call_id), 'message': message})


def message_data(subscription_id: int, receive_ns: int, payload: bytes) -> bytes:
    """Return a binary Message Data frame (opcode 0x01)."""
    return _MSG_HEADER.pack(BIN_MESSAGE_DATA, subscription_id & _U32, receive_ns) + payload


def service_call_response(service_id: int, call_id: int, encoding: str,
                          payload: bytes) -> bytes:
    """Return a binary Service Call Response frame (opcode 0x03)."""
    enc = encoding.encode()
    return _CALL_HEADER.pack(BIN_SERVICE_CALL_RESPONSE, service_id, call_id, len(enc)) + enc \
        + payload


def parse_client_message_data(frame: bytes) -> tuple[int, bytes]:
    """Return (client channel id, payload) of a Client Message Data frame."""
    if len(frame) < _CLIENT_MSG.size or frame[0] != CLIENT_MESSAGE_DATA:
        raise ProtocolError('not a client message data frame ({} bytes, opcode {})'.format(
            len(frame), frame[0] if frame else None))
    _, channel = _CLIENT_MSG.unpack_from(frame)
    return channel, bytes(frame[_CLIENT_MSG.size:])


def parse_service_call_request(frame: bytes) -> tuple[int, int, str, bytes]:
    """Return (service id, call id, encoding, payload) of a Service Call Request frame."""
    if len(frame) < _CALL_HEADER.size or frame[0] != CLIENT_SERVICE_CALL_REQUEST:
        raise ProtocolError('not a service call request frame ({} bytes)'.format(len(frame)))
    _, service, call, n = _CALL_HEADER.unpack_from(frame)
    end = _CALL_HEADER.size + n
    if end > len(frame):
        raise ProtocolError('service call request: encoding length {} past the frame end '
                            '({} bytes)'.format(n, len(frame)))
    try:
        encoding = bytes(frame[_CALL_HEADER.size:end]).decode()
    except UnicodeDecodeError:
        raise ProtocolError('service call request: encoding is not UTF-8') from None
    return service, call, encoding, bytes(frame[end:])


def parameter_value(value: Any) -> dict[str, Any]:
    """Return the ``{value, type?}`` of a ROS parameter value for ``parameterValues``.

    Doubles say ``float64`` (so 1.0 is not taken for an integer), arrays of doubles
    ``float64_array``, byte arrays ``byte_array`` (base64); non-finite doubles, which JSON
    cannot carry, become strings.
    """
    import base64
    if isinstance(value, bool) or isinstance(value, (int, str)):
        return {'value': value}
    if isinstance(value, float):
        return {'value': value, 'type': 'float64'} if math.isfinite(value) \
            else {'value': str(value)}
    if isinstance(value, (bytes, bytearray)):
        return {'value': base64.b64encode(bytes(value)).decode(), 'type': 'byte_array'}
    items = list(value)
    if items and all(isinstance(v, float) for v in items):
        if all(math.isfinite(v) for v in items):
            return {'value': items, 'type': 'float64_array'}
        return {'value': [str(v) for v in items]}
    return {'value': items}


def parameter_values(params: Sequence[tuple[str, Any]], request_id: str | None) -> str:
    """Return a ``parameterValues`` message for (name, value) pairs."""
    doc: dict[str, Any] = {'op': 'parameterValues',
                           'parameters': [dict(name=n, **parameter_value(v))
                                          for n, v in params]}
    if request_id is not None:
        doc['id'] = request_id
    return _json(doc)


def _default_share(package: str) -> str:
    from ament_index_python.packages import get_package_share_directory
    return get_package_share_directory(package)


def service_definitions(type_name: str, share: Callable[[str], str] = _default_share
                        ) -> tuple[str, str]:
    """Return the ``ros2msg`` texts (request, response) of service type ``pkg/srv/Name``.

    Each half of the installed ``.srv`` file with the definitions of the message types it
    uses appended as in a ``ros2msg`` schema (80 ``=``, ``MSG: pkg/Name``, the text).
    """
    parts = type_name.split('/')
    if len(parts) != 3 or parts[1] != 'srv':
        raise ValueError('not a service type name (pkg/srv/Name): {!r}'.format(type_name))
    package, name = parts[0], parts[2]
    with open(os.path.join(share(package), 'srv', name + '.srv'), encoding='utf-8') as f:
        text = f.read()
    halves = re.split(r'^---[ \t]*$', text, flags=re.MULTILINE)
    if len(halves) != 2:
        raise ValueError('{}: expected one --- separator line'.format(type_name))
    return (_with_dependencies(halves[0].strip('\n'), package, share),
            _with_dependencies(halves[1].strip('\n'), package, share))


def _with_dependencies(text: str, package: str, share: Callable[[str], str]) -> str:
    if not text.strip():
        return ''          # an empty request or response (std_srvs/Trigger's request)
    out = [text.rstrip('\n')]
    seen: set[str] = set()
    stack = list(reversed(dependencies(text, package)))
    while stack:
        dep = stack.pop()
        if dep in seen:
            continue
        seen.add(dep)
        pkg, name = split_type(dep)
        with open(os.path.join(share(pkg), 'msg', name + '.msg'), encoding='utf-8') as f:
            sub = f.read()
        out.append('{}\nMSG: {}\n{}'.format(SEPARATOR, dep, sub.rstrip('\n')))
        stack.extend(reversed(dependencies(sub, pkg)))
    return '\n'.join(out) + '\n'
