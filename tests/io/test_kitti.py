from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from pcainterp_stream import cli
from pcainterp_stream.errors import DatasetImportError, LogWriteError
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.kitti import (
    KittiLayout,
    KittiPair,
    import_kitti,
    iter_frames,
    open_kitti,
)
from pcainterp_stream.io.logwriter import LogFormat

REALDATA = Path(__file__).resolve().parents[3] / "shared" / "realdata"
RAW_DRIVE = REALDATA / "kitti_raw" / "2011_09_26" / "2011_09_26_drive_0001_sync"
ODOMETRY = REALDATA / "kitti_odometry_clip" / "sequences" / "a"
COLOUR_07 = REALDATA / "kitti_depth_annotated_07"  # KITTI's colour odometry layout
needs_realdata = pytest.mark.skipif(
    not REALDATA.is_dir(), reason=f"real KITTI data not found at {REALDATA}"
)

HEIGHT, WIDTH = 6, 10
FX, CX, CY, TX = 100.0, 4.5, 2.5, -54.0  # baseline 0.54 m
P_LEFT = [FX, 0, CX, 0, 0, FX, CY, 0, 0, 0, 1, 0]
P_RIGHT = [FX, 0, CX, TX, 0, FX, CY, 0, 0, 0, 1, 0]


def _numbers(values: list[float]) -> str:
    return " ".join(f"{v:e}" for v in values)


def _write_images(folder: Path, names: list[str], seed: int) -> list[np.ndarray]:
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    images = []
    for name in names:
        image = rng.integers(0, 256, size=(HEIGHT, WIDTH), dtype=np.uint8)
        assert cv2.imwrite(str(folder / name), image)
        images.append(image)
    return images


def make_raw(root: Path, n: int = 3, *, calib_in_drive: bool = False) -> Path:
    """A tiny raw layout: root/2011_01_01/2011_01_01_drive_0007_sync."""
    date = root / "2011_01_01"
    drive = date / "2011_01_01_drive_0007_sync"
    names = [f"{i:010d}.png" for i in range(n)]
    _write_images(drive / "image_00" / "data", names, seed=1)
    _write_images(drive / "image_01" / "data", names, seed=2)
    stamps = [f"2011-01-01 12:00:{i:02d}.{i * 1000:09d}" for i in range(n)]
    (drive / "image_00" / "timestamps.txt").write_text("\n".join(stamps) + "\n")
    calib = (
        "calib_time: 01-Jan-2011 00:00:00\n"
        f"S_rect_00: {WIDTH} {HEIGHT}\n"
        f"S_rect_02: {WIDTH} {HEIGHT}\n"
        f"P_rect_00: {_numbers(P_LEFT)}\n"
        f"P_rect_01: {_numbers(P_RIGHT)}\n"
    )
    ((drive if calib_in_drive else date) / "calib_cam_to_cam.txt").write_text(calib)
    return drive


def make_odometry(root: Path, n: int = 4, *, times: bool = True, poses: bool = True) -> Path:
    """A tiny odometry layout: root/sequences/05 and root/poses/05.txt."""
    sequence = root / "sequences" / "05"
    names = [f"{i:06d}.png" for i in range(n)]
    _write_images(sequence / "image_0", names, seed=3)
    _write_images(sequence / "image_1", names, seed=4)
    (sequence / "calib.txt").write_text(
        f"P0: {_numbers(P_LEFT)}\nP1: {_numbers(P_RIGHT)}\nP2: {_numbers(P_LEFT)}\n"
    )
    if times:
        (sequence / "times.txt").write_text("".join(f"{0.1037 * i:e}\n" for i in range(n)))
    if poses:
        (root / "poses").mkdir()
        lines = [_numbers([1, 0, 0, 0.1 * i, 0, 1, 0, 0, 0, 0, 1, 1.0 * i]) for i in range(n)]
        (root / "poses" / "05.txt").write_text("\n".join(lines))
    return sequence


# the colour cameras: camera 2 is 6 cm left of camera 0 (P2[0, 3] > 0), camera 3 0.48 m right
P2 = [FX, 0, CX, 6.0, 0, FX, CY, 0.1, 0, 0, 1, 0.002]
P3 = [FX, 0, CX, -48.0, 0, FX, CY, 0, 0, 0, 1, 0]


