"""Checks of the maps ``learn`` learns from: blank or flat.

A map with no disparity above 0 (a black or textureless pair) teaches nothing and is skipped;
SGBM maps that are all flat (the right image is the left one again) are refused.
"""

from __future__ import annotations

from pathlib import Path

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


def shows_surface(disparity: npt.NDArray[np.float32]) -> bool:
    """Return whether a map has a disparity above 0 (SGBM gives 0 all over a black pair)."""
    with np.errstate(invalid="ignore"):
        return bool(np.any(disparity > 0))


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
