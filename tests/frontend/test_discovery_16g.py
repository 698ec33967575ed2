"""Discovery on bug hunt 16G's logs: side-by-side stereo beside other images, a split part."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from pcainterp_stream.cli import pairing as cli_pairing
from pcainterp_stream.errors import PcaInterpError, TopicNotFoundError
from pcainterp_stream.frontend.discovery import resolve_pairing
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.records import StereoCamera

CAMERA = StereoCamera(width=160, height=60, fx=100.0, fy=100.0, cx=80.0, cy=30.0, baseline=0.5)
SBS = "/zed/zed_node/stereo/image_rect_color"


def _sbs_log(path: Path) -> Path:
    """A ZED log without its SDK: one side-by-side topic, its depth, the two camera infos."""
    rng = np.random.default_rng(5)
    scene = rng.integers(0, 256, (60, 170), np.uint8)
    frame = np.ascontiguousarray(np.hstack([scene[:, 4:164], scene[:, 8:168]]))  # 320x60
    depth = np.full((60, 160), 3.0, np.float32)
    with open_writer(path, "mcap") as writer:
        writer.add_message(SBS, rosmsg.image_message(frame, 1, "zed"), 1)
        writer.add_message(
            "/zed/zed_node/depth/depth_registered", rosmsg.image_message(depth, 1, "zed"), 1
        )
        for side in ("left", "right"):
            info = rosmsg.camera_info_message(CAMERA, 1, "zed", right=side == "right")
            writer.add_message(f"/zed/zed_node/{side}/camera_info", info, 1)
    return path


def _error(path: Path, config: PairingConfig) -> str:
    with open_log(path) as reader, pytest.raises(TopicNotFoundError) as caught:
        resolve_pairing(reader, config)
    return str(caught.value)


def test_a_side_by_side_topic_beside_other_images_is_told_to_be_split(tmp_path: Path) -> None:
    """Bug hunt 16G F2: the split hint came only when the topic was the log's one image."""
    message = _error(_sbs_log(tmp_path / "zed.mcap"), PairingConfig(discover=True))
    assert message.startswith("no stereo pair found in ")
    assert (
        f"; {SBS} holds two views side by side (320x60 images whose halves show one scene): "
        "pcainterp reads one camera per image topic, so split each image into a left and a "
        "right half on two topics first"
    ) in message
    assert "depth_registered holds" not in message


def test_a_side_by_side_topic_named_as_one_side_is_said_so(tmp_path: Path) -> None:
    """Bug hunt 16G F2: naming it as --left-topic blamed /stereo/right/image_rect, a default
    never named."""
    config = PairingConfig(discover=True, left_topic=SBS, named_sides=("left",))
    message = _error(_sbs_log(tmp_path / "zed.mcap"), config)
    assert message.startswith(
        f"{SBS} (--left-topic) holds two views side by side in each image (320x60, "
    )
    assert "split each image into a left and a right half" in message
    assert "/stereo/right/image_rect" not in message


def _part_log(path: Path) -> Path:
    """The second part of a split recording: the images, the infos latched in the first."""
    image = np.random.default_rng(1).integers(0, 256, (60, 160), np.uint8)
    with open_writer(path, "mcap") as writer:
        for i in range(2):
            for side in ("left", "right"):
                msg = rosmsg.image_message(image, i + 1, side)
                writer.add_message(f"/camera/{side}/image_raw", msg, i + 1)
            depth = rosmsg.image_message(image.astype(np.float32), i + 1, "gt")
            writer.add_message("/ground_truth/depth", depth, i + 1)
    return path


@pytest.mark.parametrize("named", [(), ("left",), ("left", "right")])
def test_a_later_part_of_a_split_recording_is_told_to_be_read_with_the_others(
    tmp_path: Path, named: tuple[str, ...]
) -> None:
    """Bug hunt 16G F6: "pass --left-topic and --right-topic"; doing so failed on
    /stereo/left/camera_info (a default) offering image and depth topics as infos."""
    topics = {f"{side}_topic": f"/camera/{side}/image_raw" for side in named}
    config = PairingConfig(discover=len(named) < 2, named_sides=named, **topics)  # type: ignore[arg-type]
    message = _error(_part_log(tmp_path / "part_1.mcap"), config)
    assert message.startswith("no stereo pair found in ")  # evaluate's hint needs these words
    assert ": it has no camera infos; " in message
    assert "its cameras /camera/left/image_raw and /camera/right/image_raw need them" in message
    assert "densify the parts together as one log (pcainterp densify PART_0 PART_1" in message
    assert "--calibration LEFT.yaml RIGHT.yaml" in message
    assert "--left-info-topic" not in message
    assert "/ground_truth/depth" not in message


def test_one_topic_named_as_both_sides_is_told_how_a_side_by_side_one_is_split() -> None:
    """Bug hunt 16G F2: naming the side-by-side topic on both sides got no word on it."""
    parser = argparse.ArgumentParser()
    cli_pairing.add_topic_options(parser)
    args = parser.parse_args(["--left-topic", SBS, "--right-topic", SBS])
    with pytest.raises(PcaInterpError) as caught:
        cli_pairing.pairing_config(args)
    message = str(caught.value)
    assert "a topic whose images hold both views side by side is split into a left" in message
    assert message.endswith("pass the right camera's topic as --right-topic")
