"""The box of a frame's image its estimate fills, where evaluate's basis rows re-densify.

densify estimates a raw or black-bordered pair in the box both cameras see and writes NaN
outside it; :func:`estimate_box` recovers that box, :class:`Boxed` crops to it and back.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.records import StereoCamera


def estimate_box(has_estimate: npt.NDArray[np.bool_]) -> tuple[int, int, int, int] | None:
    """Return the box (x, y, width, height) a frame's estimate fills exactly, None if none.

    densify estimates a raw or black-bordered pair in the box both cameras see and writes NaN
    outside it; this recovers that box from the NaN.

    Args:
        has_estimate: (H, W) bool, where the stored estimate is not NaN.

    Returns:
        The box, or None when the estimate is empty or not one filled rectangle.
    """
    rows = np.flatnonzero(has_estimate.any(axis=1))
    columns = np.flatnonzero(has_estimate.any(axis=0))
    if rows.size == 0:
        return None
    top, bottom, left, right = rows[0], rows[-1] + 1, columns[0], columns[-1] + 1
    if not has_estimate[top:bottom, left:right].all():
        return None
    return int(left), int(top), int(right - left), int(bottom - top)


@dataclass(frozen=True)
class Boxed:
    """A box (x, y, width, height) of a frame's image, where the basis rows re-densify."""

    box: tuple[int, int, int, int]
    full: StereoCamera

    @property
    def whole(self) -> bool:
        """Return whether the box is the whole image."""
        return self.box == (0, 0, self.full.width, self.full.height)

    @property
    def camera(self) -> StereoCamera:
        """Return the camera of the box (principal point moved by its corner)."""
        x, y, width, height = self.box
        return dataclasses.replace(
            self.full, width=width, height=height, cx=self.full.cx - x, cy=self.full.cy - y
        )

    def inside(self, pixels: npt.NDArray[Any]) -> npt.NDArray[np.bool_]:
        """Return (k,) bool: which (k, 2) (x, y) image px lie in the box."""
        x, y, width, height = self.box
        return (
            (pixels[:, 0] >= x - 0.5)
            & (pixels[:, 0] < x + width - 0.5)
            & (pixels[:, 1] >= y - 0.5)
            & (pixels[:, 1] < y + height - 0.5)
        )

    def points(
        self, pixels: npt.NDArray[Any], disparities: npt.NDArray[Any]
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Return the points in the box, (x, y) in box px, and their disparities (px)."""
        if self.whole:
            return pixels, disparities
        keep = self.inside(pixels)
        corner = np.array(self.box[:2], dtype=np.float64)
        return pixels[keep].astype(np.float64) - corner, disparities[keep].astype(np.float64)

    def crop(self, image: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """Return the box of an (H, W) image."""
        x, y, width, height = self.box
        return image[y : y + height, x : x + width]

    def pad(self, image: npt.NDArray[Any]) -> npt.NDArray[Any]:
        """Return a box-size image placed in a frame-size one, NaN outside the box."""
        if self.whole:
            return image
        x, y, width, height = self.box
        full = np.full(self.full.image_size, np.nan, dtype=image.dtype)
        full[y : y + height, x : x + width] = image
        return full
