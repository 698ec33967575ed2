"""Synthetic drives recorded the way a stereo driver records them: raw, distorted, unrectified.

The drive is rendered as usual, by the rectified pair (the synthetic camera), but on a canvas
wider than the image by a margin; each raw image is then sampled from that canvas where a
camera with a distorting lens (``plumb_bob`` or ``equidistant``) and a small rotation R away
from the rectified pair would have seen it (:class:`io.raw_log.Unrectifier`). The log carries
the raw images under driver topic names with the matching ``CameraInfo`` (raw K and D, R, and
P = the synthetic camera), and the ground truth of the rectified left camera (the canvas's
centre): what ``densify`` gives after rectifying is scored against the same truth as the
rectified drive.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Iterator
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from pcainterp_stream.io.camera_model import CameraCalibration, StereoCalibration, unrectify_maps
from pcainterp_stream.io.logwriter import LogFormat, ProgressCallback, WriteSummary, open_writer
from pcainterp_stream.io.raw_log import LEFT_FRAME, raw_stereo_messages
from pcainterp_stream.io.stereo_log import DEPTH, pose_message
from pcainterp_stream.records import StereoCamera, SynthFrame
from pcainterp_stream.synth import SynthConfig, generate
from pcainterp_stream.synth.log import truth_depth_message

RAW_MODELS = ("plumb_bob", "equidistant")
"""The lenses ``synth --raw`` can simulate."""

# Lens and mounting of the simulated raw cameras: a moderate barrel distortion (about
# KITTI's grey cameras' at the image corners, less at the edges), and rotations of a few
# tenths of a degree between each camera and the rectified pair.
_PLUMB_BOB = {
    "left": [-0.12, 0.02, 0.0008, -0.0005, 0.0],
    "right": [-0.11, 0.018, -0.0006, 0.0004, 0.0],
}
# a lens between equidistant (r = f theta) and pinhole (r = f tan theta = f (theta + theta^3/3
# + ...)): a pure equidistant lens of the same focal length would spread the rectified view's
# edges over few raw pixels
_EQUIDISTANT = {"left": [0.12, 0.03, 0.001, 0.0], "right": [0.11, 0.028, 0.0008, 0.0]}
_ROTATION_DEG = {"left": (0.3, -0.5, 0.2), "right": (-0.25, 0.4, -0.15)}
_PRINCIPAL_SHIFT = {"left": (3.0, -2.0), "right": (-2.5, 1.5)}  # px at full scale
# raw focal length / rectified (1: the lens sees at least the rectified view everywhere)
_FOCAL_SCALE = {"plumb_bob": 1.0, "equidistant": 1.0}


def raw_calibration(camera: StereoCamera, model: str, scale: float = 1.0) -> StereoCalibration:
    """Return the raw calibration of the simulated driver's pair whose rectified pair is ``camera``.

    Args:
        camera: the rectified stereo camera (P of both sides).
        model: ``plumb_bob`` or ``equidistant``.
        scale: the log's scale (the principal point offsets are given at full scale).

    Raises:
        ValueError: an unknown model.
    """
    if model not in RAW_MODELS:
        raise ValueError(f"raw lens model must be one of {', '.join(RAW_MODELS)}, got {model!r}")
    sides = []
    for side, p in (("left", camera.projection_left()), ("right", camera.projection_right())):
        dx, dy = _PRINCIPAL_SHIFT[side]
        zoom = _FOCAL_SCALE[model]
        k = np.array(
            [
                [camera.fx * zoom, 0.0, camera.cx + dx * scale],
                [0.0, camera.fy * zoom, camera.cy + dy * scale],
                [0.0, 0.0, 1.0],
            ]
        )
        coefficients = (_PLUMB_BOB if model == "plumb_bob" else _EQUIDISTANT)[side]
        rotation = Rotation.from_euler("xyz", _ROTATION_DEG[side], degrees=True).as_matrix()
        sides.append(
            CameraCalibration(
                width=camera.width,
                height=camera.height,
                model=model,
                k=k,
                d=np.array(coefficients, dtype=np.float64),
                r=rotation,
                p=p,
                name=f"synthetic {side} {model}",
            )
        )
    return StereoCalibration(sides[0], sides[1])


def _margin(calibration: StereoCalibration) -> int:
    """Return the canvas margin (px) every raw pixel's rectified position falls within."""
    worst = 0.0
    for cal in (calibration.left, calibration.right):
        map_x, map_y = unrectify_maps(cal)
        worst = max(
            worst,
            float(-map_x.min()),
            float(map_x.max() - (cal.width - 1)),
            float(-map_y.min()),
            float(map_y.max() - (cal.height - 1)),
        )
    return max(2, math.ceil(worst) + 2)


