"""A compact log whose camera changes mid-log: each frame's depth reads with its own f*b.

A compact log stores depth, which evaluate turns back into disparity with f*b; the channel
metadata holds the first camera's, so densify records every camera's in the metadata record
``pcainterp.cameras`` (bug hunt 12C F1: the second camera was scored with the first's f*b,
sgbm 1.147 px against the full-precision twin's 0.549).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from pcainterp_stream.evaluate.metrics import Mode, compare_with_ground_truth
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
from pcainterp_stream.golden import check_log, load_golden, save_golden
from pcainterp_stream.golden.summary import summarize_log
from pcainterp_stream.io import depth_codec, rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.output_cameras import CAMERAS_RECORD, FrameCameras, recorded_cameras_of
from pcainterp_stream.io.outputs import (
    FOCAL_BASELINE_KEY,
    FOCAL_BASELINE_SCOPE_KEY,
    OutputTopics,
    _records,
)
from pcainterp_stream.pipeline.densify import densify
from pcainterp_stream.records import SynthFrame
from pcainterp_stream.synth import SynthConfig, generate
from pcainterp_stream.synth.log import write_synthetic_log

FRAMES = 3  # per camera
DEPTH = "/pcainterp/depth"
STD = "/pcainterp/disparity_std"


def _two_cameras() -> Iterator[SynthFrame]:
    """A 620x188 camera, then a 310x94 one (half the f*b), as one log stamped from 1 s."""
    index, stamp = 0, 1_000_000_000
    for scale in (0.5, 0.25):
        for frame in generate(SynthConfig(seed=1, frames=FRAMES, scale=scale)):
            yield frame._replace(index=index, stamp_ns=stamp)
            index, stamp = index + 1, stamp + 100_000_000


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("camera_change")
    log = folder / "two.mcap"
    write_synthetic_log(_two_cameras(), log)
    out = {"log": log}
    for precision in ("compact", "full"):
        out[precision] = folder / f"two_{precision}.mcap"
        topics = OutputTopics.with_prefix("/pcainterp", precision=precision)
        densify(log, out[precision], topics=topics)
    return out


def test_a_two_camera_compact_log_evaluates_as_its_full_twin(logs: dict[str, Path]) -> None:
    options = EvaluateOptions(mode=Mode.STEREO, sweep_every=0, linear=False)
    full, _ = evaluate_log(logs["full"], options)
    compact, _ = evaluate_log(logs["compact"], options)
    assert compact.frames == full.frames == 2 * FRAMES
    for name, stats in full.methods.items():
        assert compact.methods[name].pixels == stats.pixels, name
        # the compact depth is quantised to <= 1/64 of the posterior std: not bit-equal
        assert compact.methods[name].delta_2d_sum == pytest.approx(stats.delta_2d_sum, rel=2e-3), (
            name
        )


def test_the_ground_truth_comparison_reads_each_cameras_f_b(logs: dict[str, Path]) -> None:
    full = compare_with_ground_truth(logs["full"])
    compact = compare_with_ground_truth(logs["compact"])
    assert compact.frames == full.frames == 2 * FRAMES
    assert compact.pixels == full.pixels
    for method in full.abs_error_sum:
        assert compact.mean_abs_error(method) == pytest.approx(
            full.mean_abs_error(method), rel=2e-3
        ), method


def test_the_record_lists_each_camera_from_its_first_frame(logs: dict[str, Path]) -> None:
    (record,) = _records(logs["compact"], CAMERAS_RECORD)
    cameras = FrameCameras.of_log(logs["compact"], "/pcainterp").cameras
    assert record["output_prefix"] == "/pcainterp"
    assert [entry.first_frame for entry in cameras] == [0, FRAMES]
    first, second = cameras
    assert second.focal_baseline == pytest.approx(first.focal_baseline / 2, rel=1e-6)
    assert second.first_log_time_ns == 1_000_000_000 + FRAMES * 100_000_000
    with open_log(logs["compact"]) as reader:
        raw = next(iter(reader.messages([DEPTH])))
    # the channels keep the first camera's f*b and say where the others are
    assert float(raw.channel_metadata[FOCAL_BASELINE_KEY]) == first.focal_baseline
    assert CAMERAS_RECORD in raw.channel_metadata[FOCAL_BASELINE_SCOPE_KEY]
    # another prefix's outputs are not these
    assert len(FrameCameras.of_log(logs["compact"], "/other")) == 0


def test_info_lists_each_camera_of_a_two_camera_log(logs: dict[str, Path]) -> None:
    from pcainterp_stream.pipeline.jobs import info

    first, second = FrameCameras.of_log(logs["compact"], "/pcainterp").cameras
    lines = info(logs["compact"]).splitlines()
    at = lines.index(
        "  cameras (2, a new one when the camera or the min disparity changed; compact depth "
        "decodes with each one's f*b and min disparity):"
    )
    stamp = "(stamp 1.000000000 s)"
    assert lines[at + 1] == (
        f"    f*b {first.focal_baseline:.6g} px*m, min disparity {first.min_disparity:.4g} px "
        f"from frame 0 {stamp}"
    )
    assert lines[at + 2].startswith(f"    f*b {second.focal_baseline:.6g} px*m, min disparity ")
    assert f" from frame {FRAMES} " in lines[at + 2]


def test_a_one_camera_log_records_no_cameras(logs: dict[str, Path], tmp_path: Path) -> None:
    single = tmp_path / "one.mcap"
    write_synthetic_log((f for f in _two_cameras() if f.index < FRAMES), tmp_path / "in.mcap")
    densify(tmp_path / "in.mcap", single)
    assert _records(single, CAMERAS_RECORD) == []
    assert FrameCameras.of_log(single).metadata({"a": "b"}, 0) == {"a": "b"}


def test_a_broken_record_is_refused() -> None:
    with pytest.raises(ValueError, match=r"not a pcainterp.cameras metadata record"):
        recorded_cameras_of({"count": "1"})


def test_golden_records_each_cameras_f_b(logs: dict[str, Path]) -> None:
    summary = summarize_log(logs["compact"], topics=[DEPTH])
    channel = summary.channels[DEPTH]
    first, second = FrameCameras.of_log(logs["compact"], "/pcainterp").cameras
    assert channel["focal_baseline"] == first.focal_baseline
    own = [message.get("focal_baseline") for message in channel["messages"]]
    assert own == [None] * FRAMES + [second.focal_baseline] * FRAMES


def _nudged(dense: Path, target: Path, stds: float, record: bool = False) -> Path:
    """Copy a compact log with every depth moved by ``stds`` of its std at its own f*b.

    ``record``: with its cameras record (the copy keeps no metadata record otherwise).
    """
    from mcap_copy import McapCopy

    cameras = FrameCameras.of_log(dense, "/pcainterp")
    disparity_std: dict[int, np.ndarray] = {}
    with open_log(dense) as reader:
        for raw in reader.messages([STD]):
            message = reader.decode(raw)
            disparity_std[raw.log_time_ns] = np.asarray(
                depth_codec.decode(message.format, message.data), dtype=np.float64
            )
    with McapCopy(dense, target) as copy:
        for topic, channel_id, raw in copy.messages():
            data = raw.data
            if topic == DEPTH:
                focal_baseline = float(cameras.metadata({}, raw.log_time)[FOCAL_BASELINE_KEY])
                message = rosmsg.deserialize(data, "sensor_msgs/msg/CompressedImage")
                depth = np.asarray(
                    depth_codec.decode(message.format, message.data), dtype=np.float64
                )
                with np.errstate(invalid="ignore"):
                    std = depth * depth / focal_baseline * disparity_std[raw.log_time]
                    depth = np.where(np.isfinite(std), depth + stds * std, depth)
                quant_a = depth_codec.HEADER.unpack(bytes(message.data[: depth_codec.HEADER.size]))[
                    1
                ]
                encoded = depth_codec.encode_depth(depth, quant_a=quant_a)
                moved = rosmsg.compressed_image_message(
                    encoded.data, encoded.format, rosmsg.stamp_ns(message), message.header.frame_id
                )
                data = rosmsg.serialize(moved)
            copy.add(channel_id, raw.log_time, data)
        for kept in _records(dense, CAMERAS_RECORD) if record else []:
            copy._writer.add_metadata(CAMERAS_RECORD, dict(kept))
    return target


def test_golden_checks_the_second_camera_in_its_own_std(
    logs: dict[str, Path], tmp_path: Path
) -> None:
    first, golden = tmp_path / "first.json", tmp_path / "g.json"
    save_golden(logs["compact"], first, topics=[DEPTH, STD])
    loose = json.loads(json.dumps(load_golden(first)["tolerance"]))
    loose["float"] = {"rel": 1.0, "spread": 1.0, "abs": 1.0}  # statistics: only elements
    save_golden(logs["compact"], golden, topics=[DEPTH, STD], arrays=True, tolerance=loose)
    assert load_golden(golden)["channels"][DEPTH]["focal_baseline"] > 0
    # 0.035 std of each frame's own camera: within 0.05 std; with the first camera's f*b
    # (twice the second's) the second camera's frames moved by 0.07 "std" and failed
    nudged = _nudged(logs["compact"], tmp_path / "nudged.mcap", 0.035)
    result = check_log(nudged, golden, topics=[DEPTH])
    assert result.passed, [d.text for d in result.differences]


def _without_records(dense: Path, target: Path) -> Path:
    """Copy a log's channels and messages, no metadata record (`mcap filter`'s default)."""
    from mcap_copy import McapCopy

    with McapCopy(dense, target) as copy:
        for _, channel_id, raw in copy.messages():
            copy.add(channel_id, raw.log_time, raw.data)
    return target


def test_a_compact_log_that_lost_the_record_reads_each_frames_f_b(
    logs: dict[str, Path], tmp_path: Path
) -> None:
    # review 59a F3: without the record every frame took the first camera's f*b again,
    # silently (nearest 3.94 px against 2.36)
    lost = _without_records(logs["compact"], tmp_path / "lost.mcap")
    assert _records(lost, CAMERAS_RECORD) == []
    options = EvaluateOptions(mode=Mode.STEREO, sweep_every=0, linear=False)
    kept, _ = evaluate_log(logs["compact"], options)
    result, _ = evaluate_log(lost, options)
    assert result.frames == kept.frames == 2 * FRAMES
    for name, stats in kept.methods.items():
        assert result.methods[name].pixels == stats.pixels, name
        assert result.methods[name].delta_2d_sum == pytest.approx(stats.delta_2d_sum, rel=1e-6)
    (note,) = [note for note in result.notes if CAMERAS_RECORD in note]
    assert note.startswith(f"{FRAMES} frames were decoded with the f*b their features state")
    assert not [note for note in kept.notes if CAMERAS_RECORD in note]
    truth, truth_kept = compare_with_ground_truth(lost), compare_with_ground_truth(logs["compact"])
    for method in truth_kept.abs_error_sum:
        assert truth.mean_abs_error(method) == pytest.approx(
            truth_kept.mean_abs_error(method), rel=1e-6
        ), method


def _golden_files(logs: dict[str, Path], tmp_path: Path) -> tuple[Path, Path]:
    """Save golden files of the compact log (arrays; statistics loose): as saved now, and as
    saved before messages recorded their own f*b (none of them does)."""
    first, golden, old = tmp_path / "first.json", tmp_path / "g.json", tmp_path / "old" / "g.json"
    save_golden(logs["compact"], first, topics=[DEPTH, STD])
    loose = json.loads(json.dumps(load_golden(first)["tolerance"]))
    loose["float"] = {"rel": 1.0, "spread": 1.0, "abs": 1.0}
    save_golden(logs["compact"], golden, topics=[DEPTH, STD], arrays=True, tolerance=loose)
    content = json.loads(golden.read_text())
    messages = content["channels"][DEPTH]["messages"]
    assert sum("focal_baseline" in message for message in messages) == FRAMES
    for message in messages:
        message.pop("focal_baseline", None)
    old.parent.mkdir()
    old.write_text(json.dumps(content))
    for array in tmp_path.glob("g.*"):  # the arrays beside it
        if array.name != golden.name:
            (old.parent / array.name).write_bytes(array.read_bytes())
    return golden, old


def test_an_older_golden_file_takes_each_messages_f_b_from_the_log(
    logs: dict[str, Path], tmp_path: Path
) -> None:
    # review 59a F4: a golden file saved before the fix checked the second camera in the
    # first camera's std although the log under test records its own: 0.035 std failed
    _, old = _golden_files(logs, tmp_path)
    nudged = _nudged(logs["compact"], tmp_path / "nudged.mcap", 0.035, record=True)
    result = check_log(nudged, old, topics=[DEPTH])
    assert result.passed, [d.text for d in result.differences]


def test_a_difference_names_the_f_b_its_std_used(logs: dict[str, Path], tmp_path: Path) -> None:
    # review 59a F5: a second camera's frame named the first camera's f*b (193.085)
    golden, _ = _golden_files(logs, tmp_path)
    nudged = _nudged(logs["compact"], tmp_path / "nudged.mcap", 0.07, record=True)
    result = check_log(nudged, golden, topics=[DEPTH])
    first, second = FrameCameras.of_log(logs["compact"], "/pcainterp").cameras
    texts = [d.text for d in result.differences if "elements" in d.text or "std" in d.text]
    assert not result.passed
    assert [t for t in texts if f"f*b {second.focal_baseline:g})" in t], texts
    assert [t for t in texts if f"f*b {first.focal_baseline:g})" in t], texts
