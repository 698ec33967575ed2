"""Rectify a raw stereo pair from its calibration, as ROS ``image_proc`` does (no I/O).

A camera's calibration is what a ``sensor_msgs/CameraInfo`` carries: the raw intrinsics K and
distortion D (``plumb_bob``, ``rational_polynomial`` or ``equidistant``), the rectifying
rotation R and the rectified projection P, plus the binning and region of interest the
images were taken with. Each image is remapped with ``cv2.initUndistortRectifyMap(K, D, R,
P[:3, :3])`` (``cv2.fisheye`` for ``equidistant``), bilinearly, at the size ``image_proc``'s
``image_rect`` has: the raw image's size (its ROI divided by its binning). The rectified left
camera is then P's (divided by the binning, moved by the ROI) with D = 0 and R = I; points in
the raw left camera's frame move into the rectified one by R.

The maps are built once per calibration: :class:`StereoRectifier` keeps the last one and
builds new maps only when a calibration differs in a value (a driver re-sends the same
``CameraInfo`` with every image).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import CalibrationError
from pcainterp_stream.records import DensifiedFrame, StereoCamera

MODELS = ("plumb_bob", "rational_polynomial", "equidistant")
"""The distortion models understood (ROS ``sensor_msgs/distortion_models`` names)."""

_ALIASES = {
    "radtan": "plumb_bob",
    "radial-tangential": "plumb_bob",
    "pinhole-radtan": "plumb_bob",
    "fisheye": "equidistant",
    "kannala_brandt": "equidistant",
}


def _field(message: Any, name: str) -> Any:
    """Return a CameraInfo field by its ROS 2 (lower case) or ROS 1 (upper case) name."""
    value = getattr(message, name, None)
    if value is None:
        value = getattr(message, name.upper(), None)
    return value


@dataclass(frozen=True)
class CameraCalibration:
    """One camera's calibration as a ``CameraInfo`` holds it (full-resolution values).

    Attributes:
        width: full-resolution image width (px) the calibration is for.
        height: full-resolution image height (px).
        model: distortion model, one of :data:`MODELS`.
        k: (3, 3) raw intrinsics.
        d: (n,) distortion coefficients (may be empty).
        r: (3, 3) rectifying rotation (raw camera frame -> rectified frame).
        p: (3, 4) rectified projection; P[0, 3] = -fx * baseline on the right camera.
        binning: (x, y) binning of the images (1 = none).
        roi: (x, y, width, height) of the images in the full-resolution frame.
        name: where the calibration comes from (a topic or file), for messages.
    """

    width: int
    height: int
    model: str
    k: npt.NDArray[np.float64]
    d: npt.NDArray[np.float64]
    r: npt.NDArray[np.float64]
    p: npt.NDArray[np.float64]
    binning: tuple[int, int] = (1, 1)
    roi: tuple[int, int, int, int] = (0, 0, 0, 0)
    name: str = "camera_info"

    def __post_init__(self) -> None:
        model = _ALIASES.get(self.model.strip().lower(), self.model.strip().lower())
        if model == "" and not np.any(self.d):
            model = "plumb_bob"  # no model and no distortion: a pinhole camera
        if model not in MODELS:
            raise CalibrationError(
                f"{self.name} has distortion model {self.model!r}; supported: "
                f"{', '.join(MODELS)}: rectify the images yourself and pass --rectify never"
            )
        object.__setattr__(self, "model", model)
        for label, value, shape in (
            ("K", self.k, (3, 3)),
            ("R", self.r, (3, 3)),
            ("P", self.p, (3, 4)),
        ):
            if value.shape != shape or not np.isfinite(value).all():
                raise CalibrationError(
                    f"{self.name} has {label} of shape {value.shape} or with non-finite values; "
                    f"expected a finite {shape[0]}x{shape[1]} matrix: fix the calibration"
                )
        if not np.isfinite(self.d).all():
            raise CalibrationError(f"{self.name} has non-finite distortion coefficients")
        if not (self.k[0, 0] > 0 and self.k[1, 1] > 0 and self.p[0, 0] > 0 and self.p[1, 1] > 0):
            raise CalibrationError(
                f"{self.name} has K or P without positive focal lengths (K fx={self.k[0, 0]}, "
                f"P fx={self.p[0, 0]}): a camera that can be rectified needs them; fix the "
                "calibration"
            )
        if self.width <= 0 or self.height <= 0:
            raise CalibrationError(
                f"{self.name} has image size {self.width}x{self.height}: fix the calibration"
            )

    @classmethod
    def from_camera_info(cls, message: Any, name: str) -> CameraCalibration:
        """Read a ROS 1 or ROS 2 ``CameraInfo`` message.

        Raises:
            CalibrationError: an unknown model, missing or non-finite matrices.
        """
        roi = _field(message, "roi")
        binning = (int(_field(message, "binning_x") or 0), int(_field(message, "binning_y") or 0))
        region = (0, 0, 0, 0)
        if roi is not None:
            region = (int(roi.x_offset), int(roi.y_offset), int(roi.width), int(roi.height))
        return cls(
            width=int(message.width),
            height=int(message.height),
            model=str(message.distortion_model),
            k=np.asarray(_field(message, "k"), dtype=np.float64).reshape(3, 3),
            d=np.asarray(_field(message, "d"), dtype=np.float64).reshape(-1),
            r=np.asarray(_field(message, "r"), dtype=np.float64).reshape(3, 3),
            p=np.asarray(_field(message, "p"), dtype=np.float64).reshape(3, 4),
            binning=(max(binning[0], 1), max(binning[1], 1)),
            roi=region,
            name=name,
        )

    @property
    def is_rectified(self) -> bool:
        """Return True when the images need no remap: D = 0, R = I and K = P[:3, :3]."""
        return (
            not np.any(self.d)
            and np.allclose(self.r, np.eye(3), atol=1e-9)
            and np.allclose(self.k, self.p[:, :3], rtol=1e-9, atol=1e-9)
        )

    def why_raw(self) -> str:
        """Return what makes this calibration unrectified (e.g. ``D != 0, R != I``)."""
        reasons = []
        if np.any(self.d):
            reasons.append("D != 0")
        if not np.allclose(self.r, np.eye(3), atol=1e-9):
            reasons.append("R != I")
        if not np.allclose(self.k, self.p[:, :3], rtol=1e-9, atol=1e-9):
            reasons.append("K != P[:3,:3]")
        return ", ".join(reasons) or "nothing"

    def region(self) -> tuple[int, int, int, int]:
        """Return the full-resolution ROI (x, y, width, height); the whole image when unset."""
        x, y, w, h = self.roi
        if w == 0 or h == 0:
            return (
                (0, 0, self.width, self.height)
                if (x, y) == (0, 0)
                else (x, y, self.width - x, self.height - y)
            )
        return (x, y, w, h)

    def image_size(self) -> tuple[int, int]:
        """Return (width, height) of the images (and of ``image_rect``): ROI / binning."""
        _, _, w, h = self.region()
        return (w // self.binning[0], h // self.binning[1])

    def key(self) -> bytes:
        """Return bytes that differ when any value of the calibration differs."""
        parts = [
            np.array([self.width, self.height, *self.binning, *self.roi], dtype=np.int64).tobytes(),
            self.model.encode(),
            self.k.tobytes(),
            self.d.tobytes(),
            self.r.tobytes(),
            self.p.tobytes(),
        ]
        return b"|".join(parts)

    def rectification_maps(self) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """Return (map_x, map_y): for each ``image_rect`` pixel, its position in the raw image."""
        new_k = self.p[:, :3]
        size = (self.width, self.height)
        if self.model == "equidistant":
            d = np.zeros(4) if self.d.size == 0 else self.d[:4]
            if d.size < 4:
                raise CalibrationError(
                    f"{self.name}: the equidistant model needs 4 coefficients, got {self.d.size}"
                )
            map_x, map_y = cv2.fisheye.initUndistortRectifyMap(
                self.k, d.reshape(4, 1), self.r, new_k, size, cv2.CV_32FC1
            )
        else:
            d = self.d if self.d.size else np.zeros(5)
            map_x, map_y = cv2.initUndistortRectifyMap(self.k, d, self.r, new_k, size, cv2.CV_32FC1)
        x, y, w, h = self.region()
        bx, by = self.binning
        if (x, y, w, h) != (0, 0, self.width, self.height) or (bx, by) != (1, 1):
            # image_proc's reduced maps: the ROI of the full maps, shifted, sampled every
            # binning-th pixel and scaled into the binned raw image
            map_x = (map_x[y : y + h : by, x : x + w : bx][: h // by, : w // bx] - x) / bx
            map_y = (map_y[y : y + h : by, x : x + w : bx][: h // by, : w // bx] - y) / by
        return np.ascontiguousarray(map_x, np.float32), np.ascontiguousarray(map_y, np.float32)

    def rectified_projection(self) -> npt.NDArray[np.float64]:
        """Return P of the ``image_rect`` images: moved by the ROI, divided by the binning."""
        x, y, _, _ = self.region()
        p = self.p.copy()
        p[0, 2] -= x * p[2, 2]
        p[1, 2] -= y * p[2, 2]
        p[0] /= self.binning[0]
        p[1] /= self.binning[1]
        return p

    def raw_to_rectified(self, pixels: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Return the rectified positions of raw full-resolution pixels (n, 2)."""
        points = np.asarray(pixels, np.float64).reshape(-1, 1, 2)
        if self.model == "equidistant":
            out = cv2.fisheye.undistortPoints(
                points, self.k, self.d[:4].reshape(4, 1), R=self.r, P=self.p[:, :3]
            )
        else:
            out = cv2.undistortPoints(points, self.k, self.d, R=self.r, P=self.p[:, :3])
        return np.asarray(out, np.float64).reshape(-1, 2)


