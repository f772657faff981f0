"""Atomic writes and their temporary files.

Every file fgen writes goes to a hidden temporary name in the target folder first and is
renamed into place when complete, so a reader (or a resumed run) sees either the whole old
file, the whole new one, or nothing. A killed process can leave its temporary file behind;
the name says who wrote it, so a later run can tell a stale one from one being written:

    .fgen-tmp-<pid>@<host>@<random><suffix>

A temporary file is stale when its writer ran on this host and that process is gone, or
when nothing has touched it for STALE_AFTER_S seconds (a writer on another host, or a name
from an older fgen without pid/host). No torch import here.
"""
from __future__ import annotations

import os
import re
import socket
import tempfile
import time

PREFIX = ".fgen-tmp-"
STALE_AFTER_S = 600.0  # one frame's write takes well under a second; 10 minutes is dead
_NAME = re.compile(r"^\.fgen-tmp-(\d+)@(.+)@[^@]*$")


def _host() -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", socket.gethostname() or "host")


def temp_prefix() -> str:
    return f"{PREFIX}{os.getpid()}@{_host()}@"


def make_temp(folder: str, suffix: str = "") -> str:
    """Create an empty temporary file in `folder` named after this process; its path.
    Raises OSError when the folder is not writable."""
    fd, tmp = tempfile.mkstemp(prefix=temp_prefix(), suffix=suffix, dir=folder)
    os.close(fd)
    return tmp


def fsync_path(path: str) -> None:
    """Flush a finished file's data to the disk (a rename after a crash of the machine then
    never exposes a file whose blocks were not written)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def replace(tmp: str, path: str, sync: bool = True) -> None:
    """Move a finished temporary file into place; with sync, its data is on disk first."""
    if sync:
        fsync_path(tmp)
    os.replace(tmp, path)


def write_text(path: str, text: str) -> None:
    """Write a small text file atomically (unique temporary name: safe when several
    processes write into one folder)."""
    folder = os.path.dirname(os.path.abspath(path))
    tmp = make_temp(folder, suffix=".part")
    try:
        with open(tmp, "w") as fh:
            fh.write(text)
        replace(tmp, path, sync=False)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def is_stale(folder: str, name: str, now: float | None = None) -> bool:
    """Whether the temporary file `name` in `folder` was left by a writer that is gone."""
    if not name.startswith(PREFIX):
        return False
    m = _NAME.match(name)
    if m and m.group(2) == _host():
        pid = int(m.group(1))
        if pid != os.getpid() and not _alive(pid):
            return True
    try:
        age = (time.time() if now is None else now) - os.stat(os.path.join(folder, name)).st_mtime
    except OSError:
        return False
    return age > STALE_AFTER_S


def remove_stale(folder: str) -> list[str]:
    """Delete the stale fgen temporary files in `folder`; the names removed."""
    removed = []
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    for name in names:
        if name.startswith(PREFIX) and is_stale(folder, name):
            try:
                os.unlink(os.path.join(folder, name))
                removed.append(name)
            except OSError:
                pass
    return removed
