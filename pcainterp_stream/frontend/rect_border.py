"""The black border of rectified images used as they are (``image_rect``; no I/O).

A rectification that keeps every raw pixel (OpenCV ``stereoRectify`` with ``alpha`` > 0,
Kalibr, ``image_proc`` after a calibration made so, fisheye ``balance`` > 0) leaves parts of
the rectified image that no raw pixel reaches: a black border along the image edge. Stereo
matching and the basis would take that border for scene. A raw pair is estimated in the box
of the rectified image both cameras see (:func:`frontend.rectify.valid_box`); a pair
rectified already is given the same box here, found once per calibration:

- from the camera infos recorded with the images, when they carry the raw calibration (D !=
  0, R != I or K != P: ROS publishes ``image_rect`` beside the raw camera's ``CameraInfo``),
  for images of the calibration's size: the pixels whose raw position is outside either raw
  image (:func:`calibration_border`), exactly the raw path's box;
- else from the images: pixels that are 0 in every channel, connected to the image edge, in
  every frame seen so far (:func:`black_border`), widened by a pixel for the interpolation's
  blend with the black. Black scene content is not taken for a border: an image that is dark,
  or whose black fades out through near-black pixels instead of ending in a blend with the
  scene, is not counted (:func:`frame_border`); a pixel that is not black in one frame is no
  border from then on; a border under :data:`MIN_BORDER_SHARE` of the frame is none. The
  images are looked at on the first :data:`LOOK_FRAMES` frames of a camera at most, and the
  box is decided by the first :data:`EVIDENCE_FRAMES` that give evidence: a later frame
  changes nothing, and a box that grows by less than :data:`SAY_AGAIN` of the frame is not
  taken, so the camera does not change mid-log for a pixel.

Right images shifted onto the left's cx (:mod:`frontend.right_cx`) have black columns at
one edge, the ones the shift brings in: they are border whatever the images show, with any
``--rectify`` (:func:`shift_band`, the pixels whose source lies outside the recorded image, as
:func:`frontend.rectify.invalid_pixels` marks a remap's), and the black found in the images is
looked for beside them.

The estimate is then made in the box and padded back with no estimate (NaN) outside
(:func:`frontend.rectify.pad_result`), so corners, lattice lookups and stereo matching never
see the border.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import CalibrationError
from pcainterp_stream.frontend.rectify import box_without, invalid_pixels
from pcainterp_stream.frontend.right_cx import on_left_cx
from pcainterp_stream.io.camera_model import StereoCalibration
from pcainterp_stream.records import StereoCamera

__all__ = [
    "DARK_LEVEL",
    "DARK_SHARE",
    "EVIDENCE_FRAMES",
    "LOOK_FRAMES",
    "MIN_BORDER_SHARE",
    "MIN_BOX",
    "RING_CONTRAST",
    "SAY_AGAIN",
    "BorderFinder",
    "RectifiedBorder",
    "black_border",
    "calibration_border",
    "frame_border",
    "inner_camera",
    "shift_band",
]

MIN_BORDER_SHARE = 0.005
"""A border found in the images that covers less of the frame is none (stray black pixels)."""

DARK_SHARE = 0.5
"""An image black at its edge over this share or more is dark, not bordered: not counted."""


DARK_LEVEL = 0.04
"""An image whose median is under this share of its type's range is dark: not counted."""

RING_CONTRAST = 0.5
"""Pixels beyond a border darker than this times the image's median: black content, not one."""

MIN_BOX = 32
"""A box narrower or lower than this (px) is no box: the border is not taken."""


SAY_AGAIN = 0.01
"""A box from the images is replaced only when its area changes by this share of the frame.

The border from the images only shrinks from frame to frame (a pixel that is not black once
is no border), so the box kept holds none of a later border: it is replaced (and the new one
said) only when the new one is larger by this much. A box one pixel wider would change the
camera mid-log for nothing.
"""

LOOK_FRAMES = 100
"""Frames of a camera whose images are looked at for a border, at most (dark or not)."""

EVIDENCE_FRAMES = 5
"""Frames that give evidence (not dark, not black content) after which the border is decided."""


