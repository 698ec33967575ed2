r"""Paths as text: for records that must be UTF-8, and for messages where a name must show.

A path on POSIX is bytes; Python holds a name that is not UTF-8 (a latin-1 ``caf\xe9.mcap``
from an old USB stick or a Samba share) with surrogates (``caf\udce9.mcap``), which no
UTF-8 writer takes. :func:`path_text` gives a text every writer takes (MCAP metadata, JSON,
Markdown): such bytes escaped as ``\udce9``. :func:`shown` quotes a name whose spaces or
control characters would be invisible or break the message's line.
"""

from __future__ import annotations

import os
import shlex

__all__ = ["path_text", "shown", "too_long"]


def path_text(path: str | os.PathLike[str]) -> str:
    r"""Return ``path`` as text any UTF-8 writer takes: bytes not UTF-8 escaped (``\udce9``).

    >>> path_text("caf\udce9.npz")
    'caf\\udce9.npz'
    >>> path_text("bases/café.npz")
    'bases/café.npz'
    """
    return os.fsdecode(path).encode("utf-8", "backslashreplace").decode("utf-8")


def shown(path: str | os.PathLike[str]) -> str:
    r"""Return ``path`` for a message: as is, or quoted when its edges or controls would hide.

    A name with a leading or trailing space (a copy-paste), a tab, a newline or another
    control character is quoted (the shell's quoting, control characters escaped), so that
    the message shows it and stays on one line; an ordinary name, spaces inside included,
    is printed as it is.

    >>> shown("x_dense.mcap")
    'x_dense.mcap'
    >>> shown("x_dense.mcap ")
    "'x_dense.mcap '"
    >>> shown("new\nline.mcap")
    "$'new\\nline.mcap'"
    """
    text = os.fsdecode(path)
    controls = any(ord(char) < 32 or ord(char) == 127 for char in text)
    if not controls and text == text.strip():
        return text
    if not controls:
        return shlex.quote(text)
    return "$'" + "".join(_escape(char) for char in text) + "'"


_ESCAPES = {"\n": "\\n", "\t": "\\t", "\r": "\\r", "\\": "\\\\", "'": "\\'"}


def _escape(char: str) -> str:
    """One character inside the shell's ``$'...'`` quoting."""
    if char in _ESCAPES:
        return _ESCAPES[char]
    if ord(char) < 32 or ord(char) == 127:
        return f"\\x{ord(char):02x}"
    return char


def too_long(path: str | os.PathLike[str]) -> str:
    """Say which part of ``path`` is too long for the file system (ENAMETOOLONG), and the fix.

    The last name, a folder's name, or the whole path (PATH_MAX), each with its size in
    bytes and the limit; for the one line a command ends with.

    >>> too_long("a" * 300 + ".npz")  # doctest: +ELLIPSIS
    'the file name is too long for the file system (304 bytes, at most 255): choose a ...'
    """
    raw = os.fsencode(path)
    names = raw.rstrip(b"/").split(b"/")
    name_max, path_max = _limits(os.fsdecode(raw))
    if len(names[-1]) > name_max:
        return (
            f"the file name is too long for the file system ({len(names[-1])} bytes, at most "
            f"{name_max}): choose a shorter name"
        )
    longest = max(names, key=len)
    if len(longest) > name_max:
        return (
            f"the folder name {shown(os.fsdecode(longest[:24]))}... in it is too long for the "
            f"file system ({len(longest)} bytes, at most {name_max}): choose a shorter name"
        )
    return (
        f"the path is too long for the file system ({len(raw)} bytes, at most {path_max}): "
        "choose a shorter path (fewer or shorter folder names)"
    )


def _limits(path: str) -> tuple[int, int]:
    """NAME_MAX and PATH_MAX of the file system of ``path``'s nearest folder that exists."""
    where = os.path.dirname(os.path.abspath(path))
    limits = [255, 4096]
    for _ in range(64):  # climbs to / at most (a folder of a too-long path is absent)
        try:
            limits = [os.pathconf(where, "PC_NAME_MAX"), os.pathconf(where, "PC_PATH_MAX")]
            break
        except (OSError, ValueError, AttributeError):
            if where == os.path.dirname(where):
                break
            where = os.path.dirname(where)
    return (limits[0] if limits[0] > 0 else 255), (limits[1] if limits[1] > 0 else 4096)
