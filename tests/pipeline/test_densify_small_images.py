"""densify on images too small to measure: what it says, and the fix it names.

Bug hunt 14C F5: on 16x12 random-dot pairs sparse mode wrote every frame NaN with rc 0 and
blamed "blank, dark or textureless images"; a camera switched to 16x12 mid-log made dense
mode advise a --num-disparities below its smallest, 16.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from mcap_copy import McapCopy

from pcainterp_stream import cli
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.records import StereoCamera

LEFT, RIGHT = "/stereo/left/image_rect", "/stereo/right/image_rect"
LEFT_INFO, RIGHT_INFO = "/stereo/left/camera_info", "/stereo/right/camera_info"
DISPARITY = 2
START = 1_700_000_000 * 10**9


def _tiny_log(path: Path, sizes: list[tuple[int, int]]) -> Path:
    """A random-dot log (disparity 2 px, f*b 60 px*m) of one pair per (width, height)."""
    rng = np.random.default_rng(0)
    with open_writer(path, "mcap") as writer:
        for index, (width, height) in enumerate(sizes):
            base = rng.random((height // 2 + 2, (width + DISPARITY) // 2 + 2)).astype(np.float32)
            size = (width + DISPARITY, height)
            big = np.clip(cv2.resize(base, size, interpolation=cv2.INTER_CUBIC) * 255, 0, 255)
            big = big.astype(np.uint8)
            left, right = big[:, :width].copy(), big[:, DISPARITY:].copy()
            camera = StereoCamera(width, height, 300.0, 300.0, width / 2, height / 2, 0.2)
            stamp = START + index * 100_000_000
            writer.add_message(LEFT, rosmsg.image_message(left, stamp, "left"), stamp)
            writer.add_message(RIGHT, rosmsg.image_message(right, stamp, "right"), stamp + 2000)
            info = rosmsg.camera_info_message(camera, stamp, "left")
            writer.add_message(LEFT_INFO, info, stamp + 3000)
            info = rosmsg.camera_info_message(camera, stamp, "right", right=True)
            writer.add_message(RIGHT_INFO, info, stamp + 4000)
    return path


def _run(capsys: pytest.CaptureFixture[str], *args: str | Path) -> tuple[int, str]:
    capsys.readouterr()
    code = cli.main([str(arg) for arg in args])
    captured = capsys.readouterr()
    return code, " ".join((captured.out + captured.err).split())


def test_sparse_mode_names_images_too_small_to_place_a_point(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # was "4 of 4 frames had no measurement (blank, dark or textureless images)": the corners
    # and the lattice keep 8 px from every edge, so 16x12 has no place for one
    log = _tiny_log(tmp_path / "tiny.mcap", [(16, 12)] * 4)
    code, text = _run(capsys, "densify", log, "-o", tmp_path / "out.mcap")
    assert code == 0, text
    assert (
        "4 of 4 frames had no measurement (images of 16x12 px, under the 17x17 px (width x "
        "height) sparse mode needs to place a measurement (its corners and lattice points are "
        "8 px from every edge)): they have no estimate, their depth is NaN"
    ) in text
    assert "textureless" not in text


def test_a_small_first_pair_does_not_refuse_the_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # review 14b R1: a first pair under sparse mode's floor refused the whole log, though
    # every later pair was full size
    log = _tiny_log(tmp_path / "first.mcap", [(16, 12)] + [(96, 72)] * 3)
    code, text = _run(capsys, "densify", log, "-o", tmp_path / "out.mcap")
    assert code == 0, text
    assert "1 of 4 frames had no measurement (images of 16x12 px" in text
    # review 14c R3: evaluate refused the log ("pass a smaller --num-disparities", which it
    # has not): the frame too narrow for any SGBM range has no reference and is left out
    code, text = _run(capsys, "evaluate", tmp_path / "out.mcap", "-o", tmp_path / "report")
    assert code == 0, text
    assert f"3 frames of {tmp_path / 'out.mcap'}, stereo mode" in text
    assert (
        "note: 1 frame left out: their images (16x12 px first) are too narrow for SGBM's "
        "smallest range (16 disparities), so they have no SGBM reference"
    ) in text


def test_dense_mode_names_the_smallest_range_for_a_camera_changed_mid_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # was "images 16 px wide (at the matching resolution) are narrower than the 17 px SGBM
    # needs for 16 disparities; pass a smaller --num-disparities" (16 is the smallest)
    log = _tiny_log(tmp_path / "switch.mcap", [(96, 72)] * 2 + [(16, 12)] * 2)
    out = tmp_path / "out.mcap"
    code, text = _run(capsys, "densify", log, "-o", out, "--measurements", "dense")
    assert code == 2
    assert (
        f"{log}: {LEFT}'s images from frame 2 on are 16 px wide, narrower than the 17 px SGBM "
        "needs for 160 disparities; no disparity range fits images this narrow: the smallest, "
        "16 disparities, needs 17 px"
    ) in text
    assert "smaller --num-disparities" not in text
    assert not out.exists()


@pytest.mark.parametrize(
    ("sizes", "options", "empty"),
    [
        ([(17, 17)] * 3, (), "3 of 3 frames had no measurement (17x17"),
        ([(24, 18)] * 3, ("--measurements", "dense"), "3 of 3 frames had no measurement (24x18"),
    ],
)
def test_frames_of_small_images_without_a_measurement_name_their_size(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    sizes: list[tuple[int, int]],
    options: tuple[str, ...],
    empty: str,
) -> None:
    # random-dot pairs (texture everywhere) that small: their size, not their content, is why
    # (was "(blank, dark or textureless images)" alone)
    log = _tiny_log(tmp_path / "small.mcap", sizes)
    code, text = _run(capsys, "densify", log, "-o", tmp_path / "out.mcap", *options)
    assert code == 0, text
    assert (
        f"{empty} px images: under 32 px a side SGBM's speckle filter and the points' border "
        "leave little to match; or blank, dark or textureless ones): they have no estimate, "
        "their depth is NaN"
    ) in text


def test_dark_frames_are_not_blamed_on_a_later_small_camera(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # review 14c R5: two black 96x72 frames were counted under a later 16x12 camera's size
    log = _tiny_log(tmp_path / "mix.mcap", [(96, 72)] * 4 + [(16, 12)] * 2)
    dark = tmp_path / "dark.mcap"
    seen = 0
    with McapCopy(log, dark) as copy:  # frames 1 and 2 black on both sides
        for topic, channel_id, message in copy.messages():
            data = bytearray(message.data)
            if topic in (LEFT, RIGHT):
                seen += topic == LEFT
                if seen in (2, 3):
                    height, width = 72, 96
                    data[len(data) - height * width :] = bytes(height * width)
            copy.add(channel_id, message.log_time, bytes(data))
    code, text = _run(capsys, "densify", dark, "-o", tmp_path / "out.mcap")
    assert code == 0, text
    assert "4 of 6 frames had no measurement (2 of them images of 16x12 px" in text
    assert "; the others blank, dark or textureless images)" in text
