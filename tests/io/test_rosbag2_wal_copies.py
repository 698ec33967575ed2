"""The private copy a rosbag2 sqlite3 bag with a ``-wal`` is read through (review 16c).

Before: every open of the log copied the whole ``.db3`` again (``learn`` made 6 copies), in a
``pcainterp-wal-XXXX`` folder a killed run left in the temporary folder for good, with no
check of the room it needs; every non-empty ``-wal`` was "messages not yet merged", also one
already checkpointed, and the suggested ``sqlite3`` command put the path in unquoted.
"""

from __future__ import annotations

import errno
import os
import shutil
import sqlite3
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag2 import Writer

from pcainterp_stream import interrupt
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.output_paths import temporary_prefix
from pcainterp_stream.io.rosbag2_wal import release_wal_copies

LEFT = "/stereo/left/image_rect"


@pytest.fixture(autouse=True)
def scratch(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """The temporary folder the copies go to (empty at the start of each test)."""
    release_wal_copies()
    folder = tmp_path / "scratch"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    yield folder
    release_wal_copies()


def _source(tmp_path: Path) -> Path:
    """A tidy sqlite3 bag of 6 small images; return its .db3."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    source = tmp_path / "source"
    rng = np.random.default_rng(1)
    with Writer(source, version=8) as writer:
        connection = writer.add_connection(LEFT, rosmsg.IMAGE, typestore=rosmsg.TYPESTORE)
        for i in range(6):
            stamp = 1_000_000_000 + i * 100_000_000
            image = rng.integers(0, 256, (8, 8), dtype=np.uint8)
            writer.write(
                connection, stamp, rosmsg.serialize(rosmsg.image_message(image, stamp, "left"))
            )
    return next(source.glob("*.db3"))


def _left_by_killed_recorder(db: Path, bag: Path, write: Any) -> Path:
    """Put ``db`` in WAL mode, run ``write`` on it, copy the files as a killed run leaves them."""
    bag.mkdir(parents=True)
    metadata = (db.parent / "metadata.yaml").read_text().replace(db.name, f"{bag.name}.db3")
    (bag / "metadata.yaml").write_text(metadata)
    connection = sqlite3.connect(db)
    try:
        connection.execute("PRAGMA journal_mode=WAL").fetchall()
        connection.execute("PRAGMA wal_autocheckpoint=0").fetchall()
        write(connection)
        shutil.copy(db, bag / f"{bag.name}.db3")
        shutil.copy(db.with_name(db.name + "-wal"), bag / f"{bag.name}.db3-wal")
    finally:
        connection.close()
    return bag


def _wal_bag(tmp_path: Path, name: str = "walbag") -> Path:
    """A bag whose last 4 of 6 messages are only in its ``-wal``."""
    db = _source(tmp_path)
    connection = sqlite3.connect(db)
    rows = connection.execute("SELECT * FROM messages ORDER BY timestamp").fetchall()
    connection.execute("DELETE FROM messages WHERE id IN (?, ?, ?, ?)", [r[0] for r in rows[2:]])
    connection.commit()
    connection.close()

    def write(connection: sqlite3.Connection) -> None:
        for row in rows[2:]:
            connection.execute("INSERT INTO messages VALUES (?, ?, ?, ?)", row)
            connection.commit()

    return _left_by_killed_recorder(db, tmp_path / name, write)


def _count_copies(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    copied: list[str] = []
    copyfile = shutil.copyfile

    def counting(source: Any, target: Any, **kwargs: Any) -> Any:
        copied.append(Path(source).name)
        return copyfile(source, target, **kwargs)

    monkeypatch.setattr(shutil, "copyfile", counting)
    return copied


def test_one_copy_serves_every_open_of_the_log(
    tmp_path: Path, scratch: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before: 3 opens, 3 copies of the .db3 (learn opened a log 6 times: 6 copies)."""
    bag = _wal_bag(tmp_path)
    copied = _count_copies(monkeypatch)
    for _ in range(3):
        with open_log(bag) as reader:
            assert len(list(reader.messages([LEFT]))) == 6
            assert len(reader.warnings) == 1, reader.warnings
    assert copied == ["walbag.db3", "walbag.db3-wal"]
    (folder,) = scratch.iterdir()
    assert folder.name.startswith(temporary_prefix("pcainterp-wal"))  # owner-named
    assert folder in interrupt._partials  # removed if a signal forces the end
    release_wal_copies()
    assert list(scratch.iterdir()) == []
    assert folder not in interrupt._partials


def test_a_log_written_to_since_is_copied_again_and_the_old_copy_removed(
    tmp_path: Path, scratch: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A bag still being recorded: the next open sees its new state, one copy kept."""
    bag = _wal_bag(tmp_path)
    with open_log(bag) as reader:
        assert len(list(reader.messages([LEFT]))) == 6
    wal = bag / "walbag.db3-wal"
    with wal.open("ab") as log:
        log.write(bytes(100))  # a torn frame: SQLite ignores it; the state changed
    copied = _count_copies(monkeypatch)
    with open_log(bag) as reader:
        assert len(list(reader.messages([LEFT]))) == 6
    assert copied == ["walbag.db3", "walbag.db3-wal"]
    (root,) = scratch.iterdir()
    assert len(list(root.iterdir())) == 1


def test_the_copy_of_a_killed_run_is_removed_by_the_next(tmp_path: Path, scratch: Path) -> None:
    """Before: a SIGKILL (or the OOM killer) left the whole .db3's copy in TMPDIR for good."""
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    prefix = temporary_prefix("pcainterp-wal")
    killed = scratch / (prefix.replace(f"-{os.getpid()}@", f"-{process.pid}@") + "t1x6e3v1")
    killed.mkdir()
    (killed / "walbag.db3").write_bytes(bytes(1000))
    live = scratch / (prefix.replace(f"-{os.getpid()}@", f"-{os.getppid()}@") + "abcdefgh")
    live.mkdir()  # a run still going
    with open_log(_wal_bag(tmp_path)) as reader:
        assert len(list(reader.messages([LEFT]))) == 6
    assert not killed.exists()
    assert live.is_dir()
    release_wal_copies()
    assert sorted(os.listdir(scratch)) == [live.name]


def test_no_room_for_the_copy_is_said_before_copying_naming_tmpdir(
    tmp_path: Path, scratch: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before: the copy was tried whatever the room (and its error did not name TMPDIR)."""
    bag = _wal_bag(tmp_path, name="my bag")
    copied = _count_copies(monkeypatch)
    usage = shutil.disk_usage(scratch)
    monkeypatch.setattr(shutil, "disk_usage", lambda _path: usage._replace(free=1000))
    with open_log(bag) as reader:
        assert len(list(reader.messages([LEFT]))) == 2
        assert len(reader.damage) == 1, reader.damage
        line = reader.damage[0]
    assert copied == []
    assert line.startswith(
        "my bag.db3: its write-ahead log my bag.db3-wal holds messages not yet merged, which "
        "are not read (a private copy to merge them failed: it needs "
    )
    assert f"in the temporary folder {scratch}, which has 1 kB free" in line
    assert "set TMPDIR to a folder with room for it" in line
    assert line.endswith(
        f"`sqlite3 '{bag / 'my bag.db3'}' 'PRAGMA wal_checkpoint'` merges them into the bag"
    )
    assert list(scratch.iterdir()) == []


def test_the_suggested_command_quotes_the_path(tmp_path: Path) -> None:
    """Before: `sqlite3 /x/my bag/my bag.db3 'PRAGMA wal_checkpoint'`: two wrong arguments."""
    bag = _wal_bag(tmp_path / "my bags", name="my bag")
    with open_log(bag) as reader:
        assert len(list(reader.messages([LEFT]))) == 6
        (warning,) = reader.warnings
    assert f"`sqlite3 '{bag / 'my bag.db3'}' 'PRAGMA wal_checkpoint'`" in warning


def test_a_checkpointed_wal_needs_no_copy_and_no_note(
    tmp_path: Path, scratch: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A recorder stopped after a checkpoint: the log's pages are all in the database.

    Before: the whole .db3 copied and the note "held messages not yet merged (a recorder
    that was killed)", for nothing.
    """

    def write(connection: sqlite3.Connection) -> None:
        connection.execute("CREATE TABLE extra (a)")
        connection.commit()
        connection.execute("PRAGMA wal_checkpoint(PASSIVE)").fetchall()

    bag = _left_by_killed_recorder(_source(tmp_path), tmp_path / "ckbag", write)
    assert (bag / "ckbag.db3-wal").stat().st_size > 0
    copied = _count_copies(monkeypatch)
    with open_log(bag) as reader:
        assert len(list(reader.messages([LEFT]))) == 6
        assert reader.warnings == []
        assert reader.damage == []
    assert copied == []
    assert list(scratch.iterdir()) == []


def test_a_wal_that_adds_no_message_leaves_no_note(tmp_path: Path, scratch: Path) -> None:
    """A log with changes the database lacks but no message: the copy dropped, no note."""

    def write(connection: sqlite3.Connection) -> None:
        connection.execute("CREATE TABLE extra (a)")
        connection.commit()

    bag = _left_by_killed_recorder(_source(tmp_path), tmp_path / "nomsg", write)
    with open_log(bag) as reader:
        assert len(list(reader.messages([LEFT]))) == 6
        assert reader.warnings == []
        assert reader.damage == []
    for root in scratch.iterdir():
        assert list(root.iterdir()) == []


def test_after_a_signal_the_copy_goes_with_the_reader(
    tmp_path: Path, scratch: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Guard (passes on the old code, which removed the copy at every close): an interrupted
    command ends without the exit handlers, so the shared copy is removed at close."""
    reader = open_log(_wal_bag(tmp_path))
    assert len(list(reader.messages([LEFT]))) == 6
    assert len(list(scratch.iterdir())) == 1
    monkeypatch.setattr(interrupt, "_signals_seen", 1)
    reader.close()
    assert list(scratch.iterdir()) == []


def test_a_closed_logs_copy_makes_room_for_the_next_log(
    tmp_path: Path, scratch: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before: the first log's copy stayed until the process ended, so with room for one copy
    the second walled log of a run (learn over two logs) lost its WAL's messages."""
    first, second = _wal_bag(tmp_path / "a", name="a"), _wal_bag(tmp_path / "b", name="b")
    one = sum(p.stat().st_size for p in first.iterdir() if ".db3" in p.name)
    usage = shutil.disk_usage(scratch)

    def held() -> int:
        return sum(p.stat().st_size for p in scratch.rglob("*") if p.is_file())

    room = one + (one // 4) + (1 << 20)  # the margin kept free, and one copy but not two
    monkeypatch.setattr(shutil, "disk_usage", lambda _p: usage._replace(free=room - held()))
    for bag in (first, second):
        with open_log(bag) as reader:
            assert len(list(reader.messages([LEFT]))) == 6, reader.damage
            assert reader.damage == []
    copies = [p for p in scratch.glob("*/*") if p.is_dir()]
    assert len(copies) == 1, copies


def test_an_open_logs_copy_is_kept_when_room_runs_short(
    tmp_path: Path, scratch: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A copy a reader still uses is never removed to make room for another log's."""
    first, second = _wal_bag(tmp_path / "a", name="a"), _wal_bag(tmp_path / "b", name="b")
    one = sum(p.stat().st_size for p in first.iterdir() if ".db3" in p.name)
    usage = shutil.disk_usage(scratch)

    def held() -> int:
        return sum(p.stat().st_size for p in scratch.rglob("*") if p.is_file())

    monkeypatch.setattr(
        shutil, "disk_usage", lambda _p: usage._replace(free=one + (one // 4) + (1 << 20) - held())
    )
    with open_log(first) as reader_a:
        assert len(list(reader_a.messages([LEFT]))) == 6
        with open_log(second) as reader_b:
            assert len(list(reader_b.messages([LEFT]))) == 2
            assert len(reader_b.damage) == 1
        assert len(list(reader_a.messages([LEFT]))) == 6


@pytest.mark.parametrize(
    ("code", "names", "said"),
    [
        (errno.EFBIG, "both", "a file-size limit (ulimit -f) stopped the copy: raise it)"),
        (errno.ENOSPC, "both", "set TMPDIR to a folder with room for it"),
        (errno.EACCES, "target", "refused it: set TMPDIR to a folder you can write"),
        (errno.EACCES, "source", "walbag.db3 or its -wal is damaged or unreadable"),
    ],
)
def test_a_copy_the_machine_refuses_is_not_put_down_to_the_bag(
    tmp_path: Path,
    scratch: Path,
    monkeypatch: pytest.MonkeyPatch,
    code: int,
    names: str,
    said: str,
) -> None:
    """Review 17b R2: a copy stopped by `ulimit -f` (EFBIG) said the healthy bag "is damaged
    or unreadable", and named the copy's folder in TMPDIR; review 17e R1, R2: the folder was
    replaced inside the quoted path, and a bag's own unreadable file under TMPDIR was put
    down to TMPDIR. shutil.copyfile names both files when a write fails, the one it could
    not open alone."""
    bag = _wal_bag(tmp_path)

    def refused(source: Any, target: Any, **kwargs: Any) -> Any:
        text = os.strerror(code)
        if names == "both":
            raise OSError(code, text, str(source), None, str(target))
        raise OSError(code, text, str(target if names == "target" else source))

    monkeypatch.setattr(shutil, "copyfile", refused)
    with open_log(bag) as reader:
        assert len(list(reader.messages([LEFT]))) == 2
        (line,) = reader.damage
    assert said in line
    assert "pcainterp-wal" not in line
    if names != "source":
        assert "damaged or unreadable" not in line
        assert f"the private copy in {scratch})" in line
    else:
        assert f"({bag / 'walbag.db3'})" in line
