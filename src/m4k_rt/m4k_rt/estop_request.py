"""The persisted e-stop request: a small file in the runtime directory (NRT and start-up only).

The e-stop latch lives in the RT actuator, which survives a bridge restart; but when rt_core
and the bridge restart together, both would start knowing nothing of an engaged e-stop. So
the bridge writes every change of the operator's request to ``<runtime_dir>/e_stop.request``
(one word, ``engaged`` or ``released``, replaced atomically by rename), and

* a restarting rt_core reads it **once while building the actuator**, before any task loop
  runs (no file I/O in the loops), and starts with the latch engaged when it says so;
* a restarting bridge reads it at start-up, gates ``cmd_vel`` and re-asserts the e-stop on
  its first link.

A missing or unreadable file means "no request known": the latch starts disengaged, as
before (the bridge re-asserts what it knows). A file that exists but says something else is
read as engaged: an e-stop state nobody can read is not a reason to drive.
"""

from __future__ import annotations

import os

__all__ = ['FILE_NAME', 'read_request', 'request_path', 'write_request']

FILE_NAME = 'e_stop.request'
_ENGAGED = 'engaged'
_RELEASED = 'released'


def request_path(runtime_dir: str) -> str:
    """Return the request file's path in ``runtime_dir``."""
    return os.path.join(runtime_dir, FILE_NAME)


def read_request(runtime_dir: str) -> bool | None:
    """Return True (engaged), False (released) or None (no file / unreadable directory)."""
    try:
        with open(request_path(runtime_dir), encoding='ascii', errors='replace') as f:
            word = f.read(64).strip()
    except FileNotFoundError:
        return None
    except OSError:
        return None
    return word != _RELEASED


def write_request(runtime_dir: str, engaged: bool) -> None:
    """Persist the request atomically (write a temporary file, rename); raise OSError.

    No fsync: the runtime directory is a tmpfs on a real robot (``/run``), and a power loss
    resets the RT latch and the amplifier anyway; what must survive is a process restart.
    """
    path = request_path(runtime_dir)
    tmp = '{}.{}.tmp'.format(path, os.getpid())
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o600)
    try:
        os.write(fd, ((_ENGAGED if engaged else _RELEASED) + '\n').encode('ascii'))
    finally:
        os.close(fd)
    os.replace(tmp, path)
