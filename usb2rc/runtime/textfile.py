"""Write a text file the way an editor should: all or nothing, keeping what makes it the
user's file.

`usb2rc init` and `usb2rc calibrate` write configs a running daemon may read (SIGHUP): a
reader sees the old file or the new one, never half of one. The service reads its config
as group usb2rc (root:usb2rc 0640), so a replaced file keeps its owner, group and mode: a
`sudo usb2rc calibrate` that left root:root 0640 behind would stop the next start (exit 2).

A symlinked config stays a symlink: the file it points to is written, atomically, in that
file's own directory. A dangling symlink is refused (`DanglingLink`): writing a new file
where it points would create a file the user may not expect (a mount not there yet), and
replacing the link would silently cut the user's indirection.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from dataclasses import dataclass
from pathlib import Path


class DanglingLink(OSError):
    """The path is a symlink whose target does not exist (or a symlink loop)."""

    def __init__(self, link: Path, target: str) -> None:
        super().__init__(
            f"{link} is a symlink to {target}, which does not exist: "
            "create the target or remove the link (nothing written)"
        )


class OwnerNotKept(PermissionError):
    """Replacing the file would change its owner or group, and this user cannot keep them."""


@dataclass(frozen=True)
class Keeps:
    """What the replaced file had and its replacement gets again."""

    mode: int
    uid: int
    gid: int


def resolved_target(path: str | os.PathLike[str]) -> Path:
    """The file to write: path itself, or the file its symlink chain ends at."""
    given = Path(path)
    if not given.is_symlink():
        return given
    if not given.exists():  # dangling, or a loop (exists() is False for both)
        raise DanglingLink(given, os.readlink(given))
    return Path(os.path.realpath(given))


def existing_keeps(target: Path) -> Keeps | None:
    try:
        st = target.stat()
    except FileNotFoundError:
        return None
    return Keeps(stat.S_IMODE(st.st_mode), st.st_uid, st.st_gid)


def new_file_mode() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def give_back(temp: str, keeps: Keeps, target: Path) -> None:
    """The temporary file gets the replaced file's owner, group and mode (chown first: it
    clears set-id bits)."""
    st = os.stat(temp)
    if (st.st_uid, st.st_gid) != (keeps.uid, keeps.gid):
        try:
            os.chown(temp, keeps.uid, keeps.gid)
        except PermissionError:
            raise OwnerNotKept(
                f"{target} belongs to uid {keeps.uid} gid {keeps.gid}: a new copy would not "
                "(run as root or as its owner; nothing written)"
            ) from None
    os.chmod(temp, keeps.mode)


def write_atomically(path: str | os.PathLike[str], text: str) -> None:
    """Write text to a temporary file beside the target, fsync it, rename it over the target.

    The target is path, or the file path's symlink points to (see the module doc). An
    existing file's owner, group and mode are kept; a new file gets the usual mode for this
    umask. Raises DanglingLink, OwnerNotKept or another OSError, and then wrote nothing."""
    target = resolved_target(path)
    keeps = existing_keeps(target)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        if keeps is None:
            os.chmod(tmp, new_file_mode())
        else:
            give_back(tmp, keeps, target)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
