"""The stereo matchers of dense mode (``densify --measurements dense``).

Dense mode outputs SGBM's own value where it matched, so it matches at full resolution;
``--dense-matcher`` chooses how (docs/dense.md).
"""

from __future__ import annotations

from pcainterp_stream.frontend.stereo import GfttConfig, SgbmConfig

DENSE_SGBM = SgbmConfig(full_width=True, speckle_window_size=300)
"""Dense mode's whole-range matcher (``--dense-matcher full``): full resolution (the output is
SGBM's own value where it matched) and the left band matched too (``SgbmConfig.full_width``):
the band is SGBM's largest hole, and most of it is in the right camera's view. Isolated
regions of up to 300 px are removed as speckles (the default matcher: 100): the fusion fills
them better than SGBM matched them, on real and synthetic truth alike (docs/dense.md). Also
dense mode's matcher at half resolution (``--stereo-downscale 2``)."""

REFINED_DENSE_SGBM = SgbmConfig(
    num_disparities=160, full_width=True, speckle_window_size=300, refine_range=8
)
"""The matcher of ``densify --measurements dense`` (``--dense-matcher refined``, the
default): the whole range at half resolution (160 px: surfaces nearer than 128 px cost
little there), refined at full resolution within +-8 px of it (``SgbmConfig.refine_range``;
textureless pixels removed, weak ones marked), ~0.55x the matching time of
:data:`DENSE_SGBM`, and as accurate or more on every source measured (docs/dense.md)."""

DENSE_MATCHERS = {"refined": REFINED_DENSE_SGBM, "full": DENSE_SGBM}
"""Dense mode's matchers by ``--dense-matcher`` name."""

DEFAULT_DENSE_MATCHER = "refined"
"""The ``--dense-matcher`` of ``densify --measurements dense`` when none is given."""


DENSE_GFTT = GfttConfig(max_corners=0, fill_spacing=34.0, fill_placement="lattice")
"""The points of dense mode's own sparse estimate (the field that fills SGBM's holes and
weighs its matches) at full resolution: a lattice of SGBM lookups 34 px apart over the
whole searched area, no Shi-Tomasi corners. The corners cluster on texture and on object
outlines, where a lookup is least sure and where a hole's surface is not; the even lattice
fills the holes better on real and synthetic truth alike, with fewer points and no corner
detector (docs/dense.md). ``--corners`` and ``--fill-spacing`` change it."""

HALF_DENSE_GFTT = GfttConfig(fill_placement="lattice")
"""The points of dense mode's sparse estimate at half resolution: sparse mode's corners and
40 px lattice, its points not nudged (dense mode was measured with the plain lattice)."""


def dense_points(downscale: int | None = None) -> GfttConfig:
    """Return the points of dense mode's sparse estimate for its matcher's ``downscale``.

    :data:`DENSE_GFTT`, except at half resolution (``downscale`` 2), where the upsampled map
    is better served by the sparse mode's corners and lattice (:data:`HALF_DENSE_GFTT`).
    """
    return HALF_DENSE_GFTT if downscale == 2 else DENSE_GFTT


def dense_matcher(name: str | None, downscale: int | None = None) -> str:
    """Return the name of the matcher dense mode runs.

    ``name`` (None: the default), except at half resolution (``downscale`` 2), where there is
    nothing to refine: ``full``, at half resolution.
    """
    if downscale == 2:
        return "full"
    return DEFAULT_DENSE_MATCHER if name is None else name
