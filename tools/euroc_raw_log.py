"""Raw EuRoC-style stereo pairs written as a robot's driver records them, to try ``densify`` on.

Reads a folder of raw pairs (``left_img_N.png`` / ``right_img_N.png``) with EuRoC's
``sensorLeft.yaml`` / ``sensorRight.yaml`` and writes them as an MCAP log under driver topic
names: ``NS/left/image_raw``, ``NS/right/image_raw`` (mono8, distorted, unrectified) and, unless
``--no-camera-info``, their ``NS/left/camera_info`` / ``NS/right/camera_info`` (raw K and D,
the rectifying R and P from ``cv2.stereoRectify``), as a ROS stereo driver publishes them.
Without camera infos the log is an EuRoC-style bag (``--calibration`` is then needed)::

    python tools/euroc_raw_log.py EUROC_PAIRS robot.mcap --ns /camera
    pcainterp densify robot.mcap -o robot_dense.mcap
    pcainterp evaluate robot_dense.mcap -o report
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2

from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.calibration import camera_info_message, load_calibration
from pcainterp_stream.io.logwriter import LogFormat, open_writer

PERIOD_NS = 50_000_000  # EuRoC's VI-sensor records at 20 Hz


def write_log(folder: Path, out: Path, namespace: str, camera_info: bool) -> int:
    """Write the pairs of ``folder`` to ``out``; return how many pairs were written."""
    calibration, _ = load_calibration([folder / "sensorLeft.yaml", folder / "sensorRight.yaml"])
    lefts = sorted(folder.glob("left_img_*.png"))
    with open_writer(out, LogFormat.MCAP) as writer:
        for index, left in enumerate(lefts):
            stamp = 1_000_000_000 + index * PERIOD_NS
            right = left.with_name(left.name.replace("left_", "right_", 1))
            sides = (("left", left, calibration.left), ("right", right, calibration.right))
            for side, path, camera in sides:
                image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
                if image is None:
                    raise SystemExit(f"error: {path} is not a readable image")
                frame = f"{side}_camera"
                writer.add_message(
                    f"{namespace}/{side}/image_raw",
                    rosmsg.image_message(image, stamp, frame, encoding="mono8"),
                    stamp,
                )
                if camera_info:
                    writer.add_message(
                        f"{namespace}/{side}/camera_info",
                        camera_info_message(camera, stamp, frame),
                        stamp,
                    )
    return len(lefts)


def main(argv: list[str] | None = None) -> int:
    """Run the command line."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("folder", type=Path, help="raw pairs with sensorLeft/Right.yaml")
    parser.add_argument("out", type=Path, help="MCAP log to write")
    parser.add_argument("--ns", default="/camera", help="topic namespace (default /camera)")
    parser.add_argument(
        "--no-camera-info", action="store_true", help="write the images only (EuRoC-style)"
    )
    args = parser.parse_args(argv)
    pairs = write_log(args.folder, args.out, args.ns.rstrip("/"), not args.no_camera_info)
    print(f"wrote {args.out}: {pairs} raw pairs")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
