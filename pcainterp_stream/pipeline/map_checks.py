"""Checks of the maps ``learn`` learns from: blank, flat, or copies of a few views.

A map with no disparity above 0 (a black or textureless pair) teaches nothing and is skipped;
SGBM maps that are all flat (the right image is the left one again) are refused; maps of a
camera standing still are counted as views (:class:`ViewCount`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import PcaInterpError
from pcainterp_stream.pipeline.common import _echo

BLANK_MAPS = "blank, dark or textureless images, or a depth topic without depth"


FLAT_MAPS = (
    "have almost no disparity (under 1 % of their valid pixels at 1 px or more): the right "
    "image matches the left one where it is"
)
FLAT_FIX = (
    "the right topic may show the left camera again (a remap, a republished left image: check "
    "--right-topic), or the scene is too far for the baseline"
)


def is_flat(disparity: npt.NDArray[np.float32]) -> bool:
    """Return whether under 1 % of a map's valid pixels (>= 0) have a disparity of 1 px or more.

    A pair whose right image is the left one again matches at 0 px everywhere (a few 1 px
    values where a codec's noise differs); every scene near enough to measure has more.
    """
    with np.errstate(invalid="ignore"):
        valid = np.count_nonzero(disparity >= 0)
        return bool(np.count_nonzero(disparity >= 1.0) < 0.01 * valid)


def check_flat(logs: tuple[Path, ...], flat: int, used: int) -> None:
    """Refuse SGBM maps that are all flat (:func:`is_flat`); say so when some are.

    Args:
        logs: the logs learned from (named).
        flat: the flat maps among ``used``.
        used: the maps learned from.

    Raises:
        PcaInterpError: every map is flat.
    """
    if not flat:
        return
    names = ", ".join(log.name for log in logs)
    said = f"{'all' if flat == used else flat} of the {used} SGBM maps {FLAT_MAPS}"
    if flat == used:
        raise PcaInterpError(f"{names}: {said}; {FLAT_FIX}")
    _echo(f"note: {names}: {said}")


def note_blank(logs: tuple[Path, ...], blank: int, used: int) -> None:
    """Say that ``blank`` maps with no disparity above 0 were skipped; refuse when all were.

    One process and a cluster's learn (its chunks count them) say the same.

    Args:
        logs: the logs learned from (named).
        blank: the maps skipped (:func:`shows_surface` false).
        used: the maps learned from.

    Raises:
        PcaInterpError: every map is blank.
    """
    if not blank:
        return
    found = f"{blank} of {blank + used} maps hold no disparity above 0 ({BLANK_MAPS})"
    if not used:
        names = ", ".join(log.name for log in logs)
        raise PcaInterpError(f"{names}: {found}; learn from frames that show the scene")
    _echo(f"note: {found}: they are skipped")


def shows_surface(disparity: npt.NDArray[np.float32]) -> bool:
    """Return whether a map has a disparity above 0 (SGBM gives 0 all over a black pair)."""
    with np.errstate(invalid="ignore"):
        return bool(np.any(disparity > 0))


def far_cut_counts(disparity: npt.NDArray[np.float32], cut: float) -> tuple[int, int]:
    """Return (valid pixels below ``cut``, valid pixels) of a map (:func:`warn_far_cut`)."""
    with np.errstate(invalid="ignore"):
        valid = disparity > 0
        return int(np.count_nonzero(valid & (disparity < cut))), int(np.count_nonzero(valid))


def warn_far_cut(far: int, valid: int, cut: float, focal_baseline: float) -> None:
    """Warn when a basis with no fitted prior would write much of the maps as too far.

    ``densify`` writes a disparity below one noise std (sigma) as depth +inf; a basis with
    no fitted prior (``learn --no-fit-prior``) is densified with the paper's sigma, 2 px,
    which on a camera of small f*b cuts at a few metres: a room of a 640x480 depth camera
    at half size (f*b 9.6 px*m, cut at 4.8 m) was written 80 % too far, 1.156 px against the
    truth where a fitted sigma gave 0.330 (bug hunt 16D F8).

    Args:
        far: valid map pixels below ``cut``.
        valid: valid map pixels.
        cut: the disparity (px, the maps' camera) below which depth is written as +inf.
        focal_baseline: f*b of the maps' camera (px*m).
    """
    if valid == 0 or far < 0.2 * valid:
        return
    metres = f" (beyond {focal_baseline / cut:.3g} m)" if focal_baseline > 0 else ""
    _echo(
        f"warning: {100.0 * far / valid:.0f} % of the maps' pixels have a disparity below "
        f"{cut:.3g} px{metres}, which densify writes as too far (depth +inf) with this basis's "
        "sigma (--no-fit-prior: the paper's 2 px); fit the prior (drop --no-fit-prior) or "
        "densify with a smaller --sigma"
    )


STILL_GREY = 0.75
"""Two left images whose 8x8-block means differ by less than this median |difference| (grey
levels) are one view. Measured (consecutive frames): a synthetic room's one view repeated
with fresh grey-level noise (sigma 2, a camera standing still) 0.23-0.25; moving, a
640x480 and a 1280x720 room 1.55-2.15, a synthetic street 3.6-4.4, KITTI raw 4.3-5.4. SGBM
maps cannot tell them apart: one noisy view's grid maps were 0.27-0.35 px apart, more than
the moving room's 0.16-0.25 (bug hunt 16D F3)."""

VIEW_BLOCK = 8
"""Side (px) of the blocks :class:`ViewCount` averages an image over before comparing."""


def _blocks(image: npt.NDArray[Any]) -> npt.NDArray[np.float32]:
    """Return the means of an image's :data:`VIEW_BLOCK`-px blocks (grey levels)."""
    grey = image.astype(np.float32)
    if grey.ndim == 3:
        grey = grey.mean(axis=2)
    k = VIEW_BLOCK
    height, width = (grey.shape[0] // k) * k, (grey.shape[1] // k) * k
    if not height or not width:
        return grey
    blocks = grey[:height, :width].reshape(height // k, k, width // k, k).mean(axis=(1, 3))
    return np.asarray(blocks, dtype=np.float32)


class ViewCount:
    """Counts the views among each log's SGBM maps by their left images.

    A map is a new view when its left image differs from the newest view's by
    :data:`STILL_GREY` or more. ``densify`` tells a camera standing still by its
    ego-motion and does not adopt a basis of one view; ``learn`` took 28 noisy frames of
    one view as 22 maps, with no word (that basis was 3.4x nearest on another room; bug
    hunt 16D F3). A log with no more views than half its maps is warned of.
    """

    def __init__(self) -> None:
        self.maps: dict[Path, int] = {}
        self.views: dict[Path, int] = {}
        self._last: npt.NDArray[np.float32] | None = None
        self._log: Path | None = None

    def see(self, log: Path, left: npt.NDArray[Any]) -> None:
        """Count one map of ``log`` by its left image (in stream order)."""
        blocks = _blocks(left)
        if log != self._log or self._last is None or self._last.shape != blocks.shape:
            self._log, self._last = log, None
        self.maps[log] = self.maps.get(log, 0) + 1
        if self._last is None or float(np.median(np.abs(blocks - self._last))) >= STILL_GREY:
            self.views[log] = self.views.get(log, 0) + 1
            self._last = blocks

    def check(self) -> None:
        """Warn of each log whose maps are no more views than half their number."""
        for log, maps in self.maps.items():
            views = self.views.get(log, 0)
            if maps < 2 or views * 2 > maps:
                continue
            _echo(
                f"warning: {log.name}: its {maps} maps are {views} "
                f"view{'s' if views != 1 else ''} (consecutive left images within "
                f"{STILL_GREY:g} grey levels: the camera stood still): the basis learns "
                f"{'that view' if views == 1 else 'those views'}, not {maps} maps' worth; "
                "learn from frames where the camera moves through the scene"
            )
