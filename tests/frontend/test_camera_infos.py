"""The camera infos of a log read ahead of its stream, and whether two say the same."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from pcainterp_stream.errors import CalibrationError
from pcainterp_stream.frontend.camera_infos import (
    calibration_values,
    camera_from_infos,
    first_infos,
)
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.records import StereoCamera

CAMERA = StereoCamera(width=8, height=6, fx=50.0, fy=51.0, cx=4.0, cy=3.0, baseline=0.25)
INFOS = ["/s/left/camera_info", "/s/right/camera_info"]


def _late_log(path: Path, fmt: str) -> Path:
    """Five images, then the camera infos (from 0.5 s of log on)."""
    with open_writer(path, fmt) as writer:
        for index in range(5):
            stamp = index * 100_000_000
            image = rosmsg.image_message(np.zeros((6, 8), np.uint8), stamp, "left")
            writer.add_message("/s/left/image_rect", image, stamp)
        for index, stamp in enumerate((500_000_000, 600_000_000)):
            camera = dataclasses.replace(CAMERA, baseline=0.25 + index)
            writer.add_message(INFOS[0], rosmsg.camera_info_message(camera, stamp, "l"), stamp)
            info = rosmsg.camera_info_message(camera, stamp, "r", right=True)
            writer.add_message(INFOS[1], info, stamp)
    return path


@pytest.mark.parametrize(("name", "fmt"), [("late.mcap", "mcap"), ("late.bag", "ros1")])
def test_first_infos_of_an_indexed_log(tmp_path: Path, name: str, fmt: str) -> None:
    with open_log(_late_log(tmp_path / name, fmt)) as reader:
        assert reader.indexed()
        found = first_infos(reader, INFOS)
        # the stream reads from the start afterwards, as if nothing had been read
        assert sum(1 for _ in reader.messages()) == 9
    assert [(topic, log_time_ns) for topic, log_time_ns, _ in found] == [
        (INFOS[0], 500_000_000),
        (INFOS[1], 500_000_000),
    ]
    assert rosmsg.projection_matrix(found[1][2])[0, 3] == pytest.approx(-50.0 * 0.25)


def test_no_look_ahead_without_an_index(tmp_path: Path) -> None:
    # a rosbag2 SQLite log would be read from the start to find them
    with open_log(_late_log(tmp_path / "late", "rosbag2-sqlite3")) as reader:
        assert not reader.indexed()
        assert first_infos(reader, INFOS) == []


def test_a_topic_without_an_info_is_left_out(tmp_path: Path) -> None:
    with open_log(_late_log(tmp_path / "late.mcap", "mcap")) as reader:
        found = first_infos(reader, [INFOS[0], "/other/camera_info"])
    assert [topic for topic, _, _ in found] == [INFOS[0]]


def test_calibration_values_tell_another_calibration_not_another_stamp() -> None:
    first = rosmsg.camera_info_message(CAMERA, 0, "r", right=True)
    later = rosmsg.camera_info_message(CAMERA, 10**9, "r", right=True)
    wider = rosmsg.camera_info_message(
        dataclasses.replace(CAMERA, baseline=0.3), 0, "r", right=True
    )
    assert calibration_values(first) == calibration_values(later)
    assert calibration_values(first) != calibration_values(wider)


def test_a_negative_baseline_says_the_sides_look_swapped_not_pass_baseline() -> None:
    """Bug hunt 7A: the infos of a pair given the wrong way round (the right camera's info as
    the left one) give a negative baseline, a sign problem ``--baseline`` cannot fix."""
    left = rosmsg.camera_info_message(CAMERA, 0, "l")
    right = rosmsg.camera_info_message(CAMERA, 0, "r", right=True)
    topics = {"left_topic": INFOS[1], "right_topic": INFOS[0]}  # the two exchanged
    images = ("/s/right/image_rect", "/s/left/image_rect")
    with pytest.raises(CalibrationError) as caught:
        camera_from_infos(right, left, width=8, height=6, **topics, image_topics=images)
    message = str(caught.value)
    assert message.startswith(f"camera info on {INFOS[0]} gives no baseline (P[0,3] = 0.0")
    assert f"the sides look swapped ({INFOS[0]}'s camera lies left of {INFOS[1]}'s)" in message
    assert (
        "if the images are swapped too, pass --left-topic /s/left/image_rect --right-topic "
        "/s/right/image_rect (each with its own camera info); if only the infos are crossed, "
        f"pass --left-info-topic {INFOS[0]} --right-info-topic {INFOS[1]}"
    ) in message
    assert "--baseline" not in message
    with pytest.raises(
        CalibrationError, match=r"swapped.*too, exchange --left-topic and --right-topic \(each"
    ):
        camera_from_infos(right, left, width=8, height=6, **topics)
    # no Tx at all is no sign problem: --baseline is the fix there
    with pytest.raises(CalibrationError, match=r"finite\); pass --baseline METRES$"):
        camera_from_infos(left, left, width=8, height=6)


def _vertical_infos() -> tuple[object, object]:
    """A rectified pair stacked vertically: the right (lower) P has Ty = -fy * b, Tx = 0."""
    left = rosmsg.camera_info_message(CAMERA, 0, "l")
    right = rosmsg.camera_info_message(CAMERA, 0, "r")
    p = np.array(right.p, dtype=np.float64).reshape(3, 4)
    p[1, 3] = CAMERA.fy * CAMERA.baseline
    return left, dataclasses.replace(right, p=p.reshape(-1))


@pytest.mark.parametrize("baseline", [None, 0.25])
def test_a_pair_stacked_vertically_is_named_so(baseline: float | None) -> None:
    """Bug hunt 15A F2: 'gives no baseline ... pass --baseline', then 'not rectified'."""
    left, right = _vertical_infos()
    with pytest.raises(CalibrationError) as err:
        camera_from_infos(
            left, right, width=8, height=6, right_topic="/s/right/camera_info", baseline=baseline
        )
    assert str(err.value).startswith(
        "camera info on /s/right/camera_info has P[1,3] = 12.75 and P[0,3] = 0: the cameras "
        "are stacked vertically (baseline mostly along y); only side-by-side stereo pairs are "
        "supported"
    )
    assert "\n" not in str(err.value)


def test_discovery_reads_a_vertical_pairs_ty_as_its_translation(tmp_path: Path) -> None:
    """Not Tx = 0 on both infos, 'as two monocular cameras have' (bug hunt 15A F2)."""
    from pcainterp_stream.frontend.stream_kinds import first_tx

    left, right = _vertical_infos()
    with open_writer(tmp_path / "v.mcap", "mcap") as writer:
        writer.add_message(INFOS[0], left, 1)
        writer.add_message(INFOS[1], right, 1)
    with open_log(tmp_path / "v.mcap") as reader:
        tx = first_tx(reader)
        assert tx(INFOS[0]) == 0.0
        assert tx(INFOS[1]) == pytest.approx(12.75)


def _ty_infos(ty: float, tx: float = 0.0) -> tuple[object, object]:
    """A side-by-side rectified pair whose right P has Ty = ``ty`` and Tx = ``tx`` (px*m)."""
    left = rosmsg.camera_info_message(CAMERA, 0, "l")
    right = rosmsg.camera_info_message(CAMERA, 0, "r")
    p = np.array(right.p, dtype=np.float64).reshape(3, 4)
    p[0, 3], p[1, 3] = tx, ty
    return left, dataclasses.replace(right, p=p.reshape(-1))


@pytest.mark.parametrize("ty", [0.001, -0.05, 0.9])
def test_a_noise_ty_with_no_tx_is_no_vertical_pair(ty: float) -> None:
    """Review 15a R1: Tx = 0 and Ty = 0.001 was 'stacked vertically', --baseline or not."""
    left, right = _ty_infos(ty)
    topic = "/s/right/camera_info"
    camera = camera_from_infos(left, right, width=8, height=6, right_topic=topic, baseline=0.3)
    assert camera.baseline == 0.3
    with pytest.raises(CalibrationError) as err:  # the advice that fixes it
        camera_from_infos(left, right, width=8, height=6, right_topic=topic)
    assert str(err.value).startswith(f"camera info on {topic} gives no baseline (P[0,3] = 0.0")
    assert str(err.value).endswith("pass --baseline METRES")


def test_a_ty_small_beside_the_baseline_given_is_no_vertical_pair() -> None:
    """With --baseline 0.25 (fx * b = 12.5 px*m) a Ty of 3 px*m is a side-by-side pair's."""
    left, right = _ty_infos(3.0)
    camera = camera_from_infos(left, right, width=8, height=6, baseline=0.25)
    assert camera.baseline == 0.25
    with pytest.raises(CalibrationError, match="stacked vertically"):  # no --baseline: a rig's
        camera_from_infos(left, right, width=8, height=6)
    with pytest.raises(CalibrationError, match="stacked vertically"):  # Ty = fx * b: a rig's
        camera_from_infos(*_ty_infos(12.5), width=8, height=6, baseline=0.25)


def test_discovery_takes_no_noise_ty_for_a_translation(tmp_path: Path) -> None:
    """Review 15a R1: first_tx read Ty = 0.001 of a Tx = 0 info as the pair's translation."""
    from pcainterp_stream.frontend.stream_kinds import first_tx

    left, right = _ty_infos(0.001)
    with open_writer(tmp_path / "n.mcap", "mcap") as writer:
        writer.add_message(INFOS[0], left, 1)
        writer.add_message(INFOS[1], right, 1)
    with open_log(tmp_path / "n.mcap") as reader:
        assert first_tx(reader)(INFOS[1]) == 0.0