@dataclass(frozen=True)
class RectifiedBorder:
    """Where rectified images used as they are are border, and the box estimated inside it.

    Attributes:
        box: (x, y, width, height) in px of the box of the image with no border pixel.
        camera: the rectified camera at the images' full size.
        inner: the camera of the box (principal point moved by the box's corner).
        border_share: share of the image that is border in either camera (0-1).
        source: what found the border, for the line that says so (empty: only the shift's).
        shifted: what the right images' shift onto the left's cx brings in (empty: none).
    """

    box: tuple[int, int, int, int]
    camera: StereoCamera
    inner: StereoCamera
    border_share: float
    source: str
    shifted: str = ""

    def crop(self, image: npt.NDArray[np.generic]) -> npt.NDArray[np.generic]:
        """Return the box of a (height, width[, channels]) image at the camera's size."""
        x, y, w, h = self.box
        return image[y : y + h, x : x + w]

    def line(self) -> str:
        """Return the line that says what is masked, how much and why."""
        x, y, w, h = self.box
        full = self.camera
        outside = 1.0 - (w * h) / float(full.width * full.height)
        why = [
            f"{self.source}: the rectified view reaches beyond the raw images, as alpha > 0 or "
            "a fisheye balance > 0 makes it"
        ]
        why = (why if self.source else []) + ([self.shifted] if self.shifted else [])
        return (
            f"rectified border: {100 * self.border_share:.1f} % of the {full.width}x"
            f"{full.height} frame is border in the left or the right image ({'; '.join(why)}); "
            f"estimated in the {w}x{h} box at ({x}, {y}) inside it, no estimate (NaN) in the "
            f"{100 * outside:.1f} % outside the box"
        )


def inner_camera(camera: StereoCamera, box: tuple[int, int, int, int]) -> StereoCamera:
    """Return the camera of a box (x, y, width, height) of ``camera``'s image."""
    x, y, w, h = box
    return replace(camera, width=w, height=h, cx=camera.cx - x, cy=camera.cy - y)


def shift_band(size: tuple[int, int], shift: float) -> tuple[npt.NDArray[np.bool_], str] | None:
    """Return the pixels a right image's shift brings in, and what the line says of them.

    Args:
        size: (width, height) of the images in px.
        shift: px the right images are moved right (left when negative) onto the left's cx
            (:func:`frontend.right_cx.shift_image`).

    Returns:
        (height, width) bool, the columns whose source x - ``shift`` is outside the recorded
        image, as :func:`frontend.rectify.invalid_pixels` marks a remap's (so the box leaves
        out the columns a remapped pair's would), and the reason; None for no shift.
    """
    if shift == 0:
        return None
    width, height = size
    map_x = np.tile(np.arange(width, dtype=np.float32) - np.float32(shift), (height, 1))
    map_y = np.tile(np.arange(height, dtype=np.float32)[:, None], (1, width))
    band = invalid_pixels([(map_x, map_y)], size)
    columns = int(band[0].sum())
    where = "left" if shift > 0 else "right"
    return band, (
        f"the {columns} column{'' if columns == 1 else 's'} at the {where} of the right images "
        f"that their {shift:+g} px shift onto the left's cx brings in, black"
    )


def calibration_border(
    calibration: StereoCalibration, size: tuple[int, int]
) -> npt.NDArray[np.bool_] | None:
    """Return (height, width) bool: the ``image_rect`` pixels no raw pixel of a camera reaches.

    Args:
        calibration: the pair's raw calibration (K, D, R, P), as the camera infos recorded
            with ``image_rect`` carry it.
        size: (width, height) of the images in px.

    Returns:
        The mask, as :func:`frontend.rectify.valid_box` takes it; all False when no pixel's
        raw position is more than a pixel outside (an ``alpha`` = 0 rectification maps a few
        pixels a fraction of a pixel outside: blends of the edge, not a black border). None
        when the calibration tells nothing of these images: it says they are rectified (D =
        0, R = I, K = P), is for another size, or has no maps. The right camera's pixels are
        those of its images moved onto the left's cx, as the pairer moves them
        (:mod:`frontend.right_cx`).
    """
    left, right = calibration.left, on_left_cx(calibration.left, calibration.right)
    if calibration.is_rectified or not (left.image_size() == right.image_size() == size):
        return None
    try:
        maps = [left.rectification_maps(), right.rectification_maps()]
    except (CalibrationError, cv2.error):
        return None
    bad = invalid_pixels(maps, size, size)
    width, height = size
    black = np.zeros_like(bad)
    for map_x, map_y in maps:  # black whatever the interpolation: over a pixel outside
        black |= (map_x < -1) | (map_x > width) | (map_y < -1) | (map_y > height)
    return bad if black.any() else black


def black_border(image: npt.NDArray[np.generic]) -> npt.NDArray[np.bool_]:
    """Return (height, width) bool: pixels 0 in every channel connected to the image edge.

    Args:
        image: (height, width) or (height, width, channels) image, any dtype.
    """
    black = _black(image)
    if not black.any():
        return np.asarray(black, dtype=bool)
    _, labels = cv2.connectedComponents(black.astype(np.uint8), connectivity=4)
    edge = np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])
    touching = np.unique(edge[edge > 0])  # label 0: the pixels that are not black
    return np.asarray(np.isin(labels, touching), dtype=bool)


