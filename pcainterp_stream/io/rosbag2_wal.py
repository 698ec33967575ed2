"""rosbag2 sqlite3 storage with a write-ahead log beside it: read with the log applied.

``ros2 bag record`` with the ``resilient`` storage preset writes its ``.db3`` in SQLite's WAL
mode; a recorder that is killed leaves ``NAME.db3-wal`` (and ``-shm``) beside it, holding
every message written since the last checkpoint. rosbags opens the database ``immutable``,
which makes SQLite ignore that log: those messages were silently dropped. Opening the
user's file normally would write to its ``-shm`` (and a checkpoint to the database);
instead, a storage file whose ``-wal`` holds pages the database lacks is copied with its log
into a private temporary folder, the log merged into the copy there, and the copy read. The
user's files are only read.

The copy costs the size of the ``.db3`` in the temporary folder (``TMPDIR``) and the time to
copy it, so it is made once per process and log state (the files' sizes and modification
times) and shared by every open of the log, then removed when the process ends. Its folder
is named after the process (:func:`.output_paths.temporary_prefix`) and registered as a
partial output (removed by the watchdog if the command is stopped by force); a run killed
outright (SIGKILL, out of memory) leaves it, and the next run removes it, as the spooled
standard input is (:func:`.pipes.spool`). A ``-wal`` whose committed pages the database
already holds (all checkpointed, as a recorder stopped between a checkpoint and its next
write leaves it) is seen by reading the log and those pages alone: no copy, no note.

A bag still being recorded changes while it is copied: its recorder checkpoints the log
into the database and then restarts the log. The database and the log are taken as a pair
only when the log's header salts (new at every restart) were the same before the database
was copied and after the log was, and they are the same files; else the pair is copied
again (:data:`_TRIES` times at most). A bag that changed while copied is read through the
copy (as it was then) with a note saying it is being recorded; one whose log restarted at
every try, as its last database copy that did not change while copied holds it (the
recorder's last checkpoint, without the log's messages), with a note; one whose database
changed at every try is named in a damage line and read as it is. Whether another process
has the bag open is not asked: SQLite's locks cannot tell a recorder from a reader, and
probing them from this process would drop its own connections' locks on the file.
"""

from __future__ import annotations

import atexit
import errno
import itertools
import os
import shlex
import shutil
import sqlite3
import struct
import tempfile
import threading
import urllib.parse
from dataclasses import dataclass, field
from pathlib import Path

from pcainterp_stream.interrupt import signalled
from pcainterp_stream.io.output_paths import private_folder, remove_private_folder
from pcainterp_stream.io.reader_base import _one_line

__all__ = ["WalView", "release_wal_copies", "wal_file"]

STEM = "pcainterp-wal"
"""The start of the name of a process's folder of merged copies (then its owner)."""

_WAL_MAGIC = (0x377F0682, 0x377F0683)
_WAL_HEADER = 32
_FRAME_HEADER = 24
_ROOM_MARGIN = 1 << 20
"""Bytes kept free beyond the copy itself (the sqlite journal of the merge, rounding)."""


def wal_file(storage: Path) -> Path | None:
    """Return the non-empty write-ahead log beside a ``.db3`` storage file, else None."""
    wal = storage.with_name(storage.name + "-wal")
    try:
        return wal if wal.is_file() and wal.stat().st_size > 0 else None
    except OSError:
        return None


def wal_adds_nothing(storage: Path, wal: Path) -> bool:
    """Whether merging ``wal`` into ``storage`` would leave the database as it is.

    SQLite applies a log's frames up to its last commit frame whose salts match the log's
    header. When every page those frames hold (the latest version of each) is already in
    the database byte for byte, and the database has the size the last commit states, the
    log was checkpointed and holds nothing new. Reads the log's frame headers and, for each
    page it holds, that page of the log and of the database (stopping at the first that
    differs): the log's size at most, never the database's. Frame checksums are not
    verified: a torn frame can only make a page differ, and so a copy be made.
    """
    try:
        with wal.open("rb") as log, storage.open("rb") as database:
            header = log.read(_WAL_HEADER)
            if len(header) < _WAL_HEADER:
                return True  # SQLite ignores a log without a whole header
            magic, _version, page_size, _sequence, salt1, salt2 = struct.unpack(">6I", header[:24])
            if magic not in _WAL_MAGIC or page_size < 512 or page_size & (page_size - 1):
                return True  # not a log SQLite reads: it ignores it
            frames: list[tuple[int, int]] = []  # (page number, offset of the page's data)
            committed, pages_after = 0, 0
            for index in itertools.count():
                offset = _WAL_HEADER + index * (_FRAME_HEADER + page_size)
                log.seek(offset)
                frame = log.read(_FRAME_HEADER)
                if len(frame) < _FRAME_HEADER:
                    break
                page, commit, salt1_, salt2_ = struct.unpack(">4I", frame[:16])
                if (salt1_, salt2_) != (salt1, salt2) or page == 0:
                    break  # a frame of an earlier generation of the log: the end
                frames.append((page, offset + _FRAME_HEADER))
                if commit:
                    committed, pages_after = len(frames), commit
            if not committed:
                return True  # no committed frame: nothing SQLite would apply
            database.seek(0, 2)
            if database.tell() != pages_after * page_size:
                return False
            latest = dict(frames[:committed])  # the last version of each page
            for page, data_at in latest.items():
                log.seek(data_at)
                database.seek((page - 1) * page_size)
                if log.read(page_size) != database.read(page_size):
                    return False
            return True
    except OSError:
        return False  # the copy's own error will say what is wrong


