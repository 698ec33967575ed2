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
0: off), moved by the visual odometry of :mod:`pcainterp_stream.frontend.motion`."""

CARRY_GAP = 30.0
"""A carried measurement within this distance (px) of one already used is dropped."""

CARRY_AGE_STD = 1.0
"""Extra noise std (px) per frame of a carried measurement's age."""

STEREO_DOWNSCALE = 2
"""SGBM resolution of ``densify`` on a KITTI-like camera (``--stereo-downscale auto``, the
default, matches others at full resolution: :data:`FULL_RESOLUTION_FB`; ``learn`` matches at
full resolution, 1): half resolution is ~4x cheaper SGBM and the dense map as good there (mean
Delta_2D and +-2 sigma coverage within 1 % of full resolution on the synthetic street log and
both KITTI clips, docs/results.md "Half-resolution SGBM and the dense map"): with disparities
of tens of px the dense map's error is set by the interpolation, not by the lookups' ~0.1 px."""

FULL_RESOLUTION_FB = 90.0
"""``--stereo-downscale auto``: a camera whose f*b (px*m, at the images' size) is below this
is matched at full resolution, one at or above it at half (:data:`STEREO_DOWNSCALE`): f*b is
the disparity (px) of a surface 1 m away, so below 90 px*m a surface beyond 10 m is under 9
px, and half resolution's lookups, biased by +0.1-0.3 px, cost such a camera's dense map up
to 2.2x its error (docs/results.md "Half-resolution SGBM on small-disparity cameras").
KITTI's pair keeps half resolution down to quarter size (f*b ~390 px*m, ~97 at 310x94, where
full resolution lost to nearest-neighbour interpolation in tests/pipeline/test_jobs.py); a
VI-sensor (752x480, f*b ~48), a depth camera (640x480, ~19) or a 1280x720 pair (~84) is
matched at full resolution."""

FULL_RESOLUTION_MAX_PIXELS = 1280 * 720
"""``--stereo-downscale auto``: images larger than this (px) are matched at half resolution
whatever their f*b: full resolution costs ~4x the SGBM of half, ~0.1 s per 1280x720 pair."""

MIN_FILL_SPACING = 10.0
"""Smallest ``--fill-spacing`` (px) the command line takes (0, no lattice, aside): GFTT's
default minimum corner distance, so the lattice is no denser than the corners may be. A
denser lattice measures overlapping SGBM windows (5 px blocks, each lookup's 4x4 px
support) again as if independent, and the estimate's cost grows faster than its points:
on 1226x370 KITTI pairs 40 px is ~370 points and 1 s per frame, 14 px ~1700 and 1.3 s,
10 px ~3300 and 10 s, 1 px never finished."""

DISPLAY_MAX_DEPTH = 60.0
"""Far end (m) of the fixed depth colour range of the Rerun recording and of the ``16UC1``
``--depth-mm`` image (0 to 60 m: KITTI's useful stereo range at f*b ~ 390 px*m is d >= 6.5
px; 16UC1 holds at most 65.535 m). Farther depths, ``+inf`` ("too far") included, take the
far colour; NaN (no estimate) is 0, which viewers leave blank."""

DISPLAY_MAX_DEPTH_STD = 10.0
"""Far end (m) of the fixed colour range of the depth std in the Rerun recording."""

MAX_FEATURES = 500
"""Most points of a feature stream's cloud ``densify`` measures per frame (``--max-features``):
a denser cloud (a LiDAR scan, ``stereo_image_proc``'s ``points2``) is thinned to one point per
cell of a grid (:func:`pcainterp_stream.frontend.features.thin_measurements`). Twice the ~227
points the stereo front end measures on a 620x188 KITTI pair. On 20 frames of a ``points2``
of such pairs (83,000 points per frame) 500 kept 495: 0.25 s per frame, 2-3x a 226-point
cloud's, and a 2.9 % median depth error against the cloud, where the 226 points gave 4.5 %;
250 gave 3.8 %, 1000 2.2 % at ~1 s per frame, 2000 1.8 % at ~2.3 s (the local prior's cost
grows with the square of the points)."""
