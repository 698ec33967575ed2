"""Output topics (``io/outputs.py``): their names and the channels written."""

from __future__ import annotations

import pytest

from pcainterp_stream.io.outputs import (
    OutputTopics,
    densified_prefixes,
    missing_outputs,
    topic_prefix,
)


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
