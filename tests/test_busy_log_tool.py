"""tools/busy_log.py: a stereo log with a robot's other topics added, and densify's table.

The figures docs/benchmarks.md ("Logs where other topics outweigh the cameras") quotes come
from this tool: a variant that added nothing, at the wrong times or out of log-time order,
or a table without its rows, would quote figures of the plain log.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader

from pcainterp_stream.io import rosmsg

ROOT = Path(__file__).resolve().parents[1]
TOOL = ROOT / "tools" / "busy_log.py"
LEFT = "/stereo/left/image_rect"


@pytest.fixture(scope="module")
def tool() -> Any:
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import busy_log
    finally:
        sys.path.remove(str(ROOT / "tools"))
    return busy_log


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from pcainterp_stream.pipeline.jobs import synth

    path = tmp_path_factory.mktemp("busy") / "street.mcap"
    synth(path, frames=3, seed=1, scale=0.25, fmt=None)
    return path


def _messages(path: Path) -> list[tuple[str, int, bytes, str]]:
    with path.open("rb") as stream:
        return [
            (channel.topic, message.log_time, bytes(message.data), schema.name)
            for schema, channel, message in make_reader(stream).iter_messages(log_time_order=False)
        ]


def _file_order_times(path: Path) -> list[int]:
    with path.open("rb") as stream:
        records = StreamReader(stream, emit_chunks=False).records
        return [record.log_time for record in records if isinstance(record, Message)]


@pytest.mark.parametrize("variant", ["pre", "tail", "fast", "heavy"])
def test_a_variant_adds_the_topics_in_log_time_order(
    tool: Any, log: Path, tmp_path: Path, variant: str
) -> None:
    out = tmp_path / f"{variant}.mcap"
    added = tool.write_busy(log, out, variant, seconds=0.5, cloud_points=640)
    before, after = _messages(log), _messages(out)
    inputs = [m for m in after if m[0] in {b[0] for b in before}]
    assert sorted(inputs) == sorted(before)  # every input message, data and time kept
    extra = [m for m in after if m not in inputs]
    assert len(extra) == added > 0
    counts = Counter(m[0] for m in extra)
    lefts = [m[1] for m in before if m[0] == LEFT]
    first, last = min(lefts), max(lefts)
    times = [m[1] for m in extra]
    if variant == "heavy":
        assert set(counts) == {"/imu/data", "/lidar/points", "/lidar1/points"} | {
            "/lidar2/points",
            "/lidar3/points",
        }
        assert counts["/lidar/points"] == pytest.approx((last - first) / 1e9 * 20, abs=1)
    elif variant == "fast":
        assert set(counts) == {"/imu/data"}
        assert counts["/imu/data"] == pytest.approx((last - first + 5e8) / 1e9 * 10_000, abs=5)
    else:
        assert set(counts) == {"/imu/data", "/lidar/points"}
    # the lead: before the first image (pre, fast), after the last (tail), neither (heavy)
    assert (min(times) < first - 4e8) == (variant in ("pre", "fast"))
    assert (max(times) > last + 4e8) == (variant == "tail")
    assert not set(times) & {m[1] for m in before}  # never on an input's log time
    for topic, log_time, data, schema in extra:
        message = rosmsg.deserialize(data, schema)
        assert rosmsg.stamp_ns(message) == log_time, topic
        if topic.startswith("/lidar"):
            assert message.width == 640
            assert message.point_step == 24
    order = _file_order_times(out)
    assert order == sorted(order)  # the busy log itself is in log-time order


def _run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, str(TOOL), *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )


def test_the_table_has_a_row_per_log_and_tree(log: Path, tmp_path: Path) -> None:
    tree = tmp_path / "tree"
    tree.mkdir()
    (tree / "pcainterp_stream").symlink_to(ROOT / "pcainterp_stream")
    done = _run(
        str(log),
        "--measure",
        "--variants",
        "tail",
        "--seconds",
        "1",
        "--cloud-points",
        "6400",
        "--before",
        str(tree),
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    rows = [line for line in done.stdout.splitlines() if line.startswith("| ")]
    assert rows[0].startswith("| tree | log | input MB | peak RSS MB | wall s | output / input |")
    assert [row.split(" | ")[:2] for row in rows[2:]] == [
        ["| before", "street"],
        ["| after", "street"],
        ["| before", "street_tail"],
        ["| after", "street_tail"],
    ]
    for row in rows[2:]:
        cells = row.split(" | ")
        assert 50 < float(cells[3]) < 2000, row  # peak RSS MB
        assert float(cells[4]) > 0, row  # wall s
        assert float(cells[5]) > 0.5, row  # output / input
        assert cells[6] == "0", row  # out of order
        assert cells[7] == "no |", row  # no full hold
    assert float(rows[2].split(" | ")[2]) < float(rows[4].split(" | ")[2])  # MB in: busier
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tree"]  # scratch removed


def test_bad_input_is_one_line(log: Path, tmp_path: Path) -> None:
    (tmp_path / "text.mcap").write_text("not a log\n")
    cases = [
        (["missing.mcap", "--out-dir", "o"], "missing.mcap: no such file"),
        (["text.mcap", "--out-dir", "o"], str(tmp_path / "text.mcap")),
        ([str(log)], "give --out-dir"),
        ([str(log), "--measure", "--before", str(tmp_path)], f"--before {tmp_path} holds no"),
    ]
    for args, start in cases:
        done = _run(*args, cwd=tmp_path)
        assert done.returncode == 2, args
        assert done.stdout == ""
        assert done.stderr.startswith(f"error: {start}"), done.stderr
        assert len(done.stderr.splitlines()) == 1
        assert "Traceback" not in done.stderr
