"""Where an output may be written, checked before any work.

Every output is staged beside its target and renamed onto it once complete. A rename
replaces the directory entry, so the target must be something a finished file may replace:
a new path, a regular file, or (for a rosbag2 output) a folder. A device (``/dev/null``), a
named pipe, a socket or a file descriptor (``/dev/stdout``) would be replaced by a regular
file, so they are refused; a symbolic link is written through, the file it points to
being replaced and the link kept (:func:`check_output_file` returns that file). An output
never lands onto one of the inputs, nor around one (:func:`check_not_input`).
"""

from __future__ import annotations

import contextlib
import errno
import functools
import hashlib
import os
import re
import shlex
import shutil
import socket
import stat
import sys
import tempfile
import threading
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from pcainterp_stream.errors import LogWriteError
from pcainterp_stream.interrupt import track_partial, untrack_partial
from pcainterp_stream.io import mount_points

__all__ = [
    "check_not_input",
    "check_output_file",
    "check_output_folder",
    "full_disk_advice",
    "input_bag",
    "is_standard_output",
    "make_partial_file",
    "name_too_long",
    "partial_prefix",
    "process_umask",
    "remove_stale_partials",
    "remove_stale_temporaries",
    "removed_meanwhile",
    "saved_elsewhere",
    "size_limit_advice",
    "staged_for",
    "symlink_loop",
    "temporary_prefix",
    "unreplaceable",
    "write_advice",
]

DISCARD = "give the path of a regular file (to discard the output, write one and delete it)"
"""The fix for a device or pipe as an output, where the caller names no better one."""

_DESCRIPTOR = re.compile(
    r"/(?:dev/(?:(?P<std>stdin|stdout|stderr)|fd/(?P<dev_fd>\d+))"
    r"|proc/(?P<pid>self|thread-self|\d+)/fd/(?P<proc_fd>\d+))"
)
_STANDARD = {"stdin": 0, "stdout": 1, "stderr": 2}
_STREAM_NAMES = {0: "standard input", 1: "standard output", 2: "standard error"}
_KINDS = {
    stat.S_IFCHR: "a character device",
    stat.S_IFBLK: "a block device",
    stat.S_IFIFO: "a named pipe (FIFO)",
    stat.S_IFSOCK: "a socket",
}


def _inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def _real(path: str | os.PathLike[str]) -> Path:
    """``path`` with its symbolic links followed; a link loop is kept as it stands.

    ``Path.resolve()`` raises RuntimeError on a loop (Python 3.11; OSError on 3.13).
    """
    return Path(os.path.realpath(path))


def symlink_loop(path: str | os.PathLike[str]) -> str | None:
    """Return the refusal of a path through a symbolic link loop (None: there is none).

    Such a path can be neither read nor written (ELOOP): ``PATH is a symbolic link loop;
    point it at a real file``, or for a folder above it ``PATH: folder DIR is a symbolic
    link loop; ...``. A chain of more links than the kernel follows (40) that ends
    somewhere is named as such.
    """
    try:
        os.stat(path)
    except OSError as err:
        if err.errno != errno.ELOOP:
            return None
    else:
        return None
    given = Path(path)
    link = given
    for end in range(1, len(given.parts)):  # the first part that cannot be looked at
        prefix = Path(*given.parts[:end])
        try:
            os.stat(prefix)
        except OSError:
            link = prefix
            break
    what = "a symbolic link loop" if _loops(link) else "a chain of over 40 symbolic links"
    if link == given:
        return f"{given} is {what}; point it at a real file"
    return f"{given}: folder {link} is {what}; point it at a real folder"


def _loops(link: Path) -> bool:
    """Whether following ``link`` comes back to a link already passed (else: a long chain)."""
    seen: set[str] = set()
    current = os.path.abspath(link)
    while os.path.islink(current) and current not in seen:
        seen.add(current)
        folder = os.path.realpath(os.path.dirname(current))
        current = os.path.abspath(os.path.join(folder, os.readlink(current)))
    return current in seen


