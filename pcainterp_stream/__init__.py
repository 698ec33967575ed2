"""pcainterp_stream: densify sparse depth in stereo-camera logs with a learned PCA basis.

The method is Ochs, Bradler & Mester, "Learning Rank Reduced Interpolation with Principal
Component Analysis" (IEEE IV 2017); see ``docs/estimator.md`` for the maths and the README
for the contracts.
"""

from __future__ import annotations

from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.dense import DenseModel, fuse_dense
from pcainterp_stream.estimate.estimator import (
    DensifyResult,
    SolveForm,
    Uncertainty,
    densify,
    densify_batch,
)
from pcainterp_stream.estimate.finetune import finetune_basis
from pcainterp_stream.estimate.learning import LearnMethod, learn_basis, preprocess_disparity
from pcainterp_stream.version import __version__

__all__ = [
    "Basis",
    "DenseModel",
    "DensifyResult",
    "LearnMethod",
    "SolveForm",
    "Uncertainty",
    "__version__",
    "densify",
    "densify_batch",
    "finetune_basis",
    "fuse_dense",
    "learn_basis",
    "preprocess_disparity",
]
