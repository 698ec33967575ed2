"""Rectify the raw real stereo pairs (EuRoC machine hall, MyntEye fisheye) into logs.

A measurement tool, not part of the product: it reads EuRoC-format ``sensor*.yaml``
(``intrinsics`` fu fv cu cv, ``distortion_model`` radial-tangential or equidistant,
``T_BS`` the camera's pose in the body frame), rectifies each pair with
``cv2.stereoRectify`` (``cv2.fisheye.stereoRectify`` for equidistant) and writes the
rectified pairs under the default topics, one log per folder::

    python tools/realdata_rectify.py ../shared/realdata/euroc_machine_hall out/euroc.mcap
    python tools/realdata_rectify.py ../shared/realdata/mynteye_fisheye out/fisheye.mcap

The files are public data sets: keep them out of the repository; this tool takes paths.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.io.stereo_log import stereo_messages
from pcainterp_stream.records import StereoCamera

FRAME_NS = 50_000_000
"""Stamp step between the pairs (20 Hz)."""


def read_sensor(path: Path) -> dict[str, Any]:
    """Return K, D, model, T_BS and size of one EuRoC ``sensor*.yaml``."""
    text = path.read_text()
    block = re.search(r"T_BS:.*?data:\s*\[([^\]]*)\]", text, re.DOTALL)
    if block is None:
        raise SystemExit(f"{path}: no T_BS data")
    t_bs = np.array([float(v) for v in block.group(1).split(",")]).reshape(4, 4)

    def numbers(key: str) -> list[float]:
        match = re.search(rf"^{key}:\s*\[([^\]]*)\]", text, re.MULTILINE)
        if match is None:
            raise SystemExit(f"{path}: no `{key}: [...]` line")
        return [float(value) for value in match.group(1).split(",")]

    fu, fv, cu, cv = numbers("intrinsics")
    width, height = (int(v) for v in numbers("resolution"))
    model = re.search(r"^distortion_model:\s*(\S+)", text, re.MULTILINE)
    return {
        "K": np.array([[fu, 0, cu], [0, fv, cv], [0, 0, 1]], dtype=np.float64),
        "D": np.array(numbers("distortion_coefficients"), dtype=np.float64),
        "model": model.group(1) if model else "radial-tangential",
        "T_BS": np.asarray(t_bs, dtype=np.float64),
        "size": (width, height),
    }


def rectifier(left: dict[str, Any], right: dict[str, Any]) -> tuple[list[Any], StereoCamera]:
    """Return the remap tables of both cameras and the rectified stereo camera."""
    relative = np.linalg.inv(right["T_BS"]) @ left["T_BS"]
    rotation = np.ascontiguousarray(relative[:3, :3])
    translation = np.ascontiguousarray(relative[:3, 3]).reshape(3, 1)
    size = left["size"]
    k1, d1, k2, d2 = left["K"], left["D"], right["K"], right["D"]
    if left["model"] == "equidistant":
        r1, r2, p1, p2, _ = cv2.fisheye.stereoRectify(
            k1,
            d1,
            k2,
            d2,
            size,
            rotation,
            translation,
            flags=cv2.CALIB_ZERO_DISPARITY,
            balance=0.0,
            fov_scale=1.0,
        )
        maps = [
            cv2.fisheye.initUndistortRectifyMap(k, d, r, p, size, cv2.CV_32FC1)
            for k, d, r, p in ((k1, d1, r1, p1), (k2, d2, r2, p2))
        ]
    else:
        r1, r2, p1, p2, *_ = cv2.stereoRectify(
            k1, d1, k2, d2, size, rotation, translation, flags=cv2.CALIB_ZERO_DISPARITY, alpha=0
        )
        maps = [
            cv2.initUndistortRectifyMap(k, d, r, p[:3, :3], size, cv2.CV_32FC1)
            for k, d, r, p in ((k1, d1, r1, p1), (k2, d2, r2, p2))
        ]
    baseline = float(-p2[0, 3] / p2[0, 0])
    camera = StereoCamera(
        width=size[0],
        height=size[1],
        fx=float(p1[0, 0]),
        fy=float(p1[1, 1]),
        cx=float(p1[0, 2]),
        cy=float(p1[1, 2]),
        baseline=baseline,
    )
    return maps, camera


def main(argv: list[str] | None = None) -> int:
    """Rectify the pairs of one folder into a log; return the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="euroc_machine_hall or mynteye_fisheye folder")
    parser.add_argument("out", type=Path, help="the rectified log (.mcap)")
    parser.add_argument("--repeat", type=int, default=1, help="write the pairs N times")
    args = parser.parse_args(argv)
    yamls = sorted(args.folder.glob("*.yaml"))
    left_yaml = next(p for p in yamls if "left" in p.name.lower())
    right_yaml = next(p for p in yamls if "right" in p.name.lower())
    maps, camera = rectifier(read_sensor(left_yaml), read_sensor(right_yaml))
    lefts = sorted(p for p in args.folder.glob("left*.png"))
    pairs = [(p, p.with_name(p.name.replace("left", "right", 1))) for p in lefts]
    stamp = 1_000_000_000
    with open_writer(args.out, None, inputs=[args.folder]) as writer:
        for _ in range(args.repeat):
            for left_path, right_path in pairs:
                images = []
                for path, (map_x, map_y) in zip((left_path, right_path), maps, strict=True):
                    raw: Any = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
                    images.append(
                        np.asarray(cv2.remap(raw, map_x, map_y, cv2.INTER_LINEAR), np.uint8)
                    )
                for topic, message in stereo_messages(stamp, images[0], images[1], camera):
                    writer.add_message(topic, message, stamp)
                stamp += FRAME_NS
    print(
        f"{args.out}: {len(pairs) * args.repeat} pairs, {camera.width}x{camera.height}, "
        f"f={camera.fx:.1f} px, b={camera.baseline:.4f} m, f*b={camera.focal_baseline:.1f} px*m"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
