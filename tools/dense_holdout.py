"""Score dense mode's hole filling on real KITTI frames by hiding blocks of SGBM's own map.

Real clips have no ground truth, and SGBM's real holes have no reference. This hides
square blocks of dense mode's SGBM map (full resolution, the left band matched too) where it
is valid (seeded, right of the left band), so the hidden values are a reference for what
fills them: nearest-neighbour fill (evaluate's ``sgbm_nn``), the sparse estimate (PCA-MAP
from dense mode's lookups of the masked map: its lattice, or the corners ``--corners``
asks for; densify's defaults with the built-in basis) and dense mode's fusion. The blocks
are textured surfaces SGBM matched, not the sky or
occlusions real holes often are, so this measures the fill of holes in matched surfaces
only (docs/dense.md).

    python tools/dense_holdout.py --frames 12 --blocks 40 --block-size 32
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import harness
import numpy as np

from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.dense import field_options, find_holes, fuse_dense
from pcainterp_stream.estimate.estimator import densify
from pcainterp_stream.evaluate.metrics import fill_nearest
from pcainterp_stream.frontend.matchers import (
    DEFAULT_DENSE_MATCHER,
    DENSE_MATCHERS,
    dense_points,
)
from pcainterp_stream.frontend.stereo import (
    GfttConfig,
    SgbmConfig,
    compute_weak_disparity,
    sparse_lookups,
    to_grey8,
)
from pcainterp_stream.io.kitti import iter_frames, open_kitti
from pcainterp_stream.pipeline.processor import ProcessorConfig, resolve_settings


def score_clip(
    folder: Path,
    *,
    frames: int,
    every: int,
    blocks: int,
    size: int,
    seed: int,
    matcher: str = DEFAULT_DENSE_MATCHER,
    gftt: GfttConfig | None = None,
) -> dict[str, float]:
    """Mean abs. error (px) on the hidden pixels of each filler, and dense mode's coverage.

    ``matcher``: dense mode's matcher by ``--dense-matcher`` name (``DENSE_MATCHERS``);
    ``gftt``: the sparse estimate's points (None: densify's own, ``dense_points``), looked
    up as densify does.
    """
    gftt = gftt or dense_points()
    basis = Basis.default()
    settings = resolve_settings(basis, ProcessorConfig(measurements="dense"))
    sgbm = DENSE_MATCHERS[matcher]
    left_band = SgbmConfig().band  # the blocks lie where any matcher has the whole range
    rng = np.random.default_rng(seed)
    sums = {"hidden px": 0.0, "nearest": 0.0, "sparse": 0.0, "dense": 0.0, "inside": 0.0}
    sequence = open_kitti(folder)
    for index, frame in enumerate(iter_frames(sequence, max_frames=frames * every)):
        if index % every:
            continue
        full, weak = compute_weak_disparity(frame.left, frame.right, sgbm)
        height, width = full.shape
        mask = np.zeros(full.shape, bool)
        for _ in range(blocks):
            y = int(rng.integers(0, height - size))
            x = int(rng.integers(left_band, width - size))
            mask[y : y + size, x : x + size] = True
        hidden = mask & np.isfinite(full)
        masked = np.where(mask, np.float32(np.nan), full)
        grey = to_grey8(frame.left)
        found = sparse_lookups(grey, masked, gftt, min_x=sgbm.valid_min_x)
        estimate = densify(
            basis,
            found.pixels,
            found.disparities,
            robust=ProcessorConfig().robust,
            image_size=(height, width),
            focal_baseline=sequence.camera.focal_baseline,
            **settings.densify_options(),
            **field_options(basis),
        )
        fused = fuse_dense(estimate, masked, holes=find_holes(masked, weak, zero_is_match=True))
        assert fused.disparity_std is not None
        truth = full[hidden]
        sums["hidden px"] += hidden.sum()
        filled = fill_nearest(masked)
        assert filled is not None  # the blocks leave most of the map valid
        sums["nearest"] += np.abs(filled[hidden] - truth).sum()
        sums["sparse"] += np.abs(estimate.disparity[hidden] - truth).sum()
        error = np.abs(fused.disparity[hidden] - truth)
        sums["dense"] += error.sum()
        sums["inside"] += (error <= 2 * fused.disparity_std[hidden]).sum()
        harness.log(f"{folder.name} frame {index}: {hidden.sum()} hidden px")
    count = max(sums["hidden px"], 1.0)
    return {
        "hidden px": sums["hidden px"],
        "nearest": sums["nearest"] / count,
        "sparse": sums["sparse"] / count,
        "dense": sums["dense"] / count,
        "coverage": sums["inside"] / count,
    }


def main(argv: Sequence[str] | None = None) -> int:
    """Print the table of docs/dense.md (real clips, hidden blocks)."""
    parser = harness.argument_parser(__doc__)
    harness.add_realdata(parser)
    parser.add_argument("--frames", type=int, default=12, help="frames per clip")
    parser.add_argument("--every", type=int, default=4, help="take every N-th frame")
    parser.add_argument("--blocks", type=int, default=40, help="hidden blocks per frame")
    parser.add_argument("--block-size", type=int, default=32, help="block side (px)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--matcher",
        choices=sorted(DENSE_MATCHERS),
        default=DEFAULT_DENSE_MATCHER,
        help="dense mode's matcher (densify --dense-matcher; default refined)",
    )
    harness.add_dense_points(parser)
    args = parser.parse_args(argv)
    clips = {
        "KITTI raw drive 0001": args.realdata / harness.KITTI_RAW_0001,
        "KITTI odometry clip": args.realdata / harness.KITTI_ODOMETRY_CLIP,
    }
    missing = [str(path) for path in clips.values() if not path.is_dir()]
    if missing:
        parser.error(f"{', '.join(missing)} not found; pass --realdata FOLDER")
    print(
        harness.table_header(
            ["clip", "hidden px", "nearest fill px", "sparse px", "dense px", "dense +-2 sigma"]
        )
    )
    for name, folder in clips.items():
        scores = score_clip(
            folder,
            frames=args.frames,
            every=args.every,
            blocks=args.blocks,
            size=args.block_size,
            seed=args.seed,
            matcher=args.matcher,
            gftt=harness.dense_points(args),
        )
        print(
            harness.table_row(
                [
                    name,
                    f"{scores['hidden px']:.0f}",
                    f"{scores['nearest']:.2f}",
                    f"{scores['sparse']:.2f}",
                    f"{scores['dense']:.2f}",
                    f"{100 * scores['coverage']:.1f} %",
                ]
            )
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