def make_colour(root: Path, n: int = 3, *, grey: bool = False) -> Path:
    """A tiny odometry layout with the colour pair image_2/image_3 (and the grey one)."""
    sequence = make_odometry(root, n) if grey else root / "sequences" / "05"
    names = [f"{i:06d}.png" for i in range(n)]
    for camera, seed in ((2, 5), (3, 6)):
        folder = sequence / f"image_{camera}"
        folder.mkdir(parents=True)
        rng = np.random.default_rng(seed)
        for name in names:
            image = rng.integers(0, 256, size=(HEIGHT, WIDTH, 3), dtype=np.uint8)
            assert cv2.imwrite(str(folder / name), image)
    (sequence / "calib.txt").write_text(
        "".join(f"P{i}: {_numbers(p)}\n" for i, p in enumerate((P_LEFT, P_RIGHT, P2, P3)))
    )
    if not grey:
        (root / "poses").mkdir()
        lines = [_numbers([1, 0, 0, 0.1 * i, 0, 1, 0, 0, 0, 0, 1, 1.0 * i]) for i in range(n)]
        (root / "poses" / "05.txt").write_text("\n".join(lines))
    return sequence


def _grey(path: Path) -> np.ndarray:
    return cv2.cvtColor(cv2.imread(str(path), cv2.IMREAD_COLOR), cv2.COLOR_BGR2GRAY)


def test_odometry_colour_pair_when_the_grey_one_is_absent(tmp_path: Path) -> None:
    # refused: "is not a KITTI folder; expected ... image_0, image_1"
    sequence_dir = make_colour(tmp_path / "in")
    sequence = open_kitti(sequence_dir)
    assert (sequence.layout, sequence.pair) == (KittiLayout.ODOMETRY, KittiPair.COLOUR)
    assert sequence.left_paths[0] == sequence_dir / "image_2" / "000000.png"
    assert sequence.right_paths[0] == sequence_dir / "image_3" / "000000.png"
    assert (sequence.camera.fx, sequence.camera.cx, sequence.camera.cy) == (FX, CX, CY)
    assert sequence.camera.baseline == pytest.approx((6.0 + 48.0) / FX)
    # camera 0's pose moved to camera 2, at -K^-1 P2[:, 3] in camera 0's frame
    assert sequence.camera_to_world is not None
    p2 = np.reshape(P2, (3, 4))
    centre = -np.linalg.solve(p2[:, :3], p2[:, 3])
    np.testing.assert_allclose(sequence.camera_to_world[2][:3, 3], np.add([0.2, 0, 2.0], centre))
    assert centre[0] == pytest.approx(-0.06, abs=1e-3)
    out = tmp_path / "colour.mcap"
    assert cli.main(["import-kitti", str(sequence_dir), str(out)]) == 0
    read = _read(out)
    left = [m for topic, _, m in read if topic == "/stereo/left/image_rect"]
    expected = _grey(sequence_dir / "image_2" / "000001.png")
    np.testing.assert_array_equal(rosmsg.image_array(left[1]), expected)
    right_info = next(m for topic, _, m in read if topic == "/stereo/right/camera_info")
    p = rosmsg.projection_matrix(right_info)
    assert -p[0, 3] / p[0, 0] == pytest.approx(0.54)


def test_some_frames_of_a_sequence_take_their_lines_by_number(tmp_path: Path) -> None:
    # frames 000002-000003 beside the whole sequence's times.txt and poses (as KITTI's
    # depth-annotated sequence 07): "times.txt has 4 times for 2 images"
    sequence_dir = make_odometry(tmp_path, n=4)
    for camera in ("image_0", "image_1"):
        for name in ("000000.png", "000001.png"):
            (sequence_dir / camera / name).unlink()
    sequence = open_kitti(sequence_dir)
    assert sequence.stamps_ns.tolist() == [207_400_000, 311_100_000]
    assert sequence.camera_to_world is not None
    np.testing.assert_allclose(sequence.camera_to_world[1][:3, 3], [0.3, 0, 3.0])
    (tmp_path / "poses" / "05.txt").write_text("1 2 3\n" * 4)
    with pytest.raises(DatasetImportError, match=r"line 3 of pose file .* must hold 12 numbers"):
        open_kitti(sequence_dir)