@dataclass
class _Copy:
    """A log's private view (its walled storage merged), shared by the opens of the log."""

    key: tuple[object, ...]
    path: Path | None  # the log in the view; None: read the log itself
    notes: list[str] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)
    users: int = 0
    folder: Path | None = None  # the view's own folder (removed with it)


_lock = threading.RLock()
_copies: dict[tuple[object, ...], _Copy] = {}
_roots: dict[str, Path] = {}  # temporary folder -> this process's folder of copies in it
_serial = itertools.count()


def release_wal_copies() -> None:
    """Remove every merged copy this process made (at its end; tests call it too)."""
    with _lock:
        _copies.clear()
        for root in _roots.values():
            remove_private_folder(root)
        _roots.clear()


def _root() -> Path:
    """Return this process's folder of copies in the temporary folder; make it when needed."""
    base = tempfile.gettempdir()
    root = _roots.get(base)
    if root is not None and root.is_dir():
        return root
    if not _roots:
        atexit.register(release_wal_copies)
    root = _roots[base] = private_folder(STEM)  # killed runs' copies removed first
    return root


def _quoted(storage: Path) -> str:
    return shlex.quote(str(storage))


def _checkpoint_advice(storage: Path) -> str:
    return f"`sqlite3 {_quoted(storage)} 'PRAGMA wal_checkpoint'` merges them into the bag"


def _drop_unused() -> bool:
    """Remove the copies no open reader uses; return whether any folder was removed.

    A closed log's copy is kept for the next open of the same log (learn reads a log several
    times), so a command over several walled logs would otherwise hold every copy at once.
    """
    dropped = False
    for key, copy in list(_copies.items()):
        if copy.users <= 0 and copy.folder is not None:
            del _copies[key]
            shutil.rmtree(copy.folder, ignore_errors=True)
            dropped = True
    return dropped


