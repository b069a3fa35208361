"""Who may open the live view: the Origin allow-list and the optional shared token (pure).

A browser puts the page's origin in the ``Origin`` header of every WebSocket handshake and
the page cannot change it, so checking it is what stops a web page open in the operator's
browser from reaching ``ws://localhost:8765`` through the SSH tunnel and publishing
``cmd_vel`` (cross-site WebSocket hijacking; RFC 6455 section 10.2). Native clients (the
Foxglove and Lichtblick desktop apps' own network code does not run in a page; Python or C++
clients) send no Origin: they are not a cross-site risk, and a process on the machine could
forge any header anyway, so a handshake without Origin is admitted.

Patterns of the allow-list: an exact origin (``https://app.foxglove.dev``), one with any port
(``http://localhost:*``: the host with or without a port), ``file://`` (a page loaded from a
file: Chromium, hence the Electron desktop apps of Foxglove and Lichtblick, send it), or
``null`` (opaque origins: Firefox's file pages, but also sandboxed frames of any web site --
never a default). Scheme and host compare case-insensitively.

The token is for a LAN where the port is reachable by more than the operators: the client
puts it in the URL's query, ``ws://robot:8765/?token=SECRET``, which every client can do
(a browser's WebSocket cannot add headers). It is compared in constant time and never logged.
"""

from __future__ import annotations

import hmac
import os
import re
import stat
from typing import Sequence
from urllib.parse import parse_qs, urlsplit

__all__ = ['AccessError', 'DEFAULT_ORIGINS', 'OriginPolicy', 'read_token_file',
           'token_matches']

# Foxglove's web app; the desktop apps (Electron: Chromium pages from file://); pages served
# from this machine (a self-hosted Lichtblick ``web:serve`` is http://localhost:8080).
DEFAULT_ORIGINS = (
    'https://app.foxglove.dev', 'file://',
    'http://localhost:*', 'http://127.0.0.1:*', 'http://[::1]:*',
    'https://localhost:*', 'https://127.0.0.1:*', 'https://[::1]:*',
)

_PATTERN = re.compile(r'(?P<base>[a-z][a-z0-9+.-]*://(\[[0-9a-f:.]+\]|[a-z0-9.-]+))'
                      r'(?P<port>:([0-9]{1,5}|\*))?')
_ORIGIN = re.compile(r'(?P<base>[a-z][a-z0-9+.-]*://(\[[0-9a-f:.]+\]|[a-z0-9.-]+))'
                     r'(:[0-9]{1,5})?')
_MIN_TOKEN = 16


class AccessError(ValueError):
    """A bad allow-list pattern or token file (a start-up error naming the value)."""


class OriginPolicy:
    """Decide whether a handshake's ``Origin`` header may open a connection."""

    def __init__(self, patterns: Sequence[str]) -> None:
        """Validate the patterns (AccessError naming the bad one)."""
        self.exact: set[str] = set()
        self.any_port: set[str] = set()
        for p in patterns:
            if not isinstance(p, str):
                raise AccessError('allowed_origins: expected strings, got {!r}'.format(p))
            low = p.strip().lower()
            if low in ('file://', 'null'):
                self.exact.add(low)
                continue
            m = _PATTERN.fullmatch(low)
            if m is None:
                raise AccessError(
                    'allowed_origins: {!r} is not scheme://host, scheme://host:port, '
                    'scheme://host:*, file:// or null (no path, no trailing /)'.format(p))
            if m.group('port') == ':*':
                self.any_port.add(m.group('base'))
            else:
                self.exact.add(low)
        self.patterns = tuple(patterns)

    def allows(self, origin: str | None) -> bool:
        """Return True for no Origin (a native client) or an origin the list admits."""
        if origin is None:
            return True
        low = origin.strip().lower()
        if low in self.exact:
            return True
        m = _ORIGIN.fullmatch(low)
        return m is not None and m.group('base') in self.any_port


def token_matches(path: str, token: str) -> bool:
    """Return True when the request target's query carries ``token=<token>`` (constant time)."""
    given = parse_qs(urlsplit(path).query).get('token', [])
    return len(given) == 1 and hmac.compare_digest(given[0].encode(), token.encode())


def read_token_file(path: str) -> str:
    """Return the token in ``path`` (first line, stripped); refuse a file others can read.

    Like ssh with a private key: the file must be a regular file of this user, mode 0600 or
    narrower, and the token at least 16 characters of URL-safe text.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError as exc:
        raise AccessError('token_file {!r}: cannot open: {} [errno {}]'.format(
            path, exc.strerror, exc.errno)) from None
    with os.fdopen(fd, encoding='utf-8') as f:
        st = os.fstat(f.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise AccessError('token_file {!r}: not a regular file'.format(path))
        if st.st_uid != os.geteuid():
            raise AccessError('token_file {!r}: owned by uid {}, not by uid {}'.format(
                path, st.st_uid, os.geteuid()))
        if st.st_mode & 0o077:
            raise AccessError('token_file {!r}: mode {:04o} lets other users read it; '
                              'chmod 600 it'.format(path, st.st_mode & 0o777))
        token = f.readline().strip()
    if len(token) < _MIN_TOKEN or not re.fullmatch(r'[A-Za-z0-9._~-]+', token):
        raise AccessError('token_file {!r}: the token must be at least {} characters of '
                          'A-Z a-z 0-9 . _ ~ - (it travels in a URL), e.g. '
                          '`openssl rand -hex 24`'.format(path, _MIN_TOKEN))
    return token
