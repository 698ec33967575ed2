"""Bug hunt 10A: content a golden file must guard (F11-F13), partial updates (F3), errors
naming the fix (F8), log-time tolerance (F9) and golden files of format 2 still checked."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap_ros2.writer import Writer

from pcainterp_stream.cli import main
from pcainterp_stream.errors import GoldenError
from pcainterp_stream.golden import check_log, load_golden, save_golden
from pcainterp_stream.golden.decode import MessageContent, _walk
from pcainterp_stream.io import rosmsg

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data"


def _write(path: Path, messages: list[tuple[str, str, dict[str, Any], int]]) -> Path:
    """Write (topic, type, message dict, log time ns) as an MCAP of ROS 2 messages."""
    with path.open("wb") as stream:
        writer = Writer(stream)
        schemas: dict[str, Any] = {}
        for topic, msgtype, message, log_time in messages:
            if msgtype not in schemas:
                schemas[msgtype] = writer.register_msgdef(msgtype, rosmsg.schema_text(msgtype))
            writer.write_message(
                topic, schemas[msgtype], message, log_time=log_time, publish_time=log_time
            )
        writer.finish()
    return path


def _header(stamp_ns: int = 1_000_000_000, frame: str = "cam") -> dict[str, Any]:
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame}


def _image(array: np.ndarray, encoding: str) -> dict[str, Any]:
    return {
        "header": _header(),
        "height": array.shape[0],
        "width": array.shape[1],
        "encoding": encoding,
        "is_bigendian": 0,
        "step": array.strides[0],
        "data": array.tobytes(),
    }


def _images(path: Path, zero: bool) -> Path:
    rng = np.random.default_rng(1)
    arrays = {
        "16SC1": rng.integers(-3000, 3000, (30, 40)).astype(np.int16),
        "64FC1": rng.random((30, 40)),
        "32FC2": rng.random((30, 40, 2)).astype(np.float32),
        "weird": rng.integers(0, 255, (30, 40)).astype(np.uint8),
    }
    messages = [
        (f"/img_{enc.lower()}", rosmsg.IMAGE, _image(a * 0 if zero else a, enc), 10**9)
        for enc, a in arrays.items()
    ]
    blob = np.zeros(2000, np.uint8) if zero else rng.integers(0, 255, 2000).astype(np.uint8)
    video = {"header": _header(), "format": "h264", "data": blob.tobytes()}
    messages.append(("/video", rosmsg.COMPRESSED_IMAGE, video, 10**9))
    return _write(path, messages)


@pytest.mark.parametrize("arrays", [False, True])
def test_images_the_decoder_lacked_are_guarded(tmp_path: Path, arrays: bool) -> None:
    """F11: 16SC1 / 64FC1 / 32FC2 decode to their dtype; an encoding or a CompressedImage
    that does not decode is guarded by its raw bytes, and says so at check time."""
    golden = tmp_path / "g.golden.json"
    save_golden(_images(tmp_path / "a.mcap", zero=False), golden, arrays=arrays)
    zeroed = check_log(_images(tmp_path / "b.mcap", zero=True), golden)
    changed = {d.topic for d in zeroed.differences}
    assert changed == {"/img_16sc1", "/img_64fc1", "/img_32fc2", "/img_weird", "/video"}
    same = check_log(tmp_path / "a.mcap", golden)
    assert same.passed
    assert any("'weird'" in note and "raw data bytes" in note for note in same.notes)
    assert any("'h264'" in note for note in same.notes)
    document = load_golden(golden)
    image = document["channels"]["/img_32fc2"]["messages"][0]["arrays"]["image"]
    assert image["dtype"] == "float32"
    assert image["shape"] == [30, 40, 2]


def _cloud(path: Path, points: np.ndarray, pad_type: int) -> Path:
    fields = [
        {"name": "x", "offset": 0, "datatype": 7, "count": 1},
        {"name": "y", "offset": 4, "datatype": 7, "count": 1},
        {"name": "z", "offset": 8, "datatype": 7, "count": 1},
        {"name": "desc", "offset": 12, "datatype": 7, "count": 4},
        {"name": "pad", "offset": 28, "datatype": pad_type, "count": 1},
    ]
    n = len(points)
    message = {
        "header": _header(),
        "height": 1,
        "width": n,
        "fields": fields,
        "is_bigendian": False,
        "point_step": 32,
        "row_step": 32 * n,
        "data": points.astype(np.float32).tobytes(),
        "is_dense": True,
    }
    return _write(path, [("/cloud", rosmsg.POINT_CLOUD2, message, 10**9)])


@pytest.mark.parametrize("pad_type", [7, 0])
def test_every_element_of_every_known_point_field_is_guarded(tmp_path: Path, pad_type: int) -> None:
    """F12: a field of count 4 is an (n, 4) array; a field of datatype 0 leaves a note and
    the other fields guarded."""
    points = np.random.default_rng(0).random((500, 8)).astype(np.float32)
    golden = tmp_path / "c.golden.json"
    save_golden(_cloud(tmp_path / "a.mcap", points, pad_type), golden, arrays=True)
    desc = points.copy()
    desc[:, 4:7] = 0  # desc[1..3]
    xyz = points.copy()
    xyz[:, :3] = 0
    for changed, names in ((desc, {"points.desc"}), (xyz, {"points.x", "points.y"})):
        result = check_log(_cloud(tmp_path / "b.mcap", changed, pad_type), golden)
        assert names <= {d.what.split(" ")[0] for d in result.differences}
    same = check_log(tmp_path / "a.mcap", golden)
    assert same.passed
    assert bool(same.notes) == (pad_type == 0)
    message = load_golden(golden)["channels"]["/cloud"]["messages"][0]
    assert message["arrays"]["points.desc"]["shape"] == [500, 4]


def _poses(path: Path, count: int, scale: float) -> Path:
    poses = [
        {
            "position": {"x": i * scale, "y": 0.0, "z": 0.0},
            "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
        }
        for i in range(count)
    ]
    message = {"header": _header(frame="map"), "poses": poses}
    return _write(path, [("/path", "geometry_msgs/msg/PoseArray", message, 10**9)])


@pytest.mark.parametrize("arrays", [False, True])
def test_a_sequence_of_more_than_64_messages_is_guarded(tmp_path: Path, arrays: bool) -> None:
    """F13: 100 poses moved 50x failed to fail: each field is an array over the items."""
    golden = tmp_path / "p.golden.json"
    save_golden(_poses(tmp_path / "a.mcap", 100, 1.0), golden, arrays=arrays)
    moved = check_log(_poses(tmp_path / "b.mcap", 100, -50.0), golden)
    assert {d.what.split(" ")[0] for d in moved.differences} == {"poses[*].position.x"}
    assert check_log(tmp_path / "a.mcap", golden).passed
    message = load_golden(golden)["channels"]["/path"]["messages"][0]
    assert message["values"]["poses.length"] == 100
    assert message["arrays"]["poses[*].orientation.w"]["shape"] == [100]


def test_a_long_sequence_of_strings_and_integers_is_fingerprinted() -> None:
    """F13: strings and integers of a long sequence are compared exactly, by a digest."""
    first, second = MessageContent(), MessageContent()
    _walk([str(i) for i in range(100)], "names", first, frozenset())
    _walk([str(i) for i in range(99)] + ["x"], "names", second, frozenset())
    assert first.values["names.length"] == 100
    assert first.values["names[*]"] != second.values["names[*]"]


def test_format_2_files_still_check_and_say_what_they_leave_out(tmp_path: Path) -> None:
    """Old golden files check as they were written (the repo's own are of format 2)."""
    log = _poses(tmp_path / "a.mcap", 100, 1.0)
    golden = tmp_path / "p.golden.json"
    save_golden(log, golden, format_version=2)
    assert load_golden(golden)["format"] == "pcainterp-golden/2"
    moved = check_log(_poses(tmp_path / "b.mcap", 100, -50.0), golden)
    assert moved.passed  # format 2 recorded the count only: as it always did
    assert any("format 2 records these 100 items" in note for note in moved.notes)
    assert any("--update" in note for note in moved.notes)
    upgraded = check_log(log, golden, update=True)  # rewritten in format 3
    assert upgraded.updated
    assert load_golden(golden)["format"] == "pcainterp-golden/3"
    assert not check_log(tmp_path / "b.mcap", golden).passed
    synth = check_log(DATA / "golden_synth.mcap", DATA / "golden_synth.json")
    assert synth.passed


def _depth_log(path: Path, values: list[float], log_times: list[int]) -> Path:
    messages = []
    for i, (value, log_time) in enumerate(zip(values, log_times, strict=True)):
        array = np.full((4, 4), value, np.float32)
        image = _image(array, "32FC1")
        image["header"] = _header(10**9 + i * 10**8)
        messages.append(("/depth", rosmsg.IMAGE, image, log_time))
        messages.append(("/other", rosmsg.IMAGE, dict(image), log_time))
    return _write(path, messages)


def test_update_with_topics_rewrites_only_those_channels(tmp_path: Path) -> None:
    """F3: --topics /depth --update accepted the unseen differences of /other too."""
    times = [10**9, 11 * 10**8]
    golden = tmp_path / "g.golden.json"
    save_golden(_depth_log(tmp_path / "a.mcap", [1.0, 2.0], times), golden, arrays=True)
    changed = _depth_log(tmp_path / "b.mcap", [5.0, 6.0], times)
    assert main(["golden", "check", str(changed), str(golden), "--topics", "/depth"]) == 1
    args = ["golden", "check", str(changed), str(golden), "--topics", "/depth", "--update"]
    assert main(args) == 0
    assert check_log(changed, golden, topics="/depth").passed
    still = check_log(changed, golden)
    assert {d.topic for d in still.differences} == {"/other"}  # /other kept its golden
    assert check_log(tmp_path / "a.mcap", golden, topics="/other").passed  # arrays kept


def test_log_times_have_a_tolerance_and_exact_differences_are_not_called_tolerance(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """F9: a log recorded live (log time = receive time) could never pass twice."""
    golden = tmp_path / "g.golden.json"
    save_golden(_depth_log(tmp_path / "a.mcap", [1.0, 2.0], [10**9, 11 * 10**8]), golden)
    later = _depth_log(tmp_path / "b.mcap", [1.0, 2.0], [10**9 + 500_000, 11 * 10**8 - 10**6])
    capsys.readouterr()
    assert main(["golden", "check", str(later), str(golden)]) == 1
    out = capsys.readouterr().out
    assert "in 4 places compared exactly" in out
    assert "beyond tolerance" not in out
    document = json.loads(golden.read_text())
    document["tolerance"]["log_time"] = {"abs_ns": 2_000_000}
    golden.write_text(json.dumps(document))
    assert check_log(later, golden).passed
    document["tolerance"]["log_time"] = {"abs_ns": 600_000}
    golden.write_text(json.dumps(document))
    moved = check_log(later, golden).differences
    assert [d.what for d in moved] == ["log_time_ns", "log_time_ns"]  # /depth and /other #1
    assert "tolerance 600000 ns" in moved[0].text


def test_swapped_arguments_name_the_fix(tmp_path: Path) -> None:
    """F8: a log or the .golden.npz given as GOLDEN: say what it is and what to pass."""
    log = _depth_log(tmp_path / "a.mcap", [1.0], [10**9])
    golden = tmp_path / "g.golden.json"
    save_golden(log, golden, arrays=True)
    with pytest.raises(GoldenError, match=r"is a log, not a golden file: the arguments are LOG"):
        load_golden(log)
    with pytest.raises(GoldenError, match=r"is the arrays file of the golden file g.golden.json"):
        load_golden(tmp_path / "g.golden.npz")


def test_short_float_lists_of_long_sequence_items_are_arrays() -> None:
    """A covariance per item (36 floats) is an (n, 36) array within tolerance, not a digest."""
    from dataclasses import dataclass

    from pcainterp_stream.golden.summary import array_statistics

    @dataclass
    class Item:
        c: list[float]

    items = [[float(i + j) for j in range(36)] for i in range(80)]
    first = MessageContent()
    _walk([Item(row) for row in items], "poses", first, frozenset())
    assert first.arrays["poses[*].c"].shape == (80, 36)
    assert array_statistics(first.arrays["poses[*].c"])["shape"] == [80, 36]
    assert "poses[*].c" not in first.values
