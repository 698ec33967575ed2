"""Score sparse mode (densify's defaults, built-in basis) on real truth, synthetic truth and SGBM.

Four sources, each densified by the frame processor exactly as ``pcainterp densify`` does
(fit check, carried points, hybrid prior, Cauchy IRLS, calibrated std), one variant of the
measurement options at a time:

- ``lidar``: the three KITTI depth-completion frames (``kitti_depth_annotated_07``), against
  their accumulated-LiDAR truth (disparity = f*b / depth);
- ``synth``: synthetic street drives of held-out seeds (the built-in basis learned seeds
  1000-1199), full size, against the renderer's depth, its sky (no surface) left out: unlike
  ``pcainterp evaluate``, which counts the sky of a synthetic log as disparity 0, so this
  source's figures are not evaluate's;
- ``odometry`` and ``raw``: the two KITTI clips, against the full-resolution SGBM map of the
  same pair (the reference ``evaluate`` uses for a stereo log without truth).

Figures per source: mean |disparity error| (px) over the reference's pixels, at its depth
discontinuities (> 3 px disparity range in the 9x9 window) and the +-2 sigma coverage there
and away from them, the same error for nearest-neighbour and linear (Delaunay)
interpolation of the points the estimate used (ratios) and of the frame's GFTT corners alone
(no lattice, no carried points), the share of reference pixels within +-2 sigma, depth RMSE
(m; as ``pcainterp evaluate`` defines it: over the truth depths up to 80 m, the estimated
depth capped at 80 m), the points used per frame, and the processor's wall time
relative to the first variant in the same run. ``--geodesic`` adds two geodesic nearest
neighbours of the same points: each pixel takes the value of the point nearest along the
left image (a step on the basis grid costing 1 + 0.2 |grey difference|), or along the
front end's own SGBM map (1 + min(|disparity difference|, 20 px)).

Variants change the corner options (``gftt``), the matcher's (``sgbm``) or the built-in
basis's fitted prior (``prior``: its local kernel, its noise sigma).

    python tools/sparse_sharpness.py --variants corners400 default --timing
    python tools/sparse_sharpness.py --variants default edge_aware --sources odometry --pool-timing
"""

from __future__ import annotations

import dataclasses
import itertools
import time
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path
from typing import Any

import harness
import numpy as np
import numpy.typing as npt
from sparse_timing import estimate_seconds, lookup_seconds, partition_seconds, pool_seconds

from pcainterp_stream.estimate.baselines import linear, nearest
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.evaluate.metrics import depth_errors
from pcainterp_stream.frontend.motion import CarryConfig
from pcainterp_stream.frontend.near import NearConfig
from pcainterp_stream.frontend.stereo import SgbmConfig, StereoFrontEnd, compute_disparity
from pcainterp_stream.pipeline.processor import FrameProcessor, ProcessorConfig
from pcainterp_stream.records import StereoCamera, StereoFrame

Array = npt.NDArray[np.float32]
DEPTH_CAP_M = 80.0

DEPTH_BINS_M = (0.0, 10.0, 20.0, 30.0, 40.0, 60.0, 80.0)
"""Bins of the truth's depth (m) for ``--depth-bins`` (the last one ends at the depth cap; truth
beyond it counts in the last bin's error_px, not in any depth RMSE, as in evaluate)."""

# variant name -> changes to ProcessorConfig's corner options
STREET = {"builtin": "street", "adapt": "check"}
"""Keep the built-in street basis: checked, never switched or adapted."""