def check_not_input(target: Path, inputs: Iterable[str | os.PathLike[str]]) -> None:
    """Refuse a target that is, or contains, one of the inputs, or lies in an input bag.

    A rosbag2 bag is a folder (its ``metadata.yaml`` lists the files that make the
    recording): a target inside it would replace its storage file or join the recording. A
    target inside another input folder (a KITTI drive) is allowed: it is not the recording.

    Raises:
        LogWriteError: naming the path and the fix; the target is a symbolic link loop.
    """
    loop = symlink_loop(target)
    if loop is not None:
        raise LogWriteError(f"cannot write the output: {loop}")
    resolved = _real(target)
    sources = [Path(item) for item in inputs]
    for source in sources:
        same = resolved == _real(source) or _inside(_real(source), resolved)
        if not same and os.path.exists(target) and os.path.exists(source):
            try:
                same = os.path.samefile(target, source)
            except OSError:
                same = False
        if same:
            raise LogWriteError(
                f"refusing to write the output onto the input {source}; "
                "choose a different output path"
            )
    for source in sources:  # after every input is looked at as a file: that message first
        bag = input_bag(target, source)
        if bag is not None:
            raise LogWriteError(
                f"refusing to write the output {target} inside the input bag {bag}: it would "
                f"replace or join the recording's own files; write it beside the bag (e.g. -o "
                f"{Path(os.path.abspath(bag)).name}.dense.mcap)"
            )


def input_bag(target: Path, source: Path) -> Path | None:
    """Return the rosbag2 bag (a folder) of the input ``source`` when ``target`` lies in it.

    ``source`` is the bag's folder or one of its storage files; a bag is a folder with a
    ``metadata.yaml``, which lists the files that make the recording.
    """
    folder = source if os.path.isdir(source) else source.parent
    if not os.path.isfile(folder / "metadata.yaml"):
        return None
    inside = _real(target)
    return folder if inside != _real(folder) and _inside(inside, _real(folder)) else None


def _hops(path: Path) -> Iterator[Path]:
    """Yield ``path`` and each path its chain of symbolic links leads to, absolute."""
    current = Path(os.path.abspath(path))
    for _ in range(40):  # the kernel's own limit on links followed
        yield current
        real = Path(os.path.realpath(current.parent)) / current.name
        if real != current:
            yield real
        if not os.path.islink(real):  # False too where it cannot be looked at (a long name)
            return
        current = Path(os.path.abspath(real.parent / os.readlink(real)))


def _descriptor(path: Path) -> tuple[int, bool] | None:
    """Return (descriptor, of this process) when ``path`` names an open file descriptor."""
    for hop in _hops(path):
        match = _DESCRIPTOR.fullmatch(str(hop))
        if match is None:
            continue
        if match["std"] is not None:
            return _STANDARD[match["std"]], True
        if match["dev_fd"] is not None:
            return int(match["dev_fd"]), True
        pid = match["pid"]
        own = pid in ("self", "thread-self") or int(pid) == os.getpid()
        return int(match["proc_fd"]), own
    return None


def is_standard_output(path: Path) -> bool:
    """Return whether ``path`` names this process's standard output (``/dev/stdout``, ...)."""
    return _descriptor(path) == (1, True)


def write_advice(err: OSError) -> str:
    """Return the fix for an error writing an output: "free some space, ..." for a full disk.

    A rename onto a file that cannot be replaced (``err.filename2``) says why
    (:func:`unreplaceable`); a file or folder gone (ENOENT) whose folder no longer exists
    says so; a file-size limit (EFBIG) names it.
    """
    if err.errno in (errno.ENOSPC, errno.EDQUOT):
        return "free some space, or write it elsewhere"
    if err.errno in (errno.ENOTDIR, errno.EEXIST):
        return "a file is in the way of its folder; move it, or write it elsewhere"
    if err.errno == errno.ENAMETOOLONG:
        return "the file name is too long for the file system: choose a shorter name"
    if err.errno == errno.EFBIG:
        return SIZE_LIMIT
    gone = _gone_folder(err)
    if gone is not None:
        return (
            f"folder {gone} no longer exists (removed meanwhile): make it again, or write "
            "it elsewhere"
        )
    if err.filename2 is not None:  # a rename onto the target
        refused = unreplaceable(Path(os.fsdecode(err.filename2)))
        if refused is not None:
            return refused
    return "choose a writable folder"  # read-only, no permission, or a folder refusing files


SIZE_LIMIT = (
    "the file is larger than its file system or a limit (ulimit -f) allows: write it to "
    "another file system (FAT32 takes at most 4 GiB a file), or raise the limit"
)
"""The fix for EFBIG: a file-size limit of the file system (FAT32) or of the process."""


