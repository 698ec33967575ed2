"""A pair swapped, one view twice or with drifted rows mid-log is noticed (bughunt13A F1, F3)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from pcainterp_stream.frontend import pair_watch
from pcainterp_stream.frontend import rectify as rect
from pcainterp_stream.frontend.frame_checks import StaleRight
from pcainterp_stream.frontend.pair_watch import PairWatch, frame_ranges, one_image
from pcainterp_stream.frontend.pairing import PairingConfig, StereoPairer
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.calibration import camera_info_message
from pcainterp_stream.pipeline.densify import densify
from pcainterp_stream.pipeline.jobs import synth
from pcainterp_stream.records import StereoCamera, StereoFrame
from pcainterp_stream.synth.raw import raw_calibration

HEIGHT, WIDTH = 200, 400
SECOND = 10**9


def _pair(seed: int, drop: int = 0) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
    """A textured scene: a far plane at 4 px, a near box at 20 px disparity (right ``drop``
    px lower: a drifted right camera)."""
    rng = np.random.default_rng(seed)

    def texture(h: int, w: int) -> npt.NDArray[np.float32]:
        image = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 1.5)
        return (image - image.min()) / (image.max() - image.min()) * 255

    far, near = texture(HEIGHT + 8, WIDTH + 40), texture(80, 160)
    left = far[:HEIGHT, 0:WIDTH].copy()
    right = far[:HEIGHT, 4 : WIDTH + 4].copy()  # x_right = x_left - 4
    left[60:140, 120:280] = near[:, :160]
    right[60:140, 100:260] = near[:, :160]  # x_right = x_left - 20
    if drop:
        right = np.roll(right, drop, axis=0)
        right[:drop] = right[drop]
    return np.round(left).astype(np.uint8), np.round(right).astype(np.uint8)


def _frame(index: int, left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8]) -> StereoFrame:
    stamp = index * 3 * SECOND  # a frame every 3 s: the rows are checked every other frame
    return StereoFrame(index, stamp, stamp, "left", left, right, None)  # type: ignore[arg-type]


def test_a_pair_swapped_mid_log_is_not_matched_and_warned_of() -> None:
    # before: nothing said it; SGBM matched the swapped pair at ~0 px ("too far" everywhere)
    check = StaleRight()
    out = []
    for index in range(6):
        left, right = _pair(index)
        if index in (3, 4):
            left, right = right, left
        out.append(check.check(_frame(index, left, right)))
    assert check.stale == {3, 4}
    assert not out[3].right.any()
    assert not out[4].right.any()
    assert out[5].right.any()
    assert out[2].right.any()
    lines = check.warnings(6, empty=2)
    assert len(lines) == 1
    assert "2 of 6 frames (3-4) looked swapped" in lines[0]
    assert "their depth is NaN" in lines[0]


def test_one_view_on_both_topics_mid_log_is_not_matched() -> None:
    check = StaleRight()
    for index in range(5):
        left, right = _pair(index)
        check.check(_frame(index, left, left.copy() if index == 2 else right))
    assert check.stale == {2}
    (line,) = check.warnings(5, empty=1)
    assert "1 of 5 frames (2) carried one view on both image topics" in line


def _far(left: npt.NDArray[np.uint8], disparity: float) -> npt.NDArray[np.uint8]:
    """The right image of a scene all at one sub-pixel ``disparity``: right(x) = left(x + d)."""
    move = np.float32([[1, 0, -disparity], [0, 1, 0]])
    return cv2.warpAffine(
        left, move, left.shape[::-1], flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT
    )


def test_a_scene_beyond_stereo_range_mid_log_keeps_its_estimate() -> None:
    # review 59c F1: before, frames whose whole scene went far (0.5-1 px: 96 m on a VI-sensor,
    # 390-780 m on KITTI) after good ones were blanked as "one view on both topics"
    check = StaleRight()
    for index in range(8):
        left, right = _pair(index)
        if index >= 3:
            right = _far(left, 0.5 if index % 2 else 1.0)
        assert check.check(_frame(index, left, right)).right is right
    assert check.stale == set()
    assert check.warnings(8, empty=0) == []


def test_one_image_tells_a_copy_from_a_far_scene() -> None:
    left, right = _pair(1)
    ok, coded = cv2.imencode(".jpg", left, [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    assert one_image(left, left.copy())
    assert one_image(left, cv2.imdecode(coded, cv2.IMREAD_GRAYSCALE))  # republished as JPEG
    assert not one_image(left, _far(left, 0.5))  # a scene beyond range, 0.5 px
    assert not one_image(left, _far(left, 0.2))
    assert not one_image(left, np.clip(left.astype(np.int16) + 2, 0, 255).astype(np.uint8))
    assert not one_image(left, right)


def test_a_re_encoded_copy_mid_log_is_still_caught() -> None:
    check = StaleRight()
    for index in range(5):
        left, right = _pair(index)
        if index == 3:
            _, coded = cv2.imencode(".jpg", left, [cv2.IMWRITE_JPEG_QUALITY, 90])
            right = cv2.imdecode(coded, cv2.IMREAD_GRAYSCALE)
        check.check(_frame(index, left, right))
    assert check.stale == {3}


def test_a_log_swapped_from_the_start_is_left_to_the_row_check() -> None:
    check = StaleRight()
    for index in range(3):
        left, right = _pair(index)
        check.check(_frame(index, right, left))
    assert check.stale == set()
    assert check.warnings(3, empty=0) == []


def test_clean_frames_pass_without_a_line() -> None:
    check = StaleRight()
    for index in range(6):
        left, right = _pair(index)
        assert check.check(_frame(index, left, right)).right is right
    assert check.warnings(6, empty=0) == []


def test_rows_drifting_apart_mid_log_are_warned_of_once() -> None:
    # before: the row offset was checked on the first frames only
    check = StaleRight()
    for index in range(10):
        left, right = _pair(index, drop=3 if index >= 5 else 0)
        assert check.check(_frame(index, left, right)).right is right  # kept: estimated
    (line,) = check.warnings(10, empty=0)
    assert line.startswith("from frame 6 the matched corners are 3.0 px apart vertically")
    assert "(frame 4 was within it)" in line
    assert "the calibration has drifted" in line


def test_frame_ranges() -> None:
    assert frame_ranges([7, 3, 5, 6]) == "3, 5-7"
    assert frame_ranges(list(range(0, 30, 2))) == "0, 2, 4, 6, 8, 10, ..."


class _CountingRect:
    """The watch's ``rect`` module, counting the corner matches the watch runs itself."""

    def __init__(self) -> None:
        self.calls = 0

    def correspondences(self, *args: Any) -> npt.NDArray[np.float64]:
        self.calls += 1
        return rect.correspondences(*args)

    def __getattr__(self, name: str) -> Any:
        return getattr(rect, name)