VARIANTS: dict[str, dict[str, Any]] = {
    "default": {},
    # the previous default: 400 strongest corners, no lattice
    "corners400": {"gftt": {"max_corners": 400, "fill_spacing": 0.0}},
    "corners600": {"gftt": {"max_corners": 600, "fill_spacing": 0.0}},
    # the corners alone (today's count, no lattice): nearest neighbour of the corners is the
    # baseline the sharper-sparse work started from
    "corners_only": {"gftt": {"fill_spacing": 0.0}},
    "buckets12x4": {"gftt": {"max_corners": 400, "fill_spacing": 0.0, "buckets": (12, 4)}},
    "buckets24x6": {"gftt": {"max_corners": 400, "fill_spacing": 0.0, "buckets": (24, 6)}},
    "corners400_fill30": {"gftt": {"max_corners": 400, "fill_spacing": 30.0}},
    "corners400_fill40": {"gftt": {"max_corners": 400, "fill_spacing": 40.0}},
    "corners400_fill50": {"gftt": {"max_corners": 400, "fill_spacing": 50.0}},
    "corners400_fill60": {"gftt": {"max_corners": 400, "fill_spacing": 60.0}},
    "corners300_fill40_any_contrast": {"gftt": {"max_corners": 300, "fill_min_contrast": 0.0}},
    "corners300_fill40_contrast2.5": {"gftt": {"max_corners": 300, "fill_min_contrast": 2.5}},
    "corners300_fill50": {"gftt": {"max_corners": 300, "fill_spacing": 50.0}},
    "corners300_fill40": {"gftt": {"max_corners": 300}},
    # the lattice alone (no corners), and the corners with a denser lattice
    "lattice26": {"gftt": {"max_corners": 0, "fill_spacing": 26.0}},
    "lattice30": {"gftt": {"max_corners": 0, "fill_spacing": 30.0}},
    "lattice34": {"gftt": {"max_corners": 0, "fill_spacing": 34.0}},
    "corners250_fill30": {"gftt": {"fill_spacing": 30.0}},
    "corners150_fill30": {"gftt": {"max_corners": 150, "fill_spacing": 30.0}},
    # the same point sets with the street basis kept whatever the fit check says
    "lattice26_street": {"gftt": {"max_corners": 0, "fill_spacing": 26.0}, **STREET},
    "lattice30_street": {"gftt": {"max_corners": 0, "fill_spacing": 30.0}, **STREET},
    "lattice34_street": {"gftt": {"max_corners": 0, "fill_spacing": 34.0}, **STREET},
    "indoor": {"builtin": "indoor", "adapt": "check"},
    "corners150_fill30_street": {"gftt": {"max_corners": 150, "fill_spacing": 30.0}, **STREET},
    "corners100_fill30": {"gftt": {"max_corners": 100, "fill_spacing": 30.0}},
    "corners150_fill34": {"gftt": {"max_corners": 150, "fill_spacing": 34.0}},
    "corners300_fill45": {"gftt": {"max_corners": 300, "fill_spacing": 45.0}},
    "buckets24x6_fill50": {"gftt": {"max_corners": 400, "buckets": (24, 6), "fill_spacing": 50.0}},
    # the left band x < 128 px matched too (SGBM on padded images, as dense mode does)
    "left_band": {"sgbm": {"full_width": True}},
    # the built-in prior's local kernel and noise (shipped: Laplace, 64 px, 40 px^2, 0.1 px)
    "laplace16": {"prior": {"local": {"kernel": "laplace", "length_scale": 16.0}}},
    "laplace32": {"prior": {"local": {"kernel": "laplace", "length_scale": 32.0}}},
    "laplace128": {"prior": {"local": {"kernel": "laplace", "length_scale": 128.0}}},
    "gaussian12": {"prior": {"local": {"kernel": "gaussian", "length_scale": 12.0}}},
    "gaussian24": {"prior": {"local": {"kernel": "gaussian", "length_scale": 24.0}}},
    "gaussian40": {"prior": {"local": {"kernel": "gaussian", "length_scale": 40.0}}},
    "sigma0.5": {"prior": {"sigma": 0.5}},
    "sigma1": {"prior": {"sigma": 1.0}},
    # the edge-aware local prior (densify's default) with the built-in basis's cell weight
    # 0.75, or another w (1: the stationary kernel; estimate/cells.py); no_edge_aware is
    # densify --no-edge-aware, the stationary kernel without the partition
    "edge_aware": {"edge_aware": True},
    "no_edge_aware": {"edge_aware": False},
    "cells0": {"edge_aware": True, "prior": {"local": {"cell_weight": 0.0}}},
    "cells0.25": {"edge_aware": True, "prior": {"local": {"cell_weight": 0.25}}},
    "cells0.5": {"edge_aware": True, "prior": {"local": {"cell_weight": 0.5}}},
    "cells0.6": {"edge_aware": True, "prior": {"local": {"cell_weight": 0.6}}},
    "cells0.75": {"edge_aware": True, "prior": {"local": {"cell_weight": 0.75}}},
    "cells0.9": {"edge_aware": True, "prior": {"local": {"cell_weight": 0.9}}},
    "stationary": {"prior": {"local": {"cell_weight": 1.0}}},
}

LATTICE = {"fill_placement": "lattice", "fill_min_support": 0.0}
"""The lattice fill (the default before the nudged lattice): the even 40 px lattice."""

# every variant above was measured with the lattice fill: they keep it
for _name, _changes in VARIANTS.items():
    if _name != "default":
        _changes["gftt"] = {**LATTICE, **_changes.get("gftt", {})}

