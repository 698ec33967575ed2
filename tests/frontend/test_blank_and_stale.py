"""A blank image measures nothing; a stale right image is told from a camera standing still."""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from pcainterp_stream.frontend.frame_checks import StaleRight
from pcainterp_stream.frontend.grey import is_blank
from pcainterp_stream.frontend.stereo import SgbmConfig, StereoFrontEnd
from pcainterp_stream.records import StereoFrame

HEIGHT, WIDTH, SHIFT = 160, 320, 12


def _pair(seed: int) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
    """A textured plane at SHIFT px disparity."""
    rng = np.random.default_rng(seed)
    texture = cv2.GaussianBlur(rng.random((HEIGHT, WIDTH + SHIFT)).astype(np.float32), (0, 0), 1.2)
    texture = (texture - texture.min()) / (texture.max() - texture.min()) * 255
    image = np.round(texture).astype(np.uint8)
    return np.ascontiguousarray(image[:, :WIDTH]), np.ascontiguousarray(image[:, SHIFT:])


@pytest.mark.parametrize("value", [0, 128])
def test_a_uniform_right_image_gives_no_lookup_and_no_map(value: int) -> None:
    # SGBM resolves a uniform right image's ties to 0: every lookup read 0 ("far")
    left, right = _pair(0)
    front_end = StereoFrontEnd(sgbm=SgbmConfig(num_disparities=32))
    assert front_end.measure(left, right).counts.kept > 50
    blank = front_end.measure(left, np.full_like(right, value))
    assert blank.pixels.shape == (0, 2)
    assert blank.disparities.shape == (0,)
    assert blank.disparity_map.shape == (HEIGHT, WIDTH)
    assert np.isnan(blank.disparity_map).all()


def test_blank_is_a_spread_of_two_grey_levels_or_less() -> None:
    left, _ = _pair(1)
    rng = np.random.default_rng(0)
    assert is_blank(np.zeros((40, 60), np.uint8))
    assert is_blank((left // 128).astype(np.uint8))  # two levels
    speckled = np.zeros((400, 600), np.uint8)
    speckled[rng.random(speckled.shape) < 0.002] = 255  # a few hot pixels
    assert is_blank(speckled)
    assert not is_blank((left // 64).astype(np.uint8))  # four levels: still matches
    assert not is_blank(left)


def _frame(index: int, left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8]) -> StereoFrame:
    return StereoFrame(index, index, index, "left", left, right, None)  # type: ignore[arg-type]


def test_a_right_image_repeated_while_the_left_changes_is_blanked() -> None:
    left0, right0 = _pair(2)
    left1, right1 = _pair(3)
    check = StaleRight()
    assert check.check(_frame(0, left0, right0)).right is right0
    assert check.check(_frame(1, left1, right1)).right is right1
    stale = check.check(_frame(2, left0, right1.copy()))  # the right camera stalled
    assert not stale.right.any()
    assert stale.left is left0
    assert not check.check(_frame(3, left1, right1.copy())).right.any()
    assert check.stale == {2, 3}  # still stalled: compared with the image as recorded
    # a camera standing still (both images repeated) and a new right image are not stale
    assert check.check(_frame(4, left1, right1.copy())).right.any()
    assert check.check(_frame(5, left0, right0)).right.any()
    assert check.stale == {2, 3}
    (line,) = check.warnings(6, 2)
    assert line.startswith("2 of 6 frames had a stale right image")
    assert StaleRight().warnings(6, 0) == []


@pytest.mark.parametrize("value", [0, 255])
def test_a_right_camera_blank_for_several_frames_is_blank_not_stale(value: int) -> None:
    # a black (or saturated) right camera repeats nothing: its frames are counted as
    # frames without a measurement only, not as a driver repeating its last image (review 56b R2)
    check = StaleRight()
    for index in range(4):
        left, right = _pair(10 + index)
        if index:
            right = np.full_like(right, value)
        assert check.check(_frame(index, left, right)).right is right
    assert check.stale == set()
    assert check.warnings(4, 0) == []
