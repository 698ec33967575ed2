"""A camera's calibration as ``sensor_msgs/CameraInfo`` holds it, and its rectification maps.

K and D (``plumb_bob``, ``rational_polynomial`` or ``equidistant``) describe the raw camera,
R rotates it onto the rectified pair and P projects into the rectified image; binning and a
region of interest describe how the images were taken. The maps follow ROS ``image_proc``
(``image_geometry``): ``cv2.initUndistortRectifyMap(K, D, R, P[:3, :3])``, or
``cv2.fisheye`` for ``equidistant``. No I/O: camera infos, calibration files and the
rectifier of a stereo pair (``frontend/rectify.py``) build on these records.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import CalibrationError

MODELS = ("plumb_bob", "rational_polynomial", "equidistant")
"""The distortion models understood (ROS ``sensor_msgs/distortion_models`` names)."""

ROTATION_TOLERANCE = 1e-3
"""Largest |R R^T - I| entry of a rectifying rotation: a calibration file's R written with
six or more decimals is within it; a zero, scaled or sheared R is not."""

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


def uncalibrated(name: str, matrix: str) -> str:
    """Return the error of a camera info whose ``matrix`` (K, P or both) is all zeros."""
    return (
        f"{name} has an all-zero {matrix}: the camera is not calibrated (a driver without a "
        "calibration publishes zeros); calibrate it (ROS camera_calibration) and pass "
        "--calibration LEFT.yaml RIGHT.yaml"
    )


MIN_FOCAL_BASELINE = 1.0
"""Below this f*b (px*m) a calibration is taken for wrong: 1 px of disparity at 1 m, 0.1 px at
10 m. The smallest real pairs have more (a phone's ~1 cm at fx ~1500 px: ~15 px*m; a 4 mm
endoscope at fx 500 px: 2 px*m); a P[0, 3] written in metres (-baseline, not -fx * baseline)
makes f*b the baseline in metres (0.05-0.6 px*m for common rigs) and every depth fx times too
far. A bound on f*b, not on the baseline: a tiny camera's baseline is small, its f*b is not.
A P's Ty = P[1, 3] under it is no vertical baseline either (calibration noise)."""


def vertical_ty(p: npt.NDArray[np.float64]) -> float:
    """Return a P's Ty = P[1, 3] when it is a rig's (>= :data:`MIN_FOCAL_BASELINE` px*m), else 0.

    A vertical pair's second camera has its translation there (-fy * baseline); a smaller Ty
    (0.001, calibration noise of a side-by-side pair) is none.
    """
    ty = float(p[1, 3])
    return ty if np.isfinite(ty) and abs(ty) >= MIN_FOCAL_BASELINE else 0.0


def stacked_vertically(
    p_left: npt.NDArray[np.float64],
    p_right: npt.NDArray[np.float64],
    right_name: str,
    *,
    baseline: float | None = None,
    least: float = MIN_FOCAL_BASELINE,
) -> str | None:
    """Return the error of a pair whose P put the cameras one above the other, else None.

    A vertical stereo pair's right (second) P has its translation in Ty = P[1, 3] (-fy *
    baseline), not Tx = P[0, 3]. The pair is stacked vertically when Ty_l - Ty_r is a rig's
    (``|Ty_l - Ty_r|`` >= ``least`` px*m, by default :data:`MIN_FOCAL_BASELINE`: a smaller
    one is calibration noise) and larger than ``|Tx_l - Tx_r|``; with a ``baseline`` given
    (``--baseline``, which says the pair is side by side and may come with Tx = 0), when it is
    also at least half of fx * ``baseline``: a Ty below is a side-by-side pair's noise. Neither
    ``--baseline`` nor a remap makes a vertical pair side-by-side.
    """
    with np.errstate(invalid="ignore", over="ignore"):
        tx = float(p_left[0, 3] - p_right[0, 3])
        ty = float(p_left[1, 3] - p_right[1, 3])
        if baseline is not None:
            least = max(least, 0.5 * float(p_left[0, 0]) * baseline)
    if not (np.isfinite(tx) and np.isfinite(ty) and abs(ty) > abs(tx) and abs(ty) >= least):
        return None
    return (
        f"{right_name} has P[1,3] = {p_right[1, 3]:g} and P[0,3] = {p_right[0, 3]:g}: the "
        "cameras are stacked vertically (baseline mostly along y); only side-by-side stereo "
        "pairs are supported: rotate both images and their calibrations by 90 degrees so the "
        "baseline runs along x (--baseline and --rectify do not help)"
    )