def _gone_folder(err: OSError) -> Path | None:
    """The folder of the file ``err`` names when that is ENOENT and the folder is gone."""
    if err.errno != errno.ENOENT:
        return None
    named = err.filename2 if err.filename2 is not None else err.filename
    if not isinstance(named, (str, bytes, os.PathLike)):
        return None
    folder = Path(os.fsdecode(named)).parent
    return None if os.path.isdir(folder) else folder


def size_limit_advice(error: BaseException) -> str:
    """Return ``"; "`` and :data:`SIZE_LIMIT` for EFBIG (behind sqlite's "disk I/O error" too).

    sqlite3 reports a write refused by a file-size limit as ``disk I/O error``, without the
    errno: a limit lower than the file written (``ulimit -f``) is taken as the cause then.
    """
    if isinstance(error, OSError) and error.errno == errno.EFBIG:
        return f"; {SIZE_LIMIT}"
    if type(error).__name__ == "OperationalError" and "disk I/O error" in str(error):
        # Python 3.11+ names sqlite's extended code: a limit refuses a write
        # (SQLITE_IOERR_WRITE); a read of the file back (READ, SHORT_READ, CORRUPTFS) that
        # fails is a damaged file or a failing disk, whatever the limit (review 16a R4)
        name = getattr(error, "sqlite_errorname", None)
        if isinstance(name, str) and name not in SQLITE_WRITE_ERRORS:
            return f"; {SQLITE_READ_FAILED} ({name})"
        limit = _file_size_limit()
        if limit is not None:
            return (
                f"; likely the file-size limit: this process may write at most "
                f"{limit / 1e6:.1f} MB a file (ulimit -f): raise it, or write elsewhere"
            )
    return ""


SQLITE_WRITE_ERRORS = frozenset(
    {"SQLITE_IOERR", "SQLITE_IOERR_WRITE", "SQLITE_IOERR_TRUNCATE", "SQLITE_IOERR_SHMSIZE"}
)
"""sqlite's I/O errors a file-size limit can cause (EFBIG on a write or a truncation, or on
growing the shared-memory file of a database in WAL mode)."""

SQLITE_READ_FAILED = (
    "the file system could not read or sync the file back (a failing disk or file system, "
    "or a damaged file), not a size limit: write it elsewhere"
)
"""The fix for any other sqlite I/O error while writing."""


def _file_size_limit() -> int | None:
    """This process's file-size limit in bytes (RLIMIT_FSIZE), None when unlimited/unknown."""
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    except (ImportError, OSError, ValueError):
        return None
    return None if soft == resource.RLIM_INFINITY else soft


def full_disk_advice(error: BaseException) -> str:
    """Return ``"; free some space, or write it elsewhere"`` for a full disk, else ``""``.

    A file-size limit (EFBIG) gets its own fix (:func:`size_limit_advice`).
    """
    if isinstance(error, OSError) and error.errno in (errno.ENOSPC, errno.EDQUOT):
        return f"; {write_advice(error)}"
    if type(error).__name__ == "OperationalError" and "disk is full" in str(error):
        return "; free some space, or write it elsewhere"  # sqlite3's SQLITE_FULL
    return size_limit_advice(error)


def saved_elsewhere(target: Path, error: BaseException, save: Callable[[Path], object]) -> str:
    """Save, after ``target`` could not be written, a small result the run spent long on.

    A basis ``learn`` spent minutes or hours on is a few MB: where writing ``target``
    failed (``error`` or its cause an OSError: a full disk, a folder removed meanwhile, a
    file that cannot be replaced), ``save`` writes it to a new folder in the temporary
    folder (``TMPDIR``), usually another disk.

    Returns:
        ``"; it was saved to PATH instead: move it (mv PATH TARGET) once there is room"``
        (``mkdir -p FOLDER && mv ...`` where the folder is gone; ``once that is fixed``
        for any other cause), or ``""`` where the error was not the file system's or that
        failed too (nothing left behind).
    """
    cause = error if isinstance(error, OSError) else error.__cause__
    if not isinstance(cause, OSError):
        return ""
    try:
        folder = Path(tempfile.mkdtemp(prefix="pcainterp-saved-"))
    except OSError:
        return ""
    kept = folder / target.name
    try:
        save(kept)
    except Exception:  # the temporary folder is full too: nothing saved, nothing left
        shutil.rmtree(folder, ignore_errors=True)
        return ""
    move = f"mv {shlex.quote(str(kept))} {shlex.quote(str(target))}"
    if full_disk_advice(cause).startswith("; free"):
        return f"; it was saved to {kept} instead: move it ({move}) once there is room"
    if not os.path.isdir(target.parent):
        make = f"mkdir -p {shlex.quote(str(target.parent))}"
        return f"; it was saved to {kept} instead: move it ({make} && {move})"
    return f"; it was saved to {kept} instead: move it ({move}) once that is fixed"