def frame_border(image: npt.NDArray[np.generic]) -> npt.NDArray[np.bool_] | None:
    """Return an image's black border (:func:`black_border`), or None when it tells nothing.

    A rectification's border ends in a pixel or two of blend with the scene; black scene
    content fades out through near-black pixels. An image tells nothing when it is dark (its
    median under :data:`DARK_LEVEL` of its type's range; a 16-bit image of 12-bit data is
    always dark here, so its border is never taken), when its edge is black over
    :data:`DARK_SHARE` of it or more, or when the pixels two to three pixels beyond its black
    are darker than :data:`RING_CONTRAST` times the rest of the image.

    Args:
        image: (height, width) or (height, width, channels) image, any dtype.
    """
    array = np.asarray(image)
    if _dark(array):  # first, on every 4th pixel: a dark frame costs ~1 ms, not 20-100
        return None
    black = black_border(array)
    if not black.any():
        return black
    grey = array.astype(np.float32)
    if grey.ndim == 3:
        grey = grey.mean(axis=2)
    if black.mean() >= DARK_SHARE:
        return None
    blend = _widen(black)
    ring = _widen(_widen(blend)) & ~blend
    if not ring.any() or float(np.median(grey[ring])) < RING_CONTRAST * float(
        np.median(grey[~black])
    ):
        return None
    return black


class BorderFinder:
    """Find the border of rectified pairs used as they are, once per calibration.

    Args:
        echo: given the line that says what is masked, when a border is first found and
            when its box changes by :data:`SAY_AGAIN` of the frame or more.
    """

    def __init__(self, echo: Callable[[str], None] | None = None) -> None:
        self._echo = echo
        self._key: tuple[object, ...] | None = None
        self._border: RectifiedBorder | None = None
        self._silent: tuple[object, ...] | None = None  # a calibration that tells nothing
        self._sides: list[npt.NDArray[np.bool_] | None] = [None, None]  # black in every frame
        self._looked = 0  # frames of this camera looked at
        self._evidence = 0  # of them, frames that gave evidence on a side
        self._band_key: tuple[tuple[int, int], float] | None = None
        self._band_value: tuple[npt.NDArray[np.bool_], str] | None = None

    def find(
        self,
        left: npt.NDArray[np.generic],
        right: npt.NDArray[np.generic],
        camera: StereoCamera,
        calibration: StereoCalibration | None,
        *,
        shift: float = 0.0,
        look: bool = True,
    ) -> RectifiedBorder | None:
        """Return the border of a pair of rectified images, or None when they have none.

        Args:
            left: (height, width[, channels]) left rectified image.
            right: the right image, of the same shape.
            camera: the rectified camera of the images at their full size.
            calibration: the raw calibration recorded with them, or None.
            shift: px the right image was moved onto the left's cx: the columns that brings
                in are border (:func:`shift_band`).
            look: whether to look for a border (``--rectify never``: only the shift's).
        """
        height, width = left.shape[:2]
        if right.shape[:2] != (height, width):
            return None
        size = (int(width), int(height))
        band = self._band(size, shift)
        if calibration is not None and look:
            key: tuple[object, ...] = ("calibration", calibration.key(), size, camera, shift)
            if key == self._key:
                return self._border
            if key != self._silent:
                bad = calibration_border(calibration, size)
                if bad is not None:
                    self._key, self._sides = key, [None, None]
                    source = "no raw pixel maps there by the raw calibration of the camera infos"
                    if not bad.any() and band is not None:  # only the shift's
                        self._set(band[0], camera, "", shifted=band[1])
                    else:
                        self._set(bad | _mask(band, size), camera, source, shifted=_why(band))
                    return self._border
                self._silent = key  # it tells nothing of these images: they are looked at
        key = ("images", size, camera, shift, look)
        if key != self._key:
            self._key, self._sides, self._border = key, [None, None], None
            self._looked = self._evidence = 0
            if band is not None:  # border from the first frame on, whatever the images show
                self._set(band[0], camera, "", shifted=band[1])
        if not look or all(side is not None and not side.any() for side in self._sides):
            return (
                self._border
            )  # no border on either side: black in every frame from now on cannot be
        if self._looked >= LOOK_FRAMES or self._evidence >= EVIDENCE_FRAMES:
            return self._border  # decided: the camera stays for the rest of the log
        self._looked += 1
        changed = evidence = False
        for index, image in enumerate((left, right)):
            seen = self._sides[index]
            if seen is not None:  # a border stays one while its pixels stay black
                if _dark(image):
                    continue  # black wherever it is dark: it tells nothing
                kept, evidence = seen & _black(image), True
                if not np.array_equal(kept, seen):
                    self._sides[index], changed = kept, True
                continue
            black = frame_border(image)
            if black is not None:  # else a dark frame, or black scene content: no evidence
                if index == 1 and band is not None:  # the shift's black is said as such
                    black = black & ~band[0]
                self._sides[index], changed, evidence = black, True, True
        self._evidence += evidence
        if changed:
            sides = [side for side in self._sides if side is not None]
            union = np.logical_or.reduce(sides) if sides else np.zeros((height, width), bool)
            if union.mean() < MIN_BORDER_SHARE:
                if band is None:
                    self._border = None
                else:
                    self._set(band[0], camera, "", shifted=band[1])
            else:
                # widened by a pixel: the interpolation blended the next pixels with the black
                wide = _widen(union) | _mask(band, size)
                source = "black (0) at the image edge in every frame so far"
                share = float((union | _mask(band, size)).mean())
                self._set(wide, camera, source, share=share, keep_close=True, shifted=_why(band))
        return self._border

    def _band(
        self, size: tuple[int, int], shift: float
    ) -> tuple[npt.NDArray[np.bool_], str] | None:
        """Return :func:`shift_band` of a size and shift, made once per pair of them."""
        if (size, shift) != self._band_key:
            self._band_key, self._band_value = (size, shift), shift_band(size, shift)
        return self._band_value

    def _set(
        self,
        bad: npt.NDArray[np.bool_],
        camera: StereoCamera,
        source: str,
        *,
        share: float | None = None,
        keep_close: bool = False,
        shifted: str = "",
    ) -> None:
        """Keep the border of a mask of bad pixels and say it (None when there is none).

        A box under :data:`MIN_BOX` px a side is no box to estimate in: the images are then
        used whole (a calibration that does not describe them). With ``keep_close`` (a border
        from the images, which only shrinks), the box kept stays unless the new one's area
        differs by :data:`SAY_AGAIN` of the frame or more. A border of another ``source``
        (the shift's alone, then black found in the images) is taken and said in any case.
        """
        box = box_without(bad)
        if not bad.any() or min(box[2], box[3]) < MIN_BOX:
            self._border = None
            return
        previous = self._border
        close = (
            previous is not None
            and previous.source == source
            and abs(_area(previous.box) - _area(box)) < SAY_AGAIN * bad.size
        )
        if close and keep_close:
            return  # the border only shrinks: the box kept holds none of it
        self._border = RectifiedBorder(
            box=box,
            camera=camera,
            inner=inner_camera(camera, box),
            border_share=float(bad.mean()) if share is None else share,
            source=source,
            shifted=shifted,
        )
        if self._echo is not None and not close:
            self._echo(self._border.line())


