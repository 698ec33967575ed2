"""KITTI raw drives of unrectified images (``_extract``) and image sizes the calibration
does not describe (bug hunt 12B F7): written as a raw log that densify rectifies, or refused."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from pcainterp_stream import cli
from pcainterp_stream.errors import DatasetImportError
from pcainterp_stream.frontend.rectify import StereoRectifier
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.calibration import kitti_calibration
from pcainterp_stream.io.camera_model import CameraCalibration, StereoCalibration
from pcainterp_stream.io.kitti import _pair_by_stamp, import_kitti, iter_frames, open_kitti
from pcainterp_stream.io.raw_log import Unrectifier

REALDATA = Path(__file__).resolve().parents[3] / "shared" / "realdata"
DATE = REALDATA / "kitti_raw" / "2011_09_26"
SYNC = DATE / "2011_09_26_drive_0001_sync"
ODOMETRY = REALDATA / "kitti_odometry_clip" / "sequences" / "a"
needs_realdata = pytest.mark.skipif(not DATE.is_dir(), reason=f"no real KITTI at {DATE}")

RAW_W, RAW_H = 40, 24  # S_00: the unrectified images
RECT_W, RECT_H = 36, 20  # S_rect_00
# the real R_rect of 2011_09_26 (rotations to 1e-6), a small lens
R_RECT = {
    "00": [
        *(0.9999239, 0.00983776, -0.007445048),
        *(-0.009869795, 0.9999421, -0.004278459),
        *(0.007402527, 0.004351614, 0.9999631),
    ],
    "01": [
        *(0.9996878, -0.008976826, 0.02331651),
        *(0.008876121, 0.9999508, 0.004418952),
        *(-0.02335503, -0.004210612, 0.9997184),
    ],
}
K = {"00": [30.0, 0, 20.0, 0, 29.5, 12.0, 0, 0, 1], "01": [30.5, 0, 20.5, 0, 30.0, 11.5, 0, 0, 1]}
D = {"00": [-0.37, 0.2, 0.002, 0.001, -0.07], "01": [-0.36, 0.18, 0.001, -0.0006, -0.05]}
P = {
    "00": [25.0, 0, 17.5, 0, 0, 25.0, 9.5, 0, 0, 0, 1, 0],
    "01": [25.0, 0, 17.5, -13.5, 0, 25.0, 9.5, 0, 0, 0, 1, 0],
}
T0 = 1_293_883_200_000_000_000  # 2011-01-01 12:00:00 UTC


def _numbers(values: list[float]) -> str:
    return " ".join(f"{v:e}" for v in values)


def _calib(raw: tuple[int, int] = (RAW_W, RAW_H), rect: tuple[int, int] = (RECT_W, RECT_H)) -> str:
    lines = ["calib_time: 01-Jan-2011 00:00:00"]
    for cam in ("00", "01"):
        lines += [
            f"S_{cam}: {raw[0]:e} {raw[1]:e}",
            f"K_{cam}: {_numbers(K[cam])}",
            f"D_{cam}: {_numbers(D[cam])}",
            f"S_rect_{cam}: {rect[0]:e} {rect[1]:e}",
            f"R_rect_{cam}: {_numbers(R_RECT[cam])}",
            f"P_rect_{cam}: {_numbers(P[cam])}",
        ]
    return "\n".join(lines) + "\n"


def _stamp_line(ns: int) -> str:
    seconds, rest = divmod(ns - T0, 1_000_000_000)
    return f"2011-01-01 12:00:{seconds:02d}.{rest:09d}"


def make_extract(
    root: Path, left_ns: list[int], right_ns: list[int], *, size: tuple[int, int] = (RAW_H, RAW_W)
) -> Path:
    """root/2011_01_01/2011_01_01_drive_0007_extract, each camera its own stamps."""
    date = root / "2011_01_01"
    drive = date / "2011_01_01_drive_0007_extract"
    rng = np.random.default_rng(7)
    for camera, stamps in (("image_00", left_ns), ("image_01", right_ns)):
        (drive / camera / "data").mkdir(parents=True)
        for i in range(len(stamps)):
            image = rng.integers(0, 256, size=size, dtype=np.uint8)
            assert cv2.imwrite(str(drive / camera / "data" / f"{i:010d}.png"), image)
        text = "".join(_stamp_line(ns) + "\n" for ns in stamps)
        (drive / camera / "timestamps.txt").write_text(text)
    (date / "calib_cam_to_cam.txt").write_text(_calib())
    return drive


def _read(path: Path) -> list[tuple[str, int, object]]:
    with AnyReader([path], default_typestore=rosmsg.TYPESTORE) as reader:
        return [(c.topic, t, reader.deserialize(d, c.msgtype)) for c, t, d in reader.messages()]


def test_unrectified_drive_is_written_raw_with_its_cameras(tmp_path: Path) -> None:
    # was: /stereo/left/image_rect with D = 0, K = P_rect_00 in the 40x24 raw images
    period = 103_000_000
    left = [T0 + i * period for i in range(5)]
    # the right camera's own stamps, 2.7 ms and 0.9 ms off; its frame 2 was dropped
    right = [left[0] + 2_700_000, left[1] - 900_000, left[3] + 1_000, left[4]]
    drive = make_extract(tmp_path, left, right)
    out = tmp_path / "raw.mcap"
    assert cli.main(["import-kitti", str(drive.parent), str(out)]) == 0  # the date folder
    read = _read(out)
    topics = {topic for topic, _, _ in read}
    assert topics == {
        "/camera/left/image_raw",
        "/camera/right/image_raw",
        "/camera/left/camera_info",
        "/camera/right/camera_info",
    }
    kept = [left[i] for i in (0, 1, 3, 4)]  # left 2 has no right image
    for topic in topics:
        messages = [(t, m) for name, t, m in read if name == topic]
        assert [t for t, _ in messages] == kept
        assert [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in messages] == kept
    for side, cam in (("left", "00"), ("right", "01")):
        info = next(m for name, _, m in read if name == f"/camera/{side}/camera_info")
        assert (info.width, info.height, info.distortion_model) == (RAW_W, RAW_H, "plumb_bob")
        np.testing.assert_allclose(info.k, K[cam])
        np.testing.assert_allclose(info.d, D[cam])
        np.testing.assert_allclose(info.r, R_RECT[cam])
        np.testing.assert_allclose(info.p, P[cam])
    images = [m for name, _, m in read if name == "/camera/right/image_raw"]
    expected = cv2.imread(str(drive / "image_01" / "data" / "0000000002.png"), 0)
    np.testing.assert_array_equal(rosmsg.image_array(images[2]), expected)  # left 3's partner
    sequence = open_kitti(drive)
    assert sequence.unpaired == (1, 0)
    assert sequence.lens is not None
    assert sequence.lens.left.image_size() == (RAW_W, RAW_H)


def test_pairing_by_stamp_leaves_out_what_has_no_partner() -> None:
    left = np.array([0, 100, 200, 300, 400, 500], dtype=np.int64) * 1_000_000
    right = np.array([2, 99, 230, 301, 405, 470, 510], dtype=np.int64) * 1_000_000
    # 230 is 30 ms off (> a quarter frame); 470 and 510: 500's nearest is 510
    assert _pair_by_stamp(left, right) == [(0, 0), (1, 1), (3, 3), (4, 4), (5, 6)]
    assert _pair_by_stamp(left, right[:0]) == []


def test_images_of_neither_calibrated_size_are_refused(tmp_path: Path) -> None:
    drive = make_extract(tmp_path, [T0], [T0], size=(RAW_H // 2, RAW_W // 2))
    with pytest.raises(
        DatasetImportError,
        match=r"image .*0000000000\.png is 20x12 but calibration file .*calib_cam_to_cam\.txt "
        r"is for images of S_rect_00 36x20, S_00 40x24",
    ):
        open_kitti(drive)


def test_without_s_rect_the_principal_point_checks_the_size(tmp_path: Path) -> None:
    # a calibration written by hand, without S_rect_00: raw-size images are still raw ones;
    # others far off P_rect_00's principal point are imported with a warning (review 59b F1)
    drive = make_extract(tmp_path, [T0], [T0])
    calib = drive.parent / "calib_cam_to_cam.txt"
    calib.write_text("".join(x for x in calib.read_text().splitlines(True) if "S_rect_00" not in x))
    assert open_kitti(drive).lens is not None
    for camera in ("image_00", "image_01"):  # 36x20 suits P_rect_00 (cx 17.5, cy 9.5)
        cv2.imwrite(str(drive / camera / "data" / "0000000000.png"), np.zeros((20, 36), np.uint8))
    assert open_kitti(drive).lens is None
    assert open_kitti(drive).warnings == ()
    for camera in ("image_00", "image_01"):  # 36x40: cy 9.5 is 26 % of the height off
        cv2.imwrite(str(drive / camera / "data" / "0000000000.png"), np.zeros((40, 36), np.uint8))
    (warning,) = open_kitti(drive).warnings
    assert warning.startswith("P_rect_00 of calibration file ")
    assert "(17.5, 9.5), 26% of the image off its centre (36x40, first image " in warning


def _kitti_raw_size_drive(root: Path) -> Path:
    """A _sync drive of 1392x512 images whose calibration has P_rect but neither S_ line."""
    drive = root / "2011_09_26" / "2011_09_26_drive_0001_sync"
    for camera in ("image_00", "image_01"):
        (drive / camera / "data").mkdir(parents=True)
        image = np.zeros((512, 1392), np.uint8)
        assert cv2.imwrite(str(drive / camera / "data" / "0000000000.png"), image)
    p0 = [721.5377, 0, 609.5593, 0, 0, 721.5377, 172.854, 0, 0, 0, 1, 0]
    p1 = [*p0[:3], -387.5744, *p0[4:]]
    (drive.parent / "calib_cam_to_cam.txt").write_text(
        f"P_rect_00: {_numbers(p0)}\nP_rect_01: {_numbers(p1)}\n"
    )
    return drive


def test_kitti_raw_size_with_its_rectified_calibration_is_refused(tmp_path: Path) -> None:
    # KITTI's unrectified 1392x512 images with P_rect (cy 172.9: 16 % off) and no size lines
    with pytest.raises(
        DatasetImportError,
        match=r"image .*0000000000\.png is 1392x512 but P_rect_00 of calibration file "
        r".*calib_cam_to_cam\.txt puts the principal point at \(609\.6, 172\.9\), 16% of the "
        r"image off its centre: these are KITTI's unrectified images",
    ):
        open_kitti(_kitti_raw_size_drive(tmp_path))


def _kitti360_odometry(root: Path, frames: int = 3) -> Path:
    """KITTI-360's rectified perspective pair (perspective.txt P_rect_00/01: 1408x376,
    cy 238.77, 13.5 % off centre) in the odometry layout, as SLAM tools convert it."""
    sequence = root / "sequences" / "00"
    rng = np.random.default_rng(3)
    for camera in ("image_0", "image_1"):
        (sequence / camera).mkdir(parents=True)
    for i in range(frames):
        image = rng.integers(0, 256, size=(376, 1408), dtype=np.uint8)
        assert cv2.imwrite(str(sequence / "image_0" / f"{i:06d}.png"), image)
        assert cv2.imwrite(str(sequence / "image_1" / f"{i:06d}.png"), np.roll(image, -20, 1))
    f, cx, cy, baseline = 552.554261, 682.049453, 238.769549, 0.5943
    p0 = [f, 0, cx, 0, 0, f, cy, 0, 0, 0, 1, 0]
    p1 = [*p0[:3], -f * baseline, *p0[4:]]
    (sequence / "calib.txt").write_text(f"P0: {_numbers(p0)}\nP1: {_numbers(p1)}\n")
    return sequence


def test_kitti360_rectified_pair_imports_with_a_warning(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # review 59b F1: refused before ("these are not the rectified images it describes")
    sequence = _kitti360_odometry(tmp_path)
    out = tmp_path / "k360.mcap"
    assert cli.main(["import-kitti", str(sequence), str(out)]) == 0
    err = capsys.readouterr().err
    warnings = [line for line in err.splitlines() if line.startswith("warning: ")]
    assert warnings == [
        f"warning: P0 of calibration file {sequence / 'calib.txt'} puts the principal point at "
        f"(682.0, 238.8), 14% of the image off its centre (1408x376, first image "
        f"{sequence / 'image_0' / '000000.png'}): imported as the rectified camera it "
        "describes (KITTI-360's is 13.5 % off, a crop's may be); if these images are resized "
        "or not rectified, the depths are wrong"
    ]
    assert "error" not in err
    camera = open_kitti(sequence).camera
    assert (camera.width, camera.height, camera.cy) == (1408, 376, pytest.approx(238.769549))
    assert sum(1 for topic, _, _ in _read(out) if topic.endswith("image_rect")) == 6


def test_a_calibration_without_the_raw_cameras_is_refused(tmp_path: Path) -> None:
    drive = make_extract(tmp_path, [T0], [T0])
    calib = drive.parent / "calib_cam_to_cam.txt"
    calib.write_text("".join(x for x in calib.read_text().splitlines(True) if "D_01" not in x))
    with pytest.raises(DatasetImportError, match=r"unrectified images.*misses or garbles camera"):
        open_kitti(drive)


def test_odometry_images_off_their_principal_point_are_refused(tmp_path: Path) -> None:
    sequence = tmp_path / "sequences" / "00"
    for camera in ("image_0", "image_1"):
        (sequence / camera).mkdir(parents=True)
        assert cv2.imwrite(str(sequence / camera / "000000.png"), np.zeros((512, 1392), np.uint8))
    p0 = [707.0912, 0, 601.8873, 0, 0, 707.0912, 183.1104, 0, 0, 0, 1, 0]
    p1 = [*p0[:3], -379.8145, *p0[4:]]
    (sequence / "calib.txt").write_text(f"P0: {_numbers(p0)}\nP1: {_numbers(p1)}\n")
    with pytest.raises(
        DatasetImportError,
        match=r"image .*000000\.png is 1392x512 but P0 of calibration file .*calib\.txt puts the "
        r"principal point at \(601\.9, 183\.1\), 14% of the image off its centre",
    ):
        open_kitti(sequence)


@needs_realdata
@pytest.mark.realdata
def test_real_odometry_clip_and_sync_drive_pass_the_size_checks() -> None:
    assert open_kitti(ODOMETRY).camera.image_size == (370, 1226)
    sequence = open_kitti(SYNC)
    assert sequence.lens is None
    assert sequence.camera.image_size == (375, 1242)


@needs_realdata
@pytest.mark.realdata
def test_real_sync_drive_resized_to_the_raw_size_without_s_rect_match(tmp_path: Path) -> None:
    # bug hunt 12B F7's repro: a _sync drive whose images are not S_rect_00's size
    drive = tmp_path / "2011_09_26" / "2011_09_26_drive_0001_sync"
    for camera in ("image_00", "image_01"):
        (drive / camera / "data").mkdir(parents=True)
        image = cv2.imread(str(SYNC / camera / "data" / "0000000000.png"), 0)
        cv2.imwrite(str(drive / camera / "data" / "0000000000.png"), cv2.resize(image, (1300, 400)))
    shutil.copy(DATE / "calib_cam_to_cam.txt", drive.parent)
    with pytest.raises(DatasetImportError, match=r"is 1300x400 but .* S_rect_00 1242x375, S_00"):
        open_kitti(drive)


@needs_realdata
@pytest.mark.realdata
def test_real_extract_drive_rectifies_onto_the_rectified_drive(tmp_path: Path) -> None:
    # raw images rendered from the real rectified drive with its own K_0x, D_0x, R_rect_0x,
    # P_rect_0x; imported as an _extract drive with each camera's real stamps, the camera
    # infos written rectify them back onto the rectified images, rows aligned
    frames = 3
    drive = tmp_path / "2011_09_26" / "2011_09_26_drive_0001_extract"
    drive.mkdir(parents=True)
    shutil.copy2(DATE / "calib_cam_to_cam.txt", drive.parent)
    unrectify = Unrectifier(kitti_calibration(DATE / "calib_cam_to_cam.txt"))
    rectified = list(iter_frames(open_kitti(SYNC), max_frames=frames))
    for camera in ("image_00", "image_01"):
        (drive / camera / "data").mkdir(parents=True)
        stamps = (SYNC / camera / "timestamps.txt").read_text().splitlines()[:frames]
        (drive / camera / "timestamps.txt").write_text("\n".join(stamps) + "\n")
    for frame in rectified:
        name = f"{frame.frame_index:010d}.png"
        for camera, image in zip(
            ("image_00", "image_01"), unrectify(frame.left, frame.right), strict=True
        ):
            cv2.imwrite(str(drive / camera / "data" / name), image)
    out = tmp_path / "raw.mcap"
    import_kitti(drive, out)
    read = _read(out)
    infos = [m for name, _, m in read if name.endswith("camera_info")][:2]
    calibration = StereoCalibration(
        *(
            CameraCalibration.from_camera_info(info, name)
            for info, name in zip(infos, "lr", strict=True)
        )
    )
    rectifier = StereoRectifier(calibration)
    lefts = [rosmsg.image_array(m) for name, _, m in read if name == "/camera/left/image_raw"]
    rights = [rosmsg.image_array(m) for name, _, m in read if name == "/camera/right/image_raw"]
    assert len(lefts) == len(rights) == frames  # real stamps up to 0.9 ms apart: all paired
    for frame, left, right in zip(rectified, lefts, rights, strict=True):
        for raw, side, expected in ((left, "left", frame.left), (right, "right", frame.right)):
            back = rectifier.rectify_one(raw, side)[20:355, 40:1200].astype(np.float32)
            truth = expected[20:355, 40:1200].astype(np.float32)
            (dx, dy), _ = cv2.phaseCorrelate(back, truth)
            assert abs(dy) < 0.05, (side, dy)  # rows: 0.01 px measured
            assert abs(dx) < 0.05, (side, dx)
            assert float(np.mean(np.abs(back - truth))) < 3.0  # 1.5 grey levels measured
