"""Output topics (``io/outputs.py``): their names and the channels written."""

from __future__ import annotations

import numpy as np
import pytest

from pcainterp_stream.evaluate.metrics import calibration_sums
from pcainterp_stream.io.outputs import (
    PRECISIONS,
    STD_RELATIVE_ERROR,
    OutputTopics,
    decode_estimate,
    densified_prefixes,
    frame_metadata,
    missing_outputs,
    output_messages,
    topic_prefix,
)
from pcainterp_stream.records import DensifiedFrame, StereoCamera, StereoFrame


@pytest.mark.parametrize(
    ("prefix", "expected"),
    [("/pcainterp", "/pcainterp"), ("pcainterp", "/pcainterp"), ("/p2/run_1", "/p2/run_1")],
)
def test_a_ros2_name_is_a_prefix(prefix: str, expected: str) -> None:
    assert topic_prefix(prefix) == expected
    assert OutputTopics.with_prefix(prefix).depth == f"{expected}/depth"


@pytest.mark.parametrize(
    ("prefix", "problem"),
    [
        ("", "it is empty"),
        ("/", "it has no name under /"),
        ("/a b", "'a b' has characters other than A-Z a-z 0-9 _"),
        ("/a-b", "'a-b' has characters other than"),
        ("//x", "it has an empty name between two /"),
        ("/x//y", "it has an empty name between two /"),
        ("/x/", "it ends with /"),
        ("/x/9", "'9' starts with a digit"),
    ],
)
def test_a_prefix_that_is_no_ros2_name_is_refused(prefix: str, problem: str) -> None:
    # "", "/" and "/a b" wrote //depth, //camera_info ... and /a b/depth
    with pytest.raises(ValueError, match=f"is not a ROS 2 topic name: {problem}"):
        OutputTopics.with_prefix(prefix)


def test_outputs_may_name_the_depth_mm_copy() -> None:
    # --outputs depth_mm was refused though /PREFIX/depth_mm is written by default
    compact = OutputTopics.with_prefix("/p", precision="compact")
    assert compact.depth_mm == "/p/depth_mm"
    alone = compact.only(["depth_mm"])
    assert alone.all() == ["/p/depth_mm"]
    assert compact.only(["depth"]).all() == ["/p/depth", "/p/depth_mm"]  # as before
    assert compact.only(["features"]).all() == ["/p/features"]  # as before
    full = OutputTopics.with_prefix("/p")
    assert full.depth_mm is None
    assert full.only(["depth", "depth_mm"]).all() == ["/p/depth", "/p/depth_mm"]
    assert full.only(["depth"]).all() == ["/p/depth"]
    with pytest.raises(ValueError, match=r"choose from depth, .*, camera_info, depth_mm"):
        full.only(["depth_m"])


def test_missing_outputs_name_both_forms_and_other_prefixes() -> None:
    topics = OutputTopics.with_prefix("/nope")
    wanted = [topics.disparity, topics.disparity_std, topics.camera_info]
    compact = ["/pcainterp/depth", "/pcainterp/disparity_std", "/pcainterp/camera_info"]
    full = ["/p2/disparity", "/p2/disparity_std", "/p2/camera_info", "/cam/left/image_rect"]
    assert densified_prefixes([*compact, *full, "/x/disparity_std"]) == ["/p2", "/pcainterp"]
    missing, hint = missing_outputs([*compact, *full], topics, wanted)
    assert missing == ["/nope/disparity or /nope/depth", "/nope/disparity_std", "/nope/camera_info"]
    assert hint == "; it has densified channels under /p2, /pcainterp: pass --output-prefix /p2"
    assert missing_outputs(full, topics, wanted)[0][0] == "/nope/disparity or /nope/depth"
    assert missing_outputs(["/a"], topics, wanted)[1] == ""  # not densified at all
    own = OutputTopics.with_prefix("/p2")
    assert missing_outputs(full[1:], own, [own.disparity, own.disparity_std]) == (
        ["/p2/disparity or /p2/depth"],
        "",
    )


def _densified(std: np.ndarray) -> DensifiedFrame:
    """A frame whose estimate is 10 px (f*b 3.5 px*m) and whose std is ``std``."""
    height, width = std.shape
    camera = StereoCamera(width=width, height=height, fx=7.0, fy=7.0, cx=4.0, cy=3.0, baseline=0.5)
    image = np.zeros((height, width), np.uint8)
    frame = StereoFrame(0, 1_000, 1_000, "left", image, image, camera)
    disparity = np.full((height, width), 10.0, np.float32)
    depth = np.float32(camera.focal_baseline) / disparity
    pixels = np.array([[1.0, 2.0]], np.float32)
    return DensifiedFrame(
        frame,
        pixels,
        np.array([10.0], np.float32),
        disparity,
        std,
        depth,
        depth,
        "stereo",
        {},
        min_disparity=0.25,
    )


def test_a_std_of_0_reads_as_no_value_in_a_compact_log_and_scores_as_in_a_full_one() -> None:
    """Bug hunt 14B F1: a compact std of 0 read as max std / 1311 px (0.0015 px here), so
    evaluate scored a pixel the full log leaves out of the NLL: 5,370 per pixel, not 1.64."""
    std = np.full((40, 60), 2.0, np.float32)
    std[:, :6] = 0.0  # a basis that never varies there
    result = _densified(std)
    reference = np.full(std.shape, 10.5)  # the estimate is 0.5 px off everywhere
    mask = np.ones(std.shape, bool)
    sums = {}
    for precision in PRECISIONS:
        topics = OutputTopics.with_prefix("/p", precision=precision)
        messages = dict(output_messages(result, topics))
        estimate = messages[topics.disparity if precision == "full" else topics.depth]
        decoded = decode_estimate(
            estimate,
            messages[topics.disparity_std],
            messages[topics.camera_info],
            frame_metadata(result),
        )
        if precision == "compact":
            assert np.isnan(decoded.disparity_std[:, :6]).all()  # docs/bases.md: "no value"
            assert decoded.disparity_std[:, 6:] == pytest.approx(2.0, rel=STD_RELATIVE_ERROR)
        sums[precision] = calibration_sums(
            decoded.disparity, decoded.disparity_std, reference, mask
        )
    full, compact = sums["full"], sums["compact"]
    assert full["certain"] == compact["no_std"] == 240  # left out of the NLL in both
    scored = full["n"] - full["certain"]
    assert compact["n"] == scored
    assert compact["nll"] / scored == pytest.approx(full["nll"] / scored, rel=1e-3)  # 1.64
