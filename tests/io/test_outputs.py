"""Output topics (``io/outputs.py``): their names and the channels written."""

from __future__ import annotations

import pytest

from pcainterp_stream.io.outputs import OutputTopics, topic_prefix


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
