"""Exact posterior std: how far the variance grid's std is from the exact std at every pixel.

``densify(..., uncertainty="exact-coarse")`` evaluates the posterior variance on a grid
coarser than the output image and resamples it; ``uncertainty="exact"`` evaluates it at
every output pixel. This measures, on **learned** bases and real front-end measurements,
the std of each setting against a reference computed here independently of the
estimator's variance code: the exact posterior std at **every output pixel**,

    var(x) = b(x)^T Lambda b(x) + v - ||L^-1 (B~ Lambda b(x) + c(P, x))||^2   (float64)

with b(x) the bilinear row of the basis at pixel x (the model the measurements are sampled
with, docs/estimator.md "Grid"), c(P, x) the hybrid prior's local kernel at x itself (v = 0 and
no c without it) and K = L L^T rebuilt from the frame's measurements, noise and IRLS
weights. Errors are also given against stride 1 (the exact std on the basis grid itself,
resampled), the finest grid setting.

Cases (logs and bases made by the jobs of the command line, cached in ``--work-dir``):

- synthetic: ``pcainterp synth`` (training log, seed 2; test log, seed 7; full size), bases
  learned by ``pcainterp learn`` from the training log's SGBM maps with ``--fit-prior``
  (hybrid prior) and without (the paper's prior);
- KITTI: ``pcainterp import-kitti`` of the raw drive 2011_09_26_0001 (found in
  ``--realdata``; skipped when absent), bases learned the same two ways from its first
  ``--kitti-train`` frames, tested on frames after them.

Measurements: the GFTT + SGBM lookups of each test frame as ``densify`` measures them
(``beyond_data.prepare_log``, cached); the estimate as ``densify`` resolves it from the basis
(fitted sigma, local prior and std calibration; Cauchy IRLS), without temporal prior or
carried points. Reference disparity of the +-2 sigma coverage and the Gaussian NLL: the
ground truth (synthetic) or the SGBM map of the pair (KITTI; as ``pcainterp evaluate`` does
without ground truth), at every pixel where it is valid.

Relative std error (std - reference) / reference, pooled over the test frames' pixels: at
the measurement pixels (rounded) and at pixels more than ``--far`` px from every
measurement. Time: ``densify_batch`` per frame in batches of 4 with BLAS on one thread, as
the stream processor runs it (best of ``--repeat`` after a warm-up; ``exact`` once).

    python tools/bench_variance_grid.py --work-dir /tmp/bvg
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import cv2
import harness
import numpy as np
import numpy.typing as npt
from beyond_data import LogData, prepare_log
from scipy.linalg import solve_triangular
from threadpoolctl import threadpool_limits

from pcainterp_stream import Basis, DensifyResult, densify_batch
from pcainterp_stream.allocator import keep_freed_memory
from pcainterp_stream.estimate.basis import bilinear_weights, image_to_grid, sample_rows
from pcainterp_stream.estimate.prior import covariance_scale
from pcainterp_stream.estimate.variance import _variance_stride
from pcainterp_stream.evaluate.metrics import calibration_sums
from pcainterp_stream.pipeline.processor import (
    EstimateSettings,
    ProcessorConfig,
    resolve_settings,
)

KITTI_FRAMES = 108
REFERENCE = "reference (float64, tool)"
FINEST = "finest grid"
FloatArray = npt.NDArray[np.float64]
StdMap = npt.NDArray[np.float32]
COLUMNS = (
    "case",
    "std",
    "RMS at points",
    "p99 at points",
    "RMS away",
    "p99 away",
    "+-2 sigma coverage %",
    "NLL nats/px",
    "ms/frame",
)


@dataclass(frozen=True)
class Setting:
    """One way of computing the std: a label and its ``densify_batch`` keywords."""

    label: str
    options: dict[str, Any]
    stride: int | None = None  # the variance stride, None: not on a variance grid
    rounds: int | None = None  # timing rounds; None: --repeat after a warm-up


@dataclass(frozen=True)
class Case:
    """One basis on one test log."""

    name: str
    basis: Path
    prior: str  # "hybrid" or "paper"
    log: Path
    cache: Path
    truth: bool
    frames: tuple[int, ...]


@dataclass
class Pooled:
    """Relative std errors against one reference, pooled over frames."""

    at_points: list[FloatArray] = field(default_factory=list)
    far: list[FloatArray] = field(default_factory=list)

    def cells(self) -> list[str]:
        """Markdown cells: RMS and p99 of |relative error| (%), at points and away."""
        at = np.abs(np.concatenate(self.at_points))
        far = np.abs(np.concatenate(self.far))
        return [
            f"{100 * np.sqrt(np.mean(at**2)):.1f}",
            f"{100 * np.percentile(at, 99):.1f}",
            f"{100 * np.sqrt(np.mean(far**2)):.2f}",
            f"{100 * np.percentile(far, 99):.2f}",
        ]


@dataclass
class Outcome:
    """Everything measured for one setting on one case."""

    errors: dict[str, Pooled] = field(default_factory=dict)  # by reference label
    sums: dict[str, float] = field(default_factory=dict)
    seconds: float = float("nan")

    def add_sums(self, sums: dict[str, float]) -> None:
        """Accumulate :func:`evaluate.metrics.calibration_sums` of one frame."""
        for key, value in sums.items():
            self.sums[key] = self.sums.get(key, 0.0) + value


# ----------------------------------------------------------------------------- inputs


def prepare(args: argparse.Namespace) -> list[Case]:
    """Make (once) the logs and bases of every case; return the cases."""
    work = harness.work_dir(args.work_dir)
    cases: list[Case] = []
    train = _log(work / f"synth_train_s2_{args.synth_train}.mcap", args.synth_train, seed=2)
    test = _log(work / f"synth_test_s7_{args.synth_test}.mcap", args.synth_test, seed=7)
    frames = tuple(range(min(args.frames, args.synth_test)))
    for prior in ("hybrid", "paper"):
        path = work / f"basis_synth_{prior}_l{args.synth_components}.npz"
        basis = _basis(path, train, prior, args.synth_components)
        cache = work / "cache_synth_test"
        cases.append(Case(f"synthetic, {prior}", basis, prior, test, cache, True, frames))
    drive = args.realdata / harness.KITTI_RAW_0001
    if args.skip_kitti:
        return cases
    if not drive.is_dir():
        print(f"no KITTI drive at {drive}: KITTI cases skipped", file=sys.stderr)
        return cases
    kitti_all = harness.cached(
        work / "kitti_0001.mcap", harness.build_kitti(drive), f"import-kitti {drive}"
    )
    kitti_train = harness.cached(
        work / f"kitti_0001_first{args.kitti_train}.mcap",
        harness.build_kitti(drive, max_frames=args.kitti_train),
        f"import-kitti {drive}, the first {args.kitti_train} frames",
    )
    # test frames after the training frames, spread over the rest of the drive
    rest = np.arange(args.kitti_train, KITTI_FRAMES)
    picked = rest[np.linspace(0, rest.size - 1, min(args.frames, rest.size)).astype(int)]
    frames = tuple(int(i) for i in picked)
    for prior in ("hybrid", "paper"):
        path = work / f"basis_kitti_{prior}_l{args.kitti_components}.npz"
        basis = _basis(path, kitti_train, prior, args.kitti_components)
        cache = work / "cache_kitti_0001"
        cases.append(Case(f"KITTI, {prior}", basis, prior, kitti_all, cache, False, frames))
    return cases


def _log(path: Path, frames: int, seed: int) -> Path:
    """A full-size synthetic log, rendered once (``pcainterp synth``)."""
    return harness.cached(path, harness.build_synth(frames=frames, seed=seed), f"synth {path}")


def _basis(path: Path, train: Path, prior: str, components: int) -> Path:
    """A basis learned once from ``train`` (``pcainterp learn``, ``--fit-prior`` for hybrid)."""
    build = harness.build_basis([train], components=components, fit_prior=prior == "hybrid")
    return harness.cached(path, build, f"learn {path} from {train}")


# ----------------------------------------------------------------------------- reference


def exact_std(
    basis: Basis,
    result: DensifyResult,
    settings: EstimateSettings,
    image_size: tuple[int, int],
    rows_per_chunk: int = 16,
) -> StdMap:
    """Return the exact posterior std (H, W) of one frame at every output pixel (float64).

    Rebuilt from the frame's measurements, noise and IRLS weights (``result``), the basis
    and the local prior alone: K = B~ Lambda B~^T + C_pp + diag(sigma^2 / w) = L L^T and
    var(x) = b(x)^T Lambda b(x) + v - ||L^-1 (B~ Lambda b(x) + c(P, x))||^2, scaled as
    ``densify`` scales its std (calibration factor and the frame's covariance scale).
    """
    height, width = image_size
    to_basis = basis.focal_baseline / result.focal_baseline if result.focal_baseline else 1.0
    local = settings.local_prior
    k = result.n_measurements
    indices, weights = bilinear_weights(
        image_to_grid(result.pixels, image_size, basis.grid_size), basis.grid_size
    )
    rows = sample_rows(basis.pixel_major, indices, weights).astype(np.float64)
    prior_rows = rows * basis.eigenvalues  # B~ Lambda
    system = prior_rows @ rows.T
    positions = image_to_grid(result.pixels, image_size, basis.image_size)
    if local is not None and k:
        system += local.matrix(positions)
    noise_weights = np.ones(k) if result.weights is None else result.weights
    system[np.diag_indices(k)] += result.sigma**2 / noise_weights
    lower = np.linalg.cholesky(system) if k else np.zeros((0, 0))
    scale = settings.std_scale
    if settings.scale_by_innovation:
        scale *= np.sqrt(covariance_scale(result.normalised_innovation, k))
    xs = np.arange(width, dtype=np.float64)
    along_x = None
    if local is not None:
        basis_x = image_to_grid(
            np.stack([xs, np.zeros_like(xs)], axis=1), image_size, basis.image_size
        )[:, 0]
        along_x = local.axis(positions[:, 0], basis_x)  # (k, W)
    std = np.empty(image_size, dtype=np.float32)
    for top in range(0, height, rows_per_chunk):
        ys = np.arange(top, min(top + rows_per_chunk, height), dtype=np.float64)
        grid_y, grid_x = np.meshgrid(ys, xs, indexing="ij")
        pixels = np.stack([grid_x.ravel(), grid_y.ravel()], axis=1)
        at_indices, at_weights = bilinear_weights(
            image_to_grid(pixels, image_size, basis.grid_size), basis.grid_size
        )
        b = sample_rows(basis.pixel_major, at_indices, at_weights).astype(np.float64)  # (n, l)
        variance = (b * b) @ basis.eigenvalues
        joint = prior_rows @ b.T  # (k, n)
        if local is not None and along_x is not None:
            basis_y = image_to_grid(
                np.stack([np.zeros_like(ys), ys], axis=1), image_size, basis.image_size
            )[:, 1]
            along_y = local.axis(positions[:, 1], basis_y)  # (k, rows)
            joint += (local.variance * along_y[:, :, None] * along_x[:, None, :]).reshape(k, -1)
            variance += local.variance
        if k:
            projected = solve_triangular(lower, joint, lower=True, check_finite=False)
            variance -= np.einsum("kn,kn->n", projected, projected)
        chunk = np.sqrt(np.maximum(variance, 0.0)) * (scale / to_basis)
        std[top : top + ys.size] = chunk.reshape(ys.size, width)
    return std


# ----------------------------------------------------------------------------- measurement


def masks(
    pixels: FloatArray, image_size: tuple[int, int], far: float
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
    """Return (the measurement pixels (rounded), pixels farther than ``far`` px from all)."""
    height, width = image_size
    cols = np.clip(np.rint(pixels[:, 0]).astype(int), 0, width - 1)
    rows = np.clip(np.rint(pixels[:, 1]).astype(int), 0, height - 1)
    at = np.zeros(image_size, dtype=bool)
    at[rows, cols] = True
    distance = cv2.distanceTransform((~at).astype(np.uint8), cv2.DIST_L2, 5)
    return at, distance > far


def densify_frames(
    basis: Basis,
    data: LogData,
    frames: list[int],
    batch: int,
    options: dict[str, Any],
    results: list[DensifyResult],
) -> None:
    """Densify ``frames`` in batches as the stream processor does; replace ``results``."""
    results.clear()
    for start in range(0, len(frames), batch):
        indices = frames[start : start + batch]
        results += densify_batch(
            basis,
            [data.pixels[i] for i in indices],
            [data.disparities[i] for i in indices],
            **options,
        )


def run_case(
    case: Case, settings_list: Sequence[Setting], args: argparse.Namespace
) -> dict[str, Outcome]:
    """Measure every setting on one case; return the outcomes by setting label."""
    basis = Basis.load(case.basis)
    data = prepare_log(
        case.log, case.cache, (basis.image_size, basis.focal_baseline), truth=case.truth
    )
    references = data.reference()
    camera = data.camera
    settings = resolve_settings(basis, ProcessorConfig(prior=case.prior))
    common: dict[str, Any] = {
        "robust": ProcessorConfig().robust,
        "image_size": camera.image_size,
        "focal_baseline": camera.focal_baseline,
        **settings.densify_options(),
    }
    frames = [i for i in case.frames if i < data.frames]
    outcomes = {s.label: Outcome() for s in settings_list}
    stds: dict[str, list[StdMap]] = {}
    first: list[DensifyResult] = []
    with threadpool_limits(args.blas_threads, user_api="blas"):
        for setting in settings_list:
            rounds = args.repeat + 1 if setting.rounds is None else setting.rounds
            results: list[DensifyResult] = []
            options = {**common, **setting.options}
            run = partial(densify_frames, basis, data, frames, args.batch, options, results)
            # the first of several rounds warms the caches up
            timing = harness.timed(run, max(rounds - 1, 1), warmup=rounds > 1)
            outcomes[setting.label].seconds = timing.best / len(frames)
            stds[setting.label] = [
                np.zeros(0, np.float32) if r.disparity_std is None else r.disparity_std
                for r in results
            ]
            first = first or results
    with harness.Stopwatch() as watch:
        stds[REFERENCE] = [exact_std(basis, r, settings, camera.image_size) for r in first]
    outcomes[REFERENCE] = Outcome(seconds=watch.wall / len(frames))
    finest = min((s for s in settings_list if s.stride is not None), key=lambda s: s.stride or 0)
    stds[FINEST] = stds[finest.label]
    for index, frame in enumerate(frames):
        at, far = masks(first[index].pixels, camera.image_size, args.far)
        reference = np.asarray(references[frame], dtype=np.float64)
        valid = np.isfinite(reference) & (reference >= 0)
        for label, outcome in outcomes.items():
            std = stds[label][index].astype(np.float64)
            for against in (REFERENCE, FINEST):
                exact = stds[against][index].astype(np.float64)
                relative = (std - exact) / np.maximum(exact, 1e-9)
                pooled = outcome.errors.setdefault(against, Pooled())
                pooled.at_points.append(relative[at])
                pooled.far.append(relative[far])
            outcome.add_sums(calibration_sums(first[index].disparity, std, reference, valid))
    return outcomes


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; print Markdown tables."""
    parser = harness.argument_parser(
        __doc__, formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    harness.add_work_dir(parser, description="cache folder")
    harness.add_realdata(parser)
    parser.add_argument("--skip-kitti", action="store_true", help="synthetic cases only")
    parser.add_argument("--synth-train", type=int, default=300, help="training log frames")
    parser.add_argument("--synth-test", type=int, default=12, help="test log frames")
    parser.add_argument("--synth-components", type=int, default=200, help="l (synthetic)")
    parser.add_argument("--kitti-train", type=int, default=86, help="first N frames train")
    parser.add_argument("--kitti-components", type=int, default=60, help="l (KITTI)")
    parser.add_argument("--frames", type=int, default=8, help="test frames per case")
    parser.add_argument("--far", type=float, default=10.0, help="'away' = farther (px)")
    parser.add_argument(
        "--strides", type=int, nargs="+", default=[2, 1], help="exact-coarse strides to add"
    )
    harness.add_batch_timing(parser, repeat=2, repeat_help="timing: best of N rounds")
    args = parser.parse_args(argv)
    keep_freed_memory()  # as the stream processor does
    cases = prepare(args)
    results = []
    strides: set[int] = set()
    for case in cases:
        basis = Basis.load(case.basis)
        stride = _variance_stride(basis, None)
        settings = [Setting(f"exact-coarse, default (stride {stride})", {}, stride)]
        settings += [
            Setting(f"exact-coarse, stride {s}", {"variance_stride": s}, s)
            for s in args.strides
            if s != stride
        ]
        settings.append(Setting("exact", {"uncertainty": "exact"}, rounds=1))
        strides.update(s.stride for s in settings if s.stride is not None)
        with harness.Stopwatch() as watch:
            outcomes = run_case(case, settings, args)
        frames = len(case.frames)
        results.append((case, basis, outcomes))
        print(
            f"{case.name}: l = {basis.n_components}, grid {basis.grid_size[1]}x"
            f"{basis.grid_size[0]}, {frames} frames, {watch.wall:.0f} s",
            file=sys.stderr,
            flush=True,
        )
    finest = f"the finest variance grid (exact-coarse, stride {min(strides, default=1)})"
    for against, title in ((REFERENCE, "the exact std at every pixel"), (FINEST, finest)):
        print(
            f"\nRelative std error against {title} (%; 'points' = the measurement pixels, "
            f"'away' = > {args.far:g} px from all)\n"
        )
        print(harness.table_header(COLUMNS, "ll" + "r" * (len(COLUMNS) - 2)))
        for case, _, outcomes in results:
            for label, outcome in outcomes.items():
                n = max(outcome.sums.get("n", 0.0), 1.0)
                sums = [
                    f"{100 * outcome.sums['inside_2'] / n:.2f}",
                    f"{outcome.sums['nll'] / n:.4f}",
                ]
                cells = [case.name, label, *outcome.errors[against].cells(), *sums]
                print(harness.table_row([*cells, f"{1000 * outcome.seconds:.0f}"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
