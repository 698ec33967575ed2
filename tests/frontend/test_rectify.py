"""Rectification from camera calibrations (image_proc's), the row guard, the maps' cache."""

from __future__ import annotations

import dataclasses
import re
from typing import Any

import cv2
import numpy as np
import pytest

from pcainterp_stream.errors import CalibrationError
from pcainterp_stream.frontend import rectify as rect
from pcainterp_stream.frontend.pairing import PairingConfig, StereoPairer
from pcainterp_stream.io.calibration import camera_info_message
from pcainterp_stream.io.raw_log import Unrectifier
from pcainterp_stream.records import SparseFeatures, StereoCamera
from pcainterp_stream.synth.raw import raw_calibration

CAMERA = StereoCamera(width=320, height=120, fx=180.0, fy=180.0, cx=158.0, cy=60.0, baseline=0.5)


def _texture(shape: tuple[int, int], seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, (shape[0] // 4 + 1, shape[1] // 4 + 1), dtype=np.uint8)
    return cv2.resize(small, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)


def _stereo_views(shift: float = 12.0) -> tuple[np.ndarray, np.ndarray]:
    """A rectified pair: the right view is the left shifted by a constant disparity."""
    left = _texture((CAMERA.height, CAMERA.width), seed=1)
    m = np.float32([[1, 0, -shift], [0, 1, 0]])  # right sees the scene shift to its left
    right = cv2.warpAffine(left, m, (CAMERA.width, CAMERA.height), borderMode=cv2.BORDER_REFLECT)
    return left, right


@pytest.mark.parametrize("model", ["plumb_bob", "equidistant"])
def test_rectify_undoes_the_raw_camera(model: str) -> None:
    calibration = raw_calibration(CAMERA, model)
    left, right = _stereo_views()
    raw_left, raw_right = Unrectifier(calibration)(left, right)
    assert not calibration.is_rectified
    rectifier = rect.StereoRectifier(calibration)
    back, _ = rectifier.rectify(raw_left, raw_right)
    x, y, w, h = rectifier.box
    inner = (slice(y + 4, y + h - 4), slice(x + 4, x + w - 4))
    error = np.abs(back[inner].astype(float) - left[inner].astype(float))
    assert np.median(error) < 4
    assert rectifier.camera.fx == CAMERA.fx
    assert rectifier.camera.baseline == pytest.approx(CAMERA.baseline)


def test_plumb_bob_maps_are_opencvs() -> None:
    cal = raw_calibration(CAMERA, "plumb_bob").left
    map_x, map_y = cal.rectification_maps()
    ref_x, ref_y = cv2.initUndistortRectifyMap(
        cal.k, cal.d, cal.r, cal.p[:, :3], (cal.width, cal.height), cv2.CV_32FC1
    )
    np.testing.assert_array_equal(map_x, ref_x)
    np.testing.assert_array_equal(map_y, ref_y)


def test_rational_polynomial_is_understood() -> None:
    cal = raw_calibration(CAMERA, "plumb_bob").left
    eight = rect.CameraCalibration(
        cal.width,
        cal.height,
        "rational_polynomial",
        cal.k,
        np.array([*cal.d[:5], 0.01, 0.0, 0.0]),
        cal.r,
        cal.p,
    )
    map_x, _ = eight.rectification_maps()
    ref_x, _ = cv2.initUndistortRectifyMap(
        eight.k, eight.d, eight.r, eight.p[:, :3], (cal.width, cal.height), cv2.CV_32FC1
    )
    np.testing.assert_array_equal(map_x, ref_x)


def test_binning_and_roi_as_image_proc() -> None:
    """Reduced maps: the full maps' ROI, every binning-th pixel, in binned raw pixels."""
    full = raw_calibration(CAMERA, "plumb_bob").left
    reduced = rect.CameraCalibration(
        full.width,
        full.height,
        full.model,
        full.k,
        full.d,
        full.r,
        full.p,
        binning=(2, 2),
        roi=(40, 20, 200, 80),
    )
    assert reduced.image_size() == (100, 40)
    fx, fy = full.rectification_maps()
    rx, ry = reduced.rectification_maps()
    assert rx.shape == (40, 100)
    np.testing.assert_allclose(rx[7, 9], (fx[20 + 14, 40 + 18] - 40) / 2, rtol=1e-6)
    np.testing.assert_allclose(ry[7, 9], (fy[20 + 14, 40 + 18] - 20) / 2, rtol=1e-6)
    p = reduced.rectified_projection()
    assert p[0, 0] == full.p[0, 0] / 2
    assert p[0, 2] == (full.p[0, 2] - 40) / 2


def _with_left_tx(calibration: rect.StereoCalibration, tx: float) -> rect.StereoCalibration:
    """The pair calibrated against a third camera: both P carry ``tx`` more (kitti2bag)."""
    sides = []
    for cal in (calibration.left, calibration.right):
        p = cal.p.copy()
        p[0, 3] += tx
        sides.append(dataclasses.replace(cal, p=p))
    return rect.StereoCalibration(*sides)


def test_raw_pair_with_a_left_tx_keeps_its_baseline() -> None:
    """The baseline is (Tx_left - Tx_right) / fx; the right Tx alone was 11 % short on KITTI."""
    shifted = _with_left_tx(raw_calibration(CAMERA, "plumb_bob"), 0.06 * CAMERA.fx)
    rectifier = rect.StereoRectifier(shifted)
    assert rectifier.camera.baseline == pytest.approx(CAMERA.baseline)
    assert rect.StereoRectifier(shifted, baseline=0.3).camera.baseline == 0.3
    (frame,) = _push_pair(_pairer(check_rows=False), 1000, *_stereo_views(), shifted)
    assert frame.camera.baseline == pytest.approx(CAMERA.baseline)
    swapped = rect.StereoCalibration(shifted.right, shifted.left)
    with pytest.raises(CalibrationError, match=r"gives no baseline .*left P\[0,3\] = .*swapped"):
        rect.StereoRectifier(swapped)


def test_a_sign_problem_is_never_told_to_pass_baseline() -> None:
    # bug hunt 7A F14: "swapped left/right?); fix the calibration or pass --baseline METRES":
    # --baseline cannot fix a sign
    calibration = raw_calibration(CAMERA, "plumb_bob")
    left = dataclasses.replace(calibration.left, name="c.yaml:cam0")
    right = dataclasses.replace(calibration.right, name="c.yaml:cam1")
    with pytest.raises(CalibrationError) as err:
        rect.StereoRectifier(rect.StereoCalibration(right, left))
    line = str(err.value)
    assert "swapped left/right?" in line
    assert "--baseline" not in line
    assert line.endswith(
        "c.yaml:cam0 is the left camera's calibration: pass it as the left one and c.yaml:cam1 "
        "as the right one, each with its camera's images"
    )
    no_tx = dataclasses.replace(right, p=np.hstack([right.p[:, :3], np.zeros((3, 1))]))
    with pytest.raises(CalibrationError, match=r"no Tx\); fix the calibration or pass --baseline"):
        rect.StereoRectifier(rect.StereoCalibration(left, no_tx))


def test_raw_and_rectified_paths_read_binning_and_roi_alike() -> None:
    """image_rect of a binning / ROI camera: remapped or used as it is, one camera."""
    from pcainterp_stream.frontend.camera_infos import camera_from_infos

    ideal = _ideal(raw_calibration(CAMERA, "plumb_bob"))
    reduced = rect.StereoCalibration(
        *(
            dataclasses.replace(c, binning=(2, 2), roi=(40, 20, 200, 80))
            for c in (ideal.left, ideal.right)
        )
    )
    messages = _messages(reduced, 0)
    from_infos = camera_from_infos(
        messages["/cam/left/camera_info"], messages["/cam/right/camera_info"], width=100, height=40
    )
    remapped = rect.StereoRectifier(reduced).camera
    assert from_infos == remapped
    assert (from_infos.fx, from_infos.cx) == (CAMERA.fx / 2, (CAMERA.cx - 40) / 2)
    assert from_infos.focal_baseline == pytest.approx(CAMERA.focal_baseline / 2)


def _ideal(calibration: rect.StereoCalibration) -> rect.StereoCalibration:
    """The rectified pair's own calibration: K = P[:3, :3], D = 0, R = I on both sides."""
    return rect.StereoCalibration(
        *(
            rect.CameraCalibration(
                c.width, c.height, "plumb_bob", c.p[:, :3], np.zeros(5), np.eye(3), c.p
            )
            for c in (calibration.left, calibration.right)
        )
    )


def test_a_rectified_pair_passes_through_unchanged() -> None:
    """--rectify always on a pair that is rectified already: image_proc's identity, exactly."""
    # KITTI's P: maps built from it land a hair below 0 in the first row and column
    kitti = StereoCamera(320, 120, 707.0912, 707.0912, 161.8873, 63.1104, 0.54)
    ideal = _ideal(raw_calibration(kitti, "plumb_bob"))
    assert ideal.is_rectified
    rectifier = rect.StereoRectifier(ideal)
    left, right = _stereo_views()
    out_left, out_right = rectifier.rectify(left, right)
    np.testing.assert_array_equal(out_left, left)
    np.testing.assert_array_equal(out_right, right)
    assert rectifier.box == (0, 0, kitti.width, kitti.height)
    assert rectifier.inner == rectifier.camera
    (frame,) = _push_pair(_pairer(rectify="always"), 1000, left, right, ideal)
    np.testing.assert_array_equal(frame.left, left)
    assert frame.camera.cx == rectifier.camera.cx


def test_uncalibrated_camera_info_names_calibration_files() -> None:
    """A driver without a calibration publishes K = P = 0 (ROS's "not calibrated")."""
    cal = raw_calibration(CAMERA, "plumb_bob").left
    zero = np.zeros((3, 4))
    with pytest.raises(CalibrationError) as err:
        rect.CameraCalibration(
            cal.width, cal.height, "", zero[:, :3], cal.d[:0], cal.r, zero, name="/l"
        )
    assert str(err.value).startswith("/l has an all-zero K and P: the camera is not calibrated")
    assert str(err.value).endswith("pass --calibration LEFT.yaml RIGHT.yaml")


def test_unknown_model_is_one_line() -> None:
    cal = raw_calibration(CAMERA, "plumb_bob").left
    with pytest.raises(CalibrationError, match="distortion model 'kb4'") as err:
        rect.CameraCalibration(cal.width, cal.height, "kb4", cal.k, cal.d, cal.r, cal.p)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("model", "count", "takes"),
    [
        ("plumb_bob", 6, "4, 5, 8, 12 or 14"),
        ("plumb_bob", 3, "4, 5, 8"),
        ("equidistant", 8, "4 or 5"),
    ],
)
def test_distortion_coefficients_opencv_does_not_take_are_one_line(
    model: str, count: int, takes: str
) -> None:
    # OpenCV's initUndistortRectifyMap asserted (a traceback naming no topic) on these
    cal = raw_calibration(CAMERA, "plumb_bob").left
    d = np.full(count, 0.01)
    with pytest.raises(CalibrationError, match=f"has {count} distortion coefficients but") as err:
        rect.CameraCalibration(cal.width, cal.height, model, cal.k, d, cal.r, cal.p, name="/l/info")
    assert f"/l/info has {count} distortion coefficients but {model} takes {takes}" in str(
        err.value
    )
    assert "\n" not in str(err.value)
    for fine in (4, 5):
        d = np.full(fine, 0.01)
        rect.CameraCalibration(cal.width, cal.height, model, cal.k, d, cal.r, cal.p)


def _messages(calibration: rect.StereoCalibration, stamp: int) -> dict[str, Any]:
    return {
        "/cam/left/camera_info": camera_info_message(calibration.left, stamp, "l"),
        "/cam/right/camera_info": camera_info_message(calibration.right, stamp, "r"),
    }


def _pairer(**options: Any) -> StereoPairer:
    config = PairingConfig(
        left_topic="/cam/left/image_raw",
        right_topic="/cam/right/image_raw",
        left_info_topic="/cam/left/camera_info",
        right_info_topic="/cam/right/camera_info",
        **options,
    )
    return StereoPairer(config, echo=None)


def _push_pair(
    pairer: StereoPairer,
    stamp: int,
    left: np.ndarray,
    right: np.ndarray,
    calibration: rect.StereoCalibration,
) -> list[Any]:
    from pcainterp_stream.io import rosmsg

    frames = []
    for topic, message in _messages(calibration, stamp).items():
        frames += pairer.push(topic, stamp, stamp, message)
    for topic, image in (("/cam/left/image_raw", left), ("/cam/right/image_raw", right)):
        message = rosmsg.image_message(image, stamp, "l", encoding="mono8")
        frames += pairer.push(topic, stamp, stamp, message)
    return frames


def _push_frames(
    pairer: StereoPairer,
    count: int,
    left: np.ndarray,
    right: np.ndarray,
    calibration: rect.StereoCalibration,
) -> None:
    for i in range(count):
        _push_pair(pairer, 1000 + i, left, right, calibration)


def test_pairer_rectifies_raw_pairs_and_builds_maps_once() -> None:
    calibration = raw_calibration(CAMERA, "plumb_bob")
    raw = Unrectifier(calibration)(*_stereo_views())
    pairer = _pairer()
    frames = []
    for i in range(3):
        frames += _push_pair(pairer, 1000 + i, *raw, calibration)
    assert len(frames) == 3
    first = pairer.rectification()
    assert first is not None
    frames += _push_pair(pairer, 2000, *raw, calibration)  # the same values re-sent
    assert pairer.rectification() is first
    x, _, w, h = first.box
    assert frames[0].left.shape == (h, w)
    assert frames[0].camera.cx == pytest.approx(CAMERA.cx - x)
    changed = raw_calibration(StereoCamera(320, 120, 181.0, 181.0, 158.0, 60.0, 0.5), "plumb_bob")
    _push_pair(pairer, 3000, *raw, changed)
    assert pairer.rectification() is not first


def test_features_move_into_the_rectified_frame() -> None:
    calibration = raw_calibration(CAMERA, "plumb_bob")
    raw = Unrectifier(calibration)(*_stereo_views())
    pairer = _pairer(check_rows=False)
    (frame,) = _push_pair(pairer, 1000, *raw, calibration)
    pairer._features.matched[frame.index] = SparseFeatures(
        1000, 1000, "l", np.array([[0.0, 0.0, 10.0]], dtype=np.float32)
    )
    features = pairer.features_for(frame)
    assert features is not None
    np.testing.assert_allclose(features.points[0], calibration.left.r @ [0, 0, 10], rtol=1e-5)


def _raw_pair_declared_rectified() -> tuple[tuple[np.ndarray, np.ndarray], rect.StereoCalibration]:
    """Return a raw (distorted) pair and a calibration that says it is rectified."""
    calibration = raw_calibration(CAMERA, "plumb_bob")
    raw = Unrectifier(calibration)(*_stereo_views())
    return raw, _ideal(calibration)


def test_guard_refuses_a_raw_pair_declared_rectified() -> None:
    raw, ideal = _raw_pair_declared_rectified()
    pairer = _pairer()
    with pytest.raises(CalibrationError, match="does not look rectified") as err:
        _push_frames(pairer, 6, *raw, ideal)  # the guard decides by the fifth frame
    assert "--rectify always" in str(err.value)
    never = _pairer(rectify="never", check_rows=False)
    assert len(_push_pair(never, 1000, *raw, ideal)) == 1


def test_guard_refuses_swapped_cameras() -> None:
    calibration = rect.StereoCalibration(
        *(
            rect.CameraCalibration(
                CAMERA.width, CAMERA.height, "plumb_bob", p[:, :3], np.zeros(5), np.eye(3), p
            )
            for p in (CAMERA.projection_left(), CAMERA.projection_right())
        )
    )
    left, right = _stereo_views()
    pairer = _pairer()
    with pytest.raises(CalibrationError, match="negative disparities"):
        _push_frames(pairer, 6, right, left, calibration)
    ok = _pairer()
    for i in range(6):
        assert len(_push_pair(ok, 1000 + i, left, right, calibration)) == 1
    ok.finish()


def test_rectified_streams_need_no_raw_calibration() -> None:
    """image_rect topics whose infos have no usable K, D (size 0, unknown model) use P."""
    from pcainterp_stream.io import rosmsg

    config = PairingConfig(
        left_topic="/cam/left/image_rect",
        right_topic="/cam/right/image_rect",
        left_info_topic="/cam/left/camera_info",
        right_info_topic="/cam/right/camera_info",
    )
    said: list[str] = []
    pairer = StereoPairer(config, echo=said.append)
    left, right = _stereo_views()
    frames = []
    for topic, right_side in (("/cam/left/camera_info", False), ("/cam/right/camera_info", True)):
        info = rosmsg.camera_info_message(CAMERA, 1000, "c", right=right_side)
        info.width = info.height = 0
        info.distortion_model = "unknown_model"
        frames += pairer.push(topic, 1000, 1000, info)
    for topic, image in (("/cam/left/image_rect", left), ("/cam/right/image_rect", right)):
        frames += pairer.push(
            topic, 1000, 1000, rosmsg.image_message(image, 1000, "c", encoding="mono8")
        )
    assert len(frames) == 1
    assert frames[0].camera.fx == CAMERA.fx
    assert said[0].startswith("rectify auto: /cam/left/image_rect and /cam/right/image_rect")


@pytest.mark.parametrize(("name", "remapped"), [("image_corrected", True), ("image_rect", False)])
def test_only_a_name_with_the_word_rect_is_used_without_a_remap(name: str, remapped: bool) -> None:
    """Bug hunt 15A F3: raw images on image_corrected were used unrectified (substring test)."""
    from pcainterp_stream.io import rosmsg

    calibration = raw_calibration(CAMERA, "plumb_bob")
    raw_left, raw_right = Unrectifier(calibration)(*_stereo_views())
    topics = (f"/cam/left/{name}", f"/cam/right/{name}")
    said: list[str] = []
    config = PairingConfig(
        left_topic=topics[0],
        right_topic=topics[1],
        left_info_topic="/cam/left/camera_info",
        right_info_topic="/cam/right/camera_info",
        check_rows=False,
    )
    pairer = StereoPairer(config, echo=said.append)
    for topic, message in _messages(calibration, 1000).items():
        pairer.push(topic, 1000, 1000, message)
    for topic, image in zip(topics, (raw_left, raw_right), strict=True):
        pairer.push(topic, 1000, 1000, rosmsg.image_message(image, 1000, "c", encoding="mono8"))
    assert (pairer.rectification() is not None) is remapped
    assert said[0].startswith(
        "rectify auto: remapping the raw images"
        if remapped
        else "rectify auto: /cam/left/image_rect and"
    )


def test_guard_decides_at_the_same_frame_however_slow_its_matching(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The guard matches a frame's corners in a thread while the frame goes on; the verdict
    # counts the same frames as a check in line (here the first frame's matches are enough).
    import threading

    raw, ideal = _raw_pair_declared_rectified()
    release = threading.Event()
    matched = rect.correspondences

    def slow(left: np.ndarray, right: np.ndarray) -> np.ndarray:
        release.wait(10.0)
        return matched(left, right)

    monkeypatch.setattr(rect, "correspondences", slow)
    pairer = _pairer()
    assert len(_push_pair(pairer, 1000, *raw, ideal)) == 1  # out before its rows are matched
    release.set()
    with pytest.raises(CalibrationError, match=r"of the first 1 frame\(s\)"):
        _push_frames(pairer, 5, *raw, ideal)  # refused as the next frame comes


def _rotation_y(degrees: float) -> np.ndarray:
    a = np.radians(degrees)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


@pytest.mark.parametrize(
    ("r", "says"),
    [
        (np.zeros((3, 3)), "/l has an all-zero R: the stereo rectification is not calibrated"),
        (2 * np.eye(3), "/l has an R that is not a rotation (det 8"),
        (np.diag([1.0, 1.0, -1.0]), "/l has an R that is not a rotation (det -1"),
        # a damaged message's huge entries: refused without NumPy's overflow warning
        (np.full((3, 3), 1e200), "/l has an R that is not a rotation (det "),
    ],
)
def test_an_r_that_is_no_rotation_is_one_line(r: np.ndarray, says: str) -> None:
    """Bug hunt 7A F5: an all-zero R gave NumPy warnings and a cv2 traceback downstream."""
    cal = raw_calibration(CAMERA, "plumb_bob").left
    with pytest.raises(CalibrationError) as err:
        rect.CameraCalibration(cal.width, cal.height, cal.model, cal.k, cal.d, r, cal.p, name="/l")
    assert str(err.value).startswith(says)
    assert "--calibration LEFT.yaml RIGHT.yaml" in str(err.value)
    assert "--rectify never if the images are rectified" in str(err.value)
    assert "\n" not in str(err.value)
    rounded = np.round(_rotation_y(1.0), 6)  # a calibration file's six decimals
    rect.CameraCalibration(cal.width, cal.height, cal.model, cal.k, cal.d, rounded, cal.p)


def test_a_raw_pair_with_an_all_zero_r_is_refused_by_the_pairer() -> None:
    """Before: the pairer remapped with R = 0 and the empty box crashed the matcher."""
    from pcainterp_stream.io import rosmsg

    calibration = raw_calibration(CAMERA, "plumb_bob")
    raw = Unrectifier(calibration)(*_stereo_views())
    pairer = _pairer(check_rows=False)
    for topic, info in _messages(calibration, 1000).items():
        info.r = np.zeros(9)
        pairer.push(topic, 1000, 1000, info)
    pairer.push("/cam/left/image_raw", 1000, 1000, rosmsg.image_message(raw[0], 1000, "l"))
    right = rosmsg.image_message(raw[1], 1000, "l")
    with pytest.raises(CalibrationError, match=r"^/cam/left/camera_info has an all-zero R"):
        pairer.push("/cam/right/image_raw", 1000, 1000, right)


def test_an_empty_rectified_box_names_both_infos() -> None:
    """Cameras that see nothing of one rectified image: a CalibrationError, not a crash."""
    calibration = raw_calibration(CAMERA, "plumb_bob")
    right = dataclasses.replace(calibration.right, r=_rotation_y(80.0), name="/r/info")
    left = dataclasses.replace(calibration.left, name="/l/info")
    with pytest.raises(CalibrationError) as err:
        rect.StereoRectifier(rect.StereoCalibration(left, right))
    assert re.match(
        r"/l/info and /r/info leave a \d+x\d+ px box of the 320x120 rectified", str(err.value)
    )
    assert "--calibration LEFT.yaml RIGHT.yaml" in str(err.value)


def _narrow_right(calibration: rect.StereoCalibration, width: int) -> rect.StereoCalibration:
    """The pair with a right sensor ``width`` px wide: the same K, D, R, P (bug hunt 7A F7)."""
    return rect.StereoCalibration(
        calibration.left, dataclasses.replace(calibration.right, width=width)
    )


def test_cameras_of_different_sizes_are_rectified_into_one_image() -> None:
    """Before: a NumPy broadcast traceback (the maps were built at each camera's size)."""
    calibration = raw_calibration(CAMERA, "plumb_bob")
    raw_left, raw_right = Unrectifier(calibration)(*_stereo_views())
    same = rect.StereoRectifier(calibration)
    narrow = _narrow_right(calibration, 300)
    rectifier = rect.StereoRectifier(narrow)
    assert rectifier.camera == same.camera
    left, right = rectifier.rectify(raw_left, np.ascontiguousarray(raw_right[:, :300]))
    ref_left, ref_right = same.rectify(raw_left, raw_right)
    assert left.shape == right.shape == (CAMERA.height, CAMERA.width)
    np.testing.assert_array_equal(left, ref_left)
    x, y, w, h = rectifier.box
    assert rectifier.box[2] < same.box[2]  # the right camera sees less
    map_x = rectifier._maps[1][0][y : y + h, x : x + w]
    inside = map_x < 298  # away from the cut: bicubic reads two pixels on
    np.testing.assert_array_equal(
        right[y : y + h, x : x + w][inside], ref_right[y : y + h, x : x + w][inside]
    )
    (frame,) = _push_pair(
        _pairer(check_rows=False), 1000, raw_left, np.ascontiguousarray(raw_right[:, :300]), narrow
    )
    assert frame.left.shape == frame.right.shape == (h, w)


def test_cameras_of_different_sizes_with_different_rectified_cameras_are_refused() -> None:
    calibration = _narrow_right(raw_calibration(CAMERA, "plumb_bob"), 300)
    p = calibration.right.p.copy()
    p[1, 2] -= 10  # another cy: no one rectified camera (another cx is moved: test_right_cx)
    other = rect.StereoCalibration(
        dataclasses.replace(calibration.left, name="/l/info"),
        dataclasses.replace(calibration.right, p=p, name="/r/info"),
    )
    with pytest.raises(CalibrationError) as err:
        rect.StereoRectifier(other)
    message = str(err.value)
    assert message.startswith(
        "the left camera's images are 320x120 px (/l/info) and the right's 300x120 (/r/info)"
    )
    assert "--calibration LEFT.yaml RIGHT.yaml" in message
    assert "\n" not in message


def test_a_right_tx_of_the_wrong_sign_is_told_the_baseline_that_works() -> None:
    # bug hunt 10C F5: depthai-ros's right P[0, 3] = +fx * baseline, images on their topics:
    # "pass it as the left one" failed (rows 3.8 px apart); --baseline works (the remap
    # does not use Tx), and is named with its value
    calibration = raw_calibration(CAMERA, "plumb_bob")
    right = calibration.right
    p = right.p.copy()
    p[0, 3] = -p[0, 3]
    slipped = rect.StereoCalibration(calibration.left, dataclasses.replace(right, p=p))
    with pytest.raises(CalibrationError) as err:
        rect.StereoRectifier(slipped)
    line = str(err.value)
    assert "Tx of the wrong sign?" in line
    assert f"pass --baseline {CAMERA.baseline:.6g} (Tx does not enter the remap)" in line
    assert "is the left camera's calibration" not in line
    fixed = rect.StereoRectifier(slipped, baseline=CAMERA.baseline)
    good = rect.StereoRectifier(calibration)
    for a, b in zip(fixed._maps, good._maps, strict=True):
        np.testing.assert_array_equal(a[0], b[0])


def test_a_raw_pair_stacked_vertically_is_named_so() -> None:
    """Bug hunt 15A F2: the remap path said 'gives no baseline ... pass --baseline' too."""
    calibration = raw_calibration(CAMERA, "plumb_bob")
    p = calibration.right.p.copy()
    p[1, 3], p[0, 3] = p[0, 3], 0.0
    vertical = rect.StereoCalibration(
        calibration.left, dataclasses.replace(calibration.right, p=p, name="/r/info")
    )
    for baseline in (None, 0.5):
        with pytest.raises(
            CalibrationError,
            match=r"^/r/info has P\[1,3\] = -90 and P\[0,3\] = 0: "
            "the cameras are stacked vertically",
        ):
            rect.StereoRectifier(vertical, baseline=baseline)


def test_a_raw_pair_recalibrated_to_the_same_rectified_camera_says_so_once() -> None:
    """Bug hunt 15A F6: new maps (another D, the same P) gave no second rectify line."""
    first = raw_calibration(CAMERA, "plumb_bob")
    second = rect.StereoCalibration(
        *(dataclasses.replace(c, d=c.d * 0.5) for c in (first.left, first.right))
    )
    said: list[str] = []
    pairer = StereoPairer(dataclasses.replace(_pairer().config, check_rows=False), echo=said.append)
    views = _stereo_views()
    for index, calibration in enumerate((first, first, second, second, second)):
        _push_pair(pairer, 1000 + index, *Unrectifier(calibration)(*views), calibration)
    assert len(said) == 2
    assert said[1] == said[0] + "; new maps from frame 2 on: the calibration changed"


def test_an_all_zero_k_with_a_p_describes_rectified_images() -> None:
    """Bug hunt 15A F7: D = 0, R = I, a P but K = 0 was refused as 'not calibrated'."""
    ideal = _ideal(raw_calibration(CAMERA, "plumb_bob"))
    messages = _messages(ideal, 1000)
    for message in messages.values():
        message.k[:] = 0.0
    calibration = rect.stereo_from_infos(*messages.values(), "/l", "/r")
    assert calibration.is_rectified
    np.testing.assert_array_equal(calibration.left.k, ideal.left.p[:, :3])
    pairer = _pairer(check_rows=False)
    frames: list[Any] = []
    for topic, message in messages.items():
        frames += pairer.push(topic, 1000, 1000, message)
    left, right = _stereo_views()
    from pcainterp_stream.io import rosmsg

    for topic, image in (("/cam/left/image_raw", left), ("/cam/right/image_raw", right)):
        frames += pairer.push(topic, 1000, 1000, rosmsg.image_message(image, 1000, "c"))
    assert len(frames) == 1
    assert frames[0].camera.fx == CAMERA.fx
    distorted = _messages(raw_calibration(CAMERA, "plumb_bob"), 1000)["/cam/left/camera_info"]
    distorted.k[:] = 0.0  # with distortion (or no P) it is still not calibrated
    with pytest.raises(CalibrationError, match="has an all-zero K: the camera is not calibrated"):
        rect.CameraCalibration.from_camera_info(distorted, "/l")


def test_a_raw_pair_with_a_noise_ty_and_no_tx_takes_the_baseline_given() -> None:
    """Review 15a R1: Tx = 0, Ty = 0.001 was 'stacked vertically' with --baseline too."""
    calibration = raw_calibration(CAMERA, "plumb_bob")
    p = calibration.right.p.copy()
    p[0, 3], p[1, 3] = 0.0, 0.001
    noisy = rect.StereoCalibration(
        calibration.left, dataclasses.replace(calibration.right, p=p, name="/r/info")
    )
    assert rect.StereoRectifier(noisy, baseline=0.5).camera.baseline == 0.5
    with pytest.raises(CalibrationError, match=r"^/r/info gives no baseline \(P\[0,3\] = 0.0"):
        rect.StereoRectifier(noisy)


def test_a_calibration_that_flips_every_frame_says_five_changes() -> None:
    """Review 15a R3: two calibrations alternating said one rectify line per frame."""
    first = raw_calibration(CAMERA, "plumb_bob")
    second = rect.StereoCalibration(
        *(dataclasses.replace(c, d=c.d * 0.5) for c in (first.left, first.right))
    )
    said: list[str] = []
    pairer = StereoPairer(dataclasses.replace(_pairer().config, check_rows=False), echo=said.append)
    views = _stereo_views()
    for index in range(12):
        calibration = (first, second)[index % 2]
        _push_pair(pairer, 1000 + index, *Unrectifier(calibration)(*views), calibration)
    lines = [line for line in said if line.startswith("rectify")]
    assert len(lines) == 6  # the first and five changes
    assert lines[4].endswith("; new maps from frame 4 on: the calibration changed")
    assert lines[5].endswith(
        "; new maps from frame 5 on: the calibration changed; later changes are not said (5 said)"
    )
