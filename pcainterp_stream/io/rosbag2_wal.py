"""rosbag2 sqlite3 storage with a write-ahead log beside it: read with the log applied.

``ros2 bag record`` with the ``resilient`` storage preset writes its ``.db3`` in SQLite's WAL
mode; a recorder that is killed leaves ``NAME.db3-wal`` (and ``-shm``) beside it, holding
every message written since the last checkpoint. rosbags opens the database ``immutable``,
which makes SQLite ignore that log: those messages were silently dropped. Opening the
user's file normally would write to its ``-shm`` (and a checkpoint to the database);
instead, a storage file with a non-empty ``-wal`` is copied with its log into a private
temporary folder, the log merged into the copy there, and the copy read. The user's files
are only read.
"""

from __future__ import annotations

import shutil
import sqlite3
import tempfile
from pathlib import Path

from pcainterp_stream.io.reader_base import _one_line

__all__ = ["WalView", "wal_file"]


def wal_file(storage: Path) -> Path | None:
    """Return the non-empty write-ahead log beside a ``.db3`` storage file, else None."""
    wal = storage.with_name(storage.name + "-wal")
    try:
        return wal if wal.is_file() and wal.stat().st_size > 0 else None
    except OSError:
        return None


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
        self._folder: Path | None = None
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

        Builds the copy on the first call; a copy that cannot be made (no room in the
        temporary folder) is noted in :attr:`failures` and the log read as it is.
        """
        if not self._walled:
            return self.path
        if self._folder is None:
            try:
                self._folder = Path(tempfile.mkdtemp(prefix="pcainterp-wal-"))
                self._build(self._folder)
            except (OSError, sqlite3.Error) as err:
                self.close()
                walled, self._walled = self._walled, []
                for storage in walled:
                    self.failures.append(
                        f"{storage.name}: its write-ahead log {storage.name}-wal holds messages "
                        f"not yet merged, which are not read (a private copy to merge them "
                        f"failed: {_one_line(err)}); `sqlite3 {storage} 'PRAGMA "
                        "wal_checkpoint'` merges them into the bag"
                    )
                return self.path
        return self.viewed(self.path)

    def viewed(self, path: Path) -> Path:
        """Return where ``path`` (the log or a file of its folder) lies in the view."""
        if self._folder is None:
            return path
        if path == self.path:
            return self._folder / path.name
        if path.parent == self.path:
            return self._folder / self.path.name / path.name
        return path

    def _build(self, folder: Path) -> None:
        if self.path.is_dir():
            view = folder / self.path.name
            view.mkdir()
            for entry in sorted(self.path.iterdir()):
                if entry.name.endswith(("-wal", "-shm")) or not entry.is_file():
                    continue
                if entry in self._walled:
                    self._merge(entry, view / entry.name)
                else:
                    (view / entry.name).symlink_to(entry.resolve())
        else:
            self._merge(self.path, folder / self.path.name)

    def _merge(self, storage: Path, copy: Path) -> None:
        """Copy ``storage`` and its WAL to ``copy``; merge the log into the copy."""
        wal = wal_file(storage)
        assert wal is not None
        shutil.copyfile(storage, copy)
        shutil.copyfile(wal, copy.with_name(copy.name + "-wal"))
        connection = sqlite3.connect(copy)
        try:
            connection.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchall()
            connection.execute("PRAGMA journal_mode=DELETE").fetchall()
        finally:
            connection.close()
        self.notes.append(
            f"{storage.name}: its write-ahead log {wal.name} held messages not yet merged (a "
            "recorder that was killed); read through a private copy with them merged "
            f"(`sqlite3 {storage} 'PRAGMA wal_checkpoint'` merges them into the bag)"
        )

    def close(self) -> None:
        """Remove the private copy."""
        if self._folder is not None:
            shutil.rmtree(self._folder, ignore_errors=True)
            self._folder = None