def _mask(
    band: tuple[npt.NDArray[np.bool_], str] | None, size: tuple[int, int]
) -> npt.NDArray[np.bool_]:
    """Return the pixels of a :func:`shift_band` (none for no shift)."""
    return band[0] if band is not None else np.zeros((size[1], size[0]), dtype=bool)


def _why(band: tuple[npt.NDArray[np.bool_], str] | None) -> str:
    return band[1] if band is not None else ""


def _area(box: tuple[int, int, int, int]) -> int:
    return box[2] * box[3]


def _widen(mask: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """Return the mask grown by a pixel (3x3); outside the image counts as not in it."""
    grown = cv2.dilate(
        mask.astype(np.uint8),
        np.ones((3, 3), np.uint8),
        borderType=cv2.BORDER_CONSTANT,
        borderValue=0,
    )
    return np.asarray(grown > 0, dtype=bool)


def _dark(image: npt.NDArray[np.generic]) -> bool:
    """Return whether the median of every 4th pixel is under :data:`DARK_LEVEL` of the range.

    A 16-bit image of 10-bit data, or of 12-bit data with a median under 2621, is always dark:
    it costs this look only, on at most :data:`LOOK_FRAMES` frames.
    """
    array = np.asarray(image)
    sample = array[::4, ::4].astype(np.float32)
    if sample.ndim == 3:
        sample = sample.mean(axis=2)
    full_scale = float(np.iinfo(array.dtype).max) if array.dtype.kind in "iu" else 1.0
    return float(np.median(sample)) < DARK_LEVEL * full_scale


def _black(image: npt.NDArray[np.generic]) -> npt.NDArray[np.bool_]:
    """Return (height, width) bool: the pixels 0 in every channel."""
    black = np.asarray(image) == 0
    if black.ndim == 3:
        black = black.all(axis=2)
    return np.asarray(black, dtype=bool)
