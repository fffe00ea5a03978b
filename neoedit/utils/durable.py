"""Durability primitives of the safe writers in :mod:`neoedit.utils.io`: the user's umask,
fsync of files and folders, and an atomic swap of two paths."""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import sys
from pathlib import Path


def user_umask() -> int:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def fsync_dir(path: Path) -> None:
    with contextlib.suppress(OSError):  # not every file system lets a folder be fsynced
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def seal_tree(root: Path) -> None:
    """Give every file and folder under ``root`` the user's umask (some writers, e.g.
    safetensors, create files 0600) and fsync them, deepest first, then ``root``."""
    mask = user_umask()
    for folder, _, files in os.walk(root, topdown=False):
        for f in files:
            with contextlib.suppress(OSError):
                fd = os.open(os.path.join(folder, f), os.O_RDONLY)
                try:
                    os.fchmod(fd, 0o666 & ~mask)
                    os.fsync(fd)
                finally:
                    os.close(fd)
        with contextlib.suppress(OSError):
            os.chmod(folder, 0o777 & ~mask)
        fsync_dir(Path(folder))


def exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2`` with ``RENAME_EXCHANGE``); False
    where the system or the file system cannot."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    at_fdcwd, rename_exchange = -100, 2
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.EPERM):
        return False
    raise OSError(err, os.strerror(err), str(b))