VARIANTS.update(
    {
        # the default and points beyond SGBM's range from a quarter-resolution match
        "near_reach": {"near": NearConfig()},
        "near_reach_always": {"near": NearConfig(trigger_share=0.0)},
        # without it (densify --no-near-reach), and its quarter values checked against the
        # right view's quarter map within 1 or 2 quarter px (NearConfig.lr_max_diff)
        "no_near_reach": {"near": None},
        "near_lr1": {"near": NearConfig(lr_max_diff=1.0)},
        "near_lr2": {"near": NearConfig(lr_max_diff=2.0)},
        # the added points on a 14 or 10 px grid instead of 20 px
        "near_spacing14": {"near": NearConfig(spacing=14.0)},
        "near_spacing10": {"near": NearConfig(spacing=10.0)},
        # the left band x < 128 px matched too (SGBM on padded images, as dense mode does),
        # measured on the default's nudged lattice (``left_band`` above: the plain lattice)
        "left_band_nudged": {"sgbm": {"full_width": True}},
        # the lattice: the default (named, so the tables comparing it read as such)
        "lattice": {"gftt": LATTICE},
        # the lattice's points where >= 80 % of SGBM's 21 x 21 px are valid
        "fill_support0.8": {"gftt": {**LATTICE, "fill_min_support": 0.8}},
        # as many gap-filling lookups as the 40 px lattice keeps, placed greedily where the
        # gap to the nearest point times a weight is largest (GfttConfig.fill_placement):
        # weight 1 (with the support check 0.8 the measured best, not the default: its
        # front end's cost), the prior's disparity std, or the looked-up disparity, to the
        # power given; _support0.8 / 0.95: only candidates where >= 80 % (95 %) of SGBM's
        # 21 x 21 px are valid
        # the lattice, each rejected point moved a quarter side to where a lookup passes
        # (the default: nudge_min_support 0.9), with other shares of valid SGBM px around
        # a moved point required
        **{
            f"nudged_support{_share:g}": {
                "gftt": {**LATTICE, "fill_placement": "nudged", "nudge_min_support": _share}
            }
            for _share in (0.0, 0.5, 0.8, 0.9, 0.95)
        },
        # the nudged lattice (the default) at other sides
        **{
            f"nudged_fill{_side}": {"gftt": {"fill_spacing": float(_side)}}
            for _side in (30, 32, 34, 36, 37, 38)
        },
        # the carried points with a denser lattice: none, or a wider gap to the frame's own
        "no_carry": {"carry": CarryConfig(frames=0)},
        "nudged_fill36_no_carry": {"gftt": {"fill_spacing": 36.0}, "carry": CarryConfig(frames=0)},
        "nudged_fill36_gap40": {"gftt": {"fill_spacing": 36.0}, "carry": CarryConfig(gap=40.0)},
        # fewer corners and a denser nudged lattice: about the default's count of points
        **{
            f"corners{_count}_nudged{_side}": {
                "gftt": {"max_corners": _count, "fill_spacing": float(_side)}
            }
            for _count in (150, 200)
            for _side in (34, 36)
        },
        "fill_even": {"gftt": {"fill_placement": "even", "fill_min_support": 0.0}},
        "fill_even_support0.8": {"gftt": {"fill_placement": "even", "fill_min_support": 0.8}},
        "fill_even_support0.95": {"gftt": {"fill_placement": "even", "fill_min_support": 0.95}},
    }
)
for _weight in ("prior_std", "disparity"):
    for _exponent in (0.25, 0.5, 1.0):
        for _support in (0.0, 0.8):
            _suffix = f"{_exponent:g}" if _exponent != 1.0 else ""
            _suffix += f"_support{_support:g}" if _support else ""
            VARIANTS[f"fill_{_weight}{_suffix}"] = {
                "gftt": {
                    "fill_placement": _weight,
                    "fill_exponent": _exponent,
                    "fill_min_support": _support,
                }
            }


def _variant_config(name: str) -> ProcessorConfig:
    """Return the processor options of variant ``name`` (see :data:`VARIANTS`)."""
    base = ProcessorConfig()
    changes = dict(VARIANTS[name])
    changes.pop("prior", None)
    gftt = dataclasses.replace(base.gftt, **changes.pop("gftt", {}))
    sgbm = dataclasses.replace(base.sgbm, **changes.pop("sgbm", {}))
    return dataclasses.replace(base, gftt=gftt, sgbm=sgbm, **changes)


def _variant_basis(name: str) -> Basis | None:
    """Return the built-in basis with variant ``name``'s prior (None: the shipped one).

    Only ``meta["prior"]`` differs, so the processor still treats it as the built-in basis.
    """
    changes = VARIANTS[name].get("prior")
    if not changes:
        return None
    basis = Basis.default()
    prior = dict(basis.meta["prior"])
    if "local" in changes:
        prior["local"] = {**prior["local"], **changes["local"]}
    if "sigma" in changes:
        prior["sigma"] = changes["sigma"]
    return dataclasses.replace(basis, meta={**basis.meta, "prior": prior})