class RawDrive:
    """A synthetic drive's raw pairs: see the module docstring.

    Args:
        config: the drive (its camera is the rectified pair).
        model: the lens, ``plumb_bob`` or ``equidistant``.
    """

    def __init__(self, config: SynthConfig, model: str = "plumb_bob") -> None:
        self.config = config
        self.camera = config.camera
        self.calibration = raw_calibration(self.camera, model, config.scale)
        self.margin = _margin(self.calibration)
        m = self.margin / config.scale  # full-scale px: the scaled canvas grows by 2 * margin
        self.canvas = dataclasses.replace(
            config,
            width=config.width + 2 * m,  # type: ignore[arg-type]  # scaled and rounded later
            height=config.height + 2 * m,  # type: ignore[arg-type]
            cx=config.cx + m,
            cy=config.cy + m,
        )
        self._maps = []
        for cal in (self.calibration.left, self.calibration.right):
            map_x, map_y = unrectify_maps(cal)
            self._maps.append((map_x + self.margin, map_y + self.margin))

    def frames(self) -> Iterator[tuple[SynthFrame, npt.NDArray[np.uint8], npt.NDArray[np.uint8]]]:
        """Yield (rectified frame with its truth, raw left, raw right) per frame."""
        import cv2

        m = self.margin
        height, width = self.camera.height, self.camera.width
        for frame in generate(self.canvas):
            raw = [
                np.asarray(
                    cv2.remap(image, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE),
                    dtype=np.uint8,
                )
                for image, (mx, my) in zip((frame.left, frame.right), self._maps, strict=True)
            ]
            rectified = frame._replace(
                left=frame.left[m : m + height, m : m + width],
                right=frame.right[m : m + height, m : m + width],
                depth=frame.depth[m : m + height, m : m + width],
                camera=self.camera,
            )
            yield rectified, raw[0], raw[1]


def write_raw_log(
    config: SynthConfig,
    path: str | os.PathLike[str],
    *,
    model: str = "plumb_bob",
    format: LogFormat | str | None = None,
    progress: ProgressCallback | None = None,
) -> WriteSummary:
    """Write a raw synthetic drive: raw pairs, their camera infos, the rectified truth.

    Topics: ``/camera/{left,right}/image_raw`` (mono8), ``/camera/{left,right}/camera_info``,
    ``/ground_truth/depth`` (32FC1 m, the rectified left camera, +inf for sky) and
    ``/ground_truth/pose``.
    """
    drive = RawDrive(config, model)
    with open_writer(path, format) as writer:
        for done, (frame, left, right) in enumerate(drive.frames(), start=1):
            messages: list[tuple[str, Any]] = list(
                raw_stereo_messages(frame.stamp_ns, left, right, drive.calibration)
            )
            depth = np.asarray(frame.depth, dtype=np.float32)
            messages.append((DEPTH, truth_depth_message(depth, frame.stamp_ns, LEFT_FRAME)))
            messages.append(
                ("/ground_truth/pose", pose_message(frame.camera_to_world, frame.stamp_ns))
            )
            for topic, message in messages:
                writer.add_message(topic, message, frame.stamp_ns)
            if progress is not None:
                progress(done, config.frames)
    return writer.summary()
