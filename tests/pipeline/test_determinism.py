"""The same input and options give the same output, bit for bit, on the same machine.

Two runs of ``pcainterp synth``, then ``learn`` on that log, then ``densify`` with that
basis, each run in its own Python process (own hash seed), both started together so their
threads interleave differently, each in its own folder with the same relative file names
(the basis records the paths of its logs). Every message of the logs is compared (topic,
schema, encoding, log time, publish time, bytes) and every array of the bases. Across
machines expect differences at float rounding level instead (BLAS kernels and thread
counts; see docs/cluster.md, "Determinism").
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

FRAMES = 6
COMMANDS = [
    ["synth", "drive.mcap", "--frames", str(FRAMES), "--scale", "0.25", "--seed", "5"],
    ["learn", "drive.mcap", "-o", "basis.npz", "--components", "4"],
    ["densify", "drive.mcap", "-o", "dense.mcap", "--basis", "basis.npz"],
]
CHAIN = """
import json, sys
from pcainterp_stream import cli
for args in json.loads(sys.argv[1]):
    code = cli.main(args)
    if code:
        sys.exit(code)
"""
"""Runs the ``pcainterp`` commands of argv[1] (JSON) one after another in one process."""


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """Two folders, each with drive.mcap, basis.npz and dense.mcap from COMMANDS."""
    folders = (tmp_path_factory.mktemp("run_a"), tmp_path_factory.mktemp("run_b"))
    processes = [
        subprocess.Popen(
            [sys.executable, "-c", CHAIN, json.dumps(COMMANDS)],
            cwd=folder,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for folder in folders
    ]
    for process in processes:
        _, err = process.communicate(timeout=300)
        assert process.returncode == 0, err
    return folders


def _records(path: Path) -> list[tuple[str, str, str, int, int, bytes]]:
    """Return (topic, schema, encoding, log time, publish time, data) of every message."""
    records = []
    with path.open("rb") as stream:
        for schema, channel, message in make_reader(stream).iter_messages(log_time_order=False):
            records.append(
                (
                    channel.topic,
                    schema.name if schema is not None else "",
                    channel.message_encoding,
                    message.log_time,
                    message.publish_time,
                    bytes(message.data),
                )
            )
    return records


def _assert_same_messages(a: Path, b: Path) -> None:
    first, second = _records(a), _records(b)
    assert len(first) == len(second)
    for index, (one, other) in enumerate(zip(first, second, strict=True)):
        assert one[:5] == other[:5], f"message {index}: {one[:5]} != {other[:5]}"
        assert one[5] == other[5], f"message {index} on {one[0]} has other bytes"


def test_synth_is_deterministic(runs: tuple[Path, Path]) -> None:
    a, b = (folder / "drive.mcap" for folder in runs)
    _assert_same_messages(a, b)
    assert len(_records(a)) == FRAMES * 6  # left, right, 2 infos, depth, pose


def test_learn_is_deterministic(runs: tuple[Path, Path]) -> None:
    a, b = (folder / "basis.npz" for folder in runs)
    with np.load(a) as first, np.load(b) as second:
        assert sorted(first.files) == sorted(second.files)
        for key in first.files:
            one: Any = first[key]
            other: Any = second[key]
            assert one.dtype == other.dtype, key
            assert one.shape == other.shape, key
            assert one.tobytes() == other.tobytes(), f"basis array {key} differs"


def test_densify_is_deterministic(runs: tuple[Path, Path]) -> None:
    a, b = (folder / "dense.mcap" for folder in runs)
    _assert_same_messages(a, b)
    topics = {record[0] for record in _records(a)}
    assert "/pcainterp/depth" in topics
    assert "/pcainterp/disparity_std" in topics


@pytest.mark.parametrize("name", ["drive.mcap", "basis.npz", "dense.mcap"])
def test_outputs_are_identical_files(name: str, runs: tuple[Path, Path]) -> None:
    """No wall-clock time, random name or temporary's path is written into an output.

    (numpy stamps every .npz member with the fixed date 1980-01-01, not the write time.)
    """
    a, b = (folder / name for folder in runs)
    assert a.read_bytes() == b.read_bytes()