def removed_meanwhile(partial: Path, folder: Path, during: str) -> str | None:
    """Say why an output cannot be finished when its partial was removed under the job.

    Args:
        partial: the partial output (a file or a staging folder) beside the target.
        folder: the folder that holds it, as the user named it.
        during: what was under way, e.g. ``"the output was being written"``.

    Returns:
        ``folder F no longer exists (removed while DURING)`` when the folder is gone, ``its
        partial output P was removed while DURING`` when only the partial is, and None while
        the partial is there (the error has another cause).
    """
    if os.path.lexists(partial):
        return None
    if not os.path.isdir(folder):
        return f"folder {folder} no longer exists (removed while {during})"
    return f"its partial output {partial} was removed while {during}"


def _existing_ancestor(path: Path) -> Path:
    """Return the nearest of ``path`` and its parents that exists (as a file or folder)."""
    for candidate in (path, *path.parents):
        if os.path.lexists(candidate):
            return candidate
    return Path(path.anchor or ".")


def _probe(where: Path) -> None:
    """Make and remove a folder in ``where``: what staging an output does first."""
    Path(tempfile.mkdtemp(prefix=".pcainterp-probe-", dir=where)).rmdir()


def name_too_long(path: Path) -> str | None:
    """Say why ``path``'s name is too long for its file system (None when it is not).

    Returns:
        ``the file name is too long for the file system (N bytes, at most M): choose a
        shorter name``, or None.
    """
    size, limit = len(os.fsencode(path.name)), _name_max(path.parent)
    if size <= limit:
        return None
    return (
        f"the file name is too long for the file system ({size} bytes, at most {limit}): "
        "choose a shorter name"
    )


def check_output_file(
    path: Path, *, fix: str = DISCARD, creates_folders: bool = False, links: bool = True
) -> Path:
    """Refuse, before any work, an output a finished file cannot be renamed onto.

    Args:
        path: the output as given (a file, or a rosbag2 folder).
        fix: the end of the message for a device, pipe or descriptor (how to discard or
            stream the output instead).
        creates_folders: the writer makes missing folders above ``path``; else they must exist.
        links: write through a symbolic link (else a link is refused).

    Returns:
        The path to stage the output beside and rename it onto: ``path``, or the file a
        symbolic link at ``path`` points to (the link is kept).

    Raises:
        LogWriteError: ``path``'s name is too long for its file system, it names a file
            descriptor (``/dev/stdout``), is a device, a named pipe or a socket (or a link
            to one), a link loop, a link when ``links`` is False, or its folder is missing,
            a file, or not writable.
    """
    too_long = name_too_long(path)  # first: a look at the path would fail (ENAMETOOLONG)
    if too_long is not None:
        raise LogWriteError(f"cannot write {path}: {too_long}")
    described = _descriptor(path)
    if described is not None:
        number, own = described
        name = _STREAM_NAMES.get(number, f"file descriptor {number}")
        if not own:
            name = f"file descriptor {number} of another process"
        raise LogWriteError(f"cannot write {path}: it is {name}, not a regular file; {fix}")
    target = path
    if path.is_symlink():
        target = Path(os.path.realpath(path))
        if not links:
            raise LogWriteError(
                f"cannot write {path}: it is a symbolic link (to {target}); "
                "remove the link, or write to the file it points to"
            )
    try:
        mode: int | None = os.stat(target).st_mode
    except OSError as err:
        if err.errno == errno.ELOOP:
            raise LogWriteError(
                f"cannot write {path}: it is a loop of symbolic links; remove the link"
            ) from None
        mode = None  # a new file (or a dangling link: its target is made)
    if mode is not None and not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        kind = _KINDS.get(stat.S_IFMT(mode), "not a file or folder")
        which = "it is" if target == path else f"it links to {target}, which is"
        raise LogWriteError(
            f"cannot write {path}: {which} {kind}, not a regular file, and would be "
            f"replaced by one; {fix}"
        )
    folder = target.parent
    found = _existing_ancestor(folder)
    if not found.is_dir():
        raise LogWriteError(
            f"cannot write {path}: {found} is a file, not a folder; move it, or choose another path"
        )
    if found != folder and not creates_folders:
        raise LogWriteError(
            f"cannot write {path}: folder {path.parent} does not exist; create it first"
        )
    try:
        _probe(found)
    except OSError as err:
        raise LogWriteError(
            f"cannot write {path}: {err.strerror or err}; {write_advice(err)}"
        ) from err
    if mode is not None:
        refused = unreplaceable(target)
        if refused is not None:
            raise LogWriteError(f"cannot replace {path}: {refused}")
    return target


