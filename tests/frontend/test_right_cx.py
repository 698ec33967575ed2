"""A right rectified P with another cx than the left's (bug hunt 15A F1).

``cv2.stereoRectify`` without ``CALIB_ZERO_DISPARITY`` gives such a pair; ``image_geometry``
reads its disparities as offset by cx_left - cx_right. Before, the offset was ignored on every
path: +3 px gave 30 % median depth error (3.5 % with equal cx), +12 px "left and right look
swapped". Now the right image is brought onto the left's cx.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import cv2
import numpy as np
import pytest

from pcainterp_stream.errors import CalibrationError
from pcainterp_stream.frontend import rectify as rect
from pcainterp_stream.frontend.pairing import PairingConfig, StereoPairer
from pcainterp_stream.frontend.right_cx import shift_image
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.calibration import camera_info_message
from pcainterp_stream.io.raw_log import Unrectifier
from pcainterp_stream.records import StereoCamera
from pcainterp_stream.synth.raw import raw_calibration

CAMERA = StereoCamera(width=320, height=120, fx=180.0, fy=180.0, cx=158.0, cy=60.0, baseline=0.5)


def _views(disparity: float = 12.0) -> tuple[np.ndarray, np.ndarray]:
    """A rectified pair of equal cx: the right view is the left moved by a constant disparity."""
    rng = np.random.default_rng(1)
    small = rng.integers(0, 256, (CAMERA.height // 4 + 1, CAMERA.width // 4 + 1), dtype=np.uint8)
    left = cv2.resize(small, (CAMERA.width, CAMERA.height), interpolation=cv2.INTER_CUBIC)
    m = np.float32([[1, 0, -disparity], [0, 1, 0]])
    right = cv2.warpAffine(left, m, (CAMERA.width, CAMERA.height), borderMode=cv2.BORDER_REFLECT)
    return left, right


def _right_cx(calibration: rect.StereoCalibration, more: float) -> rect.StereoCalibration:
    """The pair with the right P's cx (and K's, when K = P) ``more`` px to the right."""
    right = calibration.right
    p = right.p.copy()
    p[0, 2] += more
    k = right.k.copy()
    if calibration.right.is_rectified:
        k[0, 2] += more
    return rect.StereoCalibration(calibration.left, dataclasses.replace(right, p=p, k=k))


def _ideal() -> rect.StereoCalibration:
    """The rectified pair's own calibration: K = P, D = 0, R = I on both sides."""
    cal = raw_calibration(CAMERA, "plumb_bob")
    return rect.StereoCalibration(
        *(
            rect.CameraCalibration(
                c.width, c.height, "plumb_bob", c.p[:, :3], np.zeros(5), np.eye(3), c.p
            )
            for c in (cal.left, cal.right)
        )
    )


def _inner(image: np.ndarray, margin: int = 16) -> np.ndarray:
    return image[4:-4, margin:-margin].astype(np.float64)


def test_a_rectified_right_camera_with_another_cx_is_remapped_onto_the_lefts() -> None:
    """--rectify always (and calibration files): the remap uses the left's cx for the right."""
    left, right = _views()
    seen = shift_image(right, 3.0)  # what a right camera with cx + 3 takes
    calibration = _right_cx(_ideal(), 3.0)
    rectifier = rect.StereoRectifier(calibration)
    out_left, out_right = rectifier.rectify(left, seen)
    np.testing.assert_array_equal(out_left, left)
    np.testing.assert_array_equal(_inner(out_right), _inner(right))  # before: 3 px off
    assert "right cx 161 -> 158 px" in rectifier.cx_note
    assert rectifier.camera.cx == CAMERA.cx
    x, _, w, _ = rectifier.box
    assert x + w <= CAMERA.width - 3  # the columns no raw right pixel reaches are left out


def test_a_raw_right_camera_with_another_cx_is_remapped_onto_the_lefts() -> None:
    calibration = raw_calibration(CAMERA, "plumb_bob")
    left, right = _views()
    shifted = _right_cx(calibration, 5.0)
    raw_left, raw_right = Unrectifier(calibration)(left, right)
    # the same raw right image, read by a calibration whose rectified right camera has cx + 5
    ref = rect.StereoRectifier(calibration)
    out = rect.StereoRectifier(shifted)
    assert out.cx_note.startswith("; right cx 163 -> 158 px")
    assert ref.cx_note == ""
    _, ref_right = ref.rectify(raw_left, raw_right)
    _, out_right = out.rectify(raw_left, raw_right)
    np.testing.assert_array_equal(out_right, ref_right)  # before: 5 px apart


