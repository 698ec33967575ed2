"""Measure ``densify --features-topic`` on dense clouds: time and error per ``--max-features``.

A dense feature stream (a LiDAR scan, ``stereo_image_proc``'s ``points2``) holds tens of
thousands of points per frame; densify thins it to ``--max-features`` (one median-depth
point per grid cell). This tool builds, from real KITTI pairs (the odometry clip and the raw
drive, half size), a log whose ``/features`` is the SGBM point cloud of each pair (every
valid pixel, x y z in the left optical frame), densifies it once per cap with the
command line, and reports per cap: points kept per frame, wall time per frame (start-up
included, divided by the frames) and the median |depth error| of the dense map, relative,
against the cloud at the cloud's pixels. The first row of each clip is densify's own sparse
measurement (corners and lattice) of the same pairs without a feature stream, for scale.

    python tools/feature_thinning.py KITTI_ODOMETRY_SEQUENCE KITTI_RAW_DRIVE --frames 20
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.frontend.stereo import compute_disparity
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.depth_image import depth_metres
from pcainterp_stream.io.kitti import iter_frames, open_kitti
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.io.stereo_log import LEFT_FRAME, stereo_messages
from pcainterp_stream.records import StereoCamera

FEATURES = "/features"


def write_log(folder: Path, out: Path, frames: int) -> dict[int, npt.NDArray[np.float64]]:
    """Write a half-size log of a KITTI folder with its SGBM clouds; return depth per stamp."""
    sequence = open_kitti(folder)
    full = sequence.camera
    truth: dict[int, npt.NDArray[np.float64]] = {}
    with open_writer(out) as writer:
        for frame in iter_frames(sequence, max_frames=frames):
            left, right = (
                np.asarray(
                    cv2.resize(image, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
                ).astype(np.uint8)
                for image in (frame.left, frame.right)
            )
            height, width = left.shape
            camera = StereoCamera(
                width, height, full.fx / 2, full.fy / 2, full.cx / 2, full.cy / 2, full.baseline
            )
            for topic, message in stereo_messages(frame.stamp_ns, left, right, camera):
                writer.add_message(topic, message, frame.stamp_ns)
            disparity = compute_disparity(left, right)
            rows, columns = np.nonzero(np.isfinite(disparity) & (disparity > 1.0))
            z = camera.focal_baseline / disparity[rows, columns].astype(np.float64)
            x = (columns - camera.cx) * z / camera.fx
            y = (rows - camera.cy) * z / camera.fy
            cloud = {"x": x, "y": y, "z": z}
            fields = {name: values.astype(np.float32) for name, values in cloud.items()}
            message = rosmsg.pointcloud2_message(fields, frame.stamp_ns, LEFT_FRAME)
            writer.add_message(FEATURES, message, frame.stamp_ns)
            depth = np.full((height, width), np.nan)
            depth[rows, columns] = z
            truth[frame.stamp_ns] = depth
    return truth


def score(dense: Path, truth: dict[int, npt.NDArray[np.float64]]) -> float:
    """Median relative |depth error| of the densified depth at the cloud's pixels."""
    errors = []
    with open_log(dense) as reader:
        for raw in reader.messages(["/pcainterp/depth"]):
            message = reader.decode(raw)
            depth = depth_metres(message)
            reference = truth[rosmsg.stamp_ns(message)]
            valid = np.isfinite(reference) & np.isfinite(depth)
            errors.append(np.abs(depth[valid] - reference[valid]) / reference[valid])
    return float(np.median(np.concatenate(errors)))


def densify(log: Path, out: Path, extra: list[str]) -> tuple[float, str]:
    """Run ``pcainterp densify``; return its wall time (s) and its output."""
    command = [sys.executable, "-m", "pcainterp_stream.cli", "densify", str(log), "-o", str(out)]
    started = time.perf_counter()
    run = subprocess.run([*command, *extra], capture_output=True, text=True, check=True)
    return time.perf_counter() - started, run.stdout


def main() -> None:
    """Build the logs, densify them once per cap, print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", type=Path, nargs="+", help="KITTI sequence or drive folders")
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--caps", type=int, nargs="+", default=[250, 500, 1000])
    parser.add_argument("--work-dir", type=Path, default=Path("/tmp/feature_thinning"))
    args = parser.parse_args()
    args.work_dir.mkdir(parents=True, exist_ok=True)
    print("| clip | run | points kept/frame | s/frame | median rel. depth error |")
    print("| --- | --- | --- | --- | --- |")
    for folder in args.folders:
        name = folder.name
        log = args.work_dir / f"{name}.mcap"
        truth = write_log(folder, log, args.frames)
        runs: list[tuple[str, list[str]]] = [("sparse default (no stream)", [])] + [
            (f"--max-features {cap}", ["--features-topic", FEATURES, "--max-features", str(cap)])
            for cap in args.caps
        ]
        for label, extra in runs:
            out = args.work_dir / f"{name}_dense.mcap"
            seconds, text = densify(log, out, extra)
            kept = next(
                (
                    line.split("thinned to ")[1].split()[0]
                    for line in text.splitlines()
                    if "thinned to" in line
                ),
                next(
                    line.split(", ")[1]
                    for line in text.splitlines()
                    if line.startswith("densified")
                ),
            )
            print(
                f"| {name} | {label} | {kept} | {seconds / args.frames:.2f} | "
                f"{100 * score(out, truth):.1f} % |",
                flush=True,
            )


if __name__ == "__main__":
    main()
