"""``pcainterp evaluate``: read a densified log, measure it, write a report folder.

The log is streamed (frame t and, in temporal mode, frame t+1 in memory, plus the few frames
that wait for a right image or reference message logged after them:
:mod:`~pcainterp_stream.evaluate.log_frames`). Per frame the reference is the log's
``--reference-topic`` when one is given (any depth or disparity image, dense or sparse:
:mod:`~pcainterp_stream.evaluate.reference`), else the ground-truth depth when the log has
it (synthetic logs), else a dense SGBM map of the same pair (the paper's KITTI setup); never
the sparse points. Beside PCA-MAP, nearest neighbour and linear interpolation, SGBM's own
map of the pair is scored as a stereo baseline, as is that map with its holes filled.

The maths is in :mod:`pcainterp_stream.evaluate.metrics`; this module does the scoring and
the re-densification with the basis (uncertainty kinds, oracle, points sweep);
:mod:`~pcainterp_stream.evaluate.tables` writes the text and
:mod:`~pcainterp_stream.evaluate.figures` the figures.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import LogReadError, PcaInterpError, TopicNotFoundError
from pcainterp_stream.estimate.adapt import other_camera
from pcainterp_stream.estimate.baselines import linear, nearest
from pcainterp_stream.estimate.basis import BUILTIN_LABELS, IN_MEMORY, Basis, builtin_kind
from pcainterp_stream.estimate.estimator import clean_measurements, densify
from pcainterp_stream.evaluate.box import Boxed, estimate_box
from pcainterp_stream.evaluate.figures import write_figures
from pcainterp_stream.evaluate.frame_step import frame_step_ns
from pcainterp_stream.evaluate.input_pair import describe_pair, follow_densify, matcher_notes
from pcainterp_stream.evaluate.left_out import (
    LeftOut,
    no_reference_message,
    no_truth_cause,
    no_truth_message,
    reference_tolerance,
)
from pcainterp_stream.evaluate.log_frames import (
    GROUND_TRUTH_DEPTH,
    GROUND_TRUTH_POSE,
    Frame,
    ReadState,
    read_frames,
)
from pcainterp_stream.evaluate.metrics import (
    SWEEP_POINTS,
    CalibrationStats,
    MethodStats,
    Mode,
    ReferenceKind,
    ReferenceView,
    disparity_from_reference,
    fill_nearest,
    oracle_disparity,
    projection_errors,
    reference_view,
    relative_transform,
    stereo_transform,
)
from pcainterp_stream.evaluate.per_frame import PerFrame, own_pair_notes
from pcainterp_stream.evaluate.reference import (
    IMAGE_TYPES,
    SPARSE_BELOW,
    ReferenceTopic,
    bounds_notes,
    reference_disparity,
    reference_floor,
    resolve_reference,
)
from pcainterp_stream.evaluate.report_folder import (
    REPORT_TEXT,
    check_report_folder,
    report_json,
    write_report_folder,
)
from pcainterp_stream.evaluate.results import (
    PCA_ON_SGBM,
    SGBM,
    SGBM_NN,
    TARGET_COVERAGE,
    TARGET_RATIO,
    Evaluation,
    Example,
    RangeStats,
)
from pcainterp_stream.evaluate.tables import results_markdown, summary_table
from pcainterp_stream.evaluate.truth_values import DepthValues
from pcainterp_stream.evaluate.tuning import tuning_notes
from pcainterp_stream.frontend.images import PairImages
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.frontend.sgbm_limits import fitting
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
from pcainterp_stream.io.outputs import (
    MEASUREMENTS_KEY,
    OutputTopics,
    estimate_topics,
    recorded_pairs,
)
from pcainterp_stream.io.stereo_log import LIDAR_DEPTH
from pcainterp_stream.records import StereoCamera

__all__ = [
    "GROUND_TRUTH_DEPTH",
    "GROUND_TRUTH_POSE",
    "LEFT_IMAGE",
    "MEASUREMENTS_KEY",
    "RIGHT_IMAGE",
    "TARGET_COVERAGE",
    "TARGET_RATIO",
    "EvaluateOptions",
    "Evaluation",
    "RangeStats",
    "evaluate_log",
    "results_markdown",
    "summary_table",
    "write_figures",
    "write_report",
]

LEFT_IMAGE = "/stereo/left/image_rect"
RIGHT_IMAGE = "/stereo/right/image_rect"
MIN_MEASUREMENTS = 1
"""A frame is scored only with at least this many finite measurements inside the image:
nearest neighbour and linear interpolation of none are undefined (NaN everywhere)."""


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
        sgbm: matcher settings of the SGBM reference, of the stereo baselines and of the
            sweep's measurements.
        reference_topic: score against this depth or disparity image topic of the log
            (dense or sparse; NaN, 0 or < 0 = no truth) instead of ``/ground_truth/depth``,
            else ``/ground_truth/lidar_depth``, else SGBM; frames without a message of their
            stamp are skipped and counted.
        reference_kind: what ``reference_topic`` holds; auto: a DisparityImage holds
            disparity, an Image depth (32FC1 m, 16UC1 mm).
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
    reference_topic: str | None = None
    reference_kind: ReferenceKind = ReferenceKind.AUTO
    pairing: PairingConfig | None = None
    """The input pair's topics and rectification (default: the synthetic logs' topics as
    recorded); raw images are rectified as densify did, for the baselines and figures."""
    stamp_tolerance_ns: int | None = None
    """The largest stamp difference (ns) of a frame and its right image; None: the one the
    log records densify paired with (1 ms, pairing's default, for older logs)."""


@dataclass(frozen=True, eq=False)
class _Stereo:
    """SGBM's map of a frame's pair (the stereo baselines, the sweep, the SGBM reference)."""

    disparity: npt.NDArray[np.float32]
    """(H, W) float32 disparity (px), NaN in SGBM's holes."""
    seconds: float
    """Time SGBM took (s)."""


def _calibration_hint(path: Path, present: dict[str, Any], topics: OutputTopics) -> str:
    """Explain a densified log whose input pair has no camera infos ("": it has some)."""
    prefix = topics.camera_info.rsplit("/", 1)[0] + "/"
    inputs = [t for t, i in present.items() if not t.startswith(prefix)]
    if topics.camera_info not in present or any(
        present[t].msgtype == rosmsg.CAMERA_INFO for t in inputs
    ):
        return ""
    return (
        f"no stereo pair with camera infos in {path}: its input images have none "
        f"({topics.camera_info} is densify's output, the rectified left camera), so it was "
        "densified with --calibration; pass evaluate the same --calibration LEFT.yaml "
        "RIGHT.yaml files densify was given"
    )


def _truth(
    frame: Frame, reference: ReferenceTopic | None, use_truth: bool
) -> npt.NDArray[np.float64] | None:
    """Return the frame's ground-truth disparity (px, NaN = no truth), None without one."""
    if reference is not None:
        if frame.reference is None:
            return None
        return reference_disparity(
            frame.reference,
            reference,
            focal_baseline=frame.camera.focal_baseline,
            image_size=frame.camera.image_size,
            cx_offset=frame.cx_offset or 0.0,  # unknown: the bounds as they are (a note)
        )
    if frame.depth is not None and use_truth:
        # REP 118 as for a reference topic: NaN no truth, +inf too far (disparity 0)
        return disparity_from_reference(
            frame.depth, kind=ReferenceKind.DEPTH, focal_baseline=frame.camera.focal_baseline
        )
    return None


class _TruthValues(DepthValues):
    """Counts of the ground-truth depth's values that hold no depth (NaN) or a far one."""

    def notes(self) -> list[str]:
        """Say how the NaN were read when no pixel is +inf (a synthetic log of before)."""
        if not self.nan_sky():
            return []
        return [
            f"{100 * self.nan_share():.1f} % of {GROUND_TRUTH_DEPTH}'s pixels are NaN, "
            "read as no truth (REP 118; +inf, too far, counts as disparity 0); if the log is "
            "from an earlier `pcainterp synth`, whose sky was NaN, synthesize and densify it "
            "again to score the sky"
        ]


def _check_pair_size(frame: Frame, images: PairImages, estimate_topic: str, path: Path) -> None:
    """Refuse an input pair whose images are not the estimate's size: not the pair densified.

    A log densified again under another ``--output-prefix`` (another pair) by a version that
    recorded no prefix, or ``--left-topic`` naming another pair: SGBM of that pair cannot be
    scored against these outputs (review 57b R2: a NumPy broadcast traceback before).

    Raises:
        LogReadError: one line naming the topics, both sizes and the fix.
    """
    height, width = frame.estimate.shape[:2]
    got_height, got_width = frame.left.shape[:2]
    if (got_height, got_width) == (height, width):
        return
    pairs = [pair for pair in recorded_pairs(path) if not pair.startswith(f"{images.left_topic} ")]
    raise LogReadError(
        f"the input pair {images.left_topic}, {images.right_topic} is {got_width}x{got_height} "
        f"px but {estimate_topic} is {width}x{height} px (frame {frame.index}): these outputs "
        "were not densified from that pair; pass --left-topic and --right-topic of the pair "
        "densify read for them"
        + (
            f" (densify's records in the log name {', '.join(pairs)})"
            if pairs
            else " (`pcainterp info` lists the log's image topics)"
        )
    )


def _stereo(frame: Frame, sgbm: SgbmConfig) -> _Stereo | None:
    if frame.right is None:
        return None
    started = time.perf_counter()
    # a pair narrower than the reference's range is matched with the widest range it fits;
    # none fits a pair too narrow for any (densify had no measurement there either)
    narrow = fitting(sgbm, int(frame.left.shape[1]))
    if narrow is None:
        return None
    disparity = compute_disparity(frame.left, frame.right, narrow)
    return _Stereo(disparity, time.perf_counter() - started)


def _timed(stats: MethodStats | CalibrationStats, work: Callable[[], Any]) -> Any:
    started = time.perf_counter()
    result = work()
    stats.seconds += time.perf_counter() - started
    return result


class _Evaluator:
    """Accumulates the metrics frame by frame."""

    def __init__(self, result: Evaluation, options: EvaluateOptions, basis: Basis | None) -> None:
        self.result = result
        self.options = options
        self.basis = basis
        self.examples: list[Example] = []
        self.example_at: set[int] = set()
        self.points = 0
        self.sgbm_empty = 0
        self.other_camera: str | None = None
        """Why the basis is another camera's ("": it is not; None: not yet known)."""
        self.per_frame = PerFrame(result)
        self.reference: ReferenceTopic | None = None
        """The reference topic (None: the ground truth or SGBM)."""

    def _stats(self, name: str) -> MethodStats:
        return self.result.methods.setdefault(name, MethodStats())

    def _calibration(self, name: str) -> CalibrationStats:
        return self.result.calibration.setdefault(name, CalibrationStats())

    def add(
        self,
        frame: Frame,
        reference: npt.NDArray[np.float64],
        transform: Any,
        stereo: _Stereo | None = None,
        *,
        baselines: bool = False,
    ) -> None:
        """Score one frame against its reference (``baselines``: with the stereo ones).

        A frame with fewer than :data:`MIN_MEASUREMENTS` usable measurements is left out of
        every method (nearest and linear have nothing to interpolate, PCA-MAP has no estimate:
        NaN; the prior's mean in logs densified by earlier versions) and only counted in
        ``result.no_measurement``; one whose reference holds no truth on any pixel to score,
        likewise, in ``result.no_truth`` (and why, in ``result.no_truth_causes``): truth
        on no pixel that lands in the other view and has an estimate.
        """
        camera, size = frame.camera, frame.camera.image_size
        # the log's measurements are densify's: SGBM's 0 is a match (densify's zero_is_match)
        usable, _, _ = clean_measurements(frame.pixels, frame.disparities, size, zero_is_match=True)
        self.per_frame.start()  # its own figures: the accumulators' change over the frame
        if usable.shape[0] < MIN_MEASUREMENTS:
            self.result.no_measurement.append(frame.index)
            self.per_frame.finish(frame.index, frame.stamp_ns, frame.estimate, measured=False)
            return
        view = reference_view(reference, camera, transform)
        has_estimate = ~np.isnan(frame.estimate)  # +inf depth (far) is an estimate; NaN none
        if not (view.counted & has_estimate).any():  # no truth to score: left out, named
            self.result.no_truth.append(frame.index)
            sgbm = self.result.reference == "SGBM"
            self.result.no_truth_causes.append(
                no_truth_cause(
                    frame, reference, view.counted, self.reference, mode=self.result.mode, sgbm=sgbm
                )
            )
            self.per_frame.finish(frame.index, frame.stamp_ns, frame.estimate, truth=False)
            return
        self.result.reference_counted += int(np.count_nonzero(view.counted))
        box: tuple[int, int, int, int] | None = (0, 0, size[1], size[0])
        if not has_estimate.all():  # outside the rectified box: no method is scored there
            self.result.no_estimate += int(np.count_nonzero(view.counted & ~has_estimate))
            view = dataclasses.replace(view, counted=view.counted & has_estimate)
            box = estimate_box(has_estimate)
        sgbm_valid = np.isfinite(stereo.disparity) if baselines and stereo else None
        delta = self._stats("pca_map").add(frame.estimate, view, camera, transform)
        self._calibration("stored").add(
            frame.estimate, frame.std, view, delta, sgbm_valid=sgbm_valid
        )
        if frame.min_disparity > 0:
            floor = reference_floor(
                frame.reference,
                self.reference,
                focal_baseline=camera.focal_baseline,
                cx_offset=frame.cx_offset or 0.0,
            )
            self.result.ranges.add(
                frame.estimate, view.disparity, view.counted, frame.min_disparity, floor
            )
        nn_stats = self._stats("nearest")
        linear_stats = self._stats("linear") if self.options.linear else MethodStats()
        nn = _timed(
            nn_stats,
            lambda: nearest(frame.pixels, frame.disparities, image_size=size, zero_is_match=True),
        )
        nn_stats.add(nn.disparity, view, camera, transform)
        if self.options.linear:
            pixels, values = frame.pixels, frame.disparities
            lin = _timed(
                linear_stats, lambda: linear(pixels, values, image_size=size, zero_is_match=True)
            )
            linear_stats.add(lin.disparity, view, camera, transform)
        if stereo is not None and sgbm_valid is not None:
            self._stereo_baselines(frame, stereo, sgbm_valid, view, transform)
        if self.basis is not None and box is None:
            self.result.basis_rows_skipped += 1
        elif self.basis is not None and box is not None:
            boxed = Boxed(box, camera)
            self._with_basis(frame, reference, view, transform, stereo, sgbm_valid, boxed)
        if frame.index in self.example_at:
            self.examples.append(
                Example(
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
        self.result.reference_pixels += int(np.count_nonzero(np.isfinite(reference)))
        self.result.reference_area += reference.size
        self.result.frames += 1
        self.result.image_size = size
        self.per_frame.finish(frame.index, frame.stamp_ns, frame.estimate)

    def _stereo_baselines(
        self,
        frame: Frame,
        stereo: _Stereo,
        sgbm_valid: npt.NDArray[np.bool_],
        view: ReferenceView,
        transform: Any,
    ) -> None:
        """SGBM's own map where it has a value, and with its holes filled, on all pixels."""
        camera, methods = frame.camera, self.result.stereo
        on_sgbm = dataclasses.replace(view, counted=view.counted & sgbm_valid)
        sgbm_stats = methods.setdefault(SGBM, MethodStats())
        filled_stats = methods.setdefault(SGBM_NN, MethodStats())
        pca_stats = methods.setdefault(PCA_ON_SGBM, MethodStats())
        sgbm_stats.seconds += stereo.seconds
        sgbm_stats.add(stereo.disparity, on_sgbm, camera, transform)
        pca_stats.add(frame.estimate, on_sgbm, camera, transform)
        self.result.stereo_counted += float(np.count_nonzero(view.counted))
        filled_stats.seconds += stereo.seconds
        filled = _timed(filled_stats, lambda: fill_nearest(stereo.disparity))
        if filled is None:  # SGBM found nothing in this pair: there is nothing to fill from
            self.sgbm_empty += 1
            return
        filled_stats.add(filled, view, camera, transform)

    def _with_basis(
        self,
        frame: Frame,
        reference: npt.NDArray[np.float64],
        view: ReferenceView,
        transform: Any,
        stereo: _Stereo | None,
        sgbm_valid: npt.NDArray[np.bool_] | None,
        box: Boxed,
    ) -> None:
        """The rows that re-densify with the basis: paper, exact, oracle and the sweep.

        They re-densify in the box the stored estimate fills (``box``, the whole image but
        for a raw or black-bordered pair), as densify did: a basis learned there spans the
        box, not the frame. Outside the box they are NaN, and not scored.
        """
        assert self.basis is not None
        basis, camera = self.basis, frame.camera
        if self.other_camera is None:  # named once, from the first frame's camera
            self.other_camera = _other_camera(basis, camera, self.result)
        pixels, disparities = box.points(frame.pixels, frame.disparities)
        # "exact" here is what densify writes by default (exact on the variance grid)
        for kind, uncertainty in (("paper", "paper"), ("exact", "exact-coarse")):
            stats = self._calibration(kind)
            dense = _timed(
                stats,
                lambda uncertainty=uncertainty: densify(  # type: ignore[misc]
                    basis,
                    pixels,
                    disparities,
                    sigma=self.options.sigma,
                    uncertainty=uncertainty,
                    focal_baseline=camera.focal_baseline,
                    image_size=box.camera.image_size,
                    zero_is_match=True,
                ),
            )
            estimate, std = box.pad(dense.disparity), box.pad(dense.disparity_std)
            delta, _ = projection_errors(estimate, view, camera, transform)
            stats.add(estimate, std, view, delta, sgbm_valid=sgbm_valid)
        # the exact posterior knows only the l kept components; the training variance the
        # basis leaves out, spread evenly over the grid pixels, is a floor it misses
        residual = max(float(basis.total_variance - basis.eigenvalues.sum()), 0.0)
        to_log = camera.focal_baseline / basis.focal_baseline  # basis px -> log px
        self.result.sigma_log_px = self.options.sigma * to_log  # --sigma is in basis px
        residual_std = np.sqrt(std.astype(np.float64) ** 2 + residual / basis.mean.size * to_log**2)
        self._calibration("exact+residual").add(
            estimate, residual_std, view, delta, sgbm_valid=sgbm_valid
        )
        # the oracle fits the basis to the whole reference map: from a sparse one it would
        # fit a nearest-neighbour fill of it, no bound on any estimate, so it is left out
        # (nor is it for a basis of another camera: it would measure how far apart they are)
        inside = box.crop(reference)
        dense_enough = np.count_nonzero(np.isfinite(inside)) >= SPARSE_BELOW * inside.size
        if dense_enough and not self.other_camera:
            scale = basis.focal_baseline / camera.focal_baseline
            oracle = box.pad(oracle_disparity(basis, inside * scale) / scale)
            self._stats("oracle").add(oracle, view, camera, transform)
        every = self.options.sweep_every
        if every > 0 and self.result.frames % every == 0 and stereo is not None:
            self._sweep(frame, stereo, view, transform, box)

    def _sweep(
        self, frame: Frame, stereo: _Stereo, view: ReferenceView, transform: Any, box: Boxed
    ) -> None:
        """Error against the number of points: GFTT + SGBM lookups, strongest N corners."""
        assert self.basis is not None
        camera, size = frame.camera, frame.camera.image_size
        corners = detect_corners(
            to_grey8(frame.left),
            GfttConfig(max_corners=4 * max(SWEEP_POINTS), min_distance=5.0),
            min_x=self.options.sgbm.valid_min_x,
        )
        found = lookup_disparities(stereo.disparity, corners)
        if not box.whole:  # densify measured only in the box, so does the sweep
            keep = box.inside(found.pixels)
            found = found._replace(
                pixels=found.pixels[keep],
                disparities=found.disparities[keep],
                indices=found.indices[keep],
            )
        self.result.sweep_corners.append(int(found.pixels.shape[0]))
        for points in SWEEP_POINTS:
            if points > found.pixels.shape[0]:  # fewer corners: the count was not reached
                break
            self.result.sweep_reached[points] = self.result.sweep_reached.get(points, 0) + 1
            pixels = found.pixels[:points].astype(np.float64)
            values = found.disparities[:points].astype(np.float64)
            methods = self.result.sweep.setdefault(points, {})
            dense = densify(
                self.basis,
                *box.points(pixels, values),
                sigma=self.options.sigma,
                uncertainty="none",
                focal_baseline=camera.focal_baseline,
                image_size=box.camera.image_size,
                zero_is_match=True,
            )
            estimates = {
                "pca_map": box.pad(dense.disparity),
                "nearest": nearest(pixels, values, image_size=size, zero_is_match=True).disparity,
                "linear": linear(pixels, values, image_size=size, zero_is_match=True).disparity,
            }
            for name, estimate in estimates.items():
                methods.setdefault(name, MethodStats()).add(estimate, view, camera, transform)
        self.result.sweep_frames += 1


def _other_camera(basis: Basis, camera: StereoCamera, result: Evaluation) -> str:
    """Note, as densify warns, a basis file learned for another camera ("": alike, built-in)."""
    if builtin_kind(basis) is not None:  # learned from several cameras, mapped onto any
        return ""
    why = other_camera(basis, camera.image_size, camera.focal_baseline)
    if why:  # "; the basis was learned for another camera (...)"
        name = (result.basis or {}).get("path", "")
        result.notes.append(
            f"the basis {name} {why.removeprefix('; the basis ')}: its rows re-densify with it "
            "as densify would (densify warns of it), but the "
            "oracle row, its best fit to the truth, is left out: it would measure how far "
            "apart the cameras are; pass --basis with a basis of this camera, or none for the "
            "one the log records"
        )
    return why


def _load_basis(options: EvaluateOptions) -> Basis | None:
    if isinstance(options.basis, Path):
        return Basis.load(options.basis)
    return options.basis


def _name(basis: Basis) -> str:
    kind = builtin_kind(basis)
    return BUILTIN_LABELS[kind] if kind is not None else IN_MEMORY


def evaluate_log(
    path: Path,
    options: EvaluateOptions | None = None,
    *,
    topics: OutputTopics | None = None,
    progress: Callable[[int], None] | None = None,
    loaded: Basis | None = None,
) -> tuple[Evaluation, list[Example]]:
    """Evaluate a densified log (streaming).

    Args:
        path: a log written by ``pcainterp densify``.
        options: evaluation options.
        topics: output topic names (default the standard ``/pcainterp/*`` names).
        progress: called with the number of frames read so far.
        loaded: the basis ``options.basis`` names, already loaded (:func:`write_report`
            loads it once for the rows and the figures); None: loaded here.

    Returns:
        The :class:`Evaluation` and the example frames kept for the figures.

    Raises:
        LogReadError: the log lacks densified channels, a reference or (temporal) poses; the
            reference topic is missing, not an image or of another size than the estimate.
        PcaInterpError: the basis does not fit the log; a reference topic with the SGBM
            reference.
    """
    started = time.perf_counter()
    options = options or EvaluateOptions()
    topics = topics or OutputTopics()
    if options.reference_topic is not None and options.sgbm_reference:
        raise PcaInterpError(
            "a reference topic and the SGBM reference contradict each other; choose one"
        )
    with open_log(path) as reader:
        present = reader.topics()
        pairing, pair_source, front_end = follow_densify(
            path, options.pairing, present, topics.prefix
        )
        images = PairImages(pairing)
        if pairing is not None:
            try:
                images.resolve(reader, exclude_prefix=topics.depth.rsplit("/", 1)[0])
            except TopicNotFoundError as err:
                if not str(err).startswith("no stereo pair found"):
                    raise
                hint = _calibration_hint(path, present, topics)
                raise TopicNotFoundError(hint or str(err)) from None
            named = options.pairing
            if named is not None and (not named.discover or named.named_sides):  # typos?
                sides = {"left": images.left_topic, "right": images.right_topic}
                reader.require_topics(
                    {
                        topic: f"--{side}-topic"
                        for side, topic in sides.items()
                        if not named.discover or side in named.named_sides  # only those named
                    }
                )
        reference_topic = options.reference_topic
        if reference_topic is None and not options.sgbm_reference:
            lidar = present[LIDAR_DEPTH].msgtype if LIDAR_DEPTH in present else None
            sparse_only = GROUND_TRUTH_DEPTH not in present and lidar in IMAGE_TYPES  # else SGBM
            reference_topic = LIDAR_DEPTH if sparse_only else None
        reference = (
            None
            if reference_topic is None
            else resolve_reference(
                reference_topic,
                options.reference_kind,
                present,
                path,
                outputs=topics.prefix,
                reader=reader,
            )
        )
        has_truth = reference is not None or GROUND_TRUTH_DEPTH in present
        has_pose = GROUND_TRUTH_POSE in present
        has_right = images.right_topic in present
        estimate_topic = estimate_topics(present, topics).estimate
        count = present[estimate_topic].message_count if estimate_topic in present else None
    has_truth = has_truth and not options.sgbm_reference
    mode = Mode(options.mode) if options.mode else None
    mode = mode or (Mode.TEMPORAL if has_truth and has_pose else Mode.STEREO)
    if mode is Mode.TEMPORAL and not has_pose:
        raise LogReadError(
            f"{path} has no {GROUND_TRUTH_POSE}; temporal mode needs poses, use --mode stereo"
        )
    basis = loaded if loaded is not None else _load_basis(options)
    result = Evaluation(
        log=str(path),
        mode=str(mode),
        reference=(reference.topic if reference else "ground truth" if has_truth else "SGBM"),
        basis_note=options.basis_note,
        reference_kind=str(reference.kind) if reference else "",
        sigma=options.sigma,
        input_pair=describe_pair(images.config, pair_source),
    )
    result.notes += matcher_notes(front_end, options.sgbm) if has_right else []
    result.notes += tuning_notes(path, topics, basis is not None)  # what the stored rows are
    result.notes += own_pair_notes(result.reference)  # SGBM of a broken pair agrees with its errors
    if not has_right:
        result.stereo_note = f"skipped, the log has no {images.right_topic}"
    elif not has_truth:
        result.stereo_note = (
            "skipped, the reference is SGBM of the pair itself (they would be trivially perfect)"
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
    evaluator.reference = reference
    cx_offsets: set[float | None] = set()  # of the frames with a reference message
    total = count if options.max_frames is None else min(count or 0, options.max_frames)
    if total:
        last = total - 2 if mode is Mode.TEMPORAL else total - 1
        picks = np.linspace(0, max(last, 0), options.examples + 2)[1:-1]
        evaluator.example_at = {round(float(i)) for i in picks}
    previous: tuple[Frame, npt.NDArray[np.float64], _Stereo | None] | None = None
    read = 0
    truth_values = _TruthValues()
    state = ReadState()
    if reference is not None:  # a reference matches its frame's stamp within a tolerance
        reference_tolerance(state, options.stamp_tolerance_ns, path, topics, options.max_frames)
    frames = read_frames(
        path,
        topics,
        options.max_frames,
        reference,
        state,
        images,
        options.stamp_tolerance_ns,
        poses=mode is Mode.TEMPORAL,
    )
    left_out = LeftOut()
    narrow: list[str] = []  # the size of frames too narrow for any SGBM range
    if mode is Mode.TEMPORAL:  # a pair is two frames one interval apart
        left_out.step_ns = frame_step_ns(path, topics, options.max_frames)
    for frame in frames:
        read += 1
        if progress is not None:
            progress(read)
        _check_pair_size(frame, images, estimate_topic, path)
        truth = _truth(frame, reference, has_truth)
        if truth is not None and reference is not None:
            cx_offsets.add(frame.cx_offset)
        if truth is not None and reference is None and frame.depth is not None:
            truth_values.add(frame.depth)
        if truth is None and has_truth:  # no truth message of this stamp (within tolerance)
            result.skipped += GROUND_TRUTH_DEPTH not in frame.shared  # (else a note of its own)
            gap = frame.depth_gap_ns if reference is None else frame.reference_gap_ns
            left_out.see(gap, "truth", shared=GROUND_TRUTH_DEPTH in frame.shared)
            stereo = None
        else:
            stereo = _stereo(frame, options.sgbm)
        left_out.stamps.append(frame.stamp_ns)
        if truth is not None:
            frame_reference: npt.NDArray[np.float64] | None = truth
        elif has_truth:  # never SGBM for a frame of a log with truth: skipped, counted
            frame_reference = None
        elif stereo is None and frame.right is not None:  # too narrow for SGBM: no reference
            narrow.append(f"{frame.left.shape[1]}x{frame.left.shape[0]}")
            previous = None  # the next frame pairs with none (temporal mode)
            continue
        elif stereo is None:
            raise LogReadError(no_reference_message(frame, images.right_topic, state))
        else:
            frame_reference = stereo.disparity.astype(np.float64)
        baselines = truth is not None and stereo is not None
        if mode is Mode.STEREO:
            if frame_reference is not None:
                evaluator.add(
                    frame,
                    frame_reference,
                    stereo_transform(frame.camera),
                    stereo,
                    baselines=baselines,
                )
            continue
        if frame.pose is None:  # no pose within the tolerance: no pair with this frame
            left_out.see(frame.pose_gap_ns, "pose", shared=GROUND_TRUTH_POSE in frame.shared)
            previous = None
            continue
        if previous is not None and left_out.pairs(previous[0].stamp_ns, frame.stamp_ns):
            before, before_reference, before_stereo = previous
            assert before.pose is not None
            assert frame.pose is not None
            evaluator.add(
                before,
                before_reference,
                relative_transform(before.pose, frame.pose),
                before_stereo,
                baselines=before_stereo is not None and has_truth,
            )
        previous = None if frame_reference is None else (frame, frame_reference, stereo)
    if previous is not None:  # temporal mode: the last frame read has no next frame
        result.notes.append(
            f"the last frame ({previous[0].index}) is not scored: temporal mode moves each "
            "frame's pixels into the next frame, and it has none"
            + (" (--max-frames N scores N-1)" if read == options.max_frames else "")
        )
    result.measurements = state.measurements
    result.damage = list(state.damage)
    result.notes += state.notes + truth_values.notes()
    if narrow:  # frames of images too narrow for any SGBM range: densify measured none there
        result.notes.append(
            f"{len(narrow)} frame{'s' if len(narrow) > 1 else ''} left out: their images "
            f"({narrow[0]} px first) are too narrow for SGBM's smallest range (16 disparities), "
            "so they have no SGBM reference"
        )
    result.notes += [n for n in [state.reference_note(reference.topic)] if n] if reference else []
    result.notes += bounds_notes(reference, cx_offsets)
    causes = left_out.notes(state, GROUND_TRUTH_DEPTH if reference is None else reference.topic)
    causes += [n for n in (state.incomplete_note, state.undecodable_left_note) if n]
    causes += [n for n in (state.repeated_note, state.shared_note) if n]
    result.notes += causes + [n for n in (state.copies_note, state.undecodable_note) if n]
    if evaluator.sgbm_empty:
        result.stereo_note = (
            f"{SGBM_NN} left out on {evaluator.sgbm_empty} frames where SGBM found no pixel"
        )
    if result.frames == 0 and result.no_truth:  # every frame with a reference had no truth
        raise LogReadError(no_truth_message(path, result, reference, options.max_frames))
    if result.frames == 0:
        name = reference.topic if reference else GROUND_TRUTH_DEPTH
        tolerance = state.reference_tolerance[0] if reference else state.tolerance_ns
        without = (
            f", {left_out.truths} without a {name} message within {tolerance / 1e6:g} ms of "
            "their stamp"
            if left_out.truths
            else ""
        )
        if left_out.poses:
            without += f", {left_out.poses} without a {GROUND_TRUTH_POSE}"
        if result.no_measurement:
            without += f", {len(result.no_measurement)} without a measurement"
        temporal = mode is Mode.TEMPORAL and (left_out.poses or not result.skipped)
        why = (  # a one-frame log: stereo mode scores it (bug hunt 17G F8)
            "; temporal mode needs two in a row with poses: evaluate with --mode stereo, "
            "which scores each frame alone"
            if temporal
            else ""
        )
        raise LogReadError(
            f"no frame of {path} could be evaluated ({read} densified "
            f"frame{'' if read == 1 else 's'} read{without}{why})"
            + "".join(f"; {cause}" for cause in causes)
            + "".join(f"; damage: {line}" for line in state.damage)  # a cut-off log, say
        )
    if result.reference_pixels == 0:
        raise LogReadError(no_truth_message(path, result, reference, options.max_frames))
    result.points_per_frame = evaluator.points / result.frames
    result.seconds = time.perf_counter() - started
    return result, evaluator.examples


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
        folder: the report folder: new, empty or an earlier report's (its files replaced
            once the report is complete).
        options: evaluation options.
        topics: output topic names.
        progress: called with the number of frames read so far.

    Returns:
        The :class:`Evaluation`.

    Raises:
        PcaInterpError: the folder holds files a report does not write, or cannot be written.
    """
    options = options or EvaluateOptions()
    check_report_folder(folder)  # before the log is evaluated: a refusal costs nothing
    # loaded once: the figures show the basis the rows were computed with, even if the file
    # is replaced or removed while the log is evaluated (bug hunt 17B F2)
    basis = _load_basis(options)
    result, examples = evaluate_log(path, options, topics=topics, progress=progress, loaded=basis)
    options = dataclasses.replace(options, basis=basis)  # the figures: this one, not a re-read

    def write(staging: Path) -> None:
        figures = write_figures(result, examples, staging, _load_basis(options))
        # UTF-8 whatever the locale; a name's bytes that are not UTF-8 escaped (\udce9)
        (staging / "results.json").write_text(report_json(result.summary()), **REPORT_TEXT)
        (staging / "results.md").write_text(results_markdown(result, figures), **REPORT_TEXT)

    write_report_folder(folder, write)  # only now: a log that cannot be evaluated leaves nothing
    return result