def test_colour_option_picks_the_colour_pair_beside_the_grey_one(tmp_path: Path) -> None:
    sequence_dir = make_colour(tmp_path / "in", grey=True)
    assert open_kitti(sequence_dir).pair is KittiPair.GREY  # as before
    colour = open_kitti(sequence_dir, pair=KittiPair.COLOUR)
    assert colour.left_paths[0].parent.name == "image_2"
    assert colour.camera.baseline == pytest.approx(0.54)
    out = tmp_path / "colour.mcap"
    assert cli.main(["import-kitti", str(sequence_dir), str(out), "--colour"]) == 0
    left = next(m for topic, _, m in _read(out) if topic == "/stereo/left/image_rect")
    expected = _grey(sequence_dir / "image_2" / "000000.png")
    np.testing.assert_array_equal(rosmsg.image_array(left), expected)
    grey_only = make_odometry(tmp_path / "grey")
    with pytest.raises(
        DatasetImportError, match=r"sequence .* needs both image_2 and image_3; expected a KITTI"
    ):
        open_kitti(grey_only, pair=KittiPair.COLOUR)


def test_raw_drive_colour_pair(tmp_path: Path) -> None:
    drive = make_raw(tmp_path / "in")
    (drive / "image_00").rename(drive / "image_02")
    (drive / "image_01").rename(drive / "image_03")
    (drive / "image_02" / "timestamps.txt").write_text(
        "".join(f"2011-01-01 12:00:0{i}.000000000\n" for i in range(3))
    )
    calib = (drive.parent / "calib_cam_to_cam.txt").read_text()
    (drive.parent / "calib_cam_to_cam.txt").write_text(
        calib + f"P_rect_02: {_numbers(P2)}\nP_rect_03: {_numbers(P3)}\n"
    )
    sequence = open_kitti(drive.parent)
    assert (sequence.layout, sequence.pair, sequence.folder) == (
        KittiLayout.RAW,
        KittiPair.COLOUR,
        drive,
    )
    assert sequence.camera.baseline == pytest.approx(0.54)
    assert np.diff(sequence.stamps_ns).tolist() == [1_000_000_000, 1_000_000_000]


def _read(path: Path) -> list[tuple[str, int, object]]:
    with AnyReader([path], default_typestore=rosmsg.TYPESTORE) as reader:
        return [(c.topic, t, reader.deserialize(d, c.msgtype)) for c, t, d in reader.messages()]


