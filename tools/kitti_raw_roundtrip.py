"""KITTI recorded the way a driver records it: raw images from the rectified drive, densified.

Turns the rectified images of a KITTI raw drive back into raw ones with the drive's own
calibration (``calib_cam_to_cam.txt``: K_00, D_00, R_rect_00, P_rect_00 at S_00's size, and
camera 01), writes them under driver topic names (``/camera/left/image_raw``...) with the
``CameraInfo`` kitti2bag writes, and, with ``--check``, densifies that raw log and the rectified
drive (``import-kitti``) with no options and compares them: the raw run's maps must be the
rectified run's (the raw run is rectified to image_proc's size, whose top-left part is the
rectified drive's image).

    python tools/kitti_raw_roundtrip.py ../shared/realdata/kitti_raw/2011_09_26 raw.mcap --check

Figures printed: mean |disparity difference| of the two runs' dense maps (px) over the pixels
both estimate, and each run's mean |disparity error| against a reference (``--reference``: the
rectified pair's full-resolution SGBM map where it is valid), with their ratio.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import numpy.typing as npt

from pcainterp_stream.frontend.rectify import CameraCalibration, StereoCalibration, StereoRectifier
from pcainterp_stream.io.calibration import kitti_calibration
from pcainterp_stream.io.kitti import import_kitti, iter_frames, open_kitti
from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.io.raw_log import Unrectifier, raw_stereo_messages
from pcainterp_stream.records import StereoCamera


def calibration_file(folder: Path) -> Path:
    """Return the ``calib_cam_to_cam.txt`` of a drive folder or its date folder."""
    for candidate in (folder / "calib_cam_to_cam.txt", folder.parent / "calib_cam_to_cam.txt"):
        if candidate.is_file():
            return candidate
    raise SystemExit(f"error: no calib_cam_to_cam.txt in {folder} or {folder.parent}")


def write_raw_log(folder: Path, out: Path, max_frames: int | None = None) -> int:
    """Write the raw log of a KITTI raw drive; return the number of frames."""
    sequence = open_kitti(folder)
    calibration = kitti_calibration(calibration_file(sequence.folder))
    unrectify = Unrectifier(calibration)
    frames = 0
    with open_writer(out, None, inputs=[sequence.folder]) as writer:
        for frame in iter_frames(sequence, max_frames=max_frames):
            left, right = unrectify(frame.left, frame.right)
            for topic, message in raw_stereo_messages(frame.stamp_ns, left, right, calibration):
                writer.add_message(topic, message, frame.stamp_ns)
            frames += 1
    return frames


def _maps(log: Path) -> list[npt.NDArray[np.float32]]:
    from pcainterp_stream.frontend.pairing import PairingConfig
    from pcainterp_stream.pipeline.densify import densify

    maps: list[npt.NDArray[np.float32]] = []
    with tempfile.TemporaryDirectory() as tmp:
        densify(
            log,
            Path(tmp) / "dense.mcap",
            pairing=PairingConfig(discover=True),
            on_frame=lambda result: maps.append(result.disparity.copy()),
            echo=print,
        )
    return maps


def check(folder: Path, raw_log: Path, max_frames: int | None) -> dict[str, float]:
    """Densify the raw log and the rectified drive; return the comparison's figures."""
    from pcainterp_stream.frontend.stereo import SgbmConfig, compute_disparity

    with tempfile.TemporaryDirectory() as tmp:
        rect_log = Path(tmp) / "rectified.mcap"
        import_kitti(folder, rect_log, max_frames=max_frames)
        started = time.perf_counter()
        rect_maps = _maps(rect_log)
        rect_seconds = time.perf_counter() - started
    started = time.perf_counter()
    raw_maps = _maps(raw_log)
    raw_seconds = time.perf_counter() - started
    sequence = open_kitti(folder)
    diffs, err_rect, err_raw = [], [], []
    for frame, rect, raw in zip(
        iter_frames(sequence, max_frames=max_frames), rect_maps, raw_maps, strict=False
    ):
        h, w = rect.shape
        raw_part = raw[:h, :w]
        both = np.isfinite(rect) & np.isfinite(raw_part)
        diffs.append(np.abs(rect - raw_part)[both])
        reference = compute_disparity(frame.left, frame.right, SgbmConfig())
        valid = np.isfinite(reference) & (reference > 0) & both
        err_rect.append(np.abs(rect - reference)[valid])
        err_raw.append(np.abs(raw_part - reference)[valid])
    figures = {
        "frames": float(len(diffs)),
        "map_difference_px": float(np.mean(np.concatenate(diffs))),
        "map_difference_median_px": float(np.median(np.concatenate(diffs))),
        "error_rectified_px": float(np.mean(np.concatenate(err_rect))),
        "error_raw_px": float(np.mean(np.concatenate(err_raw))),
        "seconds_rectified": rect_seconds,
        "seconds_raw": raw_seconds,
    }
    figures["error_ratio"] = figures["error_raw_px"] / figures["error_rectified_px"]
    return figures


