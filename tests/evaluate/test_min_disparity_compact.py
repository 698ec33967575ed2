"""A compact log whose smallest resolvable disparity changes mid-log, at one camera.

The min disparity is the noise std of the basis in force (``DensifyResult.min_disparity``),
so it changes when the basis does. A full log carries it per frame (the ``DisparityImage``);
a compact log kept the first frame's per camera only (bug hunt 14B F2: a room that adapts,
0.247 px, then the street, 0.025 px: evaluate's "too far" figures of the compact log used
0.247 px on the street frames, 1.20 % of the pixels too far against the full log's 0.67 %).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from pcainterp_stream.evaluate.metrics import Mode
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.output_cameras import CamerasInForce, FrameCameras
from pcainterp_stream.io.outputs import MIN_DISPARITY_KEY, OutputTopics
from pcainterp_stream.pipeline.densify import densify
from pcainterp_stream.records import DensifiedFrame, StereoCamera, StereoFrame, SynthFrame
from pcainterp_stream.synth import SynthConfig, generate
from pcainterp_stream.synth.log import write_synthetic_log


def _room_then_street() -> Iterator[SynthFrame]:
    """12 room frames (the log's own basis is adopted), then 12 street ones: one camera."""
    index, stamp = 0, 1_000_000_000
    for config in (
        SynthConfig(seed=3, frames=12, scale=0.25, scene="indoor"),
        SynthConfig(seed=7, frames=12, scale=0.25),
    ):
        for frame in generate(config):
            yield frame._replace(index=index, stamp_ns=stamp)
            index, stamp = index + 1, stamp + 100_000_000


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("min_disparity")
    log = folder / "scene.mcap"
    write_synthetic_log(_room_then_street(), log)
    out = {}
    for precision in ("compact", "full"):
        out[precision] = folder / f"scene_{precision}.mcap"
        topics = OutputTopics.with_prefix("/pcainterp", precision=precision)
        densify(log, out[precision], topics=topics)
    return out


def test_each_compact_frame_reads_the_min_disparity_the_full_log_carries(
    logs: dict[str, Path],
) -> None:
    with open_log(logs["full"]) as reader:
        full = [
            float(reader.decode(raw).min_disparity)
            for raw in reader.messages(["/pcainterp/disparity"])
        ]
    assert len(set(full)) == 2  # the log's own basis, then the street basis (0.025 px)
    cameras = FrameCameras.of_log(logs["compact"], "/pcainterp")
    assert len({entry.focal_baseline for entry in cameras.cameras}) == 1  # one camera
    with open_log(logs["compact"]) as reader:
        compact = [
            float(cameras.metadata(raw.channel_metadata, raw.log_time_ns)[MIN_DISPARITY_KEY])
            for raw in reader.messages(["/pcainterp/depth"])
        ]
    assert compact == pytest.approx(full, rel=1e-6)  # float32 in the DisparityImage


def test_the_too_far_figures_of_a_compact_log_are_its_full_twins(logs: dict[str, Path]) -> None:
    options = EvaluateOptions(mode=Mode.STEREO, sweep_every=0, linear=False)
    full, _ = evaluate_log(logs["full"], options)
    compact, _ = evaluate_log(logs["compact"], options)
    assert compact.ranges.counted == full.ranges.counted
    assert compact.ranges.reference_far == full.ranges.reference_far  # 19,799 against 19,673
    # the compact depth is quantised (<= 1/64 std): a few pixels at the threshold move
    assert compact.ranges.estimate_far == pytest.approx(full.ranges.estimate_far, rel=0.02)


def test_info_lists_each_min_disparity(logs: dict[str, Path]) -> None:
    from pcainterp_stream.pipeline.jobs import info

    first, second = FrameCameras.of_log(logs["compact"], "/pcainterp").cameras
    lines = info(logs["compact"]).splitlines()
    at = next(n for n, line in enumerate(lines) if line.startswith("  cameras (2, "))
    assert f"min disparity {first.min_disparity:.4g} px from frame 0 " in lines[at + 1]
    assert f"min disparity {second.min_disparity:.4g} px from frame 16 " in lines[at + 2]


_CAMERAS = {
    name: StereoCamera(width=8, height=6, fx=fx, fy=fx, cx=4.0, cy=3.0, baseline=0.5)
    for name, fx in (("a", 7.0), ("b", 14.0))
}


def _frame(index: int, min_disparity: float, camera: str) -> DensifiedFrame:
    image = np.zeros((6, 8), np.uint8)
    frame = StereoFrame(index, 10 * index, 10 * index, "left", image, image, _CAMERAS[camera])
    maps = np.zeros((6, 8), np.float32)
    points = np.zeros((0, 2), np.float32)
    return DensifiedFrame(
        frame, points, points[:, 0], maps, maps, maps, maps, "stereo", {}, min_disparity
    )


def test_an_entry_per_change_of_camera_or_min_disparity() -> None:
    cameras = CamerasInForce()
    for index, (camera, min_disparity) in enumerate(
        [("a", 0.25), ("a", 0.25), ("a", 0.025), ("b", 0.025), ("b", 0.025), ("a", 0.025)]
    ):
        cameras.see(_frame(index, min_disparity, camera))
    assert [entry.first_frame for entry in cameras.entries] == [0, 2, 3, 5]
    assert [entry.min_disparity for entry in cameras.entries] == [0.25, 0.025, 0.025, 0.025]
    one = CamerasInForce()
    for index in range(3):
        one.see(_frame(index, 0.25, "a"))
    assert one.record() is None  # nothing changed: the channels' values hold


def test_a_frame_without_an_estimate_adds_no_entry_for_its_min_disparity() -> None:
    # --sigma evidence: a black frame's sigma falls back, and so would its min disparity
    cameras = CamerasInForce()
    for index, min_disparity in enumerate([0.25, 1.0, 1.0, 0.25]):
        frame = _frame(index, min_disparity, "a")
        if min_disparity == 1.0:  # no estimate: NaN maps
            nan = np.full_like(frame.disparity, np.nan)
            frame = frame._replace(disparity=nan)
        cameras.see(frame)
    assert [entry.first_frame for entry in cameras.entries] == [0]
    cameras.see(_frame(4, 0.5, "b")._replace(disparity=np.full((6, 8), np.nan, np.float32)))
    assert [entry.first_frame for entry in cameras.entries] == [0, 4]  # a camera change counts


def test_info_never_hides_a_camera_change_behind_min_disparity_entries() -> None:
    from pcainterp_stream.io.output_cameras import CAMERAS_RECORD, CameraInForce, cameras_record
    from pcainterp_stream.pipeline.jobs import _densified_by

    entries = [CameraInForce(96.5, 0.1 + n / 100, n, n, n) for n in range(15)]
    entries.append(CameraInForce(40.0, 0.3, 15, 15, 15))
    record = cameras_record(entries, "/pcainterp")
    densify_record = {"output_prefix": "/pcainterp", "basis": "built-in"}
    lines = _densified_by([("pcainterp.densify", densify_record), (CAMERAS_RECORD, record)])
    assert any(
        line.startswith("    f*b 40 px*m, min disparity 0.3 px from frame 15") for line in lines
    )
    assert lines[-1] == "    ... 3 more min disparity changes to frame 14 (0.22-0.24 px)"
