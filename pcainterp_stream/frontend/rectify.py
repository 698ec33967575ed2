"""Rectify a raw stereo pair from its calibration, as ROS ``image_proc`` does (no I/O).

A camera's calibration is what a ``sensor_msgs/CameraInfo`` carries: the raw intrinsics K and
distortion D (``plumb_bob``, ``rational_polynomial`` or ``equidistant``), the rectifying
rotation R and the rectified projection P, plus the binning and region of interest the
images were taken with. Each image is remapped with ``cv2.initUndistortRectifyMap(K, D, R,
P[:3, :3])`` (``cv2.fisheye`` for ``equidistant``; the records and maps are
:mod:`io.camera_model`'s), bicubically (``image_proc`` offers it; its default is bilinear,
measurably worse for matching), at the size ``image_proc``'s ``image_rect`` has: the raw
image's size (its ROI divided by its binning); the right camera is remapped into the left's
rectified image, since P of both infos defines one rectified camera (a right sensor of
another size too; a right P with another cx is remapped onto the left's cx, so disparities
have no offset: :mod:`frontend.right_cx`). The rectified left camera is then P's
(divided by the binning, moved by the ROI) with D = 0 and R = I; points in the raw left
camera's frame move into the rectified one by R. The estimate is made in the box of the
rectified image both raw cameras see (:func:`valid_box`) and padded back to the full size
(:func:`pad_result`). The first frames are checked for rows that do not match
(:func:`correspondences`, :func:`row_offset`).

The maps are built once per calibration: :class:`StereoRectifier` keeps the last one and
builds new maps only when a calibration differs in a value (a driver re-sends the same
``CameraInfo`` with every image). A pair that is rectified already (D = 0, R = I, K = P on
both sides) is passed through unchanged, as ``image_proc``'s identity maps would leave it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import CalibrationError
from pcainterp_stream.frontend.right_cx import cx_note, on_left_cx
from pcainterp_stream.io.camera_model import (
    MODELS,
    CameraCalibration,
    StereoCalibration,
    stacked_vertically,
    unrectify_maps,
)
from pcainterp_stream.records import DensifiedFrame, StereoCamera

__all__ = [
    "MIN_INLIER_SHARE",
    "MODELS",
    "BoxedCamera",
    "CameraCalibration",
    "RowOffset",
    "StereoCalibration",
    "StereoRectifier",
    "box_without",
    "correspondences",
    "grey8",
    "invalid_pixels",
    "pad_result",
    "row_offset",
    "stereo_from_infos",
    "unrectify_maps",
    "valid_box",
]

MIN_INLIER_SHARE = 0.2
"""A pair's ORB matches with fewer epipolar inliers than this share are chance (noise)."""

MIN_VALID_BOX = 32
"""A rectified box both raw cameras see narrower or lower than this (px) is a calibration
that does not describe the pair (an all-zero or wrong R): refused, not matched."""

ONE_CAMERA_PX = 0.01
"""Largest difference (px) of the two rectified P's fx, fy, cx, cy for cameras of different
image sizes to be rectified into one image."""


def _frames_differ(left: CameraCalibration, right: CameraCalibration) -> bool:
    """Return True when the two cameras' images differ in size, ROI or binning."""
    return (left.width, left.height, left.region(), left.binning) != (
        right.width,
        right.height,
        right.region(),
        right.binning,
    )


def _check_one_rectified_camera(left: CameraCalibration, right: CameraCalibration) -> None:
    """Refuse cameras of different image sizes whose P do not define one rectified camera.

    The right camera is rectified into the left's image with its own P: sound only when
    both P have the same fx, fy, cx, cy (a stereo calibration's; only Tx differs, and cx
    when the right is moved onto the left's: ``right`` is so moved).

    Raises:
        CalibrationError: naming both sizes and the fix.
    """
    if np.allclose(left.p[:, :3], right.p[:, :3], rtol=0, atol=ONE_CAMERA_PX):
        return
    (lw, lh), (rw, rh) = left.image_size(), right.image_size()
    raise CalibrationError(
        f"the left camera's images are {lw}x{lh} px ({left.name}) and the right's {rw}x{rh} "
        f"({right.name}), and their P differ in fx, fy, cx or cy (left "
        f"{_intrinsics(left.p)}, right {_intrinsics(right.p)}), so they define no one "
        "rectified image: pass --calibration LEFT.yaml RIGHT.yaml of a stereo calibration of "
        "the pair (both P equal but Tx), or rectify the images yourself and pass --rectify never"
    )


