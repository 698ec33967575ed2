"""pcainterp_stream: densify sparse depth in stereo-camera logs with a learned PCA basis.

The method is Ochs, Bradler & Mester, "Learning Rank Reduced Interpolation with Principal
Component Analysis" (IEEE IV 2017); see ``docs/estimator.md`` for the maths and the README
for the contracts.

The names below are imported on first use (NumPy, OpenCV and the estimator take ~0.4 s), so
that the ``pcainterp`` command is in charge of its signals from its first instruction: a
Ctrl-C while it starts gets its one-line message, not Python's traceback.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
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
    from pcainterp_stream.estimate.prior import LocalPrior, Robust, TemporalPrior
    from pcainterp_stream.version import __version__

_HOMES = {
    "Basis": "estimate.basis",
    "DenseModel": "estimate.dense",
    "fuse_dense": "estimate.dense",
    "DensifyResult": "estimate.estimator",
    "SolveForm": "estimate.estimator",
    "Uncertainty": "estimate.estimator",
    "densify": "estimate.estimator",
    "densify_batch": "estimate.estimator",
    "finetune_basis": "estimate.finetune",
    "LearnMethod": "estimate.learning",
    "learn_basis": "estimate.learning",
    "preprocess_disparity": "estimate.learning",
    "LocalPrior": "estimate.prior",
    "Robust": "estimate.prior",
    "TemporalPrior": "estimate.prior",
    "__version__": "version",
}
"""Each public name's module, below the package."""

__all__ = [
    "Basis",
    "DenseModel",
    "DensifyResult",
    "LearnMethod",
    "LocalPrior",
    "Robust",
    "SolveForm",
    "TemporalPrior",
    "Uncertainty",
    "__version__",
    "densify",
    "densify_batch",
    "finetune_basis",
    "fuse_dense",
    "learn_basis",
    "preprocess_disparity",
]


def __getattr__(name: str) -> Any:
    """Import a public name's module on first use (PEP 562) and keep the name here."""
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{home}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
