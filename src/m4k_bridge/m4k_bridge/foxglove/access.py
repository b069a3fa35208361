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

The tokens are for a LAN where the port is reachable by more than the operators, and they
are how a client gets more than the base right (:mod:`.rights`): the admission token
(``token_file``) gives the base right, ``drive_token_file`` drive, ``safety_token_file``
safety. A client presents one token, in whichever place it can set
(:func:`presented_tokens`): the URL's query ``ws://robot:8765/?token=SECRET`` (every client
can; it is the only place the Foxglove and Lichtblick apps can put it), an
``Authorization: Bearer SECRET`` header (native clients), or an extra offered subprotocol
``m4k-token.SECRET`` (a browser page can set subprotocols but no header; the server never
selects it, it answers ``foxglove.websocket.v1``). Tokens are compared in constant time and
never logged.
"""

from __future__ import annotations

import hmac
import os
import re
import ssl
import stat
from typing import Sequence
from urllib.parse import parse_qs, urlsplit

__all__ = ['AccessError', 'Credentials', 'DEFAULT_ORIGINS', 'OriginPolicy',
           'SUBPROTOCOL_TOKEN', 'presented_tokens', 'read_token_file', 'tls_context']

SUBPROTOCOL_TOKEN = 'm4k-token.'

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


def presented_tokens(path: str, authorization: list[str], subprotocols: list[str]
                     ) -> list[str]:
    """Return every token a handshake carries: query ``token``, Bearer header, subprotocol."""
    found = list(parse_qs(urlsplit(path).query).get('token', []))
    for value in authorization:
        scheme, _, cred = value.strip().partition(' ')
        if scheme.lower() == 'bearer' and cred.strip():
            found.append(cred.strip())
    for header in subprotocols:
        for offered in header.split(','):
            offered = offered.strip()
            if offered.startswith(SUBPROTOCOL_TOKEN):
                found.append(offered[len(SUBPROTOCOL_TOKEN):])
    return found


class Credentials:
    """Map the token a handshake presents to a right (None: refuse with 401).

    ``base`` is the right of an admitted client without a right token; ``admit`` the
    admission token (None: no token needed to be admitted), ``drive`` and ``safety`` the
    tokens that give those rights. Each token presented must match one of them: a wrong one
    is refused rather than served with less (the operator learns the token is wrong).
    """

    def __init__(self, base: str, admit: str | None = None, drive: str | None = None,
                 safety: str | None = None) -> None:
        """Refuse two rights sharing one token (AccessError)."""
        given = [t for t in (admit, drive, safety) if t is not None]
        if len(set(given)) != len(given):
            raise AccessError('token_file, drive_token_file and safety_token_file must hold '
                              'different tokens')
        self.base, self.admit = base, admit
        self.by_right = [(r, t) for r, t in (('safety', safety), ('drive', drive)) if t]

    @property
    def needs_token(self) -> bool:
        """Return True when no client is admitted without a token."""
        return self.admit is not None

    def right(self, tokens: list[str]) -> str | None:
        """Return the right ``tokens`` (what :func:`presented_tokens` found) give, or None."""
        if len(tokens) > 1:
            return None                  # more than one token: ambiguous, refused
        if not tokens:
            return None if self.admit is not None else self.base
        given = tokens[0].encode()
        right = None
        # Every comparison runs whatever matched first (constant time over the candidates).
        for name, token in self.by_right:
            if hmac.compare_digest(given, token.encode()) and right is None:
                right = name
        if self.admit is not None and hmac.compare_digest(given, self.admit.encode()) \
                and right is None:
            right = self.base
        return right


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


def tls_context(cert: str, key: str) -> ssl.SSLContext | None:
    """Return the server's TLS context for ``cert``/``key`` (PEM), None when both are empty.

    The key file must not be readable by others (as a token file); TLS 1.2 at least.
    """
    if not cert and not key:
        return None
    if not (cert and key):
        raise AccessError('tls_cert_file and tls_key_file go together (one is empty)')
    try:
        st = os.stat(key)
    except OSError as exc:
        raise AccessError('tls_key_file {!r}: {}'.format(key, exc.strerror)) from None
    if st.st_mode & 0o077:
        raise AccessError('tls_key_file {!r}: mode {:04o} lets other users read it; chmod '
                          '600 it'.format(key, st.st_mode & 0o777))
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    try:
        ctx.load_cert_chain(cert, key)
    except (OSError, ssl.SSLError) as exc:
        raise AccessError('tls_cert_file {!r} / tls_key_file {!r}: {}'.format(
            cert, key, exc)) from None
    return ctx