def _shifted_pair(
    more: float, says: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray, rect.StereoCalibration]:
    """The left and right views, the right view of a camera with cx + ``more``, and its
    calibration (with a raw camera's D != 0 when the topics are ``named`` rectified)."""
    left, right = _views()
    calibration = _right_cx(_ideal(), more)
    if "named" in says:  # image_rect beside the raw camera's info (D != 0)
        calibration = rect.StereoCalibration(
            *(
                dataclasses.replace(c, d=np.full(5, 0.01))
                for c in (calibration.left, calibration.right)
            )
        )
    return left, right, shift_image(right, more), calibration


def _info_pairer(topics: tuple[str, str], **options: Any) -> tuple[StereoPairer, list[str]]:
    said: list[str] = []
    config = PairingConfig(
        left_topic=topics[0],
        right_topic=topics[1],
        left_info_topic="/cam/left/camera_info",
        right_info_topic="/cam/right/camera_info",
        check_rows=False,
        **options,
    )
    return StereoPairer(config, echo=said.append), said


def _push(pairer: StereoPairer, calibration: rect.StereoCalibration, images: Any) -> list[Any]:
    topics = (pairer.config.left_topic, pairer.config.right_topic)
    frames = []
    for topic, cal in (
        ("/cam/left/camera_info", calibration.left),
        ("/cam/right/camera_info", calibration.right),
    ):
        frames += pairer.push(topic, 1000, 1000, camera_info_message(cal, 1000, "c"))
    for topic, image in zip(topics, images, strict=True):
        message = rosmsg.image_message(image, 1000, "c", encoding="mono8")
        frames += pairer.push(topic, 1000, 1000, message)
    return frames


@pytest.mark.parametrize(
    ("topics", "options", "says"),
    [
        (("/cam/left/image_raw", "/cam/right/image_raw"), {}, "say the images are rectified"),
        (("/cam/left/image_rect", "/cam/right/image_rect"), {}, "are named rectified"),
        (("/cam/left/image_raw", "/cam/right/image_raw"), {"rectify": "never"}, "rectify never"),
    ],
)
def test_images_used_as_they_are_are_shifted_onto_the_lefts_cx(
    topics: tuple[str, str], options: dict[str, Any], says: str
) -> None:
    left, right, seen, calibration = _shifted_pair(2.5, says)
    pairer, said = _info_pairer(topics, **options)
    (frame,) = _push(pairer, calibration, (left, seen))
    assert says in said[0]
    assert "right cx 160.5 -> 158 px" in said[0]
    assert said[0].endswith("the right images shifted by -2.5 px")
    # the estimate's box: inside a black border (the columns shifted in, or the raw infos')
    x, y = round(CAMERA.cx - frame.camera.cx), round(CAMERA.cy - frame.camera.cy)
    h, w = frame.left.shape
    box = (slice(y, y + h), slice(x, x + w))
    np.testing.assert_array_equal(frame.left, left[box])
    error = np.abs(_inner(frame.right) - _inner(right[box]))
    assert np.median(error) <= 1.0  # two bicubic half-pixel shifts; before: the 2.5 px off
    assert np.median(np.abs(_inner(seen[box]) - _inner(right[box]))) > 5
    assert np.array_equal(pairer.as_is(seen, "right")[box], frame.right)  # evaluate's images


def test_equal_cx_says_nothing_and_shifts_nothing() -> None:
    left, right = _views()
    pairer, said = _info_pairer(("/cam/left/image_raw", "/cam/right/image_raw"))
    (frame,) = _push(pairer, _ideal(), (left, right))
    assert "cx" not in said[0]
    np.testing.assert_array_equal(frame.right, right)


def test_shift_image_whole_pixels_exactly_and_keeps_shape() -> None:
    image = np.arange(2 * 6 * 3, dtype=np.uint16).reshape(2, 6, 3)
    moved = shift_image(image, 2.0)
    np.testing.assert_array_equal(moved[:, 2:], image[:, :4])
    assert not moved[:, :2].any()
    np.testing.assert_array_equal(shift_image(image, -2.0)[:, :4], image[:, 2:])
    assert shift_image(image, 0.5).shape == image.shape
    assert shift_image(image[..., 0], -0.5).shape == (2, 6)
    assert shift_image(image, 9.0).sum() == 0