def _lidar_frames(realdata: Path) -> Iterator[tuple[StereoFrame, Array]]:
    from dense_truth import read_annotated

    frames = read_annotated(realdata / "kitti_depth_annotated_07")
    camera = frames.camera
    assert isinstance(camera, StereoCamera)
    for index, (left, right, truth) in enumerate(
        zip(frames.lefts, frames.rights, frames.truths, strict=True)
    ):
        stamp = 1_000_000_000 + index * 100_000_000
        yield _frame(index, stamp, left, right, camera), truth.astype(np.float32)


def _frame(index: int, stamp: int, left: Any, right: Any, camera: StereoCamera) -> StereoFrame:
    return StereoFrame(index, stamp, stamp, "left", left, right, camera)


def _synth_frames(seeds: list[int], frames: int) -> Iterator[tuple[StereoFrame, Array]]:
    from pcainterp_stream.synth import SynthConfig, generate

    for seed in seeds:
        for item in generate(SynthConfig(seed=seed, frames=frames)):
            camera = item.camera
            with np.errstate(divide="ignore", invalid="ignore"):
                truth = (camera.focal_baseline / item.depth).astype(np.float32)
            yield _frame(item.index, item.stamp_ns, item.left, item.right, camera), truth


def _kitti_frames(folder: Path, frames: int) -> Iterator[tuple[StereoFrame, Array]]:
    from pcainterp_stream.io.kitti import iter_frames, open_kitti

    sequence = open_kitti(folder)
    for index, item in enumerate(iter_frames(sequence, max_frames=frames)):
        reference = compute_disparity(item.left, item.right, SgbmConfig())
        yield _frame(index, item.stamp_ns, item.left, item.right, sequence.camera), reference


def _cached(
    work: Path, name: str, make: Callable[[], Iterator[tuple[StereoFrame, Array]]]
) -> list[tuple[StereoFrame, Array]]:
    """Frames and references of a source, kept in ``work`` after the first run."""
    path = work / f"{name}.npz"
    if path.exists():
        data = np.load(path, allow_pickle=True)
        cameras = data["cameras"]
        return [
            (
                _frame(
                    i,
                    int(data["stamps"][i]),
                    data["lefts"][i],
                    data["rights"][i],
                    StereoCamera(*cameras[i]),
                ),
                data["truths"][i],
            )
            for i in range(len(data["stamps"]))
        ]
    items = list(make())
    np.savez(
        path,
        stamps=np.array([f.stamp_ns for f, _ in items]),
        lefts=np.stack([f.left for f, _ in items]),
        rights=np.stack([f.right for f, _ in items]),
        truths=np.stack([t for _, t in items]),
        cameras=np.array([dataclasses.astuple(f.camera) for f, _ in items]),
    )
    return items


