"""The runtime directory: where ports live, and who may reach them (the channel's security).

Access control is the file system's, as for ``/dev/rtpN``: the runtime directory is 0700 (0770
with a group) and refuses to be used when it is owned by someone else or is more open than
configured; sockets are 0600 (0660). Port N is the socket ``<runtime_dir>/xddp<N>``, a label
the symlink ``label.<label>`` to it.
"""

import errno
import grp
import os
import socket
import stat

from m4k_rt.channel.contract import check_label, check_port, DEFAULT_MAX_PORTS, XddpError


def default_runtime_dir() -> str:
    """Return the runtime directory: $M4K_RUNTIME_DIR, $XDG_RUNTIME_DIR/m4k, /run/m4k, /tmp."""
    path = os.environ.get('M4K_RUNTIME_DIR')
    if path:
        return path
    xdg = os.environ.get('XDG_RUNTIME_DIR')
    if xdg:
        return os.path.join(xdg, 'm4k')
    if os.geteuid() == 0:
        return '/run/m4k'
    return '/tmp/m4k-{}'.format(os.getuid())


def gid_of(group: str | int | None) -> int | None:
    """Return the gid of a group name or number (None: no group), else raise XddpError."""
    if group is None:
        return None
    if isinstance(group, int) and not isinstance(group, bool):
        return group
    if isinstance(group, str):
        try:
            return grp.getgrnam(group).gr_gid
        except KeyError:
            pass
    raise XddpError('unknown group {!r}'.format(group), None, errno.EINVAL)


def ensure_runtime_dir(path: str | None = None, group: str | int | None = None) -> str:
    """Create (0700, or 0770 + chgrp) or check the runtime directory and return its path.

    Like ssh with ``~/.ssh``, refuse a directory that is a symlink, is owned by another user,
    has another group than configured, or grants more than the configured permissions.
    """
    path = os.path.abspath(path or default_runtime_dir())
    gid = gid_of(group)
    mode = 0o770 if gid is not None else 0o700
    try:
        try:
            os.mkdir(path, mode)
            created = True
        except FileNotFoundError:
            os.makedirs(os.path.dirname(path), 0o755, exist_ok=True)
            os.mkdir(path, mode)
            created = True
        except FileExistsError:
            created = False
        if created:
            if gid is not None:
                os.chown(path, -1, gid)
            os.chmod(path, mode)  # mkdir's mode went through the umask
        st = os.lstat(path)
    except OSError as exc:
        raise XddpError('cannot create runtime directory {!r}: {}'.format(
            path, exc.strerror), path, exc.errno) from exc
    if not stat.S_ISDIR(st.st_mode):
        raise XddpError('runtime directory {!r} is not a directory (symlinks are refused)'.format(
            path), path, errno.ENOTDIR)
    if st.st_uid != os.geteuid():
        raise XddpError('runtime directory {!r} is owned by uid {}, not by uid {}: refusing to '
                        'use it'.format(path, st.st_uid, os.geteuid()), path, errno.EPERM)
    perm = st.st_mode & 0o777
    if perm & ~mode:
        raise XddpError('runtime directory {!r} has mode {:04o}, wider than {:04o}: refusing to '
                        'use it (chmod {:o} it or remove it)'.format(path, perm, mode, mode),
                        path, errno.EPERM)
    if gid is not None and st.st_gid != gid:
        raise XddpError('runtime directory {!r} has group {}, expected {}'.format(
            path, st.st_gid, gid), path, errno.EPERM)
    if perm != mode:
        os.chmod(path, mode)  # narrower than configured (e.g. 0700 with a group): ours, widen
    return path


def check_runtime_dir(path: str | None = None, group: str | int | None = None) -> str:
    """Check, as the NRT side, the runtime directory the RT side made; return its path.

    The NRT side neither creates nor changes it (a missing directory is only "nothing bound
    yet"), but before it links it refuses what :func:`ensure_runtime_dir` refuses: a symlink
    or non-directory, an owner it cannot trust, permissions wider than 0700 (0770 with a
    group), another group than the configured one. Trusted owners: this user, root, and with
    a group its members (the RT process may run as another member). Else whoever made the
    directory could have planted the sockets: a fake RT side that reads the commands or feeds
    odometry. A peer of a stack configured with a group must be given that group.
    """
    path = os.path.abspath(path or default_runtime_dir())
    gid = gid_of(group)
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return path
    except OSError as exc:
        raise XddpError('cannot check runtime directory {!r}: {}'.format(
            path, exc.strerror), path, exc.errno) from exc
    if not stat.S_ISDIR(st.st_mode):
        raise XddpError('runtime directory {!r} is not a directory (symlinks are refused)'.format(
            path), path, errno.ENOTDIR)
    euid = os.geteuid()
    if st.st_uid not in (euid, 0) and not (gid is not None and _member(st.st_uid, gid)):
        raise XddpError('runtime directory {!r} is owned by uid {}, not by uid {}{}: refusing '
                        'to link to it'.format(path, st.st_uid, euid, '' if gid is None else
                                               ' or a member of group {}'.format(gid)),
                        path, errno.EPERM)
    perm = st.st_mode & 0o777
    mode = 0o770 if gid is not None else 0o700
    if perm & ~mode:
        raise XddpError('runtime directory {!r} has mode {:04o}, wider than {:04o}: refusing to '
                        'link to it'.format(path, perm, mode), path, errno.EPERM)
    if gid is not None and st.st_gid != gid:
        raise XddpError('runtime directory {!r} has group {}, expected {}'.format(
            path, st.st_gid, gid), path, errno.EPERM)
    return path


def _member(uid: int, gid: int) -> bool:
    import pwd
    try:
        user = pwd.getpwuid(uid)
        return user.pw_gid == gid or user.pw_name in grp.getgrgid(gid).gr_mem
    except KeyError:
        return False


def port_path(port_or_label: int | str, runtime_dir: str | None = None,
              max_ports: int = DEFAULT_MAX_PORTS) -> str:
    """Return the socket path of a port number or the symlink path of a label."""
    rd = runtime_dir or default_runtime_dir()
    if isinstance(port_or_label, str):
        return os.path.join(rd, 'label.' + check_label(port_or_label))
    return os.path.join(rd, 'xddp{}'.format(check_port(port_or_label, max_ports)))


def socket_alive(path: str) -> bool:
    """Return True when a live process has a socket bound at ``path``."""
    # A datagram socket cannot connect to a stream/seqpacket listener (EPROTOTYPE) but finds
    # out whether one is bound without creating a connection the live process would see.
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
    try:
        probe.connect(path)
    except OSError as exc:
        return exc.errno not in (errno.ECONNREFUSED, errno.ENOENT)
    finally:
        probe.close()
    return True
