"""How small an image the stereo front end measures, and what ``densify`` says when it cannot.

Two limits hold whatever the images show:

* SGBM needs more columns than its disparity range (:mod:`.sgbm_limits`): dense mode's
  default (refined) matcher needs 17 px at least (its +-8 px pass), whatever
  ``--num-disparities``.
* Sparse mode's points (Shi-Tomasi corners and the lattice in their gaps) are searched
  ``GfttConfig.border`` px (8) from every edge and right of SGBM's unmatched band
  (:func:`.corners.detect_corners`, :func:`.stereo.sparse_lookups`): on an image smaller
  than :func:`points_floor` (17x17 px with full-width matching) there is no place for one.

Above them small images still give little: SGBM drops a matched region of up to
``speckle_window_size`` px (dense mode 300) as a speckle, and the points keep their border.
Measured on random-dot pairs (the best texture there is; disparities 2, 5, 8 and 12 px, two
seeds each, widths and heights of 12-96 px): both modes had frames without a measurement on
most sizes with a side under 32 px (sparse mode all 8 pairs with a side of 16 px or less, up
to 7 of 8 with a side of 17-28 px; dense mode all 8 up to 28x24 px, 4 of 8 at 96x12, 1 at
64x16) and none on any size with both sides of 32 px or more. :data:`SMALL_SIDE` is that
size: densify's "no measurement" warning names the images' size for frames smaller than it,
instead of only blaming their content.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from pcainterp_stream.frontend.sgbm_limits import fitting, narrowest_width

SMALL_SIDE = 32
"""A frame without a measurement whose images have a side under this (px) is said to be
too small to match (random-dot pairs with both sides at least this always had measurements,
in both modes: the module's docstring)."""

SMALLEST_RANGE = 16
"""SGBM's smallest disparity range (px): ``--num-disparities`` is a multiple of 16."""


def points_floor(gftt: Any, min_x: int) -> tuple[int, int]:
    """Return the smallest image (width, height px) with a place for a sparse point.

    Corners and lattice points are searched ``gftt.border`` px from every edge and right of
    ``min_x`` (SGBM's unmatched band, 0 when the band is matched too).
    """
    border = int(gftt.border)
    return max(border, min_x) + border + 1, 2 * border + 1


def too_narrow(width: int, sgbm: Any) -> str | None:
    """Why SGBM cannot match images ``width`` px wide, and what to pass; None when it can.

    ``sgbm`` is an :class:`~.stereo.SgbmConfig`; the text follows "images ... are".
    """
    needed = narrowest_width(sgbm)
    if width >= needed:
        return None
    fits = fitting(sgbm, width)
    if fits is not None:
        fix = f"pass --num-disparities {fits.num_disparities} (or less, a multiple of 16)"
    else:
        smallest = narrowest_width(replace(sgbm, num_disparities=SMALLEST_RANGE))
        fix = (
            f"no disparity range fits images this narrow: the smallest, {SMALLEST_RANGE} "
            f"disparities, needs {smallest} px"
        )
    return (
        f"{width} px wide, narrower than the {needed} px SGBM needs for "
        f"{sgbm.num_disparities} disparities; {fix}"
    )


def too_small_for_points(width: int, height: int, gftt: Any, sgbm: Any) -> str | None:
    """Why sparse mode can place no point on images of this size; None when it can.

    The text follows "images ... are".
    """
    floor_w, floor_h = points_floor(gftt, int(sgbm.valid_min_x))
    if width >= floor_w and height >= floor_h:
        return None
    band = int(sgbm.valid_min_x)
    where = f"{gftt.border} px from every edge"
    if band > gftt.border:
        where += f" and right of SGBM's {band} px unmatched band (--num-disparities narrows it)"
    return (
        f"{width}x{height} px, under the {floor_w}x{floor_h} px (width x height) sparse mode "
        f"needs to place a measurement (its corners and lattice points are {where})"
    )


def small_images_cause(width: int, height: int, gftt: Any, sgbm: Any) -> str | None:
    """Why a frame of this size had no measurement, if its size says so (None: it does not).

    ``gftt``: sparse mode's detector settings (None in dense mode).
    """
    if gftt is not None and (problem := too_small_for_points(width, height, gftt, sgbm)):
        return f"images of {problem}"
    return empty_cause((width, height)) if min(width, height) < SMALL_SIDE else None


def empty_cause(size: tuple[int, int] | None) -> str:
    """The cause said in densify's warning for frames without a measurement.

    ``size`` (width, height px) is that of such a frame's small images (a side under
    :data:`SMALL_SIDE`), None when none was that small.
    """
    if size is None:
        return "blank, dark or textureless images"
    width, height = size
    return (
        f"{width}x{height} px images: under {SMALL_SIDE} px a side SGBM's speckle filter and the "
        "points' border leave little to match; or blank, dark or textureless ones"
    )
