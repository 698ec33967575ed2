"""The black border of rectified images used as they are (frontend/rect_border.py)."""

from __future__ import annotations

import dataclasses
from typing import Any

import cv2
import numpy as np
import pytest

from pcainterp_stream.frontend import rect_border
from pcainterp_stream.frontend import rectify as rect
from pcainterp_stream.frontend.pairing import PairingConfig, StereoPairer
from pcainterp_stream.frontend.rect_border import (
    BorderFinder,
    black_border,
    calibration_border,
    frame_border,
)
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.calibration import camera_info_message
from pcainterp_stream.records import DensifiedFrame, StereoCamera
from pcainterp_stream.synth.raw import raw_calibration

CAMERA = StereoCamera(width=320, height=120, fx=180.0, fy=180.0, cx=158.0, cy=60.0, baseline=0.5)
SIZE = (CAMERA.width, CAMERA.height)


def _texture(seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.integers(30, 256, (CAMERA.height // 4 + 1, CAMERA.width // 4 + 1), dtype=np.uint8)
    return cv2.resize(small, SIZE, interpolation=cv2.INTER_LINEAR)  # no undershoot to 0


def _pair(seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    left = _texture(seed)
    shift = np.float32([[1, 0, -12.0], [0, 1, 0]])
    right = cv2.warpAffine(left, shift, SIZE, borderMode=cv2.BORDER_REFLECT)
    return left, right


def _wide(calibration: rect.StereoCalibration, zoom: float = 0.7) -> rect.StereoCalibration:
    """P seeing wider than the raw lenses: rectified keeping every raw pixel (alpha = 1)."""
    sides = []
    for cal in (calibration.left, calibration.right):
        p = cal.p.copy()
        p[0, 0] *= zoom
        p[1, 1] *= zoom
        p[0, 3] *= zoom
        sides.append(dataclasses.replace(cal, p=p))
    return rect.StereoCalibration(*sides)


def _ideal() -> rect.StereoCalibration:
    """Camera infos that say the images are rectified (D = 0, R = I, K = P)."""
    return rect.StereoCalibration(
        *(
            rect.CameraCalibration(
                CAMERA.width, CAMERA.height, "plumb_bob", p[:, :3], np.zeros(5), np.eye(3), p
            )
            for p in (CAMERA.projection_left(), CAMERA.projection_right())
        )
    )


def _bordered(calibration: rect.StereoCalibration, seed: int = 1) -> tuple[np.ndarray, ...]:
    """image_rect of the calibration: raw images (textured all over), rectified with it."""
    left, right = rect.StereoRectifier(calibration).rectify(*_pair(seed))
    return np.asarray(left), np.asarray(right)


def test_calibration_border_is_the_raw_paths_box() -> None:
    wide = _wide(raw_calibration(CAMERA, "plumb_bob"))
    bad = calibration_border(wide, SIZE)
    assert bad is not None
    assert 0.15 < bad.mean() < 0.6
    assert rect.box_without(bad) == rect.StereoRectifier(wide).box
    left, right = _bordered(wide)
    black = (left == 0) | (right == 0)
    assert black[bad].mean() > 0.8  # the border is black (but for the blends at its edge)
    assert not black[~bad].any()


def test_calibration_without_border_or_for_other_images_says_so() -> None:
    calibration = raw_calibration(CAMERA, "plumb_bob")  # the raw lenses see the whole view
    bad = calibration_border(calibration, SIZE)
    assert bad is not None
    assert not bad.any()
    assert calibration_border(_ideal(), SIZE) is None  # says nothing: the images tell
    assert calibration_border(_wide(calibration), (160, 60)) is None  # another size


def test_black_border_is_connected_to_the_edge() -> None:
    image = _texture()
    image[:, :20] = 0  # a border
    image[50:70, 150:180] = 0  # a black object inside the image
    found = black_border(image)
    assert found[:, :20].all()
    assert found.sum() == 20 * CAMERA.height
    colour = np.repeat(image[:, :, None], 3, axis=2)
    colour[0, 30, 1] = 0  # black in one channel only: not black
    np.testing.assert_array_equal(black_border(colour), found)


def _finder_frames(finder: BorderFinder, pairs: list[tuple[np.ndarray, np.ndarray]]) -> Any:
    border = None
    for left, right in pairs:
        border = finder.find(left, right, CAMERA, None)
    return border


def test_border_from_images_lasts_across_frames_and_dark_content_does_not() -> None:
    said: list[str] = []
    finder = BorderFinder(said.append)
    first = [image.copy() for image in _pair()]
    for image in first:
        image[:, :24] = 0  # the border, in every frame
        image[:40, 24:100] = 0  # a black object at the top edge, in the first frame only
    border = _finder_frames(finder, [(first[0], first[1])])
    assert border is not None
    assert border.box[1] >= 40 or border.box[0] >= 100
    later = [image.copy() for image in _pair(seed=2)]
    for image in later:
        image[:, :24] = 0
    border = _finder_frames(finder, [(later[0], later[1])])
    assert border.box == (25, 0, CAMERA.width - 25, CAMERA.height)  # widened a pixel
    assert border.inner.cx == CAMERA.cx - 25
    assert len(said) == 2  # the black object was 7.9 % of the frame: a new box, said
    assert said[-1].startswith("rectified border: 7.5 % of the 320x120 frame")
    assert "black (0) at the image edge in every frame so far" in said[-1]
    dark = np.zeros_like(later[0])
    assert _finder_frames(finder, [(dark, dark)]) == border  # a dark frame tells nothing
    narrower = [image.copy() for image in _pair(seed=3)]
    for image in narrower:
        image[:, :23] = 0  # one column less is black: the box kept holds no border still
    assert _finder_frames(finder, [(narrower[0], narrower[1])]) == border
    assert len(said) == 2


def test_a_border_a_pixel_narrower_later_keeps_the_camera() -> None:
    # alpha = 1 image_rect with infos that say rectified: column 30 black in frame 0 only
    pairer, said = _rect_pairer()
    frames = []
    for index, width in enumerate((31, 30, 30, 31, 30, 30)):
        left, right = (image.copy() for image in _pair(seed=index + 1))
        left[:, :width] = 0
        right[:, :width] = 0
        frames += _push(pairer, 1000 * (index + 1), (left, right), _ideal())
    assert len(frames) == 6
    assert {frame.left.shape for frame in frames} == {(CAMERA.height, CAMERA.width - 32)}
    assert len({frame.camera for frame in frames}) == 1  # the fit check sees all 6 frames
    assert len([s for s in said if s.startswith("rectified border:")]) == 1


def test_the_images_are_looked_at_on_the_first_frames_only(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    left, right = _pair()
    left[:, :24] = 0
    right[:, :24] = 0
    dark = (left // 16, right // 16)  # KITTI at a low gain: dark, with zeros at the edge
    monkeypatch.setattr(rect_border, "LOOK_FRAMES", 3, raising=False)
    finder = BorderFinder()
    assert _finder_frames(finder, [dark] * 3) is None
    looked: list[int] = []
    original = rect_border.black_border
    monkeypatch.setattr(
        rect_border, "black_border", lambda image: looked.append(1) or original(image)
    )
    assert finder.find(left, right, CAMERA, None) is None  # no look past LOOK_FRAMES
    assert not looked
    monkeypatch.undo()
    finder = BorderFinder()
    border = _finder_frames(finder, [(left, right)] * rect_border.EVIDENCE_FRAMES)
    assert border is not None
    wider = [image.copy() for image in _pair(seed=2)]  # the box is decided: kept
    assert finder.find(wider[0], wider[1], CAMERA, None) == border


def test_a_dark_frame_is_not_searched_for_black(monkeypatch: pytest.MonkeyPatch) -> None:
    dark = np.zeros((480, 752), np.uint16)
    dark[:, 100:] = 2000  # a 16-bit image of 12-bit data: dark by the 16-bit range
    looked: list[int] = []
    original = rect_border.black_border
    monkeypatch.setattr(
        rect_border, "black_border", lambda image: looked.append(1) or original(image)
    )
    assert frame_border(dark) is None
    assert not looked  # the dark test comes first: ~1 ms a frame, not 20-100 ms


def test_dark_frames_and_black_content_are_no_border() -> None:
    left, _ = _pair()
    bordered = left.copy()
    bordered[:, :24] = 0
    found = frame_border(bordered)
    assert found is not None
    assert found[:, :24].all()
    dark = (bordered.astype(np.float32) * 0.02).astype(np.uint8)  # black wherever < 50
    assert frame_border(dark) is None
    fading = left.copy()  # a black object at the edge that fades out through near-black
    ramp = np.clip(np.arange(60, dtype=np.float32)[None, :] - 30, 0, None) / 6
    fading[:, :60] = ramp.astype(np.uint8)
    assert frame_border(fading) is None
    assert BorderFinder().find(fading, fading, CAMERA, None) is None


def test_no_border_from_a_few_black_pixels() -> None:
    left, right = _pair()
    left[0, :5] = 0
    assert BorderFinder().find(left, right, CAMERA, None) is None
    assert BorderFinder().find(*_pair(), CAMERA, None) is None


def _rect_pairer(rectify: str = "auto") -> tuple[StereoPairer, list[str]]:
    config = PairingConfig(
        left_topic="/cam/left/image_rect",
        right_topic="/cam/right/image_rect",
        left_info_topic="/cam/left/camera_info",
        right_info_topic="/cam/right/camera_info",
        rectify=rectify,
        check_rows=False,
    )
    said: list[str] = []
    return StereoPairer(config, echo=said.append), said


def _push(
    pairer: StereoPairer,
    stamp: int,
    images: tuple[np.ndarray, ...],
    calibration: rect.StereoCalibration,
) -> list[Any]:
    frames = []
    for side, cal in (("left", calibration.left), ("right", calibration.right)):
        info = camera_info_message(cal, stamp, side)
        frames += pairer.push(f"/cam/{side}/camera_info", stamp, stamp, info)
    for side, image in zip(("left", "right"), images, strict=True):
        message = rosmsg.image_message(image, stamp, side, encoding="mono8")
        frames += pairer.push(f"/cam/{side}/image_rect", stamp, stamp, message)
    return frames


def _result(frame: Any) -> DensifiedFrame:
    shape = frame.left.shape
    ones = np.ones(shape, np.float32)
    return DensifiedFrame(
        frame=frame,
        pixels=np.zeros((0, 2), np.float32),
        disparities=np.zeros(0, np.float32),
        disparity=ones,
        disparity_std=ones,
        depth=ones,
        depth_std=ones,
        measurement_source="stereo",
        counts={},
    )


def test_image_rect_with_the_raw_calibration_is_estimated_inside_its_border() -> None:
    wide = _wide(raw_calibration(CAMERA, "plumb_bob"))
    images = _bordered(wide)
    pairer, said = _rect_pairer()
    frames = _push(pairer, 1000, images, wide) + _push(pairer, 2000, images, wide)
    assert len(frames) == 2
    x, y, w, h = rect.StereoRectifier(wide).box
    assert frames[0].left.shape == (h, w)
    assert frames[0].camera.cx == pytest.approx(CAMERA.cx - x)
    np.testing.assert_array_equal(frames[0].right, images[1][y : y + h, x : x + w])
    (line,) = [s for s in said if s.startswith("rectified border:")]  # once per calibration
    assert "raw calibration of the camera infos" in line
    full = pairer.full_result(_result(frames[0]))
    assert full.depth.shape == images[0].shape
    assert np.isfinite(full.depth).sum() == w * h
    assert not np.isfinite(full.disparity_std[images[0] == 0]).any()
    assert full.frame.camera.cx == CAMERA.cx


def test_rectify_never_uses_the_bordered_images_whole() -> None:
    wide = _wide(raw_calibration(CAMERA, "plumb_bob"))
    images = _bordered(wide)
    pairer, said = _rect_pairer("never")
    (frame,) = _push(pairer, 1000, images, wide)
    assert frame.left.shape == images[0].shape
    assert not [s for s in said if s.startswith("rectified border:")]


def test_rectified_infos_leave_the_border_to_the_images() -> None:
    left, right = (image.copy() for image in _pair())
    left[:, :30] = 0
    right[:, :30] = 0
    pairer, said = _rect_pairer()
    (frame,) = _push(pairer, 1000, (left, right), _ideal())
    assert frame.left.shape == (CAMERA.height, CAMERA.width - 31)
    assert any("black (0) at the image edge" in s for s in said)
