"""``pcainterp evaluate``: read a densified log, measure it, write a report folder.

The log is streamed (frame t and, in temporal mode, frame t+1 in memory). Per frame the
reference is the ground-truth depth when the log has it (synthetic logs) and otherwise a
dense SGBM map of the same pair (the paper's KITTI setup); never the sparse points. The
maths is in :mod:`pcainterp_stream.evaluate.metrics`; this module does the reading, the
re-densification with the basis (uncertainty kinds, oracle, points sweep), the figures
(matplotlib, Agg), ``results.md`` and ``results.json``.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import LogReadError, PcaInterpError
from pcainterp_stream.estimate.baselines import linear, nearest
from pcainterp_stream.estimate.basis import BUILT_IN, IN_MEMORY, Basis, is_default
from pcainterp_stream.estimate.estimator import densify
from pcainterp_stream.evaluate.metrics import (
    DELTA_2D_EDGES,
    DEPTH_EDGES,
    STD_EDGES,
    SWEEP_POINTS,
    CalibrationStats,
    MethodStats,
    Mode,
    disparity_from_depth,
    oracle_disparity,
    projection_errors,
    reference_view,
    relative_transform,
    stereo_transform,
)
from pcainterp_stream.frontend.stereo import (
    GfttConfig,
    SgbmConfig,
    compute_disparity,
    detect_corners,
    lookup_disparities,
    to_grey8,
)
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.outputs import OutputTopics
from pcainterp_stream.records import StereoCamera

LEFT_IMAGE = "/stereo/left/image_rect"
RIGHT_IMAGE = "/stereo/right/image_rect"
GROUND_TRUTH_DEPTH = "/ground_truth/depth"
GROUND_TRUTH_POSE = "/ground_truth/pose"
RIGHT_STAMP_TOLERANCE_NS = 1_000_000
"""The right image belongs to the frame whose stamp is this close (pairing's default)."""

PAPER_DELTA_2D = {"KITTI": (3.4, 5.4), "Virtual KITTI": (2.0, 3.3)}
"""The paper's mean Delta_2D (px) of PCA-MAP and nearest neighbour (section IV-B)."""

TARGET_RATIO = 0.65
"""Target: PCA-MAP's mean Delta_2D at most this times nearest neighbour's."""

TARGET_COVERAGE = (0.90, 0.98)
"""Target: the exact uncertainty's +-2 sigma coverage lies in this range."""


@dataclass(frozen=True)
class EvaluateOptions:
    """Options of ``pcainterp evaluate``.

    Attributes:
        basis: the basis the log was densified with (a file or a loaded basis); enables the
            oracle, the paper/exact uncertainty comparison and the points sweep.
        basis_note: how the basis was chosen, or why there is none (printed, reported).
        linear: also evaluate linear interpolation of the same points (~0.5 s per
            KITTI-size frame); nearest neighbour always is.
        mode: ``stereo``, ``temporal`` or None (temporal when the log has poses and ground
            truth, otherwise stereo).
        sigma: measurement noise std (px) for re-densification.
        sweep_every: run the points sweep on every N-th evaluated frame (0: never).
        examples: example frames kept for the figure.
        max_frames: evaluate at most this many frames (None: all).
        sgbm_reference: use SGBM of the pair as the reference even when the log has ground
            truth (the KITTI setup on a synthetic log).
        sgbm: matcher settings of the SGBM reference and of the sweep's measurements.
    """

    basis: Path | Basis | None = None
    basis_note: str = ""
    linear: bool = True
    mode: Mode | None = None
    sigma: float = 2.0
    sweep_every: int = 10
    examples: int = 2
    max_frames: int | None = None
    sgbm_reference: bool = False
    sgbm: SgbmConfig = field(default_factory=SgbmConfig)


@dataclass(frozen=True, eq=False)
class _Frame:
    """One densified frame as read from the log."""

    index: int
    stamp_ns: int
    camera: StereoCamera
    estimate: npt.NDArray[np.float32]
    std: npt.NDArray[np.float32]
    pixels: npt.NDArray[np.float64]
    disparities: npt.NDArray[np.float64]
    left: npt.NDArray[Any]
    right: npt.NDArray[Any] | None
    depth: npt.NDArray[np.float32] | None
    pose: npt.NDArray[np.float64] | None
    min_disparity: float = 0.0


@dataclass
class RangeStats:
    """How the REP 118 "farther than measurable" rule splits the counted pixels.

    A pixel is too far for the estimate where its disparity is below the frame's
    resolvable minimum (the ``DisparityImage``'s ``min_disparity``: depth ``+inf``), and
    too far for the reference where the reference disparity is (sky included).
    """

    counted: int = 0
    estimate_far: int = 0
    reference_far: int = 0
    both_far: int = 0

    def add(
        self,
        estimate: npt.NDArray[np.float32],
        reference: npt.NDArray[np.float64],
        counted: npt.NDArray[np.bool_],
        min_disparity: float,
    ) -> None:
        """Count one frame's pixels (``counted`` only)."""
        with np.errstate(invalid="ignore"):
            estimate_far = counted & (estimate < min_disparity)
            reference_far = counted & (reference < min_disparity)
        self.counted += int(counted.sum())
        self.estimate_far += int(estimate_far.sum())
        self.reference_far += int(reference_far.sum())
        self.both_far += int((estimate_far & reference_far).sum())

    def summary(self) -> dict[str, float]:
        """Return the shares too far of the counted pixels, and the agreement of each side."""
        return {
            "estimate_far": self.estimate_far / max(self.counted, 1),
            "reference_far": self.reference_far / max(self.counted, 1),
            "estimate_far_reference_agrees": self.both_far / max(self.estimate_far, 1),
            "reference_far_estimate_agrees": self.both_far / max(self.reference_far, 1),
        }


@dataclass
class Evaluation:
    """Everything ``evaluate`` measured (the JSON of the report).

    Attributes:
        log: the evaluated log.
        mode: stereo or temporal.
        reference: "ground truth" or "SGBM".
        frames: frames evaluated.
        image_size: (height, width) px.
        methods: per method (pca_map, nearest, linear, oracle) its accumulated errors.
        calibration: per uncertainty kind (stored, paper, exact) its calibration.
        sweep: per number of points, per method, its accumulated errors.
        sweep_frames: frames in the sweep.
        points_per_frame: mean sparse points per frame.
        basis: description of the basis (None without one).
        basis_note: how the basis was chosen, or why there is none.
        seconds: wall time of the evaluation (s).
        ranges: the REP 118 "too far" split of the estimate against the reference.
    """

    log: str
    mode: str
    reference: str
    frames: int = 0
    image_size: tuple[int, int] = (0, 0)
    methods: dict[str, MethodStats] = field(default_factory=dict)
    calibration: dict[str, CalibrationStats] = field(default_factory=dict)
    sweep: dict[int, dict[str, MethodStats]] = field(default_factory=dict)
    sweep_frames: int = 0
    points_per_frame: float = 0.0
    basis: dict[str, Any] | None = None
    basis_note: str = ""
    seconds: float = 0.0
    ranges: RangeStats = field(default_factory=RangeStats)

    def summary(self) -> dict[str, Any]:
        """Return every number as plain JSON-able data (means and the accumulated bins)."""
        return {
            "log": self.log,
            "mode": self.mode,
            "reference": self.reference,
            "frames": self.frames,
            "image_size": list(self.image_size),
            "points_per_frame": self.points_per_frame,
            "seconds": self.seconds,
            "basis": self.basis,
            "basis_note": self.basis_note,
            "bins": {
                "delta_2d_px": list(DELTA_2D_EDGES),
                "depth_m": list(DEPTH_EDGES),
                "std_px": list(STD_EDGES),
            },
            "methods": {
                name: {"mean": stats.summary(), "accumulated": dataclasses.asdict(stats)}
                for name, stats in self.methods.items()
            },
            "calibration": {
                name: {"mean": stats.summary(), "accumulated": dataclasses.asdict(stats)}
                for name, stats in self.calibration.items()
            },
            "ranges": {
                "mean": self.ranges.summary(),
                "accumulated": dataclasses.asdict(self.ranges),
            },
            "sweep_frames": self.sweep_frames,
            "sweep": {
                str(points): {name: stats.summary() for name, stats in methods.items()}
                for points, methods in self.sweep.items()
            },
        }

    def ratio(self) -> float:
        """Return PCA-MAP's mean Delta_2D divided by nearest neighbour's."""
        pca = self.methods["pca_map"].summary()["delta_2d_mean"]
        return pca / max(self.methods["nearest"].summary()["delta_2d_mean"], 1e-12)


def _camera(info: Any, disparity_message: Any, size: tuple[int, int]) -> StereoCamera:
    p = rosmsg.projection_matrix(info)
    return StereoCamera(
        width=size[1],
        height=size[0],
        fx=float(p[0, 0]),
        fy=float(p[1, 1]),
        cx=float(p[0, 2]),
        cy=float(p[1, 2]),
        baseline=float(disparity_message.t),
    )


def _frames(path: Path, topics: OutputTopics, max_frames: int | None) -> Iterator[_Frame]:
    """Yield the densified frames of a log in order, grouping channels by header stamp."""
    with open_log(path) as reader:
        present = reader.topics()
        needed = [topics.disparity, topics.disparity_std, topics.features, topics.camera_info]
        missing = [topic for topic in [*needed, LEFT_IMAGE] if topic not in present]
        if missing:
            raise LogReadError(
                f"{path} has no {', '.join(missing)}; evaluate needs a log written by "
                "`pcainterp densify` (with the input's stereo images)"
            )
        optional = [t for t in (GROUND_TRUTH_DEPTH, GROUND_TRUTH_POSE) if t in present]
        grouped = [*needed, LEFT_IMAGE, *optional]
        complete = len(grouped)
        # the right image may be stamped up to the pairing tolerance apart from the left;
        # densify copies it before it writes the pair's outputs, so it is read first
        wanted = [*grouped, *([RIGHT_IMAGE] if RIGHT_IMAGE in present else [])]
        rights: dict[int, Any] = {}
        pending: dict[int, dict[str, Any]] = {}
        index = 0
        for raw in reader.messages(wanted):
            message = reader.decode(raw)
            stamp = rosmsg.stamp_ns(message.image if raw.topic == topics.disparity else message)
            if raw.topic == RIGHT_IMAGE:
                rights[stamp] = message
                while len(rights) > 16:
                    rights.pop(min(rights))
                continue
            parts = pending.setdefault(stamp, {})
            parts[raw.topic] = message
            if len(parts) < complete:
                while len(pending) > 8:  # frames are written close together
                    pending.pop(min(pending))
                continue
            del pending[stamp]
            estimate = rosmsg.image_array(parts[topics.disparity].image).astype(np.float32)
            features = rosmsg.pointcloud2_arrays(parts[topics.features])
            depth = parts.get(GROUND_TRUTH_DEPTH)
            pose = parts.get(GROUND_TRUTH_POSE)
            nearest_right = min(rights, key=lambda other: abs(other - stamp), default=None)
            right = (
                rights[nearest_right]
                if nearest_right is not None
                and abs(nearest_right - stamp) <= RIGHT_STAMP_TOLERANCE_NS
                else None
            )
            yield _Frame(
                index=index,
                stamp_ns=stamp,
                camera=_camera(
                    parts[topics.camera_info],
                    parts[topics.disparity],
                    (int(estimate.shape[0]), int(estimate.shape[1])),
                ),
                estimate=estimate,
                std=rosmsg.image_array(parts[topics.disparity_std]).astype(np.float32),
                pixels=np.stack([features["u"], features["v"]], axis=1),
                disparities=features["disparity"],
                left=rosmsg.image_array(parts[LEFT_IMAGE]),
                right=None if right is None else rosmsg.image_array(right),
                depth=None if depth is None else rosmsg.image_array(depth).astype(np.float32),
                pose=None if pose is None else rosmsg.pose_matrix(pose),
                min_disparity=float(parts[topics.disparity].min_disparity),
            )
            index += 1
            if max_frames is not None and index >= max_frames:
                return


def _reference(frame: _Frame, sgbm: SgbmConfig, use_truth: bool) -> npt.NDArray[np.float64]:
    if frame.depth is not None and use_truth:
        return disparity_from_depth(frame.depth, frame.camera.focal_baseline)
    if frame.right is None:
        raise LogReadError(
            f"frame {frame.index} has neither {GROUND_TRUTH_DEPTH} nor {RIGHT_IMAGE}; "
            "evaluate needs ground truth or the right image for an SGBM reference"
        )
    return compute_disparity(frame.left, frame.right, sgbm).astype(np.float64)


def _timed(stats: MethodStats | CalibrationStats, work: Callable[[], Any]) -> Any:
    started = time.perf_counter()
    result = work()
    stats.seconds += time.perf_counter() - started
    return result


@dataclass
class _Example:
    index: int
    left: npt.NDArray[Any]
    pixels: npt.NDArray[np.float64]
    reference: npt.NDArray[np.float64]
    estimate: npt.NDArray[np.float32]
    std: npt.NDArray[np.float32]
    nearest: npt.NDArray[np.float32]


class _Evaluator:
    """Accumulates the metrics frame by frame."""

    def __init__(self, result: Evaluation, options: EvaluateOptions, basis: Basis | None) -> None:
        self.result = result
        self.options = options
        self.basis = basis
        self.examples: list[_Example] = []
        self.example_at: set[int] = set()
        self.points = 0

    def _stats(self, name: str) -> MethodStats:
        return self.result.methods.setdefault(name, MethodStats())

    def _calibration(self, name: str) -> CalibrationStats:
        return self.result.calibration.setdefault(name, CalibrationStats())

    def add(self, frame: _Frame, reference: npt.NDArray[np.float64], transform: Any) -> None:
        camera, size = frame.camera, frame.camera.image_size
        view = reference_view(reference, camera, transform)
        delta = self._stats("pca_map").add(frame.estimate, view, camera, transform)
        self._calibration("stored").add(frame.estimate, frame.std, view, delta)
        if frame.min_disparity > 0:
            self.result.ranges.add(
                frame.estimate, view.disparity, view.counted, frame.min_disparity
            )
        nn_stats = self._stats("nearest")
        linear_stats = self._stats("linear") if self.options.linear else MethodStats()
        nn = _timed(nn_stats, lambda: nearest(frame.pixels, frame.disparities, image_size=size))
        nn_stats.add(nn.disparity, view, camera, transform)
        if self.options.linear:
            pixels, values = frame.pixels, frame.disparities
            lin = _timed(linear_stats, lambda: linear(pixels, values, image_size=size))
            linear_stats.add(lin.disparity, view, camera, transform)
        if self.basis is not None:
            self._with_basis(frame, reference, view, transform)
        if frame.index in self.example_at:
            self.examples.append(
                _Example(
                    frame.index,
                    frame.left,
                    frame.pixels,
                    view.disparity,
                    frame.estimate,
                    frame.std,
                    nn.disparity,
                )
            )
        self.points += frame.pixels.shape[0]
        self.result.frames += 1
        self.result.image_size = size

    def _with_basis(
        self, frame: _Frame, reference: npt.NDArray[np.float64], view: Any, transform: Any
    ) -> None:
        assert self.basis is not None
        basis, camera = self.basis, frame.camera
        # "exact" here is what densify writes by default (exact on the variance grid)
        for kind, uncertainty in (("paper", "paper"), ("exact", "exact-coarse")):
            stats = self._calibration(kind)
            dense = _timed(
                stats,
                lambda uncertainty=uncertainty: densify(  # type: ignore[misc]
                    basis,
                    frame.pixels,
                    frame.disparities,
                    sigma=self.options.sigma,
                    uncertainty=uncertainty,
                    focal_baseline=camera.focal_baseline,
                    image_size=camera.image_size,
                ),
            )
            delta, _ = projection_errors(dense.disparity, view, camera, transform)
            stats.add(dense.disparity, dense.disparity_std, view, delta)
        # the exact posterior knows only the l kept components; the training variance the
        # basis leaves out, spread evenly over the grid pixels, is a floor it misses
        residual = max(float(basis.total_variance - basis.eigenvalues.sum()), 0.0)
        to_log = camera.focal_baseline / basis.focal_baseline  # basis px -> log px
        residual_std = np.sqrt(
            dense.disparity_std.astype(np.float64) ** 2 + residual / basis.mean.size * to_log**2
        )
        self._calibration("exact+residual").add(dense.disparity, residual_std, view, delta)
        scale = basis.focal_baseline / camera.focal_baseline
        oracle = oracle_disparity(basis, reference * scale) / scale
        self._stats("oracle").add(oracle, view, camera, transform)
        every = self.options.sweep_every
        if every > 0 and self.result.frames % every == 0:
            self._sweep(frame, view, transform)

    def _sweep(self, frame: _Frame, view: Any, transform: Any) -> None:
        """Error against the number of points: GFTT + SGBM lookups, strongest N corners."""
        assert self.basis is not None
        if frame.right is None:
            return
        camera, size = frame.camera, frame.camera.image_size
        sgbm = self.options.sgbm
        disparity_map = compute_disparity(frame.left, frame.right, sgbm)
        corners = detect_corners(
            to_grey8(frame.left),
            GfttConfig(max_corners=4 * max(SWEEP_POINTS), min_distance=5.0),
            min_x=sgbm.valid_min_x,
        )
        found = lookup_disparities(disparity_map, corners)
        for points in SWEEP_POINTS:
            pixels = found.pixels[:points].astype(np.float64)
            values = found.disparities[:points].astype(np.float64)
            methods = self.result.sweep.setdefault(points, {})
            dense = densify(
                self.basis,
                pixels,
                values,
                sigma=self.options.sigma,
                uncertainty="none",
                focal_baseline=camera.focal_baseline,
                image_size=size,
            )
            estimates = {
                "pca_map": dense.disparity,
                "nearest": nearest(pixels, values, image_size=size).disparity,
                "linear": linear(pixels, values, image_size=size).disparity,
            }
            for name, estimate in estimates.items():
                methods.setdefault(name, MethodStats()).add(estimate, view, camera, transform)
        self.result.sweep_frames += 1


def _load_basis(options: EvaluateOptions) -> Basis | None:
    if isinstance(options.basis, Path):
        return Basis.load(options.basis)
    return options.basis


def _name(basis: Basis) -> str:
    return BUILT_IN if is_default(basis) else IN_MEMORY


def evaluate_log(
    path: Path,
    options: EvaluateOptions | None = None,
    *,
    topics: OutputTopics | None = None,
    progress: Callable[[int], None] | None = None,
) -> tuple[Evaluation, list[_Example]]:
    """Evaluate a densified log (streaming).

    Args:
        path: a log written by ``pcainterp densify``.
        options: evaluation options.
        topics: output topic names (default DESIGN.md's).
        progress: called with the number of frames read so far.

    Returns:
        The :class:`Evaluation` and the example frames kept for the figures.

    Raises:
        LogReadError: the log lacks densified channels, a reference or (temporal) poses.
        PcaInterpError: the basis does not fit the log.
    """
    started = time.perf_counter()
    options = options or EvaluateOptions()
    topics = topics or OutputTopics()
    with open_log(path) as reader:
        present = reader.topics()
        has_truth = GROUND_TRUTH_DEPTH in present
        has_pose = GROUND_TRUTH_POSE in present
        count = present[topics.disparity].message_count if topics.disparity in present else None
    has_truth = has_truth and not options.sgbm_reference
    mode = Mode(options.mode) if options.mode else None
    mode = mode or (Mode.TEMPORAL if has_truth and has_pose else Mode.STEREO)
    if mode is Mode.TEMPORAL and not has_pose:
        raise LogReadError(
            f"{path} has no {GROUND_TRUTH_POSE}; temporal mode needs poses, use --mode stereo"
        )
    basis = _load_basis(options)
    result = Evaluation(
        log=str(path),
        mode=str(mode),
        reference="ground truth" if has_truth else "SGBM",
        basis_note=options.basis_note,
    )
    if basis is not None:
        result.basis = {
            "path": str(options.basis) if isinstance(options.basis, Path) else _name(basis),
            "components": basis.n_components,
            "grid": list(basis.grid_size),
            "image_size": list(basis.image_size),
            "n_train": basis.n_train,
            "explained_variance": basis.explained_variance_ratio,
        }
    evaluator = _Evaluator(result, options, basis)
    total = count if options.max_frames is None else min(count or 0, options.max_frames)
    if total:
        last = total - 2 if mode is Mode.TEMPORAL else total - 1
        picks = np.linspace(0, max(last, 0), options.examples + 2)[1:-1]
        evaluator.example_at = {round(float(i)) for i in picks}
    previous: tuple[_Frame, npt.NDArray[np.float64]] | None = None
    read = 0
    for frame in _frames(path, topics, options.max_frames):
        read += 1
        if progress is not None:
            progress(read)
        reference = _reference(frame, options.sgbm, has_truth)
        if mode is Mode.STEREO:
            evaluator.add(frame, reference, stereo_transform(frame.camera))
            continue
        if previous is not None:
            before, before_reference = previous
            assert before.pose is not None
            assert frame.pose is not None
            evaluator.add(before, before_reference, relative_transform(before.pose, frame.pose))
        previous = (frame, reference)
    if result.frames == 0:
        raise LogReadError(
            f"no frame of {path} could be evaluated ({read} densified frames read; temporal "
            "mode needs two)"
        )
    result.points_per_frame = evaluator.points / result.frames
    result.seconds = time.perf_counter() - started
    return result, evaluator.examples


# ----------------------------------------------------------------------------- report


def _percent(value: float) -> str:
    return f"{100 * value:.1f} %"


def summary_table(result: Evaluation) -> str:
    """Return the plain-text summary table ``evaluate`` prints."""
    lines = [
        f"{result.frames} frames of {result.log}, {result.mode} mode, reference: "
        f"{result.reference}, {result.points_per_frame:.0f} points per frame",
        *([f"basis of the re-densified rows: {result.basis_note}"] if result.basis_note else []),
        f"{'method':<10} {'D2D px':>8} {'/NN':>6} {'D3D m':>8} {'RMSE m':>8} {'MAE m':>7} "
        f"{'iRMSE':>7} {'iMAE':>7} {'ms/frame':>9}",
    ]
    nn_mean = result.methods["nearest"].summary()["delta_2d_mean"]
    for name, stats in result.methods.items():
        s = stats.summary()
        timing = f"{s['ms_per_frame']:.0f}" if stats.seconds > 0 else "-"
        lines.append(
            f"{name:<10} {s['delta_2d_mean']:>8.3f} {s['delta_2d_mean'] / nn_mean:>6.2f} "
            f"{s['delta_3d_mean']:>8.2f} {s['rmse_m']:>8.2f} {s['mae_m']:>7.2f} "
            f"{s['irmse_per_km']:>7.1f} {s['imae_per_km']:>7.1f} {timing:>9}"
        )
    for name, calibration in result.calibration.items():
        c = calibration.summary()
        timing = f", {c['ms_per_frame']:.0f} ms/frame" if calibration.seconds > 0 else ""
        certain = ""
        if c["certain"] > 0:  # a basis that never varies at some pixels claims std 0 there
            certain = (
                f" (std 0 at {100 * c['certain']:.2g} % of pixels; "
                f"NLL {c['nll_uncertain']:.2f} without them)"
            )
        lines.append(
            f"uncertainty {name:<7} inside +-1 sigma {_percent(c['coverage_1sigma'])}, "
            f"+-2 sigma {_percent(c['coverage_2sigma'])}, NLL {c['nll']:.2f}{certain}{timing}"
        )
    if result.ranges.counted:
        r = result.ranges.summary()
        lines.append(
            f"too far (depth +inf): estimate {_percent(r['estimate_far'])} of pixels "
            f"({_percent(r['estimate_far_reference_agrees'])} far in the reference too), "
            f"reference {_percent(r['reference_far'])} "
            f"({_percent(r['reference_far_estimate_agrees'])} found)"
        )
    return "\n".join(lines)


def _targets(result: Evaluation) -> list[str]:
    lines = []
    ratio = result.ratio()
    verdict = "met" if ratio <= TARGET_RATIO else f"missed by {ratio - TARGET_RATIO:.2f}"
    lines.append(
        f"- PCA-MAP / nearest neighbour mean Delta_2D = {ratio:.2f} (target <= "
        f"{TARGET_RATIO}; paper 0.63 KITTI, 0.61 Virtual KITTI): {verdict}."
    )
    if "exact" in result.calibration:
        coverage = result.calibration["exact"].summary()["coverage_2sigma"]
        low, high = TARGET_COVERAGE
        if low <= coverage <= high:
            verdict = "met"
        else:
            gap = low - coverage if coverage < low else coverage - high
            verdict = f"missed by {100 * gap:.1f} points"
        lines.append(
            f"- exact uncertainty +-2 sigma coverage = {_percent(coverage)} (target "
            f"{100 * low:.0f}-{100 * high:.0f} %): {verdict}."
        )
    return lines


def results_markdown(result: Evaluation, figures: list[str]) -> str:
    """Return ``results.md`` of a report folder."""
    lines = [
        f"# Evaluation of `{Path(result.log).name}`",
        "",
        f"{result.frames} frames, {result.image_size[1]}x{result.image_size[0]} px, "
        f"{result.mode} mode (Delta_2D/Delta_3D of paper section IV-B), reference: "
        f"{result.reference}; {result.points_per_frame:.0f} sparse points per frame; "
        f"evaluation took {result.seconds:.0f} s.",
        "",
        "```",
        summary_table(result),
        "```",
        "",
        "D2D: mean Delta_2D (px), /NN: ratio to nearest neighbour; D3D: mean Delta_3D (m, "
        "reference depths up to 80 m, estimated depth capped there); RMSE/MAE (m) and "
        "iRMSE/iMAE (1/km) likewise; ms/frame: time of the method during evaluation "
        "(PCA-MAP: see the uncertainty rows, a re-densification with the basis). Coverage: "
        "share of reference "
        "disparities within +-1/+-2 posterior std (Gaussian: 68.3 / 95.4 %).",
        "",
        "## Targets",
        "",
        *_targets(result),
        "",
    ]
    if result.sweep:
        lines += [
            f"## Error against the number of points ({result.sweep_frames} frames)",
            "",
            "| points | PCA-MAP D2D px | nearest D2D px | linear D2D px | PCA/NN |",
            "| --- | --- | --- | --- | --- |",
        ]
        for points, methods in sorted(result.sweep.items()):
            means = {name: stats.summary()["delta_2d_mean"] for name, stats in methods.items()}
            lines.append(
                f"| {points} | {means['pca_map']:.3f} | {means['nearest']:.3f} | "
                f"{means['linear']:.3f} | {means['pca_map'] / means['nearest']:.2f} |"
            )
        lines.append("")
    if result.basis is not None:
        b = result.basis
        lines += [
            f"Basis: `{b['path']}`, {b['components']} components on a {b['grid'][1]}x"
            f"{b['grid'][0]} grid from {b['n_train']} maps "
            f"({_percent(b['explained_variance'])} of the training variance).",
            "",
        ]
    lines += ["## Figures", ""] + [f"![{name}]({name})" for name in figures]
    lines += ["", "All numbers, with the accumulated histograms: `results.json`.", ""]
    return "\n".join(lines)


def _bar_chart(axis: Any, labels: list[str], series: dict[str, list[float]], ylabel: str) -> None:
    width = 0.8 / max(len(series), 1)
    positions = np.arange(len(labels))
    for i, (name, values) in enumerate(series.items()):
        axis.bar(positions + i * width - 0.4 + width / 2, values, width, label=name)
    axis.set_xticks(positions, labels, rotation=30, fontsize=7)
    axis.set_ylabel(ylabel)
    axis.legend(fontsize=7)


def _bin_labels(edges: tuple[float, ...], unit: str) -> list[str]:
    labels = []
    for low, high in itertools.pairwise(edges):
        labels.append(f">{low:g}{unit}" if np.isinf(high) else f"{low:g}-{high:g}")
    return labels


def _ratio(sums: list[float], counts: list[float]) -> list[float]:
    return [s / c if c > 0 else 0.0 for s, c in zip(sums, counts, strict=True)]


def write_figures(
    result: Evaluation, examples: list[_Example], folder: Path, basis: Basis | None
) -> list[str]:
    """Write the report's PNG figures; return their file names."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names: list[str] = []

    def save(figure: Any, name: str) -> None:
        figure.tight_layout()
        figure.savefig(folder / name, dpi=90)
        plt.close(figure)
        names.append(name)

    # error distribution, PCA-MAP against nearest neighbour (and the others)
    figure, axes = plt.subplots(1, 3, figsize=(15, 4))
    labels = _bin_labels(DELTA_2D_EDGES, " px")
    _bar_chart(
        axes[0],
        labels,
        {
            name: list(np.asarray(s.delta_2d_hist) / max(s.pixels, 1))
            for name, s in result.methods.items()
        },
        "share of pixels",
    )
    axes[0].set_title("Delta_2D distribution")
    _bar_chart(
        axes[1],
        _bin_labels(DEPTH_EDGES, " m"),
        {n: _ratio(s.by_depth_2d, s.by_depth_count) for n, s in result.methods.items()},
        "mean Delta_2D (px)",
    )
    axes[1].set_title("Delta_2D by reference depth (m)")
    _bar_chart(
        axes[2],
        _bin_labels(DEPTH_EDGES, " m"),
        {n: _ratio(s.by_depth_3d, s.by_depth_3d_count) for n, s in result.methods.items()},
        "mean Delta_3D (m)",
    )
    axes[2].set_yscale("log")
    axes[2].set_title("Delta_3D by reference depth (m)")
    save(figure, "errors.png")

    # uncertainty: Delta_2D and |error| by predicted std, coverage
    figure, axes = plt.subplots(1, 2, figsize=(11, 4))
    std_labels = _bin_labels(STD_EDGES, " px")
    _bar_chart(
        axes[0],
        std_labels,
        {n: _ratio(c.by_std_2d, c.by_std_count) for n, c in result.calibration.items()},
        "mean Delta_2D (px)",
    )
    axes[0].set_title("PCA-MAP Delta_2D by predicted disparity std (px)")
    for name, calibration in result.calibration.items():
        counts = np.asarray(calibration.by_std_count)
        rms = np.where(
            counts > 0, np.sqrt(_ratio(calibration.by_std_sq, calibration.by_std_count)), np.nan
        )  # empty bins are gaps, not zeros on the log axis
        axes[1].plot(std_labels, rms, marker="o", label=f"{name}: RMS error")
    centres = [0.25, 0.75, 1.5, 3.0, 6.0, 12.0]
    axes[1].plot(std_labels, centres, "k--", label="calibrated (bin centre)")
    axes[1].set_yscale("log")
    axes[1].set_ylabel("RMS disparity error (px)")
    axes[1].set_title("calibration by predicted std")
    axes[1].legend(fontsize=7)
    axes[1].tick_params(axis="x", rotation=30, labelsize=7)
    save(figure, "uncertainty.png")

    if result.sweep:
        figure, axis = plt.subplots(figsize=(6, 4))
        points = sorted(result.sweep)
        for name in ("pca_map", "nearest", "linear"):
            axis.plot(
                points,
                [result.sweep[p][name].summary()["delta_2d_mean"] for p in points],
                marker="o",
                label=name,
            )
        axis.set_xscale("log")
        axis.set_xticks(points, [str(p) for p in points])
        axis.set_xlabel("sparse points per frame")
        axis.set_ylabel("mean Delta_2D (px)")
        axis.legend()
        save(figure, "sweep.png")

    if examples:
        figure, axes = plt.subplots(len(examples), 5, figsize=(22, 1.9 * len(examples) + 0.4))
        axes = np.atleast_2d(axes)
        for row, example in zip(axes, examples, strict=True):
            high = float(np.nanpercentile(example.reference, 99)) or 1.0
            row[0].imshow(example.left, cmap="gray")
            row[0].plot(example.pixels[:, 0], example.pixels[:, 1], "r.", markersize=2)
            row[0].set_title(f"frame {example.index}: input, {len(example.pixels)} points")
            for axis, image, title in (
                (row[1], example.reference, "reference"),
                (row[2], example.estimate, "PCA-MAP"),
                (row[4], example.nearest, "nearest neighbour"),
            ):
                axis.imshow(image, cmap="turbo", vmin=0, vmax=high)
                axis.set_title(f"{title} (disparity 0-{high:.0f} px)", fontsize=8)
            shown = row[3].imshow(example.std, cmap="magma")
            row[3].set_title("posterior std (px)", fontsize=8)
            figure.colorbar(shown, ax=row[3], fraction=0.02)
            for axis in row:
                axis.set_axis_off()
        save(figure, "examples.png")

    if basis is not None:
        count = min(5, basis.n_components)
        figure, axes = plt.subplots(2, 3, figsize=(15, 3.2))
        axes = axes.ravel()
        axes[0].imshow(basis.mean, cmap="turbo")
        axes[0].set_title("basis mean (px)")
        for i in range(count):
            axes[i + 1].imshow(basis.components[i], cmap="RdBu")
            axes[i + 1].set_title(f"component {i} (lambda {basis.eigenvalues[i]:.3g})")
        for axis in axes:
            axis.set_axis_off()
        save(figure, "basis.png")
        figure, axis = plt.subplots(figsize=(6, 4))
        cumulative = np.cumsum(basis.eigenvalues) / basis.total_variance
        axis.plot(np.arange(1, basis.n_components + 1), cumulative)
        axis.set_xlabel("components")
        axis.set_ylabel("cumulative explained variance")
        axis.set_ylim(0, 1)
        axis.grid(alpha=0.3)
        save(figure, "variance.png")
    return names


def write_report(
    path: Path,
    folder: Path,
    options: EvaluateOptions | None = None,
    *,
    topics: OutputTopics | None = None,
    progress: Callable[[int], None] | None = None,
) -> Evaluation:
    """Evaluate a densified log and write ``results.md``, ``results.json`` and the PNGs.

    Args:
        path: a log written by ``pcainterp densify``.
        folder: the report folder (created).
        options: evaluation options.
        topics: output topic names.
        progress: called with the number of frames read so far.

    Returns:
        The :class:`Evaluation`.
    """
    options = options or EvaluateOptions()
    if not folder.parent.is_dir():
        raise PcaInterpError(
            f"cannot write the report to {folder}: folder {folder.parent} does not exist"
        )
    folder.mkdir(exist_ok=True)
    result, examples = evaluate_log(path, options, topics=topics, progress=progress)
    figures = write_figures(result, examples, folder, _load_basis(options))
    (folder / "results.json").write_text(json.dumps(result.summary(), indent=1) + "\n")
    (folder / "results.md").write_text(results_markdown(result, figures))
    return result
