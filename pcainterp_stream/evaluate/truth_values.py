"""The depth values that tell a synthetic log of earlier versions: its sky is NaN, not +inf.

``pcainterp synth`` writes the sky (no surface) as +inf, "too far" (REP 118); earlier
versions wrote NaN, which REP 118 reads as "no value". A depth topic with NaN but not a single
+inf (and not NaN only) is likely such a log: ``evaluate`` notes that it scores no truth
there, ``learn --depth-topic`` that it fills those pixels from the nearest one with a depth.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["DepthValues"]


@dataclass
class DepthValues:
    """Counts of a depth topic's values that hold no depth (NaN) or a far one (+inf).

    Examples:
        >>> values = DepthValues()
        >>> values.add(np.array([[1.0, np.nan], [2.0, 3.0]]))
        >>> values.nan_sky(), f"{values.nan_share():.0%}"
        (True, '25%')
        >>> values.add(np.array([[np.inf]]))
        >>> values.nan_sky()
        False
    """

    pixels: int = 0
    nan: int = 0
    far: int = 0

    def add(self, depth: npt.NDArray[np.floating[Any]]) -> None:
        """Count one depth image (m): NaN holds no depth, +inf is too far."""
        self.pixels += depth.size
        self.nan += int(np.count_nonzero(np.isnan(depth)))
        self.far += int(np.count_nonzero(np.isposinf(depth)))

    def add_disparity(self, disparity: npt.NDArray[np.floating[Any]]) -> None:
        """Count one disparity image f*b/depth: NaN holds no depth, 0 is too far (+inf)."""
        self.pixels += disparity.size
        self.nan += int(np.count_nonzero(np.isnan(disparity)))
        self.far += int(np.count_nonzero(disparity == 0))

    def nan_sky(self) -> bool:
        """Whether the values look like an earlier synthetic log's: NaN, never +inf."""
        return bool(self.nan) and not self.far and self.nan != self.pixels

    def nan_share(self) -> float:
        """Return the share of the pixels counted that are NaN (0 without pixels)."""
        return self.nan / self.pixels if self.pixels else 0.0