def _fitted_lens(lens: StereoCalibration, camera: StereoCamera) -> StereoCalibration:
    """Return ``lens`` with K moved and scaled until its valid box is ``camera``'s image."""
    zoom = camera.fx / lens.left.p[0, 0]
    scale = np.array([1.0, 1.0])  # focal length factors x, y
    shift = np.array([0.0, 0.0])  # principal point offsets (px)
    calibration = _scaled_lens(lens, camera, zoom)
    for _ in range(12):
        x, y, w, h = StereoRectifier(calibration).box
        if abs(x) + abs(y) + abs(w - camera.width) + abs(h - camera.height) <= 3:
            break
        scale *= np.array([w / camera.width, h / camera.height])
        # the box sits off centre by this much (rectified px): move the raw principal point
        # the other way, in raw px
        off = np.array([x + (w - camera.width) / 2, y + (h - camera.height) / 2])
        ratio = calibration.left.k[0, 0] / camera.fx
        shift -= off * ratio
        calibration = _scaled_lens(lens, camera, zoom, scale, shift)
    return calibration


def _scaled_lens(
    lens: StereoCalibration,
    camera: StereoCamera,
    zoom: float,
    narrow: npt.NDArray[np.float64] | None = None,
    shift: npt.NDArray[np.float64] | None = None,
) -> StereoCalibration:
    """Return ``lens`` scaled by ``zoom`` into ``camera``.

    K's focal lengths are scaled by ``narrow`` more, its principal point moved by ``shift``.
    """
    narrow = np.ones(2) if narrow is None else narrow
    shift = np.zeros(2) if shift is None else shift
    cams = []
    for cal, p in ((lens.left, camera.projection_left()), (lens.right, camera.projection_right())):
        k = cal.k.copy()
        k[0, 0] *= zoom * narrow[0]
        k[1, 1] *= zoom * narrow[1]
        k[0, 2] = (cal.k[0, 2] - cal.p[0, 2]) * zoom + p[0, 2] - shift[0]
        k[1, 2] = (cal.k[1, 2] - cal.p[1, 2]) * zoom + p[1, 2] - shift[1]
        size = (round(cal.width * zoom), round(cal.height * zoom))
        cams.append(CameraCalibration(*size, cal.model, k, cal.d, cal.r, p, name=cal.name))
    return StereoCalibration(cams[0], cams[1])


