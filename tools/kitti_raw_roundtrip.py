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

from pcainterp_stream.io.calibration import kitti_calibration
from pcainterp_stream.io.kitti import import_kitti, iter_frames, open_kitti
from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.io.raw_log import Unrectifier, raw_stereo_messages


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
    args = parser.parse_args(argv)
    frames = write_raw_log(args.kitti_dir, args.out, args.max_frames)
    print(f"wrote {args.out}: {frames} raw pairs")
    if args.check:
        figures = check(args.kitti_dir, args.out, args.max_frames)
        for key, value in figures.items():
            print(f"{key}: {value:.4g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