_IMMUTABLE_FLAGS = {0x10: "immutable", 0x20: "append-only"}
"""Linux inode flags (``FS_IMMUTABLE_FL``, ``FS_APPEND_FL``): no rename onto such a file."""
_BSD_FLAGS = {0x2: "immutable", 0x20000: "immutable", 0x4: "append-only", 0x40000: "append-only"}
"""``st_flags`` of macOS and the BSDs (``UF_``/``SF_IMMUTABLE``, ``UF_``/``SF_APPEND``)."""
_FS_IOC_GETFLAGS = 0x80086601 if sys.maxsize > 2**32 else 0x80046601


def _inode_flag(path: Path) -> str | None:
    """Return "immutable" or "append-only" when ``path`` has that flag (None otherwise)."""
    flags = getattr(os.stat(path), "st_flags", None)
    if flags is not None:
        return next((name for bit, name in _BSD_FLAGS.items() if flags & bit), None)
    if not sys.platform.startswith("linux"):
        return None
    import fcntl

    try:  # read-only, no write, so no file watcher sees the file "changed"
        handle = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY)
    except OSError:
        return None  # unreadable: nothing known (the rename is tried at the end)
    try:
        buffer = bytearray(8)
        fcntl.ioctl(handle, _FS_IOC_GETFLAGS, buffer)
        value = int.from_bytes(buffer[:4], sys.byteorder)
    except OSError:  # a file system without inode flags
        return None
    finally:
        os.close(handle)
    return next((name for bit, name in _IMMUTABLE_FLAGS.items() if value & bit), None)


def unreplaceable(target: Path) -> str | None:
    """Say why the existing ``target`` cannot be replaced by a rename, or None.

    The folder may be writable (:func:`check_output_file` makes a folder in it) while the
    file in it cannot be replaced: it is immutable or append-only (``chattr +i``/``+a``,
    ``chflags uchg``), on a read-only mount of its own (a file bind-mounted read-only), a
    mount point, or another user's file in a shared folder with the sticky bit (``chmod
    1777``, as /tmp), where only the file's or the folder's owner may replace it. Each is
    looked at without writing to the file.

    Returns:
        The reason and the fix, e.g. ``it is immutable (chattr +i; lsattr shows it): remove
        the flag (chattr -i, as root), or choose another name``.
    """
    try:
        info, folder = os.lstat(target), os.stat(target.parent)
    except OSError:
        return None  # gone meanwhile, or not to be looked at: the rename tells
    other = "or choose another name"
    flag = _inode_flag(target)
    if flag is not None:
        letter = "i" if flag == "immutable" else "a"
        linux = sys.platform.startswith("linux")
        how = f"chattr +{letter}; lsattr shows it" if linux else "chflags"
        undo = f"chattr -{letter}, as root" if linux else "chflags"
        return f"it is {flag} ({how}): remove the flag ({undo}), {other}"
    real = os.path.realpath(target)
    if mount_points.mounted_at(real):
        return f"a file system or file is mounted at it (mount shows it): unmount it, {other}"
    with contextlib.suppress(OSError):
        if os.statvfs(target).f_flag & os.ST_RDONLY:
            return f"it is on a read-only mount of its own (mounted read-only): {other}"
    user = os.geteuid() if hasattr(os, "geteuid") else 0
    sticky = folder.st_mode & stat.S_ISVTX
    if sticky and user != 0 and user not in (info.st_uid, folder.st_uid):
        return (
            f"it belongs to {_user_name(info.st_uid)} and its folder {target.absolute().parent} "
            f"is shared with the sticky bit (as /tmp), where only a file's owner may replace it: "
            f"ask them to remove it, {other}"
        )
    return None