def test_cameras_of_different_sizes_whose_p_differ_only_in_cx_are_one_camera() -> None:
    """A narrower right sensor with its own cx: remapped onto the left's (refused before)."""
    calibration = raw_calibration(CAMERA, "plumb_bob")
    narrow = rect.StereoCalibration(
        calibration.left, dataclasses.replace(calibration.right, width=300)
    )
    rectifier = rect.StereoRectifier(_right_cx(narrow, -10.0))
    assert rectifier.camera == rect.StereoRectifier(narrow).camera
    assert "right cx 148 -> 158 px" in rectifier.cx_note
    p = narrow.right.p.copy()
    p[1, 2] -= 10  # another cy: no one rectified camera
    with pytest.raises(CalibrationError, match="their P differ in fx, fy, cx or cy"):
        rect.StereoRectifier(
            rect.StereoCalibration(narrow.left, dataclasses.replace(narrow.right, p=p))
        )


@pytest.mark.parametrize("more", [1.0, -1.0, 3.0])
@pytest.mark.parametrize(
    ("topics", "options", "says"),
    [
        (("/cam/left/image_raw", "/cam/right/image_raw"), {}, "say the images are rectified"),
        (("/cam/left/image_rect", "/cam/right/image_rect"), {}, "are named rectified"),
        (("/cam/left/image_raw", "/cam/right/image_raw"), {"rectify": "never"}, "rectify never"),
    ],
)
def test_the_columns_a_shift_brings_in_are_left_out_of_the_estimate(
    more: float, topics: tuple[str, str], options: dict[str, Any], says: str
) -> None:
    """Review 15a R2: a band under 0.5 % of the frame (or any, with --rectify never) was
    matched as scene; now the box leaves the band out, as a remapped pair's does."""
    left, _, seen, calibration = _shifted_pair(more, says)
    pairer, said = _info_pairer(topics, **options)
    (frame,) = _push(pairer, calibration, (left, seen))
    assert says in said[0]
    if options:  # review 15a R6: not "as recorded" alone, the right images are not
        assert said[0].startswith("rectify never: the images are used as recorded but shifted, ")
    x, w = round(CAMERA.cx - frame.camera.cx), frame.left.shape[1]
    band = int(np.ceil(abs(more)))
    if more > 0:  # moved left by `more`: black at the right edge
        assert x + w <= CAMERA.width - band
    else:
        assert x >= band
    assert (frame.right != 0).any(axis=0).all()  # no black column is estimated on
    (line,) = [s for s in said if s.startswith("rectified border:")]
    side = "right" if more > 0 else "left"
    assert f"the {band} column{'s' if band > 1 else ''} at the {side} of the right images " in line
    assert f"that their {-more:+g} px shift onto the left's cx brings in, black)" in line
    if "named" not in says:  # no raw calibration: no alpha to blame
        assert "alpha" not in line


@pytest.mark.parametrize("rectify", ["auto", "never"])
def test_evaluate_reads_the_right_images_shifted_as_densify_did(rectify: str) -> None:
    """Review 15a R4: PairImages.rectified returning the right image as recorded passed."""
    from pcainterp_stream.frontend.images import PairImages

    left, right = _views()
    seen = shift_image(right, 3.0)  # a right camera with cx + 3
    calibration = _right_cx(_ideal(), 3.0)
    pair = PairImages(
        PairingConfig(
            left_topic="/cam/left/image_raw",
            right_topic="/cam/right/image_raw",
            left_info_topic="/cam/left/camera_info",
            right_info_topic="/cam/right/camera_info",
            rectify=rectify,
        )
    )
    pair.see_info("/cam/left/camera_info", camera_info_message(calibration.left, 1000, "c"))
    pair.see_info("/cam/right/camera_info", camera_info_message(calibration.right, 1000, "c"))
    np.testing.assert_array_equal(pair.rectified(left, "left"), left)
    out = pair.rectified(seen, "right")
    np.testing.assert_array_equal(out, shift_image(seen, -3.0))
    np.testing.assert_array_equal(out[:, :-3], right[:, :-3])  # on the left's cx
