"""Whether a mount is at a path: this process's mount table, checked against mount ids.

:func:`pcainterp_stream.io.output_paths.unreplaceable` refuses an output a file system or file
is mounted at (a rename onto it fails with EBUSY after the whole run).
"""

from __future__ import annotations

import os
import re

__all__ = ["mounted_at"]


def mounted_at(real: str) -> bool:
    """Return whether a mount is at ``real`` (a resolved path): listed, and on a mount of its own.

    The listing (:func:`_mount_points`) alone is not enough: a file bind-mounted at
    ``t/sub/f`` and then hidden under a mount on ``t/sub`` is still listed, though the
    ``t/sub/f`` one sees is a plain file of the new mount (``mv`` onto it works; review 16a R1).
    """
    return real in _mount_points() and not _same_mount(real, os.path.dirname(real))


def _mount_points() -> set[str]:
    """The mount points of this process's mount namespace (empty where unknown)."""
    try:
        with open("/proc/self/mountinfo", encoding="utf-8", errors="surrogateescape") as file:
            fields = [line.split(" ")[4] for line in file if line.count(" ") >= 4]
    except OSError:
        return set()
    return {re.sub(r"\\([0-7]{3})", lambda match: chr(int(match[1], 8)), item) for item in fields}


def _same_mount(path: str, folder: str) -> bool:
    """Return whether ``path`` lies on its folder's mount (then no mount is at it).

    The mount ids of the two (Linux ``/proc/self/fdinfo``) tell; False where they cannot be
    read (the listing is trusted then).
    """
    ids = [_mount_id(path), _mount_id(folder)]
    return ids[0] is not None and ids[0] == ids[1]


def _mount_id(path: str) -> int | None:
    """The id of the mount ``path`` lies on (``mnt_id`` of an O_PATH descriptor), or None."""
    flags = getattr(os, "O_PATH", None)
    if flags is None:
        return None
    try:
        handle = os.open(path, flags | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        with open(f"/proc/self/fdinfo/{handle}", encoding="ascii") as info:
            for line in info:
                if line.startswith("mnt_id:"):
                    return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        return None
    finally:
        os.close(handle)
    return None