@pytest.mark.parametrize("calib_in_drive", [False, True])
def test_raw_layout(tmp_path: Path, calib_in_drive: bool) -> None:
    drive = make_raw(tmp_path / "in", calib_in_drive=calib_in_drive)
    sequence = open_kitti(drive)
    assert sequence.layout == KittiLayout.RAW
    assert (sequence.camera.fx, sequence.camera.cx, sequence.camera.cy) == (FX, CX, CY)
    assert sequence.camera.baseline == pytest.approx(0.54)
    assert sequence.camera.image_size == (HEIGHT, WIDTH)
    t0 = 1_293_883_200_000_000_000  # 2011-01-01 12:00:00 UTC
    assert sequence.stamps_ns.tolist() == [t0, t0 + 1_000_001_000, t0 + 2_000_002_000]
    assert open_kitti(drive.parent).folder == drive  # a date folder with one drive
    calls: list[tuple[int, int | None]] = []
    summary = import_kitti(drive, tmp_path / "raw.mcap", progress=lambda d, t: calls.append((d, t)))
    assert calls == [(1, 3), (2, 3), (3, 3)]
    assert summary.topic_counts == {
        "/stereo/left/image_rect": 3,
        "/stereo/right/image_rect": 3,
        "/stereo/left/camera_info": 3,
        "/stereo/right/camera_info": 3,
    }
    read = _read(tmp_path / "raw.mcap")
    left = [m for topic, _, m in read if topic == "/stereo/left/image_rect"]
    expected = cv2.imread(str(drive / "image_00" / "data" / "0000000001.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(rosmsg.image_array(left[1]), expected)
    right_info = next(m for topic, _, m in read if topic == "/stereo/right/camera_info")
    np.testing.assert_allclose(rosmsg.projection_matrix(right_info).reshape(-1), P_RIGHT)
    assert [t for topic, t, _ in read if topic == "/stereo/right/image_rect"] == (
        sequence.stamps_ns.tolist()
    )


@pytest.mark.parametrize("fmt", [LogFormat.MCAP, LogFormat.ROS1])
def test_odometry_layout_with_times_and_poses(tmp_path: Path, fmt: LogFormat) -> None:
    sequence_dir = make_odometry(tmp_path / "in")
    sequence = open_kitti(sequence_dir)
    assert sequence.layout == KittiLayout.ODOMETRY
    assert sequence.stamps_ns.tolist() == [0, 103_700_000, 207_400_000, 311_100_000]
    assert sequence.camera_to_world is not None
    out = tmp_path / ("odo.mcap" if fmt == LogFormat.MCAP else "odo.bag")
    summary = import_kitti(sequence_dir, out, max_frames=3)
    assert summary.message_count == 15
    poses = [(t, m) for topic, t, m in _read(out) if topic == "/ground_truth/pose"]
    assert [t for t, _ in poses] == [0, 103_700_000, 207_400_000]
    matrix = rosmsg.pose_matrix(poses[2][1])
    np.testing.assert_allclose(matrix[:3, 3], [0.2, 0.0, 2.0])
    assert poses[2][1].header.frame_id == "world"


def test_odometry_without_times_or_poses_is_10_hz(tmp_path: Path) -> None:
    sequence = open_kitti(make_odometry(tmp_path, times=False, poses=False))
    assert sequence.stamps_ns.tolist() == [0, 100_000_000, 200_000_000, 300_000_000]
    assert sequence.camera_to_world is None
    frames = list(iter_frames(sequence, max_frames=2))
    assert [f.frame_index for f in frames] == [0, 1]
    assert frames[0].left.shape == (HEIGHT, WIDTH)
    assert frames[0].camera_to_world is None


@needs_realdata
@pytest.mark.realdata
def test_real_raw_drive(tmp_path: Path) -> None:
    sequence = open_kitti(RAW_DRIVE)
    assert (sequence.layout, len(sequence)) == (KittiLayout.RAW, 108)
    camera = sequence.camera
    assert (camera.width, camera.height) == (1242, 375)
    assert (camera.fx, camera.cx, camera.cy) == (721.5377, 609.5593, 172.854)
    assert camera.baseline == pytest.approx(387.5744 / 721.5377)
    assert sequence.stamps_ns[0] == 1_317_042_145_967_790_592  # 2011-09-26 13:02:25.967790592
    assert np.all(np.diff(sequence.stamps_ns) > 90_000_000)
    out = tmp_path / "drive.mcap"
    summary = import_kitti(RAW_DRIVE, out, max_frames=12)
    assert summary.message_count == 48
    read = _read(out)
    left = [m for topic, _, m in read if topic == "/stereo/left/image_rect"]
    expected = cv2.imread(str(sequence.left_paths[11]), cv2.IMREAD_GRAYSCALE)
    np.testing.assert_array_equal(rosmsg.image_array(left[11]), expected)


@needs_realdata
@pytest.mark.realdata
def test_real_odometry_clip(tmp_path: Path) -> None:
    out = tmp_path / "clip.mcap"
    summary = import_kitti(ODOMETRY, out)
    assert summary.topic_counts["/stereo/left/image_rect"] == 51
    assert summary.topic_counts["/ground_truth/pose"] == 51
    assert (summary.start_ns, summary.end_ns) == (0, 5_000_000_000)
    read = _read(out)
    info = next(m for topic, _, m in read if topic == "/stereo/right/camera_info")
    p = rosmsg.projection_matrix(info)
    assert (info.width, info.height) == (1226, 370)
    assert -p[0, 3] / p[0, 0] == pytest.approx(379.8145 / 707.0912)
    last_pose = [m for topic, _, m in read if topic == "/ground_truth/pose"][-1]
    first_line = (REALDATA / "kitti_odometry_clip" / "poses" / "a.txt").read_text().splitlines()
    expected = np.array(first_line[-1].split(), dtype=float).reshape(3, 4)
    np.testing.assert_allclose(rosmsg.pose_matrix(last_pose)[:3], expected, atol=1e-6)


@needs_realdata
@pytest.mark.realdata
def test_real_colour_odometry_layout(tmp_path: Path) -> None:
    if not COLOUR_07.is_dir():
        pytest.skip(f"{COLOUR_07} is absent")
    sequence = open_kitti(COLOUR_07)
    assert (sequence.layout, sequence.pair, len(sequence)) == (
        KittiLayout.ODOMETRY,
        KittiPair.COLOUR,
        3,
    )
    camera = sequence.camera
    assert (camera.width, camera.height) == (1226, 370)
    assert (camera.fx, camera.cx, camera.cy) == (707.0912, 601.8873, 183.1104)
    assert camera.baseline == pytest.approx((46.88783 + 333.4597) / 707.0912)  # P2, P3
    # frames 000168-000170 of a 1101-frame sequence: times.txt has all 1101 lines
    assert sequence.stamps_ns.tolist() == [17_467_890_000, 17_571_660_000, 17_675_510_000]
    out = tmp_path / "seq07.mcap"
    summary = import_kitti(COLOUR_07, out)
    assert summary.topic_counts["/stereo/left/image_rect"] == 3
    left = [m for topic, _, m in _read(out) if topic == "/stereo/left/image_rect"]
    expected = _grey(COLOUR_07 / "image_2" / "000170.png")
    np.testing.assert_array_equal(rosmsg.image_array(left[2]), expected)
    assert summary.topic_counts["/ground_truth/lidar_depth"] == 3
    truth = [m for topic, _, m in _read(out) if topic == "/ground_truth/lidar_depth"][1]
    png = cv2.imread(str(COLOUR_07 / "image_depth_annotated" / "000169.png"), cv2.IMREAD_UNCHANGED)
    depth = rosmsg.image_array(truth)
    np.testing.assert_array_equal(np.isfinite(depth), png > 0)
    np.testing.assert_array_equal(depth[png > 0], png[png > 0] / np.float32(256))


def _write_truth(folder: Path, names: list[str]) -> list[np.ndarray]:
    """KITTI depth-completion truth PNGs: uint16 depth * 256, 0 = no truth."""
    folder.mkdir(parents=True)
    pngs = []
    for i, name in enumerate(names):
        png = np.zeros((HEIGHT, WIDTH), dtype=np.uint16)
        png[1, 2], png[4, 7] = 256 * (5 + i) + 128, 65535  # 5.5 m + i, 255.996 m
        assert cv2.imwrite(str(folder / name), png)
        pngs.append(png)
    return pngs


def test_odometry_colour_pair_brings_its_depth_truth(tmp_path: Path) -> None:
    sequence_dir = make_colour(tmp_path / "in", n=3)
    _write_truth(sequence_dir / "image_depth_annotated", ["000000.png", "000002.png"])
    sequence = open_kitti(sequence_dir)
    assert sequence.truth_folder == sequence_dir / "image_depth_annotated"
    truths = [frame.depth_truth for frame in iter_frames(sequence)]
    assert truths[1] is None  # no truth file for that frame
    assert truths[0] is not None
    assert truths[2] is not None
    assert truths[2].dtype == np.float32
    assert (truths[2][1, 2], truths[2][4, 7]) == (6.5, np.float32(65535 / 256))
    assert np.isnan(truths[2]).sum() == HEIGHT * WIDTH - 2
    out = tmp_path / "seq.mcap"
    summary = import_kitti(sequence_dir, out)
    assert summary.topic_counts["/ground_truth/lidar_depth"] == 2
    read = [(t, m) for topic, t, m in _read(out) if topic == "/ground_truth/lidar_depth"]
    assert [t for t, _ in read] == [sequence.stamps_ns[0], sequence.stamps_ns[2]]
    message = read[0][1]
    assert (message.encoding, message.header.frame_id) == ("32FC1", "stereo_left_optical")
    np.testing.assert_array_equal(rosmsg.image_array(message), truths[0])


def test_raw_drive_truth_layout_and_the_grey_pair_leaves_it_out(tmp_path: Path) -> None:
    drive = make_raw(tmp_path / "in")
    _write_truth(drive / "proj_depth" / "groundtruth" / "image_02", ["0000000001.png"])
    grey = open_kitti(drive)  # the truth is camera 2's: not the grey pair's
    assert (grey.truth_folder, grey.unused_truth) == (
        None,
        drive / "proj_depth" / "groundtruth" / "image_02",
    )
    assert all(frame.depth_truth is None for frame in iter_frames(grey))
    (drive / "image_00").rename(drive / "image_02")
    (drive / "image_01").rename(drive / "image_03")
    calib = (drive.parent / "calib_cam_to_cam.txt").read_text()
    (drive.parent / "calib_cam_to_cam.txt").write_text(
        calib + f"P_rect_02: {_numbers(P2)}\nP_rect_03: {_numbers(P3)}\n"
    )
    colour = open_kitti(drive)
    assert colour.unused_truth is None
    assert [f.depth_truth is not None for f in iter_frames(colour)] == [False, True, False]


def test_cli_names_the_depth_truth_or_the_option_that_brings_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sequence_dir = make_colour(tmp_path / "in", n=2, grey=True)
    _write_truth(sequence_dir / "image_depth_annotated", ["000000.png", "000001.png"])
    assert cli.main(["import-kitti", str(sequence_dir), str(tmp_path / "grey.mcap")]) == 0
    out = capsys.readouterr().out
    assert "the depth truth in" in out
    assert "add --colour to import it" in out
    assert cli.main(["import-kitti", str(sequence_dir), str(tmp_path / "c.mcap"), "--colour"]) == 0
    assert "depth truth: 2 of 2 frames on /ground_truth/lidar_depth" in capsys.readouterr().out


@pytest.mark.parametrize("kind", ["8-bit", "size"])
def test_error_bad_depth_truth(tmp_path: Path, kind: str) -> None:
    sequence_dir = make_colour(tmp_path / "in", n=1)
    folder = sequence_dir / "image_depth_annotated"
    folder.mkdir()
    shape = (HEIGHT, WIDTH) if kind == "8-bit" else (HEIGHT + 1, WIDTH)
    dtype = np.uint8 if kind == "8-bit" else np.uint16
    assert cv2.imwrite(str(folder / "000000.png"), np.ones(shape, dtype=dtype))
    match = "not a 16-bit single-channel PNG" if kind == "8-bit" else "it belongs to another"
    with pytest.raises(DatasetImportError, match=rf"depth truth .*000000.png .*{match}"):
        import_kitti(sequence_dir, tmp_path / "x.mcap")
    assert not (tmp_path / "x.mcap").exists()


# --- one test per error message -------------------------------------------------------


def test_error_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(DatasetImportError, match=r"KITTI folder .*nope does not exist; expected"):
        import_kitti(tmp_path / "nope", tmp_path / "o.mcap")


def test_error_not_kitti(tmp_path: Path) -> None:
    (tmp_path / "stuff").mkdir()
    with pytest.raises(DatasetImportError, match=r"is not a KITTI folder; expected a KITTI raw"):
        open_kitti(tmp_path / "stuff")


def test_error_raw_missing_calibration(tmp_path: Path) -> None:
    drive = make_raw(tmp_path)
    (drive.parent / "calib_cam_to_cam.txt").unlink()
    with pytest.raises(DatasetImportError, match=r"no calib_cam_to_cam\.txt in .*drive_0007_sync"):
        open_kitti(drive)


def test_error_raw_missing_camera_folder(tmp_path: Path) -> None:
    drive = make_raw(tmp_path)
    for image in (drive / "image_00" / "data").iterdir():
        image.unlink()
    (drive / "image_00" / "data").rmdir()
    with pytest.raises(
        DatasetImportError,
        match=r"raw drive .* needs both image_00/data and image_01/data; restore the missing",
    ):
        open_kitti(drive)


def test_error_calibration_missing_key(tmp_path: Path) -> None:
    drive = make_raw(tmp_path)
    calib = drive.parent / "calib_cam_to_cam.txt"
    calib.write_text("\n".join(x for x in calib.read_text().splitlines() if "P_rect_01" not in x))
    with pytest.raises(DatasetImportError, match=r"calib_cam_to_cam\.txt has no P_rect_01: line"):
        open_kitti(drive)


def test_error_calibration_malformed_line(tmp_path: Path) -> None:
    sequence = make_odometry(tmp_path)
    (sequence / "calib.txt").write_text(f"P0: {_numbers(P_LEFT)}\nP1: 1 2 3 x\n")
    with pytest.raises(DatasetImportError, match=r"line 2 \(P1\) of calibration file .*12 finite"):
        open_kitti(sequence)


def test_error_odometry_missing_calibration(tmp_path: Path) -> None:
    sequence = make_odometry(tmp_path)
    (sequence / "calib.txt").unlink()
    with pytest.raises(DatasetImportError, match=r"sequence .*05 has no calib\.txt"):
        open_kitti(sequence)


def test_error_bad_baseline(tmp_path: Path) -> None:
    sequence = make_odometry(tmp_path)
    (sequence / "calib.txt").write_text(f"P0: {_numbers(P_RIGHT)}\nP1: {_numbers(P_LEFT)}\n")
    with pytest.raises(DatasetImportError, match=r"gives a baseline of -0\.54 m"):
        open_kitti(sequence)


def test_error_unequal_frame_counts(tmp_path: Path) -> None:
    sequence = make_odometry(tmp_path)
    (sequence / "image_1" / "000003.png").unlink()
    with pytest.raises(DatasetImportError, match=r"image_0 has 4 images but .*image_1 has 3"):
        open_kitti(sequence)


def test_error_mismatched_names(tmp_path: Path) -> None:
    sequence = make_odometry(tmp_path)
    (sequence / "image_1" / "000003.png").rename(sequence / "image_1" / "000009.png")
    with pytest.raises(DatasetImportError, match=r"000003\.png has no right image of the same"):
        open_kitti(sequence)


def test_error_only_one_camera(tmp_path: Path) -> None:
    sequence = make_odometry(tmp_path)
    for image in (sequence / "image_1").iterdir():
        image.unlink()
    (sequence / "image_1").rmdir()
    with pytest.raises(DatasetImportError, match="needs both image_0 and image_1"):
        open_kitti(sequence)


def test_error_no_images(tmp_path: Path) -> None:
    sequence = make_odometry(tmp_path, n=0)
    with pytest.raises(DatasetImportError, match=r"image_0 holds no \.png images"):
        open_kitti(sequence)


def test_error_unreadable_image(tmp_path: Path) -> None:
    sequence = make_odometry(tmp_path)
    (sequence / "image_1" / "000002.png").write_bytes(b"not a png")
    with pytest.raises(DatasetImportError, match=r"cannot read image .*image_1/000002\.png"):
        import_kitti(sequence, tmp_path / "o.mcap")
    assert not (tmp_path / "o.mcap").exists()


def test_error_image_size_changes(tmp_path: Path) -> None:
    sequence = make_odometry(tmp_path)
    cv2.imwrite(str(sequence / "image_0" / "000001.png"), np.zeros((4, 4), np.uint8))
    with pytest.raises(DatasetImportError, match=r"000001\.png is 4x4 but .*first image is 10x6"):
        list(iter_frames(open_kitti(sequence)))


def test_error_timestamps_count(tmp_path: Path) -> None:
    drive = make_raw(tmp_path)
    (drive / "image_00" / "timestamps.txt").write_text("2011-01-01 12:00:00.000000000\n")
    with pytest.raises(DatasetImportError, match=r"timestamps\.txt has 1 timestamps for 3 images"):
        open_kitti(drive)


def test_error_timestamps_malformed(tmp_path: Path) -> None:
    drive = make_raw(tmp_path, n=1)
    (drive / "image_00" / "timestamps.txt").write_text("yesterday at noon\n")
    with pytest.raises(DatasetImportError, match=r"line 1 of .* is 'yesterday at noon', expected"):
        open_kitti(drive)


def test_error_times_count(tmp_path: Path) -> None:
    sequence = make_odometry(tmp_path)
    (sequence / "times.txt").write_text("0.0\n0.1\n")
    with pytest.raises(DatasetImportError, match=r"times\.txt has 2 times for 4 images"):
        open_kitti(sequence)


def test_error_times_malformed(tmp_path: Path) -> None:
    sequence = make_odometry(tmp_path, n=2)
    (sequence / "times.txt").write_text("0.0\nsoon\n")
    with pytest.raises(DatasetImportError, match=r"must hold one number \(seconds\) per line"):
        open_kitti(sequence)


def test_error_poses_count(tmp_path: Path) -> None:
    sequence = make_odometry(tmp_path)
    poses = tmp_path / "poses" / "05.txt"
    poses.write_text("\n".join(poses.read_text().splitlines()[:3]))
    with pytest.raises(DatasetImportError, match=r"pose file .*05\.txt has 3 poses for 4 images"):
        open_kitti(sequence)


def test_error_poses_malformed(tmp_path: Path) -> None:
    sequence = make_odometry(tmp_path, n=1)
    (tmp_path / "poses" / "05.txt").write_text("1 0 0 0\n")
    with pytest.raises(DatasetImportError, match=r"line 1 of pose file .* must hold 12 numbers"):
        open_kitti(sequence)


def test_error_several_drives(tmp_path: Path) -> None:
    drive = make_raw(tmp_path)
    other = drive.parent / "2011_01_01_drive_0008_sync"
    (other / "image_00" / "data").mkdir(parents=True)
    with pytest.raises(DatasetImportError, match=r"holds 2 KITTI raw drives .*pass one drive"):
        open_kitti(drive.parent)


def test_names_without_zero_padding_keep_frame_order_and_poses(tmp_path: Path) -> None:
    # "0.png ... 11.png" (another tool's export): text order would put 10 and 11 after 1
    # and give frame 10 the pose and time of frame 2 (bug hunt 6A F5)
    n = 12
    sequence_dir = make_odometry(tmp_path, n=n)
    for camera in ("image_0", "image_1"):
        for i in range(n):
            (sequence_dir / camera / f"{i:06d}.png").rename(sequence_dir / camera / f"{i}.png")
    sequence = open_kitti(sequence_dir)
    assert [p.stem for p in sequence.left_paths] == [str(i) for i in range(n)]
    assert sequence.camera_to_world is not None
    np.testing.assert_allclose(sequence.camera_to_world[10][:3, 3], [1.0, 0, 10.0])
    out = tmp_path / "odo.mcap"
    import_kitti(sequence_dir, out)
    read = _read(out)
    left = [m for topic, _, m in read if topic == "/stereo/left/image_rect"]
    expected = cv2.imread(str(sequence_dir / "image_0" / "10.png"), cv2.IMREAD_GRAYSCALE)
    np.testing.assert_array_equal(rosmsg.image_array(left[10]), expected)
    poses = [(t, m) for topic, t, m in read if topic == "/ground_truth/pose"]
    assert poses[10][0] == round(0.1037 * 10 * 1e9)
    np.testing.assert_allclose(rosmsg.pose_matrix(poses[10][1])[:3, 3], [1.0, 0, 10.0])


def test_error_times_that_do_not_increase(tmp_path: Path) -> None:
    # twelve 0.0 lines gave "0.0 s of log", and evaluate then saw one frame (bug hunt 6A F15)
    sequence = make_odometry(tmp_path)
    (sequence / "times.txt").write_text("0.0\n0.1\n0.1\n0.3\n")
    with pytest.raises(
        DatasetImportError,
        match=r"line 3 of .*times\.txt \(0\.100000000 s\) is not after line 2 \(0\.100000000 s\): "
        r"frames need increasing times",
    ):
        open_kitti(sequence)


def test_error_raw_timestamps_that_do_not_increase(tmp_path: Path) -> None:
    drive = make_raw(tmp_path)
    stamps = ["2011-01-01 12:00:01.000000000", "2011-01-01 12:00:00.500000000"] * 2
    (drive / "image_00" / "timestamps.txt").write_text("\n".join(stamps[:3]) + "\n")
    with pytest.raises(DatasetImportError, match=r"line 2 of .*timestamps\.txt .* is not after"):
        open_kitti(drive)


def test_macos_dot_files_beside_the_images_are_not_frames(tmp_path: Path) -> None:
    # copies from an exFAT/HFS drive leave AppleDouble files: ._000000.png (bug hunt 6A F10)
    sequence_dir = make_odometry(tmp_path)
    for camera in ("image_0", "image_1"):
        (sequence_dir / camera / "._000000.png").write_bytes(b"\x00\x05\x16\x07 not an image")
    sequence = open_kitti(sequence_dir)
    assert [p.name for p in sequence.left_paths] == [f"{i:06d}.png" for i in range(4)]
    assert len(list(iter_frames(sequence))) == 4


def test_an_output_that_links_to_an_image_is_refused(tmp_path: Path) -> None:
    # the overwrite check got only the folder: the first image was replaced by the log
    sequence_dir = make_odometry(tmp_path / "in")
    image = sequence_dir / "image_0" / "000000.png"
    before = image.read_bytes()
    link = tmp_path / "out.mcap"
    link.symlink_to(image)
    with pytest.raises(LogWriteError, match=r"refusing to write the output onto the input .*"):
        import_kitti(sequence_dir, link)
    assert image.read_bytes() == before


@pytest.mark.parametrize("given", ["training", "root"])
def test_the_stereo_benchmark_layout_is_refused_not_read_as_a_sequence(
    tmp_path: Path, given: str
) -> None:
    # KITTI stereo 2015: image_2/000000_10.png, calib_cam_to_cam/000000.txt; with a
    # calib.txt beside them it was imported as one odometry sequence (bug hunt 6A F10)
    training = tmp_path / "data_scene_flow" / "training"
    names = [f"{scene:06d}_{frame}.png" for scene in range(2) for frame in (10, 11)]
    _write_images(training / "image_2", names, seed=1)
    _write_images(training / "image_3", names, seed=2)
    (training / "calib_cam_to_cam").mkdir()
    (training / "calib.txt").write_text(f"P2: {_numbers(P_LEFT)}\nP3: {_numbers(P_RIGHT)}\n")
    folder = training if given == "training" else training.parent
    with pytest.raises(
        DatasetImportError,
        match=r"holds KITTI's stereo 2012/2015 benchmark layout \(.*image_2/00000\d_1[01]\.png: "
        r"unrelated scenes .* not a sequence; import the KITTI raw drive",
    ):
        open_kitti(folder)
    with pytest.raises(DatasetImportError, match="stereo 2012/2015 benchmark"):
        open_kitti(training, pair=KittiPair.COLOUR)
