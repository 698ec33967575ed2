"""Fit the built-in basis's edge-aware cell weight w by the evidence, on synthetic and real frames.

The edge-aware local prior (``pcainterp_stream/estimate/cells.py``) scales the local kernel
between measurements of different cells of the SGBM-geodesic partition by w. This script
measures frames as ``densify`` does (GFTT corners and lattice looked up in half-resolution
SGBM, no carried points), makes each frame's cells along that SGBM map, and prints the
summed log evidence of every candidate w (:func:`fitting.fit_cell_weight`) with the
built-in basis's kernel and sigma kept, per source:

- ``synth``: the basis's own fit drive (``pcainterp synth --frames 40 --seed 150``, the
  frames sigma and the std calibration were fitted on);
- ``odometry`` and ``raw``: the two KITTI clips from pair ``--kitti-first`` on (the first
  40 pairs are the ones ``sparse_sharpness.py`` scores).

``--cell-weight W`` stores W (chosen by hand, e.g. on the real clips) instead of the
evidence's choice. The std calibration fitted for the stationary kernel does not hold for
another model: the std factor is refitted as the basis's fit does (``fit_std_scale``: 95.4 %
of the SGBM reference within +-2 std on the fit drive, densified as ``densify`` does, with
and without the per-frame covariance scale), once with w and once with the stationary
kernel in the same run; the shipped factors are multiplied by their ratio.

``--write`` stores w, the table of ``cell_weight_log_evidence`` and the rescaled std
factors in the built-in basis's ``meta["prior"]``; its arrays are kept.

    python tools/fit_cell_weight.py
    python tools/fit_cell_weight.py --sources synth --cell-weight 0.75 --write
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import harness
import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate import fitting
from pcainterp_stream.estimate.basis import Basis, default_basis_path
from pcainterp_stream.estimate.cells import Partition
from pcainterp_stream.estimate.estimator import clean_measurements
from pcainterp_stream.estimate.prior import LocalPrior
from pcainterp_stream.frontend.stereo import StereoFrontEnd
from pcainterp_stream.pipeline.processor import ProcessorConfig

Pair = tuple[npt.NDArray[Any], npt.NDArray[Any], tuple[int, int], float]
"""left, right, (height, width), f*b."""


def _synth_pairs(seed: int, frames: int) -> Iterator[Pair]:
    from pcainterp_stream.synth import SynthConfig, generate

    for item in generate(SynthConfig(seed=seed, frames=frames)):
        camera = item.camera
        yield item.left, item.right, camera.image_size, camera.focal_baseline


def _kitti_pairs(folder: Path, first: int, frames: int) -> Iterator[Pair]:
    from pcainterp_stream.io.kitti import iter_frames, open_kitti

    sequence = open_kitti(folder)
    camera = sequence.camera
    for index, item in enumerate(iter_frames(sequence, max_frames=first + frames)):
        if index >= first:
            yield item.left, item.right, camera.image_size, camera.focal_baseline


def evidence_table(basis: Basis, pairs: Iterator[Pair]) -> tuple[float, dict[float, float], int]:
    """Return (best w, log evidence per w, frames) of the pairs, measured as densify does."""
    config = ProcessorConfig()
    front_end = StereoFrontEnd(config.gftt, config.sgbm)
    frames: list[fitting.FitFrame] = []
    cells: list[npt.NDArray[np.int64]] = []
    for left, right, image_size, focal_baseline in pairs:
        measured = front_end.measure(left, right)
        pixels, disparities, _ = clean_measurements(
            measured.pixels, measured.disparities, image_size, zero_is_match=True
        )
        frame = fitting.fit_frame(
            basis, pixels, disparities, image_size=image_size, focal_baseline=focal_baseline
        )
        # seeded by the frame's own measurements, as densify's stereo workers do
        found = Partition.along(measured.disparity_map, pixels, image_size, basis.grid_size)
        frames.append(frame)
        cells.append(np.zeros(0, np.int64) if found is None else found.cells(pixels).point_cells)
    prior = basis.meta["prior"]
    local = LocalPrior.from_meta(prior["local"])
    best, scores = fitting.fit_cell_weight(
        basis, frames, cells, local=local, sigma=float(prior["sigma"])
    )
    return best, scores, len(frames)


def std_scales(basis: Basis, pairs: Iterator[Pair], weight: float) -> tuple[float, float]:
    """Return (std_scale, innovation_std_scale) fitted with cell weight ``weight`` and with 1.

    Each returned factor is the one fitted with ``weight`` over the one fitted with the
    stationary kernel on the same frames (``fitting.fit_std_scale``).
    """
    from pcainterp_stream.estimate.estimator import densify
    from pcainterp_stream.estimate.prior import covariance_scale

    config = ProcessorConfig()
    front_end = StereoFrontEnd(config.gftt, config.sgbm)
    prior = basis.meta["prior"]
    shipped = LocalPrior.from_meta(prior["local"])
    fitted: dict[float, tuple[float, float]] = {}
    measured = [(front_end.measure(left, right), size, fb) for left, right, size, fb in pairs]
    for cell_weight in (weight, 1.0):
        local = dataclasses.replace(shipped, cell_weight=cell_weight)
        estimates, stds, scaled, references = [], [], [], []
        for one, image_size, focal_baseline in measured:
            result = densify(
                basis,
                one.pixels,
                one.disparities,
                sigma=float(prior["sigma"]),
                local_prior=local,
                robust=config.robust,
                image_size=image_size,
                focal_baseline=focal_baseline,
                edge_map=one.disparity_map,
                zero_is_match=True,
            )
            assert result.disparity_std is not None
            estimates.append(result.disparity)
            stds.append(result.disparity_std)
            factor = covariance_scale(result.normalised_innovation, result.n_measurements)
            scaled.append(result.disparity_std * np.float32(np.sqrt(factor)))
            references.append(np.where(one.disparity_map > 0, one.disparity_map, np.nan))
        fitted[cell_weight] = (
            fitting.fit_std_scale(estimates, stds, references),
            fitting.fit_std_scale(estimates, scaled, references),
        )
    return (
        fitted[weight][0] / fitted[1.0][0],
        fitted[weight][1] / fitted[1.0][1],
    )


def main(argv: list[str] | None = None) -> int:
    """Print the evidence of each cell weight per source; optionally store the fitted one."""
    parser = harness.argument_parser(__doc__)
    harness.add_realdata(parser)
    parser.add_argument(
        "--sources",
        nargs="+",
        default=["synth", "odometry", "raw"],
        choices=["synth", "odometry", "raw"],
    )
    parser.add_argument("--synth-seed", type=int, default=150)
    parser.add_argument("--synth-frames", type=int, default=40)
    parser.add_argument("--kitti-first", type=int, default=40, help="first pair of the clips")
    parser.add_argument("--kitti-frames", type=int, default=40)
    parser.add_argument(
        "--cell-weight", type=float, help="store this w instead of the evidence's choice"
    )
    parser.add_argument("--write", action="store_true", help="store w in the built-in basis")
    parser.add_argument("--write-source", default="synth", choices=["synth", "odometry", "raw"])
    args = parser.parse_args(argv)
    realdata: Path = args.realdata
    basis = Basis.default()
    makers = {
        "synth": lambda: _synth_pairs(args.synth_seed, args.synth_frames),
        "odometry": lambda: _kitti_pairs(
            realdata / harness.KITTI_ODOMETRY_CLIP, args.kitti_first, args.kitti_frames
        ),
        "raw": lambda: _kitti_pairs(
            realdata / harness.KITTI_RAW_0001, args.kitti_first, args.kitti_frames
        ),
    }
    fitted: dict[str, tuple[float, dict[float, float]]] = {}
    for source in args.sources:
        best, scores, count = evidence_table(basis, makers[source]())
        fitted[source] = (best, scores)
        top = max(scores.values())
        print(f"\n{source}: {count} frames, best w {best:g}")
        print(harness.table_header(["w", "log evidence - best (nats)"], "lr"))
        for weight, score in scores.items():
            print(harness.table_row([f"{weight:g}", f"{score - top:.1f}"]), flush=True)
    if args.write and args.write_source not in fitted:
        parser.error(f"--write-source {args.write_source} is not among --sources")
    if args.cell_weight is not None or args.write:
        best, scores = fitted[args.write_source]
        weight = best if args.cell_weight is None else args.cell_weight
        ratio, innovation_ratio = std_scales(basis, makers[args.write_source](), weight)
        prior = dict(basis.meta["prior"])
        print(
            f"\nstd factor with w {weight:g} / stationary ({args.write_source}): {ratio:.4f}, "
            f"with the per-frame scale {innovation_ratio:.4f}"
        )
        if not args.write:
            return 0
        prior["local"] = {**prior["local"], "cell_weight": weight}
        prior["cell_weight_log_evidence"] = {f"{w:g}": s for w, s in scores.items()}
        prior["cell_weight_fit"] = " ".join(["tools/fit_cell_weight.py", *(argv or sys.argv[1:])])
        for key, factor in (("std_scale", ratio), ("innovation_std_scale", innovation_ratio)):
            prior[f"{key}_stationary"] = prior[key]
            prior[key] = prior[key] * factor
        updated = dataclasses.replace(basis, meta={**basis.meta, "prior": prior})
        updated.save(default_basis_path())
        print(f"wrote cell_weight {weight:g} into {default_basis_path()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