class WalView:
    """Where a rosbag2 log is read from: itself, or a private copy with its WAL merged.

    Attributes:
        notes: one-line warnings (the WAL merged) for the reader to report.
        failures: one-line damage notes (a WAL that could not be merged: its messages are
            not read) for the reader to report.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.notes: list[str] = []
        self.failures: list[str] = []
        self._copy: _Copy | None = None
        self._walled = self._walled_storage(path)

    @staticmethod
    def _walled_storage(path: Path) -> list[Path]:
        if path.is_dir():
            candidates = sorted(p for p in path.iterdir() if p.suffix == ".db3" and p.is_file())
        elif path.is_file() and not path.name.endswith(("-wal", "-shm")):
            candidates = [path]
        else:
            candidates = []
        return [p for p in candidates if wal_file(p) is not None]

    def source(self) -> Path:
        """Return the path to hand rosbags (a private copy when a WAL lies beside storage).

        Finds or builds the process's copy on the first call; a copy that cannot be made
        (no room in the temporary folder) is noted in :attr:`failures` and the log read
        as it is.
        """
        if not self._walled:
            return self.path
        if self._copy is None:
            with _lock:
                copy = self._acquire()
            self._copy = copy
            self.notes, self.failures = list(copy.notes), list(copy.failures)
        return self.viewed(self.path)

    def viewed(self, path: Path) -> Path:
        """Return where ``path`` (the log or a file of its folder) lies in the view."""
        view = None if self._copy is None else self._copy.path
        if view is None:
            return path
        if path == self.path:
            return view
        if path.parent == self.path:
            return view / path.name
        return path

    def named(self, text: str) -> str:
        """Return ``text`` (an error) with the private copy's paths put back as the user's.

        A damaged storage file whose copy was made fails to open from the copy: the error
        named a folder in TMPDIR the user never gave and that is gone at the end.
        """
        view = None if self._copy is None else self._copy.path
        return text if view is None else text.replace(str(view), str(self.path))

    def close(self) -> None:
        """Let go of the copy (removed at the process's end, or when the log changes).

        After a signal every copy is removed now: the command then ends without the exit
        handlers (:func:`.interrupt.end_if_signalled`).
        """
        if self._copy is not None:
            with _lock:
                self._copy.users -= 1
            self._copy = None
        if signalled():
            release_wal_copies()

    def _key(self) -> tuple[object, ...]:
        """The log's identity and state: its walled storage files' and logs' sizes, times."""
        state: list[object] = [str(self.path.resolve())]
        for storage in self._walled:
            wal = storage.with_name(storage.name + "-wal")
            for part in (storage, wal):
                try:
                    stat = part.stat()
                    state.append((part.name, stat.st_size, stat.st_mtime_ns))
                except OSError:
                    state.append((part.name, None, None))
        return tuple(state)

    def _acquire(self) -> _Copy:
        key = self._key()
        copy = _copies.get(key)
        if copy is None or (copy.folder is not None and not copy.folder.is_dir()):
            self._forget_older(str(key[0]))
            copy = _copies[key] = self._make(key)
        copy.users += 1
        return copy

    @staticmethod
    def _forget_older(log: str) -> None:
        """Remove the unused copies of an earlier state of the log (it was written to since)."""
        for key, copy in list(_copies.items()):
            if key[0] == log and copy.users <= 0:
                del _copies[key]
                if copy.folder is not None:
                    shutil.rmtree(copy.folder, ignore_errors=True)

    def _make(self, key: tuple[object, ...]) -> _Copy:
        walled = [s for s in self._walled if not _checkpointed(s)]
        if not walled:
            return _Copy(key, None)
        needed = sum(_size(s) + _size(_wal_of(s)) for s in walled) + _ROOM_MARGIN
        base = tempfile.gettempdir()
        try:
            free = shutil.disk_usage(base).free
        except OSError:
            free = needed
        if free < needed and _drop_unused():  # copies of logs closed earlier in the run
            try:
                free = shutil.disk_usage(base).free
            except OSError:
                free = needed
        if free < needed:
            reason = (
                f"it needs {_megabytes(needed)} in the temporary folder {base}, which has "
                f"{_megabytes(free)} free"
            )
            return _Copy(key, None, failures=[_failure(s, reason) for s in walled])
        folder: Path | None = None
        try:
            folder = _root() / str(next(_serial))
            folder.mkdir()
            notes = self._build(folder, walled)
        except (OSError, sqlite3.Error, _Changing) as err:
            if folder is not None:
                shutil.rmtree(folder, ignore_errors=True)
            if isinstance(err, _Changing):
                return _Copy(key, None, failures=[_changing(s) for s in walled])
            if isinstance(err, FileNotFoundError) and not any(_wal_of(s).exists() for s in walled):
                return _Copy(key, None)  # the recorder stopped meanwhile: its log is merged
            reason = _copy_reason(err, base)
            fix = _copy_fix(err, base)
            return _Copy(key, None, failures=[_failure(s, reason, fix=fix) for s in walled])
        if not notes:  # the logs held no message the databases lack
            shutil.rmtree(folder, ignore_errors=True)
            return _Copy(key, None)
        view = folder / self.path.name
        return _Copy(key, view, notes=notes, folder=folder)

    def _build(self, folder: Path, walled: list[Path]) -> list[str]:
        """Make the view in ``folder``; return its notes (none: no message added)."""
        added: list[tuple[Path, _Merged]] = []
        if self.path.is_dir():
            view = folder / self.path.name
            view.mkdir()
            for entry in sorted(self.path.iterdir()):
                if entry.name.endswith(("-wal", "-shm")) or not entry.is_file():
                    continue
                if entry in walled:
                    added.append((entry, _merge(entry, view / entry.name)))
                else:
                    (view / entry.name).symlink_to(entry.resolve())
        else:
            added.append((self.path, _merge(self.path, folder / self.path.name)))
        if all(merged.added == 0 and not merged.recording for _, merged in added):
            return []
        notes = []
        for storage, merged in added:
            if merged.without_log:
                notes.append(
                    f"{storage.name} is being recorded: its write-ahead log {storage.name}-wal "
                    f"restarted each of the {_TRIES} times it was copied, so the bag is read "
                    "as of its recorder's last checkpoint, without the messages that log "
                    "holds; read it again once the recorder has stopped"
                )
                continue
            held = "messages" if merged.added is None else f"{merged.added} messages"
            if merged.recording:  # the copy, not the bag a checkpoint may change under rosbags
                merged_too = f", with the {held} its write-ahead log held merged"
                notes.append(
                    f"{storage.name} is being recorded (it changed while it was copied): "
                    "read through a private copy of it as it was then"
                    f"{merged_too if merged.added != 0 else ''}; the messages recorded since "
                    "are not read"
                )
            elif merged.added != 0:
                notes.append(
                    f"{storage.name}: its write-ahead log {storage.name}-wal held {held} not "
                    "yet merged (its recorder was killed, or is still recording); read through "
                    f"a private copy with them merged ({_checkpoint_advice(storage)})"
                )
        return notes


def _checkpointed(storage: Path) -> bool:
    """Whether the log beside ``storage`` adds nothing, the files unchanged while it is told.

    A recorder that writes on while the log is read may have restarted it (bug hunt 17B F1):
    then the storage is copied (and the copy checked) as any other.
    """
    wal = _wal_of(storage)
    before = (_state(storage), _state(wal), _generation(wal))
    return (
        wal_adds_nothing(storage, wal)
        and (_state(storage), _state(wal), _generation(wal)) == before
    )


def _changing(storage: Path) -> str:
    """The damage line of a storage file that changed at every try to copy it.

    The bag is then read as it is, and a checkpoint of its recorder may change it under the
    reader: what follows (a "malformed" database, messages out of order) is the recording's.
    """
    return (
        f"{storage.name} is being recorded: it changed each of the {_TRIES} times it was "
        "copied, so its write-ahead log's messages are not read and the bag is read in place, "
        "where the recorder's checkpoints may change it under the reader (later damage or "
        "out-of-order lines come from that); read it once the recorder has stopped"
    )


def _wal_of(storage: Path) -> Path:
    return storage.with_name(storage.name + "-wal")


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


def _megabytes(size: int) -> str:
    return f"{size / 1e6:.0f} MB" if size >= 1e6 else f"{size / 1e3:.0f} kB"


ROOM_FIX = "set TMPDIR to a folder with room for it"


def _in_copies(name: str | bytes | None, base: str) -> bool:
    """Whether the file ``name`` of an error is one of this module's copies in ``base``."""
    return name is not None and os.fsdecode(name).startswith(os.path.join(base, STEM))


def _copy_reason(err: BaseException, base: str) -> str:
    """``err`` from making the copy in one line, the copy's own paths not named.

    ``shutil.copyfile`` names both files (the bag's and the copy's): the copy's folder is
    gone by the time the user reads the line, and means nothing to them.
    """
    if not isinstance(err, OSError) or not err.strerror:
        return _one_line(err)
    names = [name for name in (err.filename, err.filename2) if name is not None]
    user = [os.fsdecode(name) for name in names if not _in_copies(name, base)]
    if any(_in_copies(name, base) for name in names):
        into = f"copying {user[0]} into" if user else "writing"
        where = f" ({into} the private copy in {base})"
    else:
        where = f" ({user[0]})" if user else ""
    return f"{type(err).__name__}: {err.strerror}{where}"  # whole: the paths are the point


def _copy_fix(err: BaseException, base: str) -> str | None:
    """What to do about ``err`` from making the copy (None: the bag's own files are at fault).

    Room or a file-size limit are the machine's, as is a temporary folder that refuses to
    make the copy (another TMPDIR helps); sqlite's "disk I/O error" or "database disk image
    is malformed" while merging, or a read of the bag that fails, are the bag's.
    """
    if not isinstance(err, OSError):
        return None
    if err.errno in (errno.ENOSPC, errno.EDQUOT):
        return ROOM_FIX
    if err.errno == errno.EFBIG:
        return "a file-size limit (ulimit -f) stopped the copy: raise it"
    refused = err.errno in (errno.EACCES, errno.EPERM, errno.EROFS)
    if refused and err.filename2 is None and _in_copies(err.filename, base):
        return f"the temporary folder {base} refused it: set TMPDIR to a folder you can write"
    return None


def _failure(storage: Path, reason: str, *, fix: str | None = ROOM_FIX) -> str:
    """The damage line of a WAL not merged, with ``fix`` (None: the bag's files are at fault).

    Without a fix of the machine's (:func:`_copy_fix`), the bag's own files are damaged or
    unreadable, which more room would not change.
    """
    if fix is None:
        fix = f"{storage.name} or its -wal is damaged or unreadable"
    return (
        f"{storage.name}: its write-ahead log {storage.name}-wal holds messages not yet "
        f"merged, which are not read (a private copy to merge them failed: {reason}; "
        f"{fix}); {_checkpoint_advice(storage)}"
    )


_TRIES = 4
"""Copies of a walled storage file made before its bag is said to be changing as it is copied."""


class _Changing(Exception):
    """A storage file and its log changed at every try to copy them (a recorder writes on)."""


@dataclass
class _Merged:
    """What :func:`_merge` made: the messages its log added, and whether the bag moved."""

    added: int | None  # the messages the log added (None: cannot be told)
    recording: bool = False  # the files changed while they were copied (a recorder writes)
    without_log: bool = False  # no consistent copy with the log: the database alone


def _generation(wal: Path) -> bytes | None:
    """The log's salts: a writer that restarts the log (after a checkpoint) changes them."""
    try:
        with wal.open("rb") as log:
            header = log.read(_WAL_HEADER)
    except OSError:
        return None
    return header[16:24] if len(header) == _WAL_HEADER else None


def _state(path: Path) -> tuple[int, ...] | None:
    """A file's identity and state (device, inode, size, modification time), None if gone."""
    try:
        stat = path.stat()
    except OSError:
        return None
    return (stat.st_dev, stat.st_ino, stat.st_size, stat.st_mtime_ns)


def _merge(storage: Path, copy: Path) -> _Merged:
    """Copy ``storage`` and its WAL to ``copy``; merge the log into the copy.

    A recorder still writing the bag checkpoints its log into the database and then
    restarts the log (new salts in its header): a database copied before that and a log
    copied after do not fit together (messages lost or repeated, "database disk image is
    malformed"; bug hunt 17B F1). The pair is consistent when the log's salts were the same
    before the database was copied and after the log was (a log only grows within one
    generation, and a checkpoint writes only pages that log holds); else it is copied again,
    up to :data:`_TRIES` times. If the log restarted each time, the last database copy is
    read alone when it did not change while copied (the bag as of the recorder's last
    checkpoint, without the log's messages). The user's files are only read.

    Raises:
        _Changing: neither a consistent pair nor an unchanged database could be copied.
    """
    wal, copied_wal = _wal_of(storage), copy.with_name(copy.name + "-wal")
    recording = False
    for attempt in range(_TRIES):
        generation, database, log = _generation(wal), _state(storage), _state(wal)
        shutil.copyfile(storage, copy)
        database_after = _state(storage)
        last = _last_id(copy)  # the copy's own messages, read before its log is beside it
        shutil.copyfile(wal, copied_wal)
        log_after = _state(wal)
        recording = recording or database_after != database or log_after != log
        same_files = (
            database is not None
            and database_after is not None
            and log is not None
            and log_after is not None
            and database[:2] == database_after[:2]
            and log[:2] == log_after[:2]
        )
        if same_files and generation == _generation(copied_wal) == _generation(wal):
            return _Merged(_apply(copy, last), recording=recording)
        recording = True
        if attempt == _TRIES - 1 and database is not None and database == database_after:
            copied_wal.unlink()
            return _Merged(0, recording=True, without_log=True)
    raise _Changing(storage.name)


def _last_id(database: Path) -> int | None:
    """The highest message id of a database read alone (None: none, or it cannot be read)."""
    uri = f"file:{urllib.parse.quote(str(database.resolve()))}?immutable=1"
    try:
        connection = sqlite3.connect(uri, uri=True)
        try:
            row = connection.execute("SELECT max(rowid) FROM messages").fetchone()
        finally:
            connection.close()
    except sqlite3.Error:  # no messages table without the log: every message is the log's
        return None
    return None if row is None or row[0] is None else int(row[0])


def _apply(copy: Path, last: int | None) -> int | None:
    """Merge the log beside ``copy`` into it; return the messages past id ``last``."""
    connection = sqlite3.connect(copy)
    try:
        connection.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchall()
        connection.execute("PRAGMA journal_mode=DELETE").fetchall()
        return _added_messages(connection, last)
    finally:
        connection.close()


def _added_messages(merged: sqlite3.Connection, last: int | None) -> int | None:
    """Count the messages ``merged`` holds beyond id ``last`` (its database's alone).

    rosbag2 appends messages with rising ids and never deletes one: those past the
    database's highest id (read with the log ignored, as rosbags reads it) are the log's.
    """
    try:
        if last is None:
            row = merged.execute("SELECT count(*) FROM messages").fetchone()
        else:
            query = "SELECT count(*) FROM messages WHERE rowid > ?"
            row = merged.execute(query, (last,)).fetchone()
        return int(row[0])
    except sqlite3.Error:
        return None
