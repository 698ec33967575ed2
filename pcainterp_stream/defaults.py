"""Defaults of the estimate chosen by measurement (docs/results.md, "Beyond the paper").

Kept free of imports so that the command line can show them in ``--help`` without loading
numpy or OpenCV.
"""

from __future__ import annotations

ROBUST = "cauchy"
"""IRLS loss of ``densify`` (``--robust``)."""

TEMPORAL = False
"""Whether ``densify`` carries each frame's posterior into the next frame's prior."""
