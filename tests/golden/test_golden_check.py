"""Golden files of a densified log: a re-run passes, every real change fails and is named."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import Writer

from pcainterp_stream.cli import main
from pcainterp_stream.errors import GoldenError
from pcainterp_stream.golden import (
    arrays_path,
    check_log,
    format_differences,
    load_golden,
    save_golden,
)
from pcainterp_stream.io import depth_codec, rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.outputs import FOCAL_BASELINE_KEY
from pcainterp_stream.records import RawMessage

ROOT = Path(__file__).resolve().parents[2]
OTHER_BASIS = ROOT / "tests" / "data" / "golden_basis.npz"


def _run(*args: str | Path) -> int:
    return main([str(a) for a in args])


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A 4-frame synthetic drive at scale 0.25, densified with the defaults, and its golden."""
    folder = tmp_path_factory.mktemp("golden")
    log, dense = folder / "drive.mcap", folder / "dense.mcap"
    assert _run("synth", log, "--frames", 4, "--scale", 0.25, "--seed", 0) == 0
    assert _run("densify", log, "-o", dense) == 0
    golden = folder / "dense.golden.json"
    assert _run("golden", "save", dense, "-o", golden, "--arrays") == 0
    return {"folder": folder, "log": log, "dense": dense, "golden": golden}


def _copy(source: Path, target: Path, change: Callable[[RawMessage], RawMessage | None]) -> Path:
    """Copy a log message by message through ``change`` (None drops the message)."""
    with open_log(source) as reader, target.open("wb") as stream:
        writer = Writer(stream)
        writer.start(profile="ros2", library="test")
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for raw in reader.messages():
            changed = change(raw)
            if changed is None:
                continue
            if changed.schema_name not in schemas:
                schemas[changed.schema_name] = writer.register_schema(
                    changed.schema_name, changed.schema_encoding, changed.schema_data
                )
            if changed.topic not in channels:
                channels[changed.topic] = writer.register_channel(
                    changed.topic,
                    changed.message_encoding,
                    schemas[changed.schema_name],
                    dict(changed.channel_metadata),
                )
            writer.add_message(
                channels[changed.topic], changed.log_time_ns, changed.data, changed.publish_time_ns
            )
        writer.finish()
    return target


