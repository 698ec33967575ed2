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
