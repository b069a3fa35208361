"""The persisted e-stop request: a small file in the state directory (NRT and start-up only).

The e-stop latch lives in the RT actuator, which survives a bridge restart; but when rt_core
and the bridge restart together -- a service restart, a reboot -- both would start knowing
nothing of an engaged e-stop. So the bridge writes every change of the operator's request to
``<state_dir>/e_stop.request`` (one word, ``engaged`` or ``released``), and

* a restarting rt_core reads it **once while building the actuator**, before any task loop
  runs (no file I/O in the loops), and starts with the latch engaged when it says so;
* a restarting bridge reads it at start-up, gates ``cmd_vel`` and re-asserts the e-stop on
  its first link.

**Where** (:func:`state_dir`), first that applies:

1. ``$M4K_STATE_DIR``;
2. ``$STATE_DIRECTORY`` (systemd sets it from the unit's ``StateDirectory=``; the shipped
   ``config/systemd/m4k.service`` has ``StateDirectory=m4k``: ``/var/lib/m4k``, kept across
   service restarts and reboots -- unlike ``RuntimeDirectory=``, which systemd deletes when
   the service stops);
3. ``$M4K_RUNTIME_DIR`` when set, else the process's runtime directory when it was given
   one: a private stack (a test, a bench, a scenario, a process started by hand on its own
   runtime directory) keeps its own e-stop, so one stack's e-stop never reaches another's,
   and a fresh private directory starts with none;
4. otherwise the user's persistent state: ``$XDG_STATE_HOME/m4k`` (``~/.local/state/m4k``),
   ``/var/lib/m4k`` as root.

``bringup`` and the launch file resolve it once, from their own environment before they set
the children's ``M4K_RUNTIME_DIR``, and hand it on as ``M4K_STATE_DIR``: ``make run`` /
``bringup`` with no runtime directory of your own keeps the request in (4), across reboots.

**Written** atomically and durably (:func:`write_request`): a temporary file in the same
directory, fsync, rename over the old one, fsync of the directory -- a power cut leaves the
old word or the new one, never a torn file.

**Read** (:func:`read_request`): no file is "no request known" (a first start); ``engaged`` /
``released`` are what they say; anything else -- an unreadable file or directory, an empty,
torn or unknown word -- reads as **engaged**, with a diagnostic that names the path and the
cause: an e-stop state nobody can read is not a reason to drive.
"""

from __future__ import annotations

from dataclasses import dataclass
import errno
import os
from typing import Mapping

__all__ = ['FILE_NAME', 'Persisted', 'read_request', 'request_path', 'state_dir',
           'STATE_DIR_ENV', 'write_request']

FILE_NAME = 'e_stop.request'
STATE_DIR_ENV = 'M4K_STATE_DIR'
_ENGAGED = 'engaged'
_RELEASED = 'released'
_MAX_BYTES = 64


@dataclass(frozen=True)
class Persisted:
    """What the request file says: ``engaged`` True/False, or None (no file: none known).

    ``problem`` is empty, or why the file was read as engaged (unreadable, corrupt).
    """

    engaged: bool | None
    problem: str = ''


def state_dir(environ: Mapping[str, str] | None = None, runtime_dir: str | None = None) -> str:
    """Return the directory of the persisted e-stop request (see the module docstring).

    ``environ``: default ``os.environ``; ``runtime_dir``: the process's runtime directory
    (rule 3 after ``$M4K_RUNTIME_DIR``).
    """
    env = os.environ if environ is None else environ
    for value in (env.get(STATE_DIR_ENV, ''),
                  env.get('STATE_DIRECTORY', '').split(':')[0],   # systemd: the first listed
                  env.get('M4K_RUNTIME_DIR', ''), runtime_dir or ''):
        if value:
            return value
    if os.geteuid() == 0:
        return '/var/lib/m4k'
    base = env.get('XDG_STATE_HOME') or os.path.join(
        env.get('HOME') or os.path.expanduser('~'), '.local', 'state')
    return os.path.join(base, 'm4k')


def request_path(directory: str) -> str:
    """Return the request file's path in ``directory``."""
    return os.path.join(directory, FILE_NAME)


def read_request(directory: str) -> Persisted:
    """Return what the request file in ``directory`` says; unreadable or corrupt: engaged."""
    path = request_path(directory)
    try:
        with open(path, 'rb') as f:
            data = f.read(_MAX_BYTES + 1)
    except FileNotFoundError:
        return Persisted(None)
    except OSError as exc:
        return Persisted(True, 'cannot read {}: {} (errno {}): read as ENGAGED'.format(
            path, exc.strerror or exc, errno.errorcode.get(exc.errno or 0, exc.errno)))
    try:
        word = data.decode('ascii').strip() if len(data) <= _MAX_BYTES else None
    except UnicodeDecodeError:
        word = None
    if word == _ENGAGED:
        return Persisted(True)
    if word == _RELEASED:
        return Persisted(False)
    return Persisted(True, '{} is corrupt (expected "engaged" or "released", got {!r}): read '
                     'as ENGAGED'.format(path, data[:_MAX_BYTES]))


def write_request(directory: str, engaged: bool) -> None:
    """Persist the request atomically and durably; raise OSError.

    Create ``directory`` (0700) when missing; write a temporary file beside the request,
    fsync it, rename it over the request, fsync the directory (the rename itself is on disk).
    """
    os.makedirs(directory, mode=0o700, exist_ok=True)
    path = request_path(directory)
    tmp = '{}.{}.tmp'.format(path, os.getpid())
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o600)
    try:
        os.write(fd, ((_ENGAGED if engaged else _RELEASED) + '\n').encode('ascii'))
        os.fsync(fd)
    except BaseException:
        os.close(fd)
        os.unlink(tmp)
        raise
    os.close(fd)
    os.replace(tmp, path)
    dfd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)