def reduced_projection(
    p: npt.NDArray[np.float64], offset: tuple[int, int], binning: tuple[int, int]
) -> npt.NDArray[np.float64]:
    """Return the P of the images a camera takes with a ROI at ``offset`` and ``binning``.

    ``CameraInfo``'s P is the full-resolution camera's (REP 104); the images of a region
    of interest and of binning are described by P with the principal point moved by the
    ROI's offset and the first two rows (fx, cx, Tx; fy, cy) divided by the binning, as
    ``image_geometry``'s ``PinholeCameraModel`` reads them. The baseline (Tx / fx) is kept.
    """
    out = np.array(p, dtype=np.float64).reshape(3, 4)
    out[0, 2] -= offset[0] * out[2, 2]
    out[1, 2] -= offset[1] * out[2, 2]
    out[0] /= max(int(binning[0]), 1)
    out[1] /= max(int(binning[1]), 1)
    return out


def image_projection(message: Any) -> npt.NDArray[np.float64]:
    """Return the P of the images a ``CameraInfo`` (ROS 1 or 2 names) describes.

    Its full-resolution P reduced by its ROI and binning (:func:`reduced_projection`); a
    message without ``roi`` or binning fields (binning 0 = 1) gives its P as it is.
    """
    p = np.asarray(_field(message, "p"), dtype=np.float64).reshape(3, 4)
    roi = _field(message, "roi")
    offset = (0, 0) if roi is None else (int(roi.x_offset), int(roi.y_offset))
    binning = (int(_field(message, "binning_x") or 0), int(_field(message, "binning_y") or 0))
    return reduced_projection(p, offset, binning)


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
        takes = (4, 5) if model == "equidistant" else (4, 5, 8, 12, 14)
        if self.d.size and self.d.size not in takes:
            raise CalibrationError(
                f"{self.name} has {self.d.size} distortion coefficients but {model} takes "
                f"{', '.join(map(str, takes[:-1]))} or {takes[-1]}: fix the calibration, or pass "
                "--calibration FILE, or --rectify never for images that are rectified"
            )
        zeros = [name for name, m in (("K", self.k), ("P", self.p[:, :3])) if not np.any(m)]
        if zeros:  # ROS's "not calibrated"
            raise CalibrationError(uncalibrated(self.name, " and ".join(zeros)))
        self._check_rotation()
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

    def _check_rotation(self) -> None:
        """Refuse an R that is no rotation: all zeros, or not orthonormal with det +1.

        A driver that fills K and D but has no stereo rectification leaves R all zero
        (``camera_info_manager``'s default); its maps send every pixel to one point, and the
        box both cameras see is empty.
        """
        fix = (
            "pass --calibration LEFT.yaml RIGHT.yaml (a stereo calibration, e.g. ROS "
            "camera_calibration's), or --rectify never if the images are rectified"
        )
        if not np.any(self.r):
            raise CalibrationError(
                f"{self.name} has an all-zero R: the stereo rectification is not calibrated "
                f"(a driver that fills only K and D publishes zeros); {fix}"
            )
        with np.errstate(all="ignore"):  # a damaged R (1e200, inf, NaN) is refused below
            error = float(np.abs(self.r @ self.r.T - np.eye(3)).max())
            det = float(np.linalg.det(self.r))
        if not (error <= ROTATION_TOLERANCE and det >= 0):
            raise CalibrationError(
                f"{self.name} has an R that is not a rotation (det {det:.6g}, R R^T off the "
                f"identity by up to {error:.3g}; a rectifying R is orthonormal with det 1); "
                f"fix the calibration or {fix}"
            )

    @classmethod
    def from_camera_info(cls, message: Any, name: str) -> CameraCalibration:
        """Read a ROS 1 or ROS 2 ``CameraInfo`` message.

        An all-zero K with a P, no distortion and R = I describes rectified images by P
        alone (``image_geometry`` projects with P): K is taken as P[:3, :3]. Without a P (or
        with distortion, or a rotation) an all-zero K is "not calibrated", refused.

        Raises:
            CalibrationError: an unknown model, missing or non-finite matrices.
        """
        roi = _field(message, "roi")
        binning = (int(_field(message, "binning_x") or 0), int(_field(message, "binning_y") or 0))
        region = (0, 0, 0, 0)
        if roi is not None:
            region = (int(roi.x_offset), int(roi.y_offset), int(roi.width), int(roi.height))
        k = np.asarray(_field(message, "k"), dtype=np.float64).reshape(3, 3)
        d = np.asarray(_field(message, "d"), dtype=np.float64).reshape(-1)
        r = np.asarray(_field(message, "r"), dtype=np.float64).reshape(3, 3)
        p = np.asarray(_field(message, "p"), dtype=np.float64).reshape(3, 4)
        if not np.any(k) and np.any(p[:, :3]) and not np.any(d) and np.array_equal(r, np.eye(3)):
            k = p[:, :3].copy()  # rectified images described by P alone, as image_geometry reads
        return cls(
            width=int(message.width),
            height=int(message.height),
            model=str(message.distortion_model),
            k=k,
            d=d,
            r=r,
            p=p,
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

    def rectification_maps(
        self, frame: CameraCalibration | None = None
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """Return (map_x, map_y): for each ``image_rect`` pixel, its position in the raw image.

        Args:
            frame: the camera whose rectified image the maps cover (its full-resolution
                size, ROI and binning); this one's by default. A stereo pair's right camera
                is rectified into the left's image: P of both defines one rectified camera,
                whatever size each raw sensor has. The positions are in this camera's raw
                image (its ROI, its binning).
        """
        new_k = self.p[:, :3]
        out = self if frame is None else frame
        size = (out.width, out.height)
        if self.model == "equidistant":
            map_x, map_y = cv2.fisheye.initUndistortRectifyMap(
                self.k, self._fisheye_d(), self.r, new_k, size, cv2.CV_32FC1
            )
        else:
            d = self.d if self.d.size else np.zeros(5)
            map_x, map_y = cv2.initUndistortRectifyMap(self.k, d, self.r, new_k, size, cv2.CV_32FC1)
        x, y, w, h = out.region()
        bx, by = out.binning
        if (x, y, w, h) != (0, 0, out.width, out.height) or (bx, by) != (1, 1):
            # image_proc's reduced maps: the ROI of the full maps, sampled every binning-th
            # pixel (the rectified image's), shifted and scaled into the binned raw image
            map_x = map_x[y : y + h : by, x : x + w : bx][: h // by, : w // bx]
            map_y = map_y[y : y + h : by, x : x + w : bx][: h // by, : w // bx]
        rx, ry, _, _ = self.region()
        rbx, rby = self.binning
        if (rx, ry, rbx, rby) != (0, 0, 1, 1):
            map_x, map_y = (map_x - rx) / rbx, (map_y - ry) / rby
        return np.ascontiguousarray(map_x, np.float32), np.ascontiguousarray(map_y, np.float32)

    def _fisheye_d(self) -> npt.NDArray[np.float64]:
        """Return the (4, 1) coefficients ``cv2.fisheye`` takes: zeros for an empty D."""
        d = np.zeros(4) if self.d.size == 0 else self.d[:4]
        if d.size < 4:
            raise CalibrationError(
                f"{self.name}: the equidistant model needs 4 coefficients, got {self.d.size}"
            )
        return np.asarray(d, np.float64).reshape(4, 1)

    def rectified_projection(self) -> npt.NDArray[np.float64]:
        """Return P of the ``image_rect`` images: moved by the ROI, divided by the binning."""
        x, y, _, _ = self.region()
        return reduced_projection(self.p, (x, y), self.binning)

    def baseline(self, right: CameraCalibration) -> float:
        """Return the baseline (m) of this left camera and ``right``: (Tx_l - Tx_r) / fx.

        NaN or a value <= 0 when their P give none (the caller says what to do).
        """
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            return float((self.p[0, 3] - right.p[0, 3]) / right.p[0, 0])

    def raw_to_rectified(self, pixels: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Return the rectified positions of raw full-resolution pixels (n, 2).

        An empty D is no distortion, as for the maps (an ``equidistant`` one too: it
        raised a reshape ``ValueError`` in the crossed-cables check before).
        """
        points = np.asarray(pixels, np.float64).reshape(-1, 1, 2)
        if self.model == "equidistant":
            out = cv2.fisheye.undistortPoints(
                points, self.k, self._fisheye_d(), R=self.r, P=self.p[:, :3]
            )
        else:
            d = self.d if self.d.size else np.zeros(5)  # as the maps take it
            out = cv2.undistortPoints(points, self.k, d, R=self.r, P=self.p[:, :3])
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