def _depth_edges(truth: Array, valid: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """Reference pixels at a depth discontinuity (> 3 px range in their 9x9 window).

    The range is taken over the valid reference pixels of the window only.
    """
    import cv2

    kernel = np.ones((9, 9), np.uint8)
    high = cv2.dilate(np.where(valid, truth, 0.0).astype(np.float32), kernel)
    low = cv2.erode(np.where(valid, truth, 1e6).astype(np.float32), kernel)
    return np.asarray(valid & (high - low > 3.0))


def geodesic_nearest(
    field: npt.NDArray[Any],
    pixels: Array,
    values: Array,
    *,
    beta: float,
    cap: float = np.inf,
    scale: float = 0.25,
) -> Array:
    """Each pixel takes the value of the point nearest along ``field`` (not across its edges).

    On ``field`` resized by ``scale`` (the basis grid's; nearest, so no edge is blurred), a
    step between 4-neighbours costs 1 + beta min(|field difference|, cap), 1 where either
    value is not finite; multi-source Dijkstra finds each node's nearest point; the labels
    are resized back (nearest). beta = 0 is a city-block nearest neighbour.
    """
    import cv2
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    height, width = field.shape
    rows, cols = round(height * scale), round(width * scale)
    resized = cv2.resize(
        np.asarray(field, np.float32), (cols, rows), interpolation=cv2.INTER_NEAREST
    )
    small: Array = np.asarray(resized, np.float32)
    index = np.arange(rows * cols).reshape(rows, cols)

    def cost(a: Array, b: Array) -> Array:
        step = np.abs(a - b)
        step[~np.isfinite(step)] = 0.0
        return np.asarray(1.0 + beta * np.minimum(step, cap), np.float32)

    pairs = [
        (index[:, :-1], index[:, 1:], cost(small[:, :-1], small[:, 1:])),
        (index[:-1], index[1:], cost(small[:-1], small[1:])),
    ]
    start = np.concatenate([a.ravel() for a, _, _ in pairs])
    end = np.concatenate([b.ravel() for _, b, _ in pairs])
    weight = np.concatenate([c.ravel() for _, _, c in pairs])
    graph = coo_matrix((weight, (start, end)), shape=(rows * cols, rows * cols)).tocsr()
    grid = np.round((pixels.astype(np.float64) + 0.5) * scale - 0.5).astype(np.int64)
    grid = np.clip(grid, 0, [cols - 1, rows - 1])
    nodes, first = np.unique(index[grid[:, 1], grid[:, 0]], return_index=True)
    _, _, sources = dijkstra(
        graph, directed=False, indices=nodes, min_only=True, return_predecessors=True
    )
    owner = np.full(rows * cols, -1, np.int64)
    owner[nodes] = first
    labels = owner[sources].reshape(rows, cols).astype(np.float32)
    labels = cv2.resize(labels, (width, height), interpolation=cv2.INTER_NEAREST)
    return np.asarray(values[labels.astype(np.int64)], np.float32)


CHECK_LINES: list[str] = []
"""The fit check's lines of the last :func:`score` (``--explain`` prints them)."""


def score(
    items: list[tuple[StereoFrame, Array]],
    config: ProcessorConfig,
    basis: Basis | None = None,
    geodesic: bool = False,
) -> dict[str, float]:
    """Densify the frames with ``config``; return the figures against their references."""
    started = time.perf_counter()
    with FrameProcessor(basis, config) as processor:
        results = list(processor.process([frame for frame, _ in items]))
        adapted = processor.adaptation.adapted
        CHECK_LINES[:] = list(processor.adaptation.lines)
    seconds = time.perf_counter() - started
    # the corners alone (a lattice-only variant's: the default's corners, what users had)
    count = config.gftt.max_corners or ProcessorConfig().gftt.max_corners
    alone = dataclasses.replace(config.gftt, fill_spacing=0.0, max_corners=count)
    corners_only = StereoFrontEnd(alone, config.sgbm)
    sums = dict.fromkeys(
        (
            "px",
            "err",
            "nn",
            "linear",
            "corners_nn",
            "corners_linear",
            "geodesic",
            "geodesic_sgbm",
            "inside",
            "sq_depth",
            "edge_px",
            "edge_err",
            "edge_inside",
            "range_px",
            "range_err",
            "near_inside",
            "near_estimate",
            "near_truth",
            "capped",
            "depth_px",
        ),
        0.0,
    )
    # pixels, sum |error| px, sum sq depth m^2, pixels of truth within the depth cap
    bins = np.zeros((len(DEPTH_BINS_M) - 1, 4))
    points = 0
    for (frame, truth), result in zip(items, results, strict=True):
        valid = np.isfinite(truth) & (truth > 0)
        estimate = result.disparity
        error = np.abs(estimate - truth)[valid]
        corners = corners_only.measure(frame.left, frame.right)
        # SGBM's 0 is a match, as in densify and evaluate's baselines
        nn = partial(nearest, image_size=truth.shape, zero_is_match=True)
        lin = partial(linear, image_size=truth.shape, zero_is_match=True)
        baselines = {
            "nn": nn(result.pixels, result.disparities),
            "linear": lin(result.pixels, result.disparities),
            "corners_nn": nn(corners.pixels, corners.disparities),
            "corners_linear": lin(corners.pixels, corners.disparities),
        }
        for key, baseline in baselines.items():
            sums[key] += np.abs(baseline.disparity - truth)[valid].sum()
        if geodesic:
            # along the grey image, and along the front end's own SGBM map (its holes free)
            grey = geodesic_nearest(frame.left, result.pixels, result.disparities, beta=0.2)
            sums["geodesic"] += np.abs(grey - truth)[valid].sum()
            sgbm = corners.disparity_map
            assert sgbm is not None
            sgbm = np.where(sgbm > 0, sgbm, np.nan)
            along = geodesic_nearest(sgbm, result.pixels, result.disparities, beta=1.0, cap=20.0)
            sums["geodesic_sgbm"] += np.abs(along - truth)[valid].sum()
        # within the matcher's range: the pixels a looked-up point can be right at
        reach = truth[valid] < config.sgbm.num_disparities
        sums["range_px"] += reach.sum()
        sums["range_err"] += error[reach].sum()
        sums["near_estimate"] += estimate[valid][~reach].sum()
        sums["near_truth"] += truth[valid][~reach].sum()
        std = result.disparity_std[valid]
        inside = error <= 2.0 * std
        sums["near_inside"] += inside[~reach].sum()
        sums["px"] += valid.sum()
        sums["err"] += error.sum()
        sums["inside"] += inside.sum()
        edge = _depth_edges(truth, valid)[valid]
        sums["edge_px"] += edge.sum()
        sums["edge_err"] += error[edge].sum()
        sums["edge_inside"] += inside[edge].sum()
        # depth RMSE by evaluate's rule (metrics.depth_errors), over all pixels and per bin:
        # truth beyond the cap is not counted, the estimated depth is capped
        focal_baseline = frame.camera.focal_baseline
        depth_true = focal_baseline / truth[valid]
        cap_disparity = focal_baseline / DEPTH_CAP_M
        depth_est = focal_baseline / np.maximum(
            np.nan_to_num(estimate[valid], nan=0.0), cap_disparity
        )  # for the count of capped estimates only
        depth = depth_errors(estimate, truth, valid, focal_baseline=focal_baseline)
        sums["sq_depth"] += depth["sq"]
        sums["depth_px"] += depth["n"]
        sums["capped"] += float(
            (depth_est >= DEPTH_CAP_M).sum() - (depth_true >= DEPTH_CAP_M).sum()
        )
        bin_of = np.clip(
            np.digitize(np.minimum(depth_true, DEPTH_CAP_M), DEPTH_BINS_M) - 1,
            0,
            len(DEPTH_BINS_M) - 2,
        )
        for index in range(len(DEPTH_BINS_M) - 1):
            inside_bin = bin_of == index
            bins[index, 0] += inside_bin.sum()
            bins[index, 1] += error[inside_bin].sum()
            in_bin = np.zeros_like(valid)
            in_bin[valid] = inside_bin
            binned = depth_errors(estimate, truth, in_bin, focal_baseline=focal_baseline)
            bins[index, 2] += binned["sq"]
            bins[index, 3] += binned["n"]
        points += len(result.pixels)
    return {
        "error_px": sums["err"] / sums["px"],
        "range_error_px": sums["range_err"] / max(sums["range_px"], 1.0),
        # the truth nearer than the matcher's range: its share of the pixels and of the
        # error, the estimate's and the truth's mean there, +-2 sigma coverage there
        "near_px_pct": 100.0 * (1.0 - sums["range_px"] / sums["px"]),
        "near_error_pct": 100.0 * (1.0 - sums["range_err"] / sums["err"]),
        "near_estimate_px": sums["near_estimate"] / max(sums["px"] - sums["range_px"], 1.0),
        "near_truth_px": sums["near_truth"] / max(sums["px"] - sums["range_px"], 1.0),
        "near_coverage": 100.0 * sums["near_inside"] / max(sums["px"] - sums["range_px"], 1.0),
        "nearest_px": sums["nn"] / sums["px"],
        "ratio_nn": sums["err"] / sums["nn"],
        "linear_px": sums["linear"] / sums["px"],
        "ratio_linear": sums["err"] / sums["linear"],
        "corners_nn_px": sums["corners_nn"] / sums["px"],
        "corners_linear_px": sums["corners_linear"] / sums["px"],
        "geodesic_nn_px": sums["geodesic"] / sums["px"],
        "geodesic_sgbm_nn_px": sums["geodesic_sgbm"] / sums["px"],
        "coverage_2sigma": 100.0 * sums["inside"] / sums["px"],
        "edge_error_px": sums["edge_err"] / max(sums["edge_px"], 1.0),
        "edge_coverage": 100.0 * sums["edge_inside"] / max(sums["edge_px"], 1.0),
        "away_coverage": 100.0
        * (sums["inside"] - sums["edge_inside"])
        / max(sums["px"] - sums["edge_px"], 1.0),
        "depth_rmse_m": float(np.sqrt(sums["sq_depth"] / max(sums["depth_px"], 1.0))),
        # by the truth's depth (DEPTH_BINS_M): mean |disparity error| px and depth RMSE m
        **{
            f"{key}_{low:g}-{high:g}m": value
            for (low, high), (count, error_sum, squares, near_count) in zip(
                itertools.pairwise(DEPTH_BINS_M), bins, strict=True
            )
            for key, value in (
                ("error_px", error_sum / max(count, 1.0)),
                ("depth_rmse_m", float(np.sqrt(squares / max(near_count, 1.0)))),
            )
        },
        # estimates at the depth cap where the truth is nearer (net count)
        "capped_px": sums["capped"],
        "points": points / len(items),
        "adapted": float(adapted),
        "seconds": seconds,
        "frames": float(len(items)),
    }


def guided_filter(guide: Array, image: Array, radius: int, eps: float) -> Array:
    """He et al.'s guided filter of ``image`` with ``guide`` (box windows of side 2r + 1)."""
    import cv2

    size = (2 * radius + 1, 2 * radius + 1)

    def box(x: Array) -> Array:
        return np.asarray(cv2.boxFilter(x, -1, size, borderType=cv2.BORDER_REFLECT), np.float32)

    mean_i, mean_p = box(guide), box(image)
    slope = (box(guide * image) - mean_i * mean_p) / (box(guide * guide) - mean_i**2 + eps)
    offset = mean_p - slope * mean_i
    return np.asarray(box(slope) * guide + box(offset), np.float32)


GUIDED = [(4, 1e-3), (8, 1e-3), (8, 1e-2), (16, 1e-3), (16, 1e-2), (32, 1e-2)]
"""(radius px, eps) of the guided-filter rows (``--guided``)."""


def guided_rows(items: list[tuple[StereoFrame, Array]], config: ProcessorConfig) -> list[str]:
    """Mean error and +-2 sigma coverage of the estimate refined by a guided filter.

    The left image (0-1) guides; the refined map q is blended by the posterior std s,
    f + w (q - f) with w = s^2 / (s^2 + s0^2) (s0 = 1, 3 px) or w = 1; the std is kept.
    """
    with FrameProcessor(None, config) as processor:
        results = list(processor.process([frame for frame, _ in items]))
    sums: dict[str, list[float]] = {}
    for (frame, truth), result in zip(items, results, strict=True):
        valid = np.isfinite(truth) & (truth > 0)
        guide = np.asarray(frame.left, np.float32) / 255.0
        estimate = np.asarray(result.disparity, np.float32)
        std = result.disparity_std

        rows: dict[str, Array] = {"none": estimate}
        for radius, eps in GUIDED:
            refined = guided_filter(guide, estimate, radius, eps)
            rows[f"r {radius}, eps {eps:g}, w = 1"] = refined
            for s0 in (1.0, 3.0):
                weight = std * std / (std * std + s0 * s0)
                rows[f"r {radius}, eps {eps:g}, s0 {s0:g}"] = estimate + weight * (
                    refined - estimate
                )
        for name, refined in rows.items():
            error = np.abs(refined - truth)[valid]
            row = sums.setdefault(name, [0.0, 0.0, 0.0])
            row[0] += error.sum()
            row[1] += valid.sum()
            row[2] += (error <= 2.0 * std[valid]).sum()
    return [f"| {k} | {e / n:.3f} | {100 * c / n:.1f} |" for k, (e, n, c) in sums.items()]


def main(argv: list[str] | None = None) -> int:
    """Run the variants on the sources; print one Markdown table per source."""
    parser = harness.argument_parser(__doc__)
    harness.add_work_dir(parser, Path("/tmp/sparse_sharpness"))
    harness.add_realdata(parser)
    parser.add_argument("--variants", nargs="+", default=["default"], choices=sorted(VARIANTS))
    parser.add_argument(
        "--sources",
        nargs="+",
        default=["lidar", "synth", "odometry", "raw"],
        choices=["lidar", "synth", "odometry", "raw"],
    )
    parser.add_argument("--synth-seeds", type=int, nargs="+", default=[9001, 9002])
    parser.add_argument("--synth-frames", type=int, default=20)
    parser.add_argument("--kitti-frames", type=int, default=40)
    parser.add_argument(
        "--explain", action="store_true", help="print each variant's fit-check lines"
    )
    parser.add_argument(
        "--near",
        action="store_true",
        help="also score the pixels whose truth is nearer than the matcher's range",
    )
    parser.add_argument(
        "--depth-bins",
        action="store_true",
        help="also score by the truth's depth: mean |disparity error| and depth RMSE per bin",
    )
    parser.add_argument(
        "--timing", action="store_true", help="also time the estimate alone per variant"
    )
    parser.add_argument(
        "--lookup-timing",
        action="store_true",
        help="also time the front end's lookups (corners and fill) per variant, against SGBM alone",
    )
    parser.add_argument(
        "--pool-timing",
        action="store_true",
        help="also time the estimate pool's own batches (carried points included), "
        "replayed per variant in turns",
    )
    parser.add_argument(
        "--geodesic",
        action="store_true",
        help="also score an image-geodesic nearest neighbour of the same points",
    )
    parser.add_argument(
        "--guided",
        action="store_true",
        help="also score a guided filter of the first variant's maps with the left image",
    )
    args = parser.parse_args(argv)
    work = harness.work_dir(args.work_dir)
    realdata: Path = args.realdata
    makers: dict[str, Callable[[], Iterator[tuple[StereoFrame, Array]]]] = {
        "lidar": lambda: _lidar_frames(realdata),
        "synth": lambda: _synth_frames(args.synth_seeds, args.synth_frames),
        "odometry": lambda: _kitti_frames(
            realdata / harness.KITTI_ODOMETRY_CLIP, args.kitti_frames
        ),
        "raw": lambda: _kitti_frames(realdata / harness.KITTI_RAW_0001, args.kitti_frames),
    }
    keys = (
        "error_px",
        "range_error_px",
        *(
            ("near_px_pct", "near_error_pct", "near_estimate_px", "near_truth_px", "near_coverage")
            if args.near
            else ()
        ),
        "edge_error_px",
        "edge_coverage",
        "away_coverage",
        "nearest_px",
        "ratio_nn",
        "linear_px",
        "ratio_linear",
        "corners_nn_px",
        "corners_linear_px",
        *(("geodesic_nn_px", "geodesic_sgbm_nn_px") if args.geodesic else ()),
        "coverage_2sigma",
        "depth_rmse_m",
        *(
            (
                *(
                    f"{key}_{low:g}-{high:g}m"
                    for low, high in itertools.pairwise(DEPTH_BINS_M)
                    for key in ("error_px", "depth_rmse_m")
                ),
                "capped_px",
            )
            if args.depth_bins
            else ()
        ),
        "points",
        "adapted",
        "seconds",
    )
    for source in args.sources:
        tag = (
            source
            if source != "synth"
            else f"synth_{'_'.join(map(str, args.synth_seeds))}_{args.synth_frames}"
        )
        if source in ("odometry", "raw"):
            tag = f"{source}_{args.kitti_frames}"
        items = _cached(work, tag, makers[source])
        print(f"\n{source}: {len(items)} frames")
        print("| variant | " + " | ".join(keys) + " | time ratio |")
        print("| --- |" + " ---: |" * (len(keys) + 1))
        first = None
        lines: list[str] = []
        for variant in args.variants:
            figures = score(items, _variant_config(variant), _variant_basis(variant), args.geodesic)
            first = first or figures["seconds"]
            cells = " | ".join(f"{figures[k]:.3f}" for k in keys)
            print(f"| {variant} | {cells} | {figures['seconds'] / first:.2f} |", flush=True)
            if args.explain:
                lines.extend(f"  {source} {variant}: {line}" for line in CHECK_LINES)
        if lines:
            print("\n".join(lines), flush=True)
            lines.clear()
        if args.guided:
            print("\n| guided filter (first variant) | error_px | coverage_2sigma |")
            print("| --- | ---: | ---: |")
            print("\n".join(guided_rows(items, _variant_config(args.variants[0]))), flush=True)
        if args.timing:
            configs = [_variant_config(v) for v in args.variants]
            bases = [_variant_basis(v) for v in args.variants]
            seconds = estimate_seconds(items, configs, bases)
            print(
                "estimate CPU ms/frame: "
                + ", ".join(
                    f"{v} {1000 * t:.1f} ({t / seconds[0]:.2f}x)"
                    for v, t in zip(args.variants, seconds, strict=True)
                )
                + f"; seeding (stereo worker) {1000 * partition_seconds(items):.2f}",
                flush=True,
            )
        if args.lookup_timing:
            configs = [_variant_config(v) for v in args.variants]
            bases = [_variant_basis(v) for v in args.variants]
            spent, matching = lookup_seconds(items, configs, bases)
            print(
                "lookups CPU ms/frame (corners and fill; / SGBM alone "
                f"{1000 * matching:.1f} ms): "
                + ", ".join(
                    f"{v} {1000 * t:.1f} ({t / matching:.3f})"
                    for v, t in zip(args.variants, spent, strict=True)
                ),
                flush=True,
            )
        if args.pool_timing:
            configs = [_variant_config(v) for v in args.variants]
            bases = [_variant_basis(v) for v in args.variants]
            rounds = pool_seconds(items, configs, bases)
            first_rounds = np.array(rounds[0])
            print(
                "estimate pool CPU ms/frame (median of rounds; ratio per round, median): "
                + ", ".join(
                    f"{v} {1000 * np.median(r):.1f} ({np.median(np.array(r) / first_rounds):.3f}x)"
                    for v, r in zip(args.variants, rounds, strict=True)
                ),
                flush=True,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