@dataclass(frozen=True)
class StereoCalibration:
    """The two calibrations of a stereo pair (from camera infos or calibration files)."""

    left: CameraCalibration
    right: CameraCalibration

    @property
    def is_rectified(self) -> bool:
        """Return True when neither camera needs a remap."""
        return self.left.is_rectified and self.right.is_rectified

    def why_raw(self) -> str:
        """Return what makes the pair unrectified, per side."""
        sides = [
            f"{side} {cal.why_raw()}"
            for side, cal in (("left", self.left), ("right", self.right))
            if not cal.is_rectified
        ]
        return "; ".join(sides)

    def key(self) -> bytes:
        """Return bytes that differ when a value of either calibration differs."""
        return self.left.key() + b"||" + self.right.key()


class StereoRectifier:
    """Remap raw stereo pairs into the rectified pair their calibration defines.

    Args:
        calibration: the pair's calibration.
        baseline: baseline override (m); else -P_right[0, 3] / P_right[0, 0].

    Raises:
        CalibrationError: the right P gives no positive baseline and none is given.
    """

    def __init__(self, calibration: StereoCalibration, baseline: float | None = None) -> None:
        self.calibration = calibration
        left, right = calibration.left, calibration.right
        self._maps = [cal.rectification_maps() for cal in (left, right)]
        p = left.rectified_projection()
        width, height = left.image_size()
        if baseline is None:
            p_right = right.p
            with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
                baseline = float(-p_right[0, 3] / p_right[0, 0])
            if not (baseline > 0 and np.isfinite(baseline)):
                sign = "swapped left/right?" if baseline < 0 else "no Tx"
                raise CalibrationError(
                    f"{right.name} gives no baseline (P[0,3] = {p_right[0, 3]}, fx = "
                    f"{p_right[0, 0]}; expected -fx * baseline < 0: {sign}); fix the "
                    "calibration or pass --baseline METRES"
                )
        self.camera = StereoCamera(
            width=int(width),
            height=int(height),
            fx=float(p[0, 0]),
            fy=float(p[1, 1]),
            cx=float(p[0, 2]),
            cy=float(p[1, 2]),
            baseline=float(baseline),
        )
        self.rotation = left.r.copy()
        self.box = valid_box(self._maps, left.image_size(), right.image_size())
        x, y, w, h = self.box
        self.inner = StereoCamera(
            width=w,
            height=h,
            fx=self.camera.fx,
            fy=self.camera.fy,
            cx=self.camera.cx - x,
            cy=self.camera.cy - y,
            baseline=self.camera.baseline,
        )

    def check_size(self, shape: tuple[int, ...], side: str) -> None:
        """Refuse an image whose size is not the calibration's (ROI / binning).

        Raises:
            CalibrationError: naming both sizes and the calibration.
        """
        cal = self.calibration.left if side == "left" else self.calibration.right
        width, height = cal.image_size()
        if (shape[1], shape[0]) != (width, height):
            raise CalibrationError(
                f"the {side} image is {shape[1]}x{shape[0]} but its calibration ({cal.name}) is "
                f"for {width}x{height}: pass the calibration of this camera and resolution"
            )

    def rectify(
        self, left: npt.NDArray[np.generic], right: npt.NDArray[np.generic]
    ) -> tuple[npt.NDArray[np.generic], npt.NDArray[np.generic]]:
        """Return the rectified (left, right) images (bicubic, zero outside the raw image)."""
        return self.rectify_one(left, "left"), self.rectify_one(right, "right")

    def rectify_one(self, image: npt.NDArray[np.generic], side: str) -> npt.NDArray[np.generic]:
        """Return one rectified image of the pair (``side``: ``left`` or ``right``)."""
        self.check_size(image.shape, side)
        map_x, map_y = self._maps[0 if side == "left" else 1]
        remapped = cv2.remap(
            np.asarray(image, dtype=image.dtype),
            map_x,
            map_y,
            cv2.INTER_CUBIC,
            borderMode=cv2.BORDER_CONSTANT,
        )
        return np.asarray(remapped)

    def rotate_points(self, points: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        """Move (n, 3) points from the raw left camera's frame into the rectified one."""
        return (np.asarray(points, np.float64) @ self.rotation.T).astype(np.float32)


def stereo_from_infos(
    left_info: Any, right_info: Any, left_name: str, right_name: str
) -> StereoCalibration:
    """Return the calibration of a pair from its two ``CameraInfo`` messages."""
    return StereoCalibration(
        CameraCalibration.from_camera_info(left_info, left_name),
        CameraCalibration.from_camera_info(right_info, right_name),
    )


@dataclass(frozen=True)
class RowOffset:
    """How far a stereo pair is from rectified, from matched corners.

    Attributes:
        matches: correspondences used (inliers of a RANSAC fundamental matrix).
        median_abs_dy: median |y_left - y_right| (px): about 0 on a rectified pair.
        median_dx: median x_left - x_right (px): a disparity, positive on a correct pair.
    """

    matches: int
    median_abs_dy: float
    median_dx: float


def _grey8(image: npt.NDArray[np.generic]) -> npt.NDArray[np.uint8]:
    if image.ndim == 3:
        image = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    if image.dtype != np.uint8:
        scale = 255.0 / max(float(np.max(image)), 1.0)
        image = np.clip(image.astype(np.float32) * scale, 0, 255).astype(np.uint8)
    return np.ascontiguousarray(image, dtype=np.uint8)


def correspondences(
    left: npt.NDArray[np.generic], right: npt.NDArray[np.generic], features: int = 1500
) -> npt.NDArray[np.float64]:
    """Return (n, 4) x_l, y_l, x_r, y_r of ORB matches consistent with one epipolar geometry.

    Cross-checked descriptor matches are kept when a RANSAC fundamental matrix has them as
    inliers: a correct correspondence, whether or not the pair is rectified.
    """
    orb = cv2.ORB.create(nfeatures=features)
    a, b = _grey8(left), _grey8(right)
    kp_l, des_l = orb.detectAndCompute(a, None)
    kp_r, des_r = orb.detectAndCompute(b, None)
    if des_l is None or des_r is None or len(kp_l) < 8 or len(kp_r) < 8:
        return np.zeros((0, 4))
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(des_l, des_r)
    if len(matches) < 15:
        return np.zeros((0, 4))
    pts = np.array(
        [[*kp_l[m.queryIdx].pt, *kp_r[m.trainIdx].pt] for m in matches], dtype=np.float64
    )
    _, mask = cv2.findFundamentalMat(pts[:, :2], pts[:, 2:], cv2.FM_RANSAC, 1.0, 0.999)
    if mask is None:
        return np.zeros((0, 4))
    return np.asarray(pts[mask.ravel().astype(bool)], dtype=np.float64)


def row_offset(points: npt.NDArray[np.float64]) -> RowOffset:
    """Summarise correspondences (n, 4) as a :class:`RowOffset`."""
    if points.shape[0] == 0:
        return RowOffset(0, float("nan"), float("nan"))
    return RowOffset(
        matches=int(points.shape[0]),
        median_abs_dy=float(np.median(np.abs(points[:, 1] - points[:, 3]))),
        median_dx=float(np.median(points[:, 0] - points[:, 2])),
    )


def unrectify_maps(
    calibration: CameraCalibration,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Return (map_x, map_y): for each raw full-resolution pixel, its rectified position.

    ``cv2.remap(rectified, map_x, map_y, ...)`` then renders the raw image a camera with this
    calibration would have taken of the rectified view (used to make raw test logs).
    """
    xs, ys = np.meshgrid(
        np.arange(calibration.width, dtype=np.float64),
        np.arange(calibration.height, dtype=np.float64),
    )
    rect = calibration.raw_to_rectified(np.stack([xs.ravel(), ys.ravel()], axis=1))
    shape = (calibration.height, calibration.width)
    return (
        rect[:, 0].reshape(shape).astype(np.float32),
        rect[:, 1].reshape(shape).astype(np.float32),
    )


def valid_box(
    maps: list[tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]],
    *sizes: tuple[int, int],
) -> tuple[int, int, int, int]:
    """Return (x, y, width, height): a large box of the rectified image valid in both cameras.

    A rectified pixel is valid when both its raw positions fall inside the raw images. The box
    is found by shaving off, one at a time, the border row or column with the most invalid
    pixels (per pixel of its length) until none is left.
    """
    height0, width0 = maps[0][0].shape[:2]
    valid: npt.NDArray[np.bool_] = np.ones((height0, width0), dtype=bool)
    for (map_x, map_y), (width, height) in zip(maps, sizes, strict=True):
        valid &= (map_x >= 0) & (map_x <= width - 1) & (map_y >= 0) & (map_y <= height - 1)
    top, left, bottom, right = 0, 0, height0, width0
    bad = ~valid
    while top < bottom and left < right:
        box = bad[top:bottom, left:right]
        edges = {
            "top": box[0].mean(),
            "bottom": box[-1].mean(),
            "left": box[:, 0].mean(),
            "right": box[:, -1].mean(),
        }
        side = max(edges, key=lambda k: edges[k])
        if edges[side] == 0:
            break
        if side == "top":
            top += 1
        elif side == "bottom":
            bottom -= 1
        elif side == "left":
            left += 1
        else:
            right -= 1
    return (left, top, max(right - left, 0), max(bottom - top, 0))


def pad_result(result: DensifiedFrame, rectifier: StereoRectifier) -> DensifiedFrame:
    """Return a frame estimated in ``rectifier.box`` at the full rectified size (NaN outside)."""
    x, y, w, h = rectifier.box
    full = rectifier.camera
    if (x, y, w, h) == (0, 0, full.width, full.height):
        return result._replace(frame=result.frame._replace(camera=full))

    def pad(array: npt.NDArray[Any], fill: float) -> npt.NDArray[Any]:
        out = np.full((full.height, full.width, *array.shape[2:]), fill, dtype=array.dtype)
        out[y : y + h, x : x + w] = array
        return out

    frame = result.frame._replace(
        camera=full, left=pad(result.frame.left, 0), right=pad(result.frame.right, 0)
    )
    pixels = (result.pixels + np.array([x, y], dtype=result.pixels.dtype)).astype(
        result.pixels.dtype
    )
    return result._replace(
        frame=frame,
        pixels=pixels,
        disparity=pad(result.disparity, np.nan),
        disparity_std=pad(result.disparity_std, np.nan),
        depth=pad(result.depth, np.nan),
        depth_std=pad(result.depth_std, np.nan),
    )
