"""Files replaced all or nothing, as calibration tools need: a crash, a kill -9 or a full disk
leaves the old or the new file, never a mix, and never a stray temporary file but in one narrow
window.

The content is built by the caller first, written to a temporary file in the target's directory,
fsynced and renamed over the target; then the directory is fsynced. On Linux the temporary file
is unnamed (O_TMPFILE) until its content is complete and on disk, so a killed writer leaves one
only if killed between naming it and the rename; the next save of the same target removes such
leftovers (only files of dead writers). Missing parent directories are created (as
camera_info_manager does). A symlinked target is written through: the file it points to is
replaced and the link stays. An existing file keeps its permission mode and owner where
possible; one with no write permission at all (e.g. 0444) is refused rather than replaced, as
an ofstream would fail on it. Errors name the target, never the temporary file.
"""
from __future__ import annotations

import contextlib
import errno
import os
import random
import re
import stat
import tempfile
from typing import Callable, Optional


class SaveError(OSError):
    """A file could not be written. ``strerror`` is the reason alone (one line), ``str()`` names
    the target too; the target is unchanged."""

    def __init__(self, path: str, reason: str, code: Optional[int] = None):
        reason = ' '.join(str(reason).splitlines())
        super().__init__(code if code is not None else errno.EINVAL, reason, path)
        self.message = f'cannot save {path}: {reason}'

    def __str__(self):
        return self.message


def _temp_prefix(base: str, pid: Optional[int] = None) -> str:
    """Hidden temporary name next to the target, with the writer's pid so that the next save can
    tell a dead writer's leftover from a live one's file in progress."""
    return f'.{base}.tmp-{os.getpid() if pid is None else pid}-'


def _process_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    if not 0 < pid < (1 << 22):  # pid_max limit; os.kill(0, ...) would signal our group
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # EPERM: someone else's live process
        return True
    return True


def _remove_stale_temps(directory: str, base: str):
    """Remove temporary files that writers of this target left when they were killed (SIGKILL,
    power loss: no code runs to remove them). Only our exact name pattern, only for pids that
    no longer run; best effort."""
    pattern = re.compile(re.escape(f'.{base}.tmp-') + r'([0-9]{1,10})-[a-z0-9_]{8}\Z')
    try:
        names = os.listdir(directory)
    except OSError:
        return
    for name in names:
        match = pattern.match(name)
        if match and not _process_alive(int(match.group(1))):
            with contextlib.suppress(OSError):
                os.unlink(os.path.join(directory, name))


def _umask() -> int:
    """The process umask without changing it (os.umask would, racing other threads)."""
    try:
        with open('/proc/self/status') as f:
            for line in f:
                if line.startswith('Umask:'):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _open_unnamed(directory: str, mode: int):
    """An unnamed file in ``directory`` (Linux O_TMPFILE) and no name yet, or (None, None) where
    the kernel, the file system or a missing /proc cannot give one: then a named temporary file
    is used."""
    flag = getattr(os, 'O_TMPFILE', 0)
    if not flag or not os.path.isdir('/proc/self/fd'):
        return None, None
    try:
        return os.open(directory, flag | os.O_WRONLY, mode), None
    except OSError:
        return None, None


def _link_unnamed(fd: int, directory: str, prefix: str) -> str:
    """Give the unnamed file ``fd`` a fresh temporary name (the pattern _remove_stale_temps knows)."""
    # linkat(AT_SYMLINK_FOLLOW) on /proc/self/fd/N, as open(2) documents for O_TMPFILE. Python
    # calls plain link(), which does not follow the magic link, unless a src_dir_fd is given.
    proc_fd = os.open('/proc/self/fd', os.O_RDONLY | os.O_DIRECTORY)
    try:
        for _ in range(100):
            name = os.path.join(directory, prefix + ''.join(random.choices(_TEMP_CHARS, k=8)))
            try:
                os.link(str(fd), name, src_dir_fd=proc_fd, follow_symlinks=True)
                return name
            except FileExistsError:
                continue
    finally:
        os.close(proc_fd)
    raise FileExistsError(errno.EEXIST, 'no free temporary name')


_TEMP_CHARS = 'abcdefghijklmnopqrstuvwxyz0123456789_'


def write_atomically(path: str, data: bytes, error: Callable[..., SaveError] = SaveError):
    """Replace the file ``path`` by ``data``, all or nothing (see the module docstring). Raises
    ``error(shown_path, reason, errno)`` (a SaveError) naming the target; the target is then
    unchanged and no temporary file of this call stays behind."""
    target = os.path.realpath(path)
    shown = path if target == os.path.abspath(path) else f'{path} (link to {target})'

    def fail(reason, code=None):
        return error(shown, reason, code)

    parent = os.path.dirname(os.path.abspath(path))
    try:
        os.makedirs(parent, exist_ok=True)
    except OSError as exc:
        raise fail(f'cannot create directory {parent}: {exc.strerror}', exc.errno) from None
    target = os.path.realpath(path)  # again: the parent may have been created just now
    if os.path.islink(target):
        raise fail('symbolic link loop', errno.ELOOP)
    directory, base = os.path.split(target)
    try:
        st = os.stat(target)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise fail(exc.strerror, exc.errno) from None
    if st is None:
        mode = 0o666 & ~_umask()  # what open() would create
    elif stat.S_ISDIR(st.st_mode):
        raise fail('it is a directory: allowed: a file path', errno.EISDIR)
    elif not stat.S_ISREG(st.st_mode):
        raise fail('it is not a regular file', errno.EINVAL)
    else:
        mode = stat.S_IMODE(st.st_mode)
        if not mode & 0o222:
            # A read-only calibration is someone's "do not overwrite"; renaming over it would
            # only need write permission on the directory, so refuse as ofstream would.
            raise fail(f'the file is read-only (mode {mode:04o}): make it writable to replace it', errno.EACCES)
    _remove_stale_temps(directory, base)
    fd, temp = _open_unnamed(directory, mode)
    if fd is None:
        try:
            fd, temp = tempfile.mkstemp(prefix=_temp_prefix(base), dir=directory)
        except OSError as exc:
            raise fail(f'cannot create a file in {directory}: {exc.strerror}', exc.errno) from None
    try:
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
            os.fchmod(fd, mode)
            if st is not None and (st.st_uid, st.st_gid) != (os.geteuid(), os.getegid()):
                with contextlib.suppress(OSError):  # only root may give the file back
                    os.fchown(fd, st.st_uid, st.st_gid)
            os.fsync(fd)
            if temp is None:
                # Only now, complete and on disk, does the content get a name: a writer killed
                # before this point leaves nothing behind.
                temp = _link_unnamed(fd, directory, _temp_prefix(base))
        finally:
            os.close(fd)
        os.replace(temp, target)
    except BaseException as exc:
        if temp is not None:
            with contextlib.suppress(OSError):
                os.unlink(temp)
        if isinstance(exc, OSError):
            raise fail(exc.strerror or type(exc).__name__, exc.errno) from None
        raise
    try:  # make the rename itself durable
        dir_fd = os.open(directory, os.O_RDONLY | getattr(os, 'O_DIRECTORY', 0))
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)
    except OSError as exc:
        if exc.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF):  # fs without directory fsync
            raise fail(f'written, but flushing directory {directory} failed: {exc.strerror}', exc.errno) from None
