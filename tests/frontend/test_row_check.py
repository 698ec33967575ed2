"""The row check: an unrectified or swapped pair is refused, also after dark start-up frames."""

from __future__ import annotations

import dataclasses
from typing import Any

import cv2
import numpy as np
import pytest

from pcainterp_stream.errors import CalibrationError
from pcainterp_stream.frontend import rectify as rect
from pcainterp_stream.frontend import row_check
from pcainterp_stream.frontend.pairing import PairingConfig, StereoPairer
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.calibration import camera_info_message
from pcainterp_stream.io.raw_log import Unrectifier
from pcainterp_stream.records import StereoCamera
from pcainterp_stream.synth.raw import raw_calibration

CAMERA = StereoCamera(width=320, height=120, fx=180.0, fy=180.0, cx=158.0, cy=60.0, baseline=0.5)
LEFT, RIGHT = "/cam/left/image_raw", "/cam/right/image_raw"
LEFT_INFO, RIGHT_INFO = "/cam/left/camera_info", "/cam/right/camera_info"
Pair = tuple[np.ndarray, np.ndarray]


def _views(shift: float = 12.0) -> Pair:
    """A rectified pair: the right view is the left shifted by a constant disparity."""
    rng = np.random.default_rng(1)
    small = rng.integers(0, 256, (CAMERA.height // 4 + 1, CAMERA.width // 4 + 1), dtype=np.uint8)
    left = cv2.resize(small, (CAMERA.width, CAMERA.height), interpolation=cv2.INTER_CUBIC)
    shifted = np.float32([[1, 0, -shift], [0, 1, 0]])
    right = cv2.warpAffine(left, shifted, (CAMERA.width, CAMERA.height), borderMode=4)
    return left, right


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


RAW = raw_calibration(CAMERA, "plumb_bob")
IDEAL = _ideal(RAW)
DARK: Pair = (np.zeros((CAMERA.height, CAMERA.width), np.uint8),) * 2


def _run(frames: list[Pair], calibration: rect.StereoCalibration) -> StereoPairer:
    """Push the frames through a pairer (camera infos of ``calibration``) and finish it."""
    pairer = StereoPairer(
        PairingConfig(
            left_topic=LEFT,
            right_topic=RIGHT,
            left_info_topic=LEFT_INFO,
            right_info_topic=RIGHT_INFO,
        )
    )
    for index, (left, right) in enumerate(frames):
        stamp = 1000 + index
        messages: dict[str, Any] = {
            LEFT_INFO: camera_info_message(calibration.left, stamp, "l"),
            RIGHT_INFO: camera_info_message(calibration.right, stamp, "r"),
            LEFT: rosmsg.image_message(left, stamp, "l", encoding="mono8"),
            RIGHT: rosmsg.image_message(right, stamp, "l", encoding="mono8"),
        }
        for topic, message in messages.items():
            pairer.push(topic, stamp, stamp, message)
    pairer.finish()
    return pairer


def test_dark_first_frames_do_not_switch_the_check_off() -> None:
    # a camera's auto-exposure start-up: the first frames give no match; the check goes on
    raw = Unrectifier(RAW)(*_views())
    with pytest.raises(CalibrationError, match=r"does not look rectified.* first 6 frame\(s\)"):
        _run([DARK] * 5 + [raw], IDEAL)  # raw images whose camera infos say rectified
    left, right = _views()
    with pytest.raises(CalibrationError, match="negative disparities"):
        _run([DARK] * 5 + [(right, left)], IDEAL)  # rectified, the sides swapped
    assert _run([DARK] * 5 + [(left, right)], IDEAL).stats.row_check_hint() is None


def test_a_check_that_never_decides_says_so(monkeypatch: pytest.MonkeyPatch) -> None:
    hint = _run([DARK] * 3, IDEAL).stats.row_check_hint()
    assert hint == (
        f"could not check that {LEFT} / {RIGHT} is rectified and not swapped: 0 matched "
        "corners in all 3 frames, 30 needed (dark, blank or unrelated images); it was "
        "densified unchecked: if the depth looks wrong, check the camera infos and which "
        "camera each topic carries"
    )
    # it looks at the first ROW_CHECK_MAX_FRAMES frames at most, then lets the log be
    monkeypatch.setattr(row_check, "ROW_CHECK_MAX_FRAMES", 4)
    raw = Unrectifier(RAW)(*_views())
    hint = _run([DARK] * 4 + [raw] * 2, IDEAL).stats.row_check_hint()
    assert hint is not None
    assert "0 matched corners in the first 4 frames, 30 needed" in hint


def test_a_log_that_ends_before_enough_matches_is_judged_on_what_it_had(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(row_check, "ROW_CHECK_MATCHES", 10**6)  # never enough while streaming
    raw = Unrectifier(RAW)(*_views())
    with pytest.raises(CalibrationError, match=r"does not look rectified.* first 2 frame\(s\)"):
        _run([raw] * 2, IDEAL)


def test_a_raw_pair_with_its_sides_swapped_names_the_topics_to_swap() -> None:
    # crossed cables: each topic carries the other camera's raw images, the infos are right
    raw_left, raw_right = Unrectifier(RAW)(*_views())
    with pytest.raises(CalibrationError) as err:
        _run([(raw_right, raw_left)], RAW)
    message = str(err.value)
    assert "px with the two images exchanged: left and right look swapped" in message
    assert message.endswith(
        f"pass --left-topic {RIGHT} --right-topic {LEFT} --left-info-topic {LEFT_INFO} "
        f"--right-info-topic {RIGHT_INFO}"
    )
    assert "\n" not in message
    assert _run([(raw_left, raw_right)], RAW).stats.row_check_hint() is None  # as recorded


def test_a_calibration_that_does_not_fit_is_not_called_a_swap() -> None:
    raw = Unrectifier(RAW)(*_views())
    tilt = cv2.Rodrigues(np.array([np.radians(3.0), 0.0, 0.0]))[0]  # the left camera's R is off
    wrong = rect.StereoCalibration(dataclasses.replace(RAW.left, r=tilt @ RAW.left.r), RAW.right)
    with pytest.raises(CalibrationError, match="does not look rectified") as err:
        _run([raw], wrong)
    assert "the calibration does not fit these images: check the camera infos" in str(err.value)
    assert "exchanged" not in str(err.value)


def test_a_low_gain_log_is_checked() -> None:
    # a night log (KITTI at gain 0.05): ORB found no corner, so it went unchecked
    def dim(pair: Pair) -> Pair:
        left, right = pair
        return (left * 0.05).astype(np.uint8), (right * 0.05).astype(np.uint8)

    assert int(dim(_views())[0].max()) <= 13
    matches = rect.correspondences(*dim(_views()))
    assert matches.shape[0] >= row_check.ROW_CHECK_MIN_MATCHES
    raw = dim(Unrectifier(RAW)(*_views()))
    with pytest.raises(CalibrationError, match="does not look rectified"):
        _run([raw] * 3, IDEAL)  # raw images whose camera infos say rectified
    assert _run([dim(_views())] * 3, IDEAL).stats.row_check_hint() is None


def test_noise_gives_no_correspondences() -> None:
    # a fundamental matrix fits ~15 of the matches of any two noise images: chance, no verdict
    rng = np.random.default_rng(3)
    for top in (4, 40):  # a lens cap at night (equalised), a blank wall's sensor noise
        left, right = (rng.integers(0, top, (376, 1241)).astype(np.uint8) for _ in range(2))
        assert rect.correspondences(left, right).shape == (0, 4)
    noise = [
        tuple(rng.integers(0, 4, (CAMERA.height, CAMERA.width)).astype(np.uint8) for _ in range(2))
        for _ in range(6)
    ]
    hint = _run(noise, IDEAL).stats.row_check_hint()
    assert hint is not None
    assert "0 matched corners in all 6 frames" in hint


@pytest.mark.parametrize("jpeg", [False, True])
def test_one_camera_on_both_topics_is_refused(jpeg: bool) -> None:
    # a launch file's remap (or image_transport republish) of the left camera as the right one:
    # SGBM matches it at 0 px everywhere, which is a valid disparity, so nothing else stops it
    left, _ = _views()
    right = left
    if jpeg:  # the same camera's compressed topic: the same view with coding noise
        right = cv2.imdecode(cv2.imencode(".jpg", left, [cv2.IMWRITE_JPEG_QUALITY, 80])[1], 0)
    with pytest.raises(CalibrationError, match=f"shows one view twice.*{RIGHT} carries the left"):
        _run([(left, right)] * 3, IDEAL)


@pytest.mark.parametrize("dark", [0, 10])
def test_a_small_disparity_everywhere_is_not_one_view(dark: int) -> None:
    # a far scene still lies a pixel or two apart in the two views; dark start-up frames
    # (no matches, images alike) do not vote on it
    assert _run([DARK] * dark + [_views(shift=1.2)] * 3, IDEAL).stats.row_check_hint() is None


def test_each_refusal_is_worded_for_every_command_that_checks() -> None:
    # learn and evaluate check the pair too: "--rectify never densifies them anyway" was
    # densify's word (bug hunt 6A F10)
    left, right = _views()
    for pair, kind in [
        (Unrectifier(RAW)(left, right), "does not look rectified"),
        ((right, left), "negative disparities"),
        ((left, left), "shows one view twice"),
    ]:
        with pytest.raises(CalibrationError, match=kind) as err:
            _run([pair] * 3, IDEAL)
        assert "--rectify never uses the pair as recorded, unchecked" in str(err.value)
        assert "densif" not in str(err.value)


def test_each_frames_corners_are_kept_for_the_pair_watch_until_the_verdict() -> None:
    left, right = _views()
    check = row_check.RowCheck(LEFT, RIGHT, info_topics=None)
    check.see(*DARK, rectifier=None, index=0)  # dark: no matches, the check goes on
    check.see(left, right, rectifier=None, index=1)  # its 150+ matches decide
    check.see(left, right, rectifier=None, index=2)  # after the verdict: not matched
    check.finish()
    assert check.done
    given = check.corners(1)
    assert given is not None
    corners = given.result(timeout=10)
    assert np.array_equal(corners, rect.correspondences(left, right))  # as the watch matches
    assert corners.shape[0] >= row_check.ROW_CHECK_MATCHES
    assert check.corners(1) is None  # given once
    assert check.corners(0) is None  # an earlier frame's: let go when frame 1's were asked
    assert check.corners(2) is None
    unindexed = row_check.RowCheck(LEFT, RIGHT, info_topics=None)
    unindexed.see(left, right, rectifier=None)
    unindexed.finish()
    assert unindexed.corners(0) is None


def test_crossed_equidistant_cameras_without_coefficients_are_named_a_swap() -> None:
    """Bug hunt 15A F4: equidistant infos with D = [] crashed the crossed-cables check."""
    fisheye = raw_calibration(CAMERA, "equidistant")
    zeros, empty = (
        rect.StereoCalibration(
            *(dataclasses.replace(c, d=d) for c in (fisheye.left, fisheye.right))
        )
        for d in (np.zeros(4), np.zeros(0))
    )
    pixels = np.array([[10.0, 20.0], [200.0, 100.0]])
    np.testing.assert_array_equal(
        empty.right.raw_to_rectified(pixels), zeros.right.raw_to_rectified(pixels)
    )
    raw_left, raw_right = Unrectifier(zeros)(*_views())
    with pytest.raises(CalibrationError) as err:  # before: ValueError, cannot reshape size 0
        _run([(raw_right, raw_left)], empty)
    assert "with the two images exchanged: left and right look swapped" in str(err.value)


@pytest.fixture(scope="module")
def indoor_pairs() -> tuple[list[Pair], StereoCamera]:
    """The first 2 frames of the synthetic indoor log (752x480, seed 2)."""
    from pcainterp_stream.synth import SynthConfig, generate

    config = SynthConfig(
        seed=2,
        frames=2,
        width=752,
        height=480,
        fx=436.0,
        fy=436.0,
        cx=364.4,
        cy=256.6,
        baseline=0.11,
        scene="indoor",
    )
    frames = list(generate(config))
    return [(frame.left, frame.right) for frame in frames], frames[0].camera


def test_one_side_blurred_vertically_is_still_rectified(
    indoor_pairs: tuple[list[Pair], StereoCamera], capfd: pytest.CaptureFixture[str]
) -> None:
    # bug hunt 16F F4: ORB's corners on a blurred side sit on other pyramid levels, their rows
    # quantised to 1.2**L px: the median offset read 1.44 px and the rectified pair was refused
    pairs, camera = indoor_pairs
    ideal = _ideal(raw_calibration(camera, "plumb_bob"))
    blurred = [(left, cv2.blur(right, (1, 15))) for left, right in pairs]
    assert _run(blurred, ideal).stats.row_check_hint() is None
    assert "found on the same pyramid level" in capfd.readouterr().err


def test_a_blurred_raw_pair_is_still_refused(
    indoor_pairs: tuple[list[Pair], StereoCamera],
) -> None:
    pairs, camera = indoor_pairs
    calibration = raw_calibration(camera, "plumb_bob")
    raw = [Unrectifier(calibration)(left, right) for left, right in pairs]
    blurred = [(left, cv2.blur(right, (1, 15))) for left, right in raw]
    with pytest.raises(CalibrationError, match="does not look rectified"):
        _run(blurred, _ideal(calibration))
