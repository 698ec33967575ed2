"""pcainterp_stream: densify sparse depth in stereo-camera logs with a learned PCA basis.

The method is Ochs, Bradler & Mester, "Learning Rank Reduced Interpolation with Principal
Component Analysis" (IEEE IV 2017); see ``DESIGN.md`` for the maths and the contracts.
"""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__"]
