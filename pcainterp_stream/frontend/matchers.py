"""The stereo matchers of dense mode (``densify --measurements dense``).

Dense mode outputs SGBM's own value where it matched, so it matches at full resolution;
``--dense-matcher`` chooses how (docs/dense.md).
"""

from __future__ import annotations

from pcainterp_stream.frontend.stereo import SgbmConfig

DENSE_SGBM = SgbmConfig(full_width=True, speckle_window_size=300)
"""The matcher of ``densify --measurements dense``: full resolution (the output is SGBM's own
value where it matched) and the left band matched too (``SgbmConfig.full_width``): the band
is SGBM's largest hole, and most of it is in the right camera's view. Isolated regions of
up to 300 px are removed as speckles (the default matcher: 100): the fusion fills them
better than SGBM matched them, on real and synthetic truth alike (docs/dense.md)."""

REFINED_DENSE_SGBM = SgbmConfig(
    num_disparities=160, full_width=True, speckle_window_size=300, refine_range=8
)
"""Dense mode's cheaper matcher (``densify --measurements dense --dense-matcher refined``):
the whole range at half resolution (160 px: surfaces nearer than 128 px cost little
there), refined at full resolution within +-8 px of it (``SgbmConfig.refine_range``),
~0.55x the matching time of :data:`DENSE_SGBM`. More accurate on the synthetic drives and
the raw drive's hidden blocks, a little less on KITTI's real truth and the odometry clip's
hidden blocks, and its +-2 sigma in the synthetic holes is too narrow (docs/dense.md):
not the default."""

DENSE_MATCHERS = {"full": DENSE_SGBM, "refined": REFINED_DENSE_SGBM}
"""Dense mode's matchers by ``--dense-matcher`` name; ``full`` is the default."""
