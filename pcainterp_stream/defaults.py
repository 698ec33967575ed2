"""Defaults of the estimate chosen by measurement (docs/results.md, "Beyond the paper").

Kept free of imports so that the command line can show them in ``--help`` without loading
numpy or OpenCV.
"""

from __future__ import annotations

ROBUST = "cauchy"
"""IRLS loss of ``densify`` (``--robust``)."""

TEMPORAL = False
"""Whether ``densify`` carries each frame's posterior into the next frame's prior."""

CARRY_FRAMES = 4
"""Earlier frames whose measurements ``densify`` carries into each frame (``--carry-frames``;
0: off), moved by the visual odometry of :mod:`pcainterp_stream.motion`."""

CARRY_GAP = 30.0
"""A carried measurement within this distance (px) of one already used is dropped."""

CARRY_AGE_STD = 1.0
"""Extra noise std (px) per frame of a carried measurement's age."""
