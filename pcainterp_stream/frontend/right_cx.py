"""A right rectified camera whose P has another cx than the left's, moved onto the left's cx.

``cv2.stereoRectify`` without ``CALIB_ZERO_DISPARITY`` (and a Middlebury-style ``doffs``)
gives the two rectified cameras different principal points: a point at depth Z is seen at
x_left - x_right = fx * baseline / Z + (cx_left - cx_right), and ROS ``image_geometry``
reads such a pair to the letter (``StereoCameraModel::getZ`` is -Tx_r / (disparity -
(cx_l - cx_r))). Everything after the pairer (SGBM's disparity range, depth = fx * baseline
/ disparity, the row check) takes disparities without that offset, so the right image is
brought onto the left's cx before it, and the left camera's P describes the pair:

- a remapped pair (:class:`frontend.rectify.StereoRectifier`): the right camera is remapped
  with its P's cx replaced by the left's (:func:`on_left_cx`), an exact rectification into
  the left's rectified image;
- images used as they are (rectified already): the right image is shifted horizontally by
  cx_left - cx_right px (:func:`shift_image`, bicubic as the remap; the columns shifted in
  are black, and left out of the estimate as a remapped pair's box leaves out the columns
  no raw pixel reaches: :func:`frontend.rect_border.shift_band`, with any ``--rectify``).

No I/O; the line the ``rectify`` decision says is :func:`cx_note`.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.io.camera_model import CameraCalibration, image_projection

__all__ = ["CX_TOLERANCE_PX", "as_is_shift", "cx_note", "on_left_cx", "shift_image"]

CX_TOLERANCE_PX = 0.01
"""Largest difference (px) of the two P's cx taken as equal (printed with 3-6 decimals)."""


def on_left_cx(left: CameraCalibration, right: CameraCalibration) -> CameraCalibration:
    """Return ``right`` with its P's cx replaced by the left's (``right`` when they agree)."""
    if abs(float(left.p[0, 2] - right.p[0, 2])) <= CX_TOLERANCE_PX:
        return right
    p = right.p.copy()
    p[0, 2] = left.p[0, 2]
    return replace(right, p=p)


def cx_note(cx_right: float, cx_left: float) -> str:
    """Return what the ``rectify`` line says of a right cx moved (empty when they agree)."""
    if abs(cx_left - cx_right) <= CX_TOLERANCE_PX:
        return ""
    return (
        f"; right cx {cx_right:g} -> {cx_left:g} px (the right P's cx is not the left's: "
        f"disparities would be off by {cx_left - cx_right:+g} px, as image_geometry reads "
        "the pair)"
    )


def as_is_shift(left_info: Any, right_info: Any) -> tuple[float, str]:
    """Return (px, note): the shift of right images used as they are, and what it does.

    cx_left - cx_right of the P of the images the two ``CameraInfo`` describe (moved by
    their ROI, divided by their binning); (0.0, "") when they agree, or when an info is
    missing or its P gives no camera (all zeros, non-finite, no positive fx and fy: the
    caller refuses or ignores that P).
    """
    if left_info is None or right_info is None:
        return 0.0, ""
    try:
        cx = []
        for info in (left_info, right_info):
            p = image_projection(info)
            if not (np.isfinite(p).all() and p[0, 0] > 0 and p[1, 1] > 0):
                return 0.0, ""
            cx.append(float(p[0, 2]))
    except (TypeError, ValueError, AttributeError):
        return 0.0, ""
    shift = cx[0] - cx[1]
    if abs(shift) <= CX_TOLERANCE_PX:
        return 0.0, ""
    return shift, f"{cx_note(cx[1], cx[0])}: the right images shifted by {shift:+g} px"


def shift_image(image: npt.NDArray[Any], shift: float) -> npt.NDArray[Any]:
    """Return ``image`` moved right by ``shift`` px (left when negative); black shifted in.

    A whole number of pixels is a copy; a fraction is interpolated bicubically, as the
    remap of a raw pair is (:meth:`frontend.rectify.StereoRectifier.rectify_one`).
    """
    if shift == 0:
        return image
    width = image.shape[1]
    whole = round(shift)
    if abs(shift - whole) < 1e-6:
        out = np.zeros_like(image)
        if whole > 0:
            out[:, min(whole, width) :] = image[:, : max(width - whole, 0)]
        else:
            out[:, : max(width + whole, 0)] = image[:, min(-whole, width) :]
        return out
    matrix = np.array([[1.0, 0.0, shift], [0.0, 1.0, 0.0]])
    moved = cv2.warpAffine(
        np.ascontiguousarray(image),
        matrix,
        (width, image.shape[0]),
        flags=cv2.INTER_CUBIC,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0,
    )
    return np.asarray(moved, dtype=image.dtype).reshape(image.shape)
