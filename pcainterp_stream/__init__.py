"""pcainterp_stream: densify sparse depth in stereo-camera logs with a learned PCA basis.

The method is Ochs, Bradler & Mester, "Learning Rank Reduced Interpolation with Principal
Component Analysis" (IEEE IV 2017); see ``DESIGN.md`` for the maths and the contracts.
"""

from __future__ import annotations

__version__ = "0.1.0"

from pcainterp_stream.basis import Basis
from pcainterp_stream.estimator import (
    DensifyResult,
    SolveForm,
    Uncertainty,
    densify,
    densify_batch,
)
from pcainterp_stream.learning import LearnMethod, learn_basis, preprocess_disparity

__all__ = [
    "Basis",
    "DensifyResult",
    "LearnMethod",
    "SolveForm",
    "Uncertainty",
    "__version__",
    "densify",
    "densify_batch",
    "learn_basis",
    "preprocess_disparity",
]