def _intrinsics(p: npt.NDArray[np.float64]) -> str:
    return f"fx={p[0, 0]:g} fy={p[1, 1]:g} cx={p[0, 2]:g} cy={p[1, 2]:g}"


class StereoRectifier:
    """Remap raw stereo pairs into the rectified pair their calibration defines.

    Args:
        calibration: the pair's calibration.
        baseline: baseline override (m); else (P_left[0, 3] - P_right[0, 3]) / fx (ROS
            writes the left Tx 0; a pair calibrated against a third camera does not).

    Attributes:
        aligned: the calibration the maps are made with: ``calibration`` with the right
            P's cx replaced by the left's when they differ (:mod:`frontend.right_cx`), so
            disparities have no cx_left - cx_right offset.
        cx_note: what the ``rectify`` line says of that (empty when the cx agree).

    Raises:
        CalibrationError: the right P gives no positive baseline and none is given, or puts
            the cameras one above the other (its Ty).
    """

    def __init__(self, calibration: StereoCalibration, baseline: float | None = None) -> None:
        self.calibration = calibration
        left, right = calibration.left, on_left_cx(calibration.left, calibration.right)
        self.aligned = StereoCalibration(left, right)
        self.cx_note = cx_note(float(calibration.right.p[0, 2]), float(left.p[0, 2]))
        # an identity remap: resampling would only add rounding (and float maps a hair
        # outside the image would shave a border row and column off the valid box)
        self.identity = self.aligned.is_rectified and left.image_size() == right.image_size()
        if _frames_differ(left, right):
            _check_one_rectified_camera(left, right)
        # both into the left's rectified image: P of both infos define one rectified camera
        self._maps = [cal.rectification_maps(left) for cal in (left, right)]
        vertical = stacked_vertically(left.p, right.p, right.name, baseline=baseline)
        if vertical is not None:
            raise CalibrationError(vertical)
        p = left.rectified_projection()
        width, height = left.image_size()
        if baseline is None:
            p_right = right.p
            baseline = left.baseline(right)
            if not (baseline > 0 and np.isfinite(baseline)):
                left_tx = f", left P[0,3] = {left.p[0, 3]}" if left.p[0, 3] else ""
                # a negative baseline is a sign problem: --baseline cannot fix infos crossed
                # (the left one has the Tx), but does a right Tx of the wrong sign (the remap
                # uses P[:3, :3], not Tx; the row check then tells swapped images)
                sign, fix = (
                    (
                        "swapped left/right?",
                        f"{right.name} is the left camera's calibration: pass it as the left "
                        f"one and {left.name} as the right one, each with its camera's images",
                    )
                    if baseline < 0 and (left.p[0, 3] != 0 or self.identity)
                    else (
                        "Tx of the wrong sign?",
                        f"if the images are on their topics (a driver writing Tx = +fx * "
                        f"baseline), pass --baseline {-baseline:.6g} (Tx does not enter the "
                        f"remap); if the cameras are swapped, pass each camera's images and "
                        f"info as the other side",
                    )
                    if baseline < 0
                    else ("no Tx", "fix the calibration or pass --baseline METRES")
                )
                raise CalibrationError(
                    f"{right.name} gives no baseline (P[0,3] = {p_right[0, 3]}, fx = "
                    f"{p_right[0, 0]}{left_tx}; expected P_left[0,3] - P_right[0,3] = fx * "
                    f"baseline > 0: {sign}); {fix}"
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
        if self.identity:
            self.box = (0, 0, int(width), int(height))
        else:
            self.box = valid_box(self._maps, left.image_size(), right.image_size())
        x, y, w, h = self.box
        if min(w, h) < MIN_VALID_BOX:
            raise CalibrationError(
                f"{left.name} and {right.name} leave a {w}x{h} px box of the {width}x{height} "
                "rectified image that both raw cameras see: their K, D, R and P do not describe "
                "one stereo pair; fix the calibration or pass --calibration LEFT.yaml "
                "RIGHT.yaml (--rectify never if the images are rectified)"
            )
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
        if self.identity:
            return np.asarray(image)
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


def grey8(image: npt.NDArray[np.generic]) -> npt.NDArray[np.uint8]:
    """Return one image as 8-bit grey (RGB converted, deeper images scaled by their maximum)."""
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
    inliers: a correct correspondence, whether or not the pair is rectified. Each image is
    histogram-equalised first: ORB's FAST threshold is absolute, so a dark or low-gain image
    (a night log, gain 0.05) gave no corners at all, though stereo matching finds its texture.
    Equalised noise (a lens cap) gives corners too, but unrelated ones: a fundamental matrix
    fits about 15 of its ~650 matches by chance, against 60-70 % of a scene's. Fewer inliers
    than :data:`MIN_INLIER_SHARE` of the matches are chance: none is returned.
    """
    orb = cv2.ORB.create(nfeatures=features)
    a, b = cv2.equalizeHist(grey8(left)), cv2.equalizeHist(grey8(right))
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
    if mask is None or mask.sum() < MIN_INLIER_SHARE * len(matches):
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


def valid_box(
    maps: list[tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]],
    *sizes: tuple[int, int],
) -> tuple[int, int, int, int]:
    """Return (x, y, width, height): a large box of the rectified image valid in both cameras.

    A rectified pixel is valid when both its raw positions fall inside the raw images. The box
    is found by shaving off, one at a time, the border row or column with the most invalid
    pixels (per pixel of its length) until none is left.
    """
    return box_without(invalid_pixels(maps, *sizes))


def invalid_pixels(
    maps: list[tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]],
    *sizes: tuple[int, int],
) -> npt.NDArray[np.bool_]:
    """Return (height, width) bool: rectified pixels whose raw position in a camera is outside.

    Args:
        maps: each camera's (map_x, map_y), (height, width) float32 raw positions in px.
        sizes: each camera's raw image (width, height) in px.
    """
    height0, width0 = maps[0][0].shape[:2]
    valid: npt.NDArray[np.bool_] = np.ones((height0, width0), dtype=bool)
    for (map_x, map_y), (width, height) in zip(maps, sizes, strict=True):
        valid &= (map_x >= 0) & (map_x <= width - 1) & (map_y >= 0) & (map_y <= height - 1)
    return ~valid


def box_without(bad: npt.NDArray[np.bool_]) -> tuple[int, int, int, int]:
    """Return (x, y, width, height): a large box of an image holding none of ``bad``.

    The border row or column with the most ``bad`` pixels (per pixel of its length) is shaved
    off, one at a time, until none is left.

    Args:
        bad: (height, width) bool, the pixels the box must not hold.
    """
    height0, width0 = bad.shape[:2]
    top, left, bottom, right = 0, 0, height0, width0
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


class BoxedCamera(Protocol):
    """A rectified camera (``camera``) whose estimate is made in a box of it (``box``)."""

    @property
    def box(self) -> tuple[int, int, int, int]:
        """(x, y, width, height) of the box in the rectified image (px)."""
        ...

    @property
    def camera(self) -> StereoCamera:
        """The rectified camera at its full size."""
        ...


def pad_result(result: DensifiedFrame, rectifier: BoxedCamera) -> DensifiedFrame:
    """Return a frame estimated in ``rectifier.box`` at the full rectified size (NaN outside).

    ``rectifier`` is a :class:`StereoRectifier` or the border of rectified images used as
    they are (:class:`frontend.rect_border.RectifiedBorder`).
    """
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