def test_a_rerun_passes_and_the_cli_says_so(
    drive: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    again = tmp_path / "again.mcap"
    assert _run("densify", drive["log"], "-o", again) == 0
    capsys.readouterr()
    assert _run("golden", "check", again, drive["golden"]) == 0
    assert "matches" in capsys.readouterr().out
    document = load_golden(drive["golden"])
    assert document["tolerance"]["pixels"]["std_atol"] > 0  # tolerances are in the file
    assert (drive["golden"].with_suffix(".npz")).is_file()
    depth = document["channels"]["/pcainterp/depth"]
    assert depth["message_count"] == 4
    assert {"log_time_ns", "stamp_ns", "values", "arrays", "array_keys"} <= set(
        depth["messages"][0]
    )
    assert set(depth["messages"][0]["arrays"]["image"]) >= {"median", "mad", "quantiles", "nan"}


def test_off_a_terminal_the_cli_prints_the_plain_progress_lines(
    drive: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # golden had a bar of its own, silent off a terminal; the other jobs print a plain line
    # a minute there (a CI step that prints nothing for 10 minutes is ended): now it does too
    from pcainterp_stream.pipeline import common

    monkeypatch.setattr(common, "PLAIN_PROGRESS_EVERY_S", 0.0)  # a line per message
    with open_log(drive["dense"]) as reader:
        count = sum(1 for _ in reader.messages())
    for args, said in [
        (["check", drive["dense"], drive["golden"]], "checking dense.mcap"),
        (["save", drive["dense"], "-o", tmp_path / "again.json"], "summarising dense.mcap"),
    ]:
        capsys.readouterr()
        assert _run("golden", *args) == 0
        lines = capsys.readouterr().err.splitlines()
        assert len(lines) == count
        assert lines[-1].startswith(f"{said}: {count}/{count} messages, ")


def test_fewer_corners_fail_naming_the_depth(
    drive: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fewer = tmp_path / "fewer.mcap"
    assert _run("densify", drive["log"], "-o", fewer, "--corners", 15) == 0
    capsys.readouterr()
    assert _run("golden", "check", fewer, drive["golden"], "--max-lines", 5) == 1
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 7  # five differences, the count of the rest, the verdict
    assert lines[0].startswith("/pcainterp/depth #0 (stamp ")
    assert "tolerance" in lines[0]
    assert lines[5].startswith("... and ")
    assert "differs from dense.golden.json" in lines[6]

    result = check_log(fewer, drive["golden"], topics=["/pcainterp/features"])
    assert result.differences
    assert {d.topic for d in result.differences} == {"/pcainterp/features"}


def test_another_basis_fails(drive: dict[str, Path], tmp_path: Path) -> None:
    other = tmp_path / "other.mcap"
    assert _run("densify", drive["log"], "-o", other, "--basis", OTHER_BASIS) == 0
    differences = check_log(other, drive["golden"]).differences
    topics = {d.topic for d in differences}
    assert "/pcainterp/depth" in topics
    assert not topics & {"/stereo/left/image_rect", "/ground_truth/depth"}


def test_a_dropped_frame_and_a_renamed_channel_fail(drive: dict[str, Path], tmp_path: Path) -> None:
    with open_log(drive["dense"]) as reader:
        times = sorted({raw.log_time_ns for raw in reader.messages(["/pcainterp/depth"])})
    dropped = _copy(
        drive["dense"],
        tmp_path / "dropped.mcap",
        lambda raw: None if raw.log_time_ns == times[2] else raw,
    )
    differences = check_log(dropped, drive["golden"]).differences
    text = format_differences(differences, None)
    assert "/pcainterp/depth: message_count 3, golden 4" in text
    assert "/pcainterp/depth #2 (stamp " in text
    assert "message missing from the log" in text
    assert "#3" not in text  # later frames are matched by stamp, not shifted

    renamed = _copy(
        drive["dense"],
        tmp_path / "renamed.mcap",
        lambda raw: (
            raw._replace(topic="/pcainterp/range") if raw.topic == "/pcainterp/depth" else raw
        ),
    )
    text = format_differences(check_log(renamed, drive["golden"]).differences, None)
    assert "/pcainterp/depth: channel missing from the log (golden: 4 messages" in text
    assert "/pcainterp/range: channel not in the golden file" in text


def _moved_depth(dense: Path, target: Path, stds: float, keep_metadata: bool = True) -> Path:
    """Copy a compact densified log with every depth moved by ``stds`` of its posterior std.

    The depth std is the delta method's depth^2 / (f*b) * disparity std; the depth is
    re-encoded with its own depthQuantA, so only the move changes it.
    """
    disparity_std: dict[int, np.ndarray] = {}
    with open_log(dense) as reader:
        for raw in reader.messages(["/pcainterp/disparity_std"]):
            message = reader.decode(raw)
            disparity_std[raw.log_time_ns] = np.asarray(
                depth_codec.decode(message.format, message.data), dtype=np.float64
            )

    def move(raw: RawMessage) -> RawMessage:
        if raw.topic != "/pcainterp/depth":
            return raw if keep_metadata else raw._replace(channel_metadata={})
        focal_baseline = float(raw.channel_metadata[FOCAL_BASELINE_KEY])
        message = rosmsg.deserialize(raw.data, raw.msgtype)
        depth = np.asarray(depth_codec.decode(message.format, message.data), dtype=np.float64)
        with np.errstate(invalid="ignore"):  # +inf depth (too far) keeps its value
            std = depth * depth / focal_baseline * disparity_std[raw.log_time_ns]
            depth = np.where(np.isfinite(std), depth + stds * std, depth)
        quant_a = depth_codec.HEADER.unpack(bytes(message.data[: depth_codec.HEADER.size]))[1]
        encoded = depth_codec.encode_depth(depth, quant_a=quant_a)
        moved = rosmsg.compressed_image_message(
            encoded.data, encoded.format, rosmsg.stamp_ns(message), message.header.frame_id
        )
        metadata = raw.channel_metadata if keep_metadata else {}
        return raw._replace(data=rosmsg.serialize(moved), channel_metadata=metadata)

    return _copy(dense, target, move)


def test_a_compact_depth_is_checked_in_units_of_its_std(
    drive: dict[str, Path], tmp_path: Path
) -> None:
    # the default (compact) log has no depth_std: the depth std comes from the disparity std
    document = load_golden(drive["golden"])
    assert "/pcainterp/depth_std" not in document["channels"]
    assert "/pcainterp/disparity" not in document["channels"]
    focal_baseline = document["channels"]["/pcainterp/depth"]["focal_baseline"]
    assert focal_baseline > 0

    copied = _moved_depth(drive["dense"], tmp_path / "copied.mcap", 0.0)
    assert check_log(copied, drive["golden"]).passed  # the copy itself changes nothing

    moved = _moved_depth(drive["dense"], tmp_path / "moved.mcap", 3.0)
    differences = check_log(moved, drive["golden"], topics=["/pcainterp/depth"]).differences
    elements = [d for d in differences if d.what == "image elements"]
    assert [d.index for d in elements] == [0, 1, 2, 3]
    text = elements[0].text
    assert "beyond 0.05 std (depth^2 / f*b * /pcainterp/disparity_std" in text
    assert f"f*b {focal_baseline:g}" in text
    worst = float(text.rsplit("(", 1)[1].removesuffix(" std)"))
    # the worst moved by at least the three stds applied (more where the inverse-depth
    # code is small and re-rounding it is a larger step in depth)
    assert worst > 2.5


def test_a_compact_depth_within_its_std_passes_elementwise(
    drive: dict[str, Path], tmp_path: Path
) -> None:
    # a move far below the tolerance of 0.05 std, but above atol/rtol's 1e-4 + 1e-3 |z|
    # wherever the std exceeds 0.1 % of the depth
    golden = tmp_path / "g.json"
    loose = json.loads(json.dumps(load_golden(drive["golden"])["tolerance"]))
    loose["float"] = {"rel": 1.0, "spread": 1.0, "abs": 1.0}  # statistics: only elements
    save_golden(
        drive["dense"],
        golden,
        topics=["/pcainterp/depth", "/pcainterp/disparity_std"],
        arrays=True,
        tolerance=loose,
    )
    # a golden file saved before f*b was recorded: f*b is read from the log under test
    document = json.loads(golden.read_text())
    for channel in document["channels"].values():
        del channel["focal_baseline"]
    old = tmp_path / "old.json"
    arrays_path(golden).rename(old.with_suffix(".npz"))  # the name it had then
    document["arrays_file"] = "old.npz"
    old.write_text(json.dumps(document))

    nudged = _moved_depth(drive["dense"], tmp_path / "nudged.mcap", 0.02)
    assert check_log(nudged, old).passed
    moved = _moved_depth(drive["dense"], tmp_path / "moved.mcap", 3.0)
    assert any(d.what == "image elements" for d in check_log(moved, old).differences)
    # neither f*b recorded nor in the log: the element check falls back to atol/rtol
    bare = _moved_depth(drive["dense"], tmp_path / "bare.mcap", 0.02, keep_metadata=False)
    texts = [d.text for d in check_log(bare, old).differences if d.what == "image elements"]
    assert texts
    assert all("beyond atol" in t for t in texts)


def test_update_rewrites_the_golden(drive: dict[str, Path], tmp_path: Path) -> None:
    golden = tmp_path / "g.json"
    save_golden(drive["log"], golden, topics=["/stereo/left/image_rect", "/ground_truth/depth"])
    document = json.loads(golden.read_text())
    document["tolerance"]["float"]["rel"] = 0.01  # an edited tolerance survives --update
    document["channels"]["/ground_truth/depth"]["messages"][1]["arrays"]["image"]["median"] += 1
    golden.write_text(json.dumps(document))
    assert _run("golden", "check", drive["log"], golden) == 1
    assert _run("golden", "check", drive["log"], golden, "--update") == 0
    assert _run("golden", "check", drive["log"], golden) == 0
    rewritten = load_golden(golden)
    assert rewritten["tolerance"]["float"]["rel"] == 0.01
    assert rewritten["topics"] == ["/stereo/left/image_rect", "/ground_truth/depth"]


def test_other_log_formats(drive: dict[str, Path], tmp_path: Path) -> None:
    golden = tmp_path / "synth.golden.json"
    save_golden(drive["log"], golden)
    for fmt in ("ros1", "rosbag2"):
        other = tmp_path / f"drive_{fmt}"
        assert (
            _run("synth", other, "--frames", 4, "--scale", 0.25, "--seed", 0, "--format", fmt) == 0
        )
        written = next(p for p in tmp_path.glob(f"drive_{fmt}*"))
        result = check_log(written, golden)
        assert result.passed, format_differences(result.differences)
        assert check_log(written, golden, topics=["/ground_truth/depth"]).passed


def test_bad_input_is_one_line_and_exit_2(
    drive: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    newer = tmp_path / "newer.json"
    document = json.loads(drive["golden"].read_text())
    document["format"] = "pcainterp-golden/99"
    newer.write_text(json.dumps(document))
    capsys.readouterr()
    assert _run("golden", "check", drive["dense"], newer) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "newer than this pcainterp-stream" in err
    with pytest.raises(GoldenError, match="upgrade pcainterp-stream"):
        check_log(drive["dense"], newer)

    truncated = tmp_path / "truncated.mcap"
    truncated.write_bytes(drive["dense"].read_bytes()[:200_000])
    target = tmp_path / "never.json"
    assert _run("golden", "save", truncated, "-o", target) == 2
    assert "truncated" in capsys.readouterr().err
    assert not target.exists()
    assert list(tmp_path.glob(".never*")) == []
    assert _run("golden", "check", truncated, drive["golden"], "--update") == 2
    capsys.readouterr()

    assert _run("golden", "check", drive["dense"], drive["golden"], "--topics", "/nope") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "topic /nope is not in the golden file" in err
    assert _run("golden", "save", drive["dense"], "-o", target, "--topics", "/nope") == 2
    assert "topic /nope not found in dense.mcap" in capsys.readouterr().err
    assert not target.exists()


@pytest.mark.parametrize("where", ["full disk", "file as folder"])
def test_a_golden_file_that_cannot_be_written_is_one_line(
    drive: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    where: str,
) -> None:
    from pcainterp_stream.golden import store

    target, failing = tmp_path / "g.json", tmp_path / "g.golden.npz"
    if where == "full disk":

        def full(*args: object, **kwargs: object) -> None:
            raise OSError(28, "No space left on device")

        monkeypatch.setattr(store.np, "savez_compressed", full)
    else:
        (tmp_path / "afile").write_text("kept")
        target = failing = tmp_path / "afile" / "g.json"
    capsys.readouterr()
    assert _run("golden", "save", drive["dense"], "-o", target, "--arrays") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert f"cannot write {failing}: " in err
    assert "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == (["afile"] if where != "full disk" else [])


REALDATA = ROOT.parent / "shared" / "realdata"


@pytest.mark.realdata
@pytest.mark.skipif(not REALDATA.is_dir(), reason="../shared/realdata is absent")
def test_logs_written_by_others(tmp_path: Path) -> None:
    """A real ROS 2 recording of every sensor_msgs type, and ROS 1 bags in three codecs."""
    recording = REALDATA / "mcap_ros2" / "supported_ros2_messages.mcap"
    golden = tmp_path / "ros2.golden.json"
    summary = save_golden(recording, golden, arrays=True)
    first = {topic: c["messages"][0] for topic, c in summary.channels.items() if c["messages"]}
    assert set(first["/image"]["arrays"]) == {"image"}
    assert set(first["/compressed_image"]["arrays"]) == {"image"}  # jpeg, by OpenCV
    assert {"points.x", "points.intensity"} <= set(first["/point_cloud2"]["arrays"])
    assert len(first["/camera_info"]["values"]["p"]) == 12
    assert check_log(recording, golden).passed

    golden = tmp_path / "ros1.golden.json"
    save_golden(REALDATA / "ros1" / "example.bag", golden)
    for name in ("example-lz4.bag", "example-bz2.bag"):
        result = check_log(REALDATA / "ros1" / name, golden)
        assert result.passed, format_differences(result.differences)
