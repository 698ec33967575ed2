"""A rosbag2 sqlite3 bag still being recorded: its private merged copy is consistent.

A recorder in WAL mode checkpoints its log into the database and then restarts the log
(new salts): a database copied before that and a log copied after it did not fit together,
and the copy lost or repeated messages, or was "malformed" (bug hunt 17B F1).
"""

from __future__ import annotations

import shutil
import sqlite3
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag2 import Writer

from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.rosbag2_wal import release_wal_copies

LEFT = "/stereo/left/image_rect"


@pytest.fixture(autouse=True)
def scratch(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    release_wal_copies()
    folder = tmp_path / "scratch"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    yield folder
    release_wal_copies()


class Recorder:
    """A bag with a recorder's connection open on it (WAL mode, no automatic checkpoint)."""

    def __init__(self, tmp_path: Path) -> None:
        self.bag = tmp_path / "live"
        rng = np.random.default_rng(3)
        self.rows: list[tuple[int, bytes]] = []
        with Writer(self.bag, version=8) as writer:
            connection = writer.add_connection(LEFT, rosmsg.IMAGE, typestore=rosmsg.TYPESTORE)
            for i in range(2):
                self._add(rng, i, lambda stamp, data: writer.write(connection, stamp, data))
        self.db = next(self.bag.glob("*.db3"))
        self.rng = rng
        self.connection = sqlite3.connect(self.db, isolation_level=None)
        self.connection.execute("PRAGMA journal_mode=WAL").fetchall()
        self.connection.execute("PRAGMA wal_autocheckpoint=0").fetchall()
        self.record(6)

    def _add(self, rng: np.random.Generator, i: int, write: Callable[[int, bytes], Any]) -> None:
        stamp = 1_000_000_000 + i * 100_000_000
        image = rng.integers(0, 256, (64, 64), dtype=np.uint8)  # a page or more each
        data = rosmsg.serialize(rosmsg.image_message(image, stamp, "left"))
        write(stamp, data)
        self.rows.append((stamp, data))

    def record(self, count: int) -> None:
        """Append ``count`` messages, one transaction each."""
        for _ in range(count):
            self._add(self.rng, len(self.rows), self._insert)

    def _insert(self, stamp: int, data: bytes) -> None:
        self.connection.execute(
            "INSERT INTO messages (topic_id, timestamp, data) VALUES (1, ?, ?)", (stamp, data)
        )

    def checkpoint_and_record(self, count: int) -> None:
        """Checkpoint the log into the database, then record on: the log restarts."""
        self.connection.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchall()
        self.record(count)

    def close(self) -> None:
        self.connection.close()


@pytest.fixture
def recorder(tmp_path: Path) -> Iterator[Recorder]:
    live = Recorder(tmp_path)
    yield live
    live.close()


def _on_copy(monkeypatch: pytest.MonkeyPatch, suffix: str, times: int, act: Any) -> list[str]:
    """Run ``act`` when a file ending in ``suffix`` was copied (``times`` times at most)."""
    copied: list[str] = []
    copyfile = shutil.copyfile

    def copying(source: Any, target: Any, **kwargs: Any) -> Any:
        copied.append(Path(source).name)
        if str(source).endswith(suffix) and copied.count(Path(source).name) <= times:
            result = copyfile(source, target, **kwargs)
            act()
            return result
        return copyfile(source, target, **kwargs)

    monkeypatch.setattr(shutil, "copyfile", copying)
    return copied


def _read(bag: Path) -> tuple[list[tuple[int, bytes]], list[str], list[str]]:
    with open_log(bag) as reader:
        read = [(m.log_time_ns, bytes(m.data)) for m in reader.messages([LEFT])]
        return read, list(reader.warnings), list(reader.damage)


def test_a_log_restarted_between_the_two_copies_is_copied_again(
    recorder: Recorder, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before: the database copied before a checkpoint and the restarted log after it did not
    fit: 11 messages with the right stamps were read, 6 of them with wrong data (pages the
    checkpoint moved into the database were missing from the copy), and no word of it."""
    copied = _on_copy(monkeypatch, ".db3", 1, lambda: recorder.checkpoint_and_record(3))
    read, warnings, damage = _read(recorder.bag)
    assert read == recorder.rows  # all 11, in order, each once
    assert copied == ["live.db3", "live.db3-wal", "live.db3", "live.db3-wal"]
    assert not damage
    (warning,) = warnings
    assert "live.db3 is being recorded (it changed while it was copied" in warning
    assert "with the 3 messages its write-ahead log held merged" in warning


def test_a_log_that_restarts_at_every_copy_leaves_the_database_as_checkpointed(
    recorder: Recorder, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The log restarted while copied at every try: the database alone, as the recorder's
    last checkpoint left it (a consistent bag, fewer messages), and one warning saying so."""
    checkpoints = 0

    def restart() -> None:
        nonlocal checkpoints
        checkpoints += 1
        recorder.checkpoint_and_record(1)

    _on_copy(monkeypatch, ".db3-wal", 99, restart)
    read, warnings, damage = _read(recorder.bag)
    assert checkpoints == 4
    assert not damage
    # the 4th database copy: before the 4th checkpoint, whose message and the one recorded
    # after it are not read
    assert read == recorder.rows[:-2]
    (warning,) = warnings
    assert "is being recorded: its write-ahead log live.db3-wal restarted each of the 4" in warning
    assert "once the recorder has stopped" in warning


def test_a_bag_changing_at_every_copy_is_said_to_be_recorded(
    recorder: Recorder, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The database itself changed while copied at every try: one damage line naming the
    recording, no torn copy read."""
    _on_copy(monkeypatch, ".db3", 99, lambda: recorder.checkpoint_and_record(1))
    _, warnings, damage = _read(recorder.bag)
    assert not warnings
    (line,) = damage
    assert "live.db3 is being recorded: it changed each of the 4 times it was copied" in line
    assert "read it once the recorder has stopped" in line


def test_a_killed_recorders_bag_is_copied_once_without_a_recording_note(
    recorder: Recorder, monkeypatch: pytest.MonkeyPatch
) -> None:
    copied = _on_copy(monkeypatch, ".db3", 0, lambda: None)
    read, warnings, _ = _read(recorder.bag)
    assert copied == ["live.db3", "live.db3-wal"]
    assert read == recorder.rows
    (warning,) = warnings
    assert "held 6 messages not yet merged (its recorder was killed" in warning


def test_a_recorder_that_stops_while_the_bag_is_copied_leaves_it_whole(
    recorder: Recorder, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Review 17d R2: the recorder's last close merged and removed its log between the two
    copies: the missing -wal made "holds messages not yet merged, which are not read ...
    damaged or unreadable" of a bag that was whole. Now it is read as it is, all of it."""
    _on_copy(monkeypatch, ".db3", 1, recorder.close)
    read, warnings, damage = _read(recorder.bag)
    assert not (recorder.bag / "live.db3-wal").exists()
    assert read == recorder.rows
    assert damage == []
    assert warnings == []
