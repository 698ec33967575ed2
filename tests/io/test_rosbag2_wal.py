"""A rosbag2 sqlite3 bag left with its write-ahead log (a killed ``resilient`` recorder).

Before (bug hunt 16B F2): rosbags opens the database ``immutable``, so every message in
``NAME.db3-wal`` was silently dropped (2 of 6 frames densified, no warning).
"""

from __future__ import annotations

import shutil
import sqlite3
import tempfile
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Writer

from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.rosbag2_wal import release_wal_copies

LEFT = "/stereo/left/image_rect"


def _wal_bag(tmp_path: Path, name: str = "walbag") -> Path:
    """A sqlite3 bag of 6 images whose last 4 messages are only in its ``-wal``."""
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
    db = next(source.glob("*.db3"))
    bag = tmp_path / name
    bag.mkdir()
    shutil.copy(source / "metadata.yaml", bag / "metadata.yaml")
    text = (bag / "metadata.yaml").read_text().replace(db.name, f"{name}.db3")
    (bag / "metadata.yaml").write_text(text)
    connection_ = sqlite3.connect(db)
    try:
        rows = connection_.execute("SELECT * FROM messages ORDER BY timestamp").fetchall()
        connection_.execute(
            "DELETE FROM messages WHERE id IN (?, ?, ?, ?)", [r[0] for r in rows[2:]]
        )
        connection_.commit()
        connection_.execute("PRAGMA journal_mode=WAL").fetchall()
        connection_.execute("PRAGMA wal_autocheckpoint=0").fetchall()
        for row in rows[2:]:
            connection_.execute("INSERT INTO messages VALUES (?, ?, ?, ?)", row)
            connection_.commit()
        # the files as a killed recorder leaves them: the log not merged
        shutil.copy(db, bag / f"{name}.db3")
        shutil.copy(db.with_name(db.name + "-wal"), bag / f"{name}.db3-wal")
    finally:
        connection_.close()
    return bag


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


@pytest.mark.parametrize("as_file", [False, True])
def test_the_messages_in_the_wal_are_read_and_the_bag_left_alone(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, as_file: bool
) -> None:
    """All 6 images, one warning naming the WAL; the user's files unchanged, no copy left."""
    bag = _wal_bag(tmp_path)
    before = _snapshot(bag)
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    path = bag / "walbag.db3" if as_file else bag
    with open_log(path) as reader:
        stamps = [r.log_time_ns for r in reader.messages([LEFT])]
        assert len(stamps) == 6  # before: 2
        assert reader.damage == []
        assert len(reader.warnings) == 1
        assert "walbag.db3-wal held 4 messages not yet merged" in reader.warnings[0]
        assert f"`sqlite3 {bag / 'walbag.db3'} 'PRAGMA wal_checkpoint'`" in reader.warnings[0]
    assert _snapshot(bag) == before
    # one copy per process, kept for the next open, removed at its end
    assert [p.name.startswith("pcainterp-wal-") for p in scratch.iterdir()] == [True]
    release_wal_copies()
    assert list(scratch.iterdir()) == []


def test_a_wal_that_cannot_be_merged_is_named_as_damage(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """No room for the private copy: the bag read as it is, the damage says what is missing."""
    bag = _wal_bag(tmp_path)

    def full(*_args: object, **_kwargs: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(shutil, "copyfile", full)
    with open_log(bag) as reader:
        assert len(list(reader.messages([LEFT]))) == 2
        assert len(reader.damage) == 1
        assert reader.damage[0].startswith(
            "walbag.db3: its write-ahead log walbag.db3-wal holds messages not yet merged, "
            "which are not read (a private copy to merge them failed: "
        )
        assert reader.damage[0].endswith("'PRAGMA wal_checkpoint'` merges them into the bag")


def test_a_damaged_bag_read_through_its_copy_names_the_bag_and_the_damage(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The error named the private copy in TMPDIR (gone at the end) and no cause."""
    import os

    from pcainterp_stream.errors import LogReadError

    bag = _wal_bag(tmp_path)
    db = bag / "walbag.db3"
    os.truncate(db, db.stat().st_size // 2)  # an interrupted copy
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    with pytest.raises(LogReadError) as caught:
        open_log(bag)
    said = str(caught.value)
    release_wal_copies()
    assert str(scratch) not in said
    assert f"{bag / 'walbag.db3'}: database disk image is malformed" in said
    assert said.endswith(
        "its storage file is damaged or cannot be read (an interrupted copy, a failing disk); "
        "copy the bag again"
    )


def test_a_wal_merge_that_sqlite_refuses_is_not_put_down_to_room(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """sqlite's "disk I/O error" merging a damaged bag said to set TMPDIR to more room."""
    from pcainterp_stream.io import rosbag2_wal

    bag = _wal_bag(tmp_path)

    def damaged(*_args: object) -> None:
        raise sqlite3.OperationalError("disk I/O error")

    monkeypatch.setattr(rosbag2_wal, "_merge", damaged)
    with open_log(bag) as reader:
        assert len(list(reader.messages([LEFT]))) == 2
        assert len(reader.damage) == 1
        assert "TMPDIR" not in reader.damage[0]
        assert (
            "(a private copy to merge them failed: OperationalError: disk I/O error; walbag.db3 "
            "or its -wal is damaged or unreadable)"
        ) in reader.damage[0]
    release_wal_copies()