def _user_name(uid: int) -> str:
    """The login name of user ``uid`` (``user UID`` where it has none)."""
    try:
        import pwd

        return f"user {pwd.getpwuid(uid).pw_name}"
    except (ImportError, KeyError):
        return f"user {uid}"


def check_output_folder(folder: Path) -> None:
    """Refuse, before any work, a folder outputs cannot be written into (made if missing).

    Raises:
        LogWriteError: ``folder`` is a file (or a device), lies below a file, or it (or,
            when missing, the folder it would be made in) is not writable.
    """
    found = _existing_ancestor(folder)
    if not found.is_dir():
        where = "it is" if found == folder or folder.is_symlink() else f"{found} is"
        raise LogWriteError(
            f"cannot write into {folder}: {where} a file, not a folder; pass a folder"
        )
    try:
        _probe(found)
    except OSError as err:
        raise LogWriteError(
            f"cannot write into {folder}: {err.strerror or err}; {write_advice(err)}"
        ) from err


def _host() -> str:
    """This machine's name as a partial output's name holds it (safe characters, short)."""
    return re.sub(r"[^A-Za-z0-9.]", "_", socket.gethostname())[:40] or "host"


def _boot_id() -> str | None:
    """This boot of this machine: a random id the kernel draws at boot (None if unknown)."""
    try:  # Linux, containers included (the kernel's, not the container's)
        with open("/proc/sys/kernel/random/boot_id", encoding="ascii") as file:
            text = file.read()
    except (OSError, ValueError):
        text = ""
    if not text and sys.platform == "darwin":  # no PID namespaces there: the boot is the scope
        text = _sysctl_text(b"kern.bootsessionuuid")
    digits = re.sub(r"[^0-9a-f]", "", text.lower())
    return digits[:12] if len(digits) >= 12 else None


def _sysctl_text(name: bytes) -> str:
    """Return a string sysctl of macOS ("" where there is none)."""
    import ctypes

    try:
        libc = ctypes.CDLL(None)
        size = ctypes.c_size_t(64)
        buffer = ctypes.create_string_buffer(size.value)
        if libc.sysctlbyname(name, buffer, ctypes.byref(size), None, ctypes.c_size_t(0)) != 0:
            return ""
        return buffer.value.decode("ascii", "replace")
    except (OSError, AttributeError, ValueError):
        return ""


def _pid_namespace() -> str | None:
    """The PID namespace this process's ids belong to: the inode of ``/proc/self/ns/pid``.

    "0" on macOS, which has no PID namespaces; None where it is unknown (Linux without
    /proc or a sandbox hiding it, Windows).
    """
    try:
        return str(os.stat("/proc/self/ns/pid").st_ino)
    except OSError:
        pass
    if sys.platform == "darwin":
        return "0"
    return None  # Linux without /proc (or a sandbox hiding it), Windows: unknown


@functools.cache
def _scope() -> str | None:
    """Where this process's id means this process: 8 hex digits of a hash of BOOT.NAMESPACE.

    None if either is unknown. The host name alone does not say it: containers sharing the
    host's name (``docker --net=host``) have PID namespaces of their own, and two machines
    may have one name. A hash keeps the partial's name short (a file name is at most ~255
    bytes on most file systems).
    """
    boot, namespace = _boot_id(), _pid_namespace()
    if boot is None or namespace is None:
        return None
    return hashlib.sha256(f"{boot}.{namespace}".encode("ascii", "replace")).hexdigest()[:8]


def _owner() -> str:
    """This process as a partial output's name holds it: ``PID@HOST~SCOPE``."""
    return f"{os.getpid()}@{_host()}~{_scope() or 'unknown'}"


_PID_DIGITS = 10
"""Room kept for a process id in a partial's name (any id of any system fits)."""
_RANDOM_CHARACTERS = 8
"""The unique part ``tempfile`` adds to a prefix."""