def test_densify_takes_the_first_row_offset_from_the_row_check(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # before: the watch matched frame 0's corners (~55 ms a KITTI pair) although the row
    # check had just matched the same frame's; a log shorter than 5 s has no other check
    log = tmp_path / "small.mcap"
    synth(log, frames=3, seed=3, scale=0.25, fmt="mcap")
    counting = _CountingRect()
    monkeypatch.setattr(pair_watch, "rect", counting)
    summary = densify(log, tmp_path / "out.mcap")
    assert summary.frames == 3
    assert summary.pairing.row_check_undecided is None  # the row check matched and passed
    assert counting.calls == 0


_CALIBRATION = raw_calibration(
    StereoCamera(width=WIDTH, height=HEIGHT, fx=200.0, fy=200.0, cx=199.0, cy=99.0, baseline=0.5),
    "plumb_bob",
)
IDEAL = rect.StereoCalibration(  # a rectified pair's own: K = P[:3, :3], D = 0, R = I
    *(
        rect.CameraCalibration(
            c.width, c.height, "plumb_bob", c.p[:, :3], np.zeros(5), np.eye(3), c.p
        )
        for c in (_CALIBRATION.left, _CALIBRATION.right)
    )
)


def _paired(pairs: list[tuple[Any, Any]], *, seeded: bool) -> StaleRight:
    """Pair the images (a frame every 3 s, row check on) and watch each frame as densify does."""
    pairer = StereoPairer(
        PairingConfig(
            left_topic="/l/image_rect",
            right_topic="/r/image_rect",
            left_info_topic="/l/camera_info",
            right_info_topic="/r/camera_info",
        )
    )
    check = StaleRight()
    assert check.watch is not None
    if seeded:
        check.watch.row_corners = pairer.row_corners
    for index, (left, right) in enumerate(pairs):
        stamp = (index + 1) * 3 * SECOND
        messages = {
            "/l/camera_info": camera_info_message(IDEAL.left, stamp, "l"),
            "/r/camera_info": camera_info_message(IDEAL.right, stamp, "r"),
            "/l/image_rect": rosmsg.image_message(left, stamp, "l"),
            "/r/image_rect": rosmsg.image_message(right, stamp, "l"),
        }
        for topic, message in messages.items():
            for frame in pairer.push(topic, stamp, stamp, message):
                assert check.check(frame).right is frame.right  # kept: estimated
    for frame in pairer.flush():
        check.check(frame)
    pairer.finish()
    return check


@pytest.mark.parametrize("dark", [0, 2])
def test_drifted_rows_are_warned_of_against_the_row_checks_corners(dark: int) -> None:
    # the reference the drift is measured from is the row check's corners of the watch's
    # first frame (after dark start-up frames too, which neither measures): same warning
    black = np.zeros((HEIGHT, WIDTH), np.uint8)
    pairs = [(black, black)] * dark + [_pair(i, drop=3 if i >= 5 else 0) for i in range(10)]
    lines = {}
    for seeded in (False, True):
        check = _paired(pairs, seeded=seeded)
        assert check.watch is not None
        checks = len(range(0, 10, 2))  # every other frame: one per 5 s of log
        assert check.watch.corner_matches == checks - seeded
        (lines[seeded],) = check.warnings(10 + dark, empty=0)
    assert lines[True] == lines[False]
    assert lines[True].startswith(
        f"from frame {6 + dark} the matched corners are 3.0 px apart vertically, 3.0 px more "
        f"than on the first frames (frame {4 + dark} was within it); in 2 of 4 checks"
    )


def test_a_16_bit_pair_is_matched_by_the_watch_itself() -> None:
    # the row check's 8-bit images (each scaled by its maximum) are not the watch's (both
    # scaled by one percentile): its corners are not taken
    def refuse(index: int) -> None:
        raise AssertionError(f"asked for frame {index}'s corners")

    watch = PairWatch(row_corners=refuse)
    left, right = _pair(1)
    wide = left.astype(np.uint16) * 200, right.astype(np.uint16) * 200
    assert not watch.broken(_frame(0, *wide))  # type: ignore[arg-type]
    assert watch.corner_matches == 1
    watch.close()