def lidar_check(annotated: Path, calib_cam_to_cam: Path, tmp: Path) -> dict[str, float]:
    """The bar against real LiDAR truth, on KITTI's depth-annotated colour frames.

    The rectified colour pair (``image_2``/``image_3``, P2/P3 of ``calib.txt``) is written as a
    rectified log and, through the raw lens of cameras 02/03 of ``calib_cam_to_cam`` (K, D,
    R_rect at S's size, with the sequence's own P), as a raw log; both are densified with no
    options and scored against ``image_depth_annotated`` (depth = value / 256 m).
    """
    from dense_truth import read_annotated

    from pcainterp_stream.io.stereo_log import stereo_messages

    frames = read_annotated(annotated)
    camera = frames.camera
    assert isinstance(camera, StereoCamera)
    height, width = camera.height, camera.width
    # The drive's lens (its distortion and rectifying rotations), with K fitted so that the
    # view both raw cameras share is this sequence's rectified image, as KITTI cut its
    # rectified images from that view: the raw images then hold what the rectified ones show.
    lens = kitti_calibration(calib_cam_to_cam, "02", "03")
    calibration = _fitted_lens(lens, camera)
    unrectify = Unrectifier(calibration)
    rect_log, raw_log = tmp / "annotated_rect.mcap", tmp / "annotated_raw.mcap"
    with open_writer(rect_log, None) as rect_writer, open_writer(raw_log, None) as raw_writer:
        for i, (left, right) in enumerate(zip(frames.lefts, frames.rights, strict=True)):
            stamp = 1_000_000_000 + i * 100_000_000
            for topic, message in stereo_messages(stamp, left, right, camera):
                rect_writer.add_message(topic, message, stamp)
            raw_left, raw_right = unrectify(left, right)
            for topic, message in raw_stereo_messages(stamp, raw_left, raw_right, calibration):
                raw_writer.add_message(topic, message, stamp)
    errors: dict[str, list[npt.NDArray[np.float64]]] = {"rect": [], "raw": []}
    rect_maps, raw_maps = _maps(rect_log), _maps(raw_log)
    for truth, rect, raw in zip(frames.truths, rect_maps, raw_maps, strict=True):
        raw_part = raw[:height, :width]
        ok = np.isfinite(truth) & np.isfinite(rect) & np.isfinite(raw_part)
        errors["rect"].append(np.abs(rect - truth)[ok])
        errors["raw"].append(np.abs(raw_part - truth)[ok])
    figures = {
        "lidar_frames": float(len(frames.names)),
        "lidar_pixels": float(sum(e.size for e in errors["rect"])),
        "lidar_error_rectified_px": float(np.mean(np.concatenate(errors["rect"]))),
        "lidar_error_raw_px": float(np.mean(np.concatenate(errors["raw"]))),
    }
    figures["lidar_error_ratio"] = (
        figures["lidar_error_raw_px"] / figures["lidar_error_rectified_px"]
    )
    return figures


def main(argv: list[str] | None = None) -> int:
    """Write the raw log (and with --check compare the two runs); return the exit code."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "kitti_dir", type=Path, help="a KITTI raw drive *_sync folder (or its date folder)"
    )
    parser.add_argument(
        "out", type=Path, help="the raw log to write (.mcap, .bag or rosbag2 folder)"
    )
    parser.add_argument("--max-frames", type=int, default=None, metavar="N")
    parser.add_argument("--check", action="store_true", help="densify both logs and compare")
    parser.add_argument(
        "--lidar",
        type=Path,
        default=None,
        metavar="DIR",
        help="also the bar against real LiDAR truth: a KITTI depth-annotated sequence folder "
        "(image_2, image_3, image_depth_annotated, calib.txt), recorded raw through the lens "
        "of cameras 02/03 of KITTI_DIR's calib_cam_to_cam.txt",
    )
    args = parser.parse_args(argv)
    frames = write_raw_log(args.kitti_dir, args.out, args.max_frames)
    print(f"wrote {args.out}: {frames} raw pairs")
    if args.check:
        figures = check(args.kitti_dir, args.out, args.max_frames)
        for key, value in figures.items():
            print(f"{key}: {value:.4g}")
    if args.lidar is not None:
        with tempfile.TemporaryDirectory() as tmp:
            figures = lidar_check(args.lidar, calibration_file(args.kitti_dir), Path(tmp))
        for key, value in figures.items():
            print(f"{key}: {value:.4g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