def _name_max(folder: Path) -> int:
    """The longest file name, in bytes, the file system of ``folder`` takes (255 if unknown)."""
    try:
        limit = os.pathconf(_existing_ancestor(folder), "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):  # no pathconf (Windows), or no such name
        return 255
    return limit if limit > 0 else 255


def _partial_start(target: Path, where: Path | None = None) -> str:
    """Return ``.NAME.partial-``: the start of ``target``'s partials' names in ``where``.

    NAME is the target's name, or, when a partial's name would be longer than the file
    system takes (:func:`_name_max`), its start followed by ``~`` and 8 hex digits of a
    hash of the whole name. It depends on the folder, host and scope only (never on the
    process id), so a later run names a killed run's partials as that run did.
    """
    name = target.name
    owner = f"@{_host()}~{_scope() or 'unknown'}-"
    fixed = len(os.fsencode(f"..partial-{owner}")) + _PID_DIGITS + _RANDOM_CHARACTERS
    room = _name_max(target.parent if where is None else where) - fixed
    if len(os.fsencode(name)) <= room:
        return f".{name}.partial-"
    digest = hashlib.sha256(os.fsencode(name)).hexdigest()[:8]
    short = name[: max(room - 9, 1)]
    while len(short) > 1 and len(os.fsencode(short)) > room - 9:
        short = short[:-1]
    return f".{short}~{digest}.partial-"


def staged_for(path: Path) -> Path:
    """Return the output ``path`` is written for: the user's file, not a staging folder's.

    ``densify --out-dir`` writes each log's output in a hidden staging folder,
    ``DIR/.NAME.partial-OWNER-XXXX/NAME``, then moves it to ``DIR/NAME``: an error names
    ``DIR/NAME`` (the staging folder is removed with the error). Any other ``path`` is
    returned as it is.
    """
    target = path.parent.parent / path.name
    if path.parent.name.startswith(_partial_start(target)):
        return target
    return path


def partial_prefix(target: Path, where: Path | None = None) -> str:
    """Return the name prefix of ``target``'s partial output: ``.NAME.partial-OWNER-``.

    OWNER is ``PID@HOST~SCOPE``: the writer's process id and machine, and a hash of its
    boot and PID namespace, so that a later run can tell the partial output of a run that
    was killed (:func:`remove_stale_partials`) from that of a run still going; ``tempfile``
    adds a unique suffix, so two runs never share one. NAME is the target's name, shortened
    where the whole would be too long for the file system (:func:`_partial_start`);
    ``where`` is the folder the partial is made in (default: ``target``'s).
    """
    return f"{_partial_start(target, where)}{_owner()}-"


def make_partial_file(target: Path) -> tuple[int, Path]:
    """Create ``target``'s partial file beside it; return its open descriptor and path.

    Named by :func:`partial_prefix` (the owner in the name, shortened to fit the file
    system), after removing the partial files a killed earlier run left
    (:func:`remove_stale_partials`). Its mode is a new file's (``0o666`` less the umask),
    not ``mkstemp``'s private ``0o600``.

    Raises:
        OSError: the folder refuses the file (the caller names ``target`` and the fix).
    """
    remove_stale_partials(target)
    handle, name = tempfile.mkstemp(prefix=partial_prefix(target), dir=target.parent)
    try:
        os.chmod(name, 0o666 & ~process_umask())
    except OSError:
        os.close(handle)
        Path(name).unlink(missing_ok=True)
        raise
    return handle, Path(name)


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` of this PID namespace exists (another user's included)."""
    if pid <= 0:
        return True  # not a process id of ours: never taken for a dead one
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # PermissionError: it exists, another user's
        return True
    try:  # a zombie (killed, its parent yet to reap it) writes nothing more
        with open(f"/proc/{pid}/stat", "rb") as file:
            return file.read().rpartition(b")")[2].split()[:1] != [b"Z"]
    except (OSError, IndexError):
        return True


def _size(path: Path) -> int:
    """Bytes in the file, or in the files below the folder, at ``path``."""
    if path.is_dir() and not path.is_symlink():
        total = 0
        for root, _, files in os.walk(path):
            for name in files:
                with contextlib.suppress(OSError):
                    total += os.lstat(os.path.join(root, name)).st_size
        return total
    try:
        return path.lstat().st_size
    except OSError:
        return 0


def _stale(folder: Path, start: str) -> Iterator[Path]:
    """Yield the entries of ``folder`` named ``START OWNER-XXXX`` of a dead process.

    Only an owner of this machine, boot and PID namespace (:func:`_owner`) is looked up:
    a process id means nothing in another namespace, where a live writer would look dead.
    Where the namespace is unknown nothing is removed, nor are names without an owner's
    scope (those of earlier versions).
    """
    scope = _scope()
    if scope is None:
        return
    owner = re.escape(f"@{_host()}~{scope}")
    pattern = re.compile(re.escape(start) + r"(\d+)" + owner + r"-[^-]+")
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return
    for entry in entries:
        match = pattern.fullmatch(entry.name)
        if match is not None and int(match[1]) != os.getpid() and not process_alive(int(match[1])):
            yield Path(entry.path)


def temporary_prefix(stem: str) -> str:
    """Return the prefix of a temporary folder of this process: ``STEM-OWNER-``."""
    return f"{stem}-{_owner()}-"


def remove_stale_temporaries(folder: Path, stem: str) -> None:
    """Remove, silently, ``folder``'s temporaries (:func:`temporary_prefix`) of killed runs."""
    for path in _stale(folder, f"{stem}-"):
        shutil.rmtree(path, ignore_errors=True)


def private_folder(stem: str) -> Path:
    """Make a folder of this process's in TMPDIR (``STEM-OWNER-*``), killed runs' removed.

    Tracked as a partial output: a signal that ends the run removes it; so does
    :func:`remove_private_folder`.
    """
    remove_stale_temporaries(Path(tempfile.gettempdir()), stem)
    folder = Path(tempfile.mkdtemp(prefix=temporary_prefix(stem)))
    track_partial(folder)
    return folder


def remove_private_folder(folder: Path) -> None:
    """Remove a :func:`private_folder` and stop tracking it."""
    shutil.rmtree(folder, ignore_errors=True)
    untrack_partial(folder)


def remove_stale_partials(
    target: Path, *, label: str | None = None, where: Path | None = None
) -> int:
    """Remove ``target``'s partial outputs left by runs that were killed; say so per output.

    A killed run (SIGKILL, an out-of-memory kill, a batch system's hard time limit) cannot
    remove its hidden partial output. Only the partial outputs of ``target`` named by
    :func:`partial_prefix` with this machine's name, boot and PID namespace and the id of a
    process that no longer exists are removed: one of a run still going (here, in another
    container or on another machine sharing the folder) is never touched. One line on
    standard error per removal, with its size.

    Args:
        target: the output about to be written.
        label: the output as the line names it (default: ``target``).
        where: the folder the partial outputs are made in (default: ``target``'s).

    Returns:
        The number of partial outputs removed.
    """
    removed = 0
    folder = target.parent if where is None else where
    for path in _stale(folder, _partial_start(target, folder)):
        size = _size(path)
        try:
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            else:
                path.unlink()
        except OSError:
            continue  # not ours to remove (permissions): left as it is
        removed += 1
        with contextlib.suppress(OSError, ValueError):
            print(
                f"note: removed {label or target}'s partial output left by an earlier run "
                f"that was killed ({size / 1e6:.1f} MB)",
                file=sys.stderr,
            )
    return removed


def _umask_of_status() -> int | None:
    """The process's umask as Linux shows it (``Umask:`` of /proc/self/status, Linux 4.7+)."""
    try:
        with open("/proc/self/status", encoding="ascii", errors="replace") as file:
            for line in file:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    return None


def _umask_by_setting() -> int:
    """Read the umask by setting it and back (0o077 meanwhile: a file made then is private)."""
    mask = os.umask(0o077)
    os.umask(mask)
    return mask


_STATUS_UMASK = _umask_of_status()
_START_UMASK: int = (  # at import: before the threads (0, a umask of some images, included)
    _STATUS_UMASK if _STATUS_UMASK is not None else _umask_by_setting()
)


def process_umask() -> int:
    """Return the process's umask without changing it while other threads may make files.

    Read from /proc where Linux shows it; elsewhere set and restored only while this is
    the process's one thread, otherwise the umask at import.
    """
    mask = _umask_of_status()
    if mask is not None:
        return mask
    if threading.active_count() == 1:
        return _umask_by_setting()
    return _START_UMASK
