"""What ``pcainterp evaluate`` measured: the records the report's tables and figures read.

:class:`Evaluation` is filled frame by frame by :mod:`pcainterp_stream.evaluate.report` and
read by :mod:`~pcainterp_stream.evaluate.tables` (text, ``results.json``) and
:mod:`~pcainterp_stream.evaluate.figures` (PNGs).
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.evaluate.metrics import (
    DELTA_2D_EDGES,
    DEPTH_EDGES,
    STD_EDGES,
    CalibrationStats,
    MethodStats,
)
from pcainterp_stream.evaluate.per_frame import FrameFigures
from pcainterp_stream.evaluate.reference import SPARSE_BELOW

PAPER_DELTA_2D = {"KITTI": (3.4, 5.4), "Virtual KITTI": (2.0, 3.3)}
"""The paper's mean Delta_2D (px) of PCA-MAP and nearest neighbour (section IV-B)."""

TARGET_RATIO = 0.65
"""Target: PCA-MAP's mean Delta_2D at most this times nearest neighbour's."""

TARGET_COVERAGE = (0.90, 0.98)
"""Target: the +-2 sigma coverage of the std the log carries (else of evaluate's exact
uncertainty) lies in this range."""

TARGET_SGBM_NN_RATIO = 0.85
"""Dense-mode target: PCA-MAP's mean Delta_2D at most this times ``sgbm_nn``'s."""

NAMED_FRAMES = 10
"""Frames named in a note (the rest are counted)."""

SGBM = "sgbm"
"""Stereo baseline: SGBM's own full-resolution map, scored where it has a value."""
SGBM_NN = "sgbm_nn"
"""Stereo baseline: SGBM's map with its holes filled by the nearest valid pixel."""
PCA_ON_SGBM = "pca_map@sgbm"
"""PCA-MAP scored on the same pixels as :data:`SGBM` (where SGBM has a value)."""


@dataclass
class RangeStats:
    """How the REP 118 "farther than measurable" rule splits the counted pixels.

    A pixel is too far for the estimate where its disparity is below the frame's
    resolvable minimum (the ``DisparityImage``'s ``min_disparity``: depth ``+inf``), and
    too far for the reference where the reference disparity is (sky included).
    ``reference_blind`` counts the pixels of frames whose reference cannot say "too far": a
    DisparityImage holds no truth below its min_disparity, so one whose lowest truth is at or
    above the frame's minimum (densify's own ``/pcainterp/disparity``) has no far pixel.
    """

    counted: int = 0
    estimate_far: int = 0
    reference_far: int = 0
    both_far: int = 0
    reference_blind: int = 0

    def add(
        self,
        estimate: npt.NDArray[np.float32],
        reference: npt.NDArray[np.float64],
        counted: npt.NDArray[np.bool_],
        min_disparity: float,
        reference_floor: float = 0.0,
    ) -> None:
        """Count one frame's pixels (``counted`` only).

        ``reference_floor``: the lowest disparity the reference can hold as truth (a
        DisparityImage's min_disparity; 0 for another reference).
        """
        with np.errstate(invalid="ignore"):
            estimate_far = counted & (estimate < min_disparity)
            reference_far = counted & (reference < min_disparity)
        self.counted += int(counted.sum())
        self.estimate_far += int(estimate_far.sum())
        self.reference_far += int(reference_far.sum())
        self.both_far += int((estimate_far & reference_far).sum())
        if reference_floor >= min_disparity * (1 - 1e-5):  # both float32 in the messages
            self.reference_blind += int(counted.sum())

    @property
    def blind(self) -> bool:
        """Whether no counted pixel's reference could say "too far" (the shares say nothing)."""
        return self.counted > 0 and self.reference_blind == self.counted

    def summary(self) -> dict[str, float]:
        """Return the shares too far of the counted pixels, and the agreement of each side."""
        return {
            "estimate_far": self.estimate_far / max(self.counted, 1),
            "reference_far": self.reference_far / max(self.counted, 1),
            "estimate_far_reference_agrees": self.both_far / max(self.estimate_far, 1),
            "reference_far_estimate_agrees": self.both_far / max(self.reference_far, 1),
        }


@dataclass
class Example:
    """One frame kept for the examples figure (arrays (H, W), disparity in px)."""

    index: int
    left: npt.NDArray[Any]
    pixels: npt.NDArray[np.float64]
    reference: npt.NDArray[np.float64]
    estimate: npt.NDArray[np.float32]
    std: npt.NDArray[np.float32]
    nearest: npt.NDArray[np.float32]


def _stats_json(stats: MethodStats | CalibrationStats) -> dict[str, Any]:
    return {"mean": stats.summary(), "accumulated": dataclasses.asdict(stats)}


@dataclass
class Evaluation:
    """Everything ``evaluate`` measured (the JSON of the report).

    Attributes:
        log: the evaluated log.
        mode: stereo or temporal.
        reference: "ground truth" (the log's ``/ground_truth/depth``), "SGBM" (of the pair),
            or the ``--reference-topic`` scored against.
        frames: frames evaluated.
        image_size: (height, width) px.
        methods: per method (pca_map, nearest, linear, oracle) its accumulated errors.
        calibration: per uncertainty kind (stored, paper, exact) its calibration.
        sweep: per number of points, per method, its accumulated errors.
        sweep_frames: frames in the sweep.
        sweep_reached: per number of points, the sweep frames that had that many corners
            with a disparity (a count no frame reached has no row).
        sweep_corners: corners with a disparity found on each sweep frame.
        sigma: measurement noise std (px) of evaluate's re-densifications.
        points_per_frame: mean sparse points per frame.
        basis: description of the basis (None without one).
        basis_note: how the basis was chosen, or why there is none.
        seconds: wall time of the evaluation (s).
        ranges: the REP 118 "too far" split of the estimate against the reference.
        reference_kind: "depth" or "disparity" for a reference topic, "" otherwise.
        reference_pixels: pixels with truth in the evaluated frames' references.
        reference_area: all pixels of the evaluated frames' references.
        skipped: frames skipped because no reference message was stamped near them.
        stereo: the stereo baselines (:data:`SGBM`, :data:`SGBM_NN`, :data:`PCA_ON_SGBM`),
            apart from ``methods`` as they are not all scored on the same pixels.
        stereo_note: why the stereo baselines are missing ("" when they are there).
        stereo_counted: counted pixels of the frames the stereo baselines ran on.
        measurements: the ``pcainterp.measurements`` channel metadata of the densified log
            (``dense`` or ``sparse``), None when the log records none.
        damage: damage found reading the log (a truncated file), one line each.
        no_measurement: indices (from 0, in log order) of the frames left out of every
            method because they had no measurement (black, dark or textureless images).
        no_truth: indices of the frames left out of every method because their reference
            held no truth on any pixel that could be scored (a LiDAR drop-out, SGBM of a
            pair matching nothing, a DisparityImage whose values are all out of its own
            bounds or window, truth that leaves the other view or lies only where the
            estimate is NaN).
        no_truth_causes: why, one phrase per frame of ``no_truth`` (same order).
        no_estimate: counted reference pixels where the stored estimate is NaN (no estimate:
            outside the rectified box of a raw or black-bordered pair), left out of every
            method and uncertainty row.
        reference_counted: counted reference pixels before those were left out.
        basis_rows_skipped: frames whose estimate is no box (NaN in an irregular region),
            left out of the re-densified rows (paper, exact, oracle, sweep).
        notes: what reading the log found that the figures depend on, one sentence each
            (NaN read as "no truth", channel metadata a conversion dropped).
        sigma_log_px: ``sigma`` in the log's px (it is in the basis's: x the log's f*b / the
            basis's, of the last frame re-densified); None when no row re-densified.
        input_pair: the input pair SGBM matched: topics, calibration, ``--rectify`` and
            where they came from (densify's record of the log, or found again).
        per_frame: each frame given to the scoring (in order, those without a measurement
            too), its own figures (:class:`~pcainterp_stream.evaluate.per_frame.FrameFigures`).
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
    sweep_reached: dict[int, int] = field(default_factory=dict)
    sweep_corners: list[int] = field(default_factory=list)
    sigma: float = 2.0
    points_per_frame: float = 0.0
    basis: dict[str, Any] | None = None
    basis_note: str = ""
    seconds: float = 0.0
    ranges: RangeStats = field(default_factory=RangeStats)
    reference_kind: str = ""
    reference_pixels: int = 0
    reference_area: int = 0
    skipped: int = 0
    stereo: dict[str, MethodStats] = field(default_factory=dict)
    stereo_note: str = ""
    stereo_counted: float = 0.0
    measurements: str | None = None
    damage: list[str] = field(default_factory=list)
    no_measurement: list[int] = field(default_factory=list)
    no_truth: list[int] = field(default_factory=list)
    no_truth_causes: list[str] = field(default_factory=list)
    no_estimate: int = 0
    reference_counted: int = 0
    basis_rows_skipped: int = 0
    notes: list[str] = field(default_factory=list)
    input_pair: str = ""
    sigma_log_px: float | None = None
    per_frame: list[FrameFigures] = field(default_factory=list)

    @property
    def sigma_label(self) -> str:
        """Return ``--sigma`` as the report states it: in the basis's px and the log's."""
        label = f"--sigma {self.sigma:g} px"
        if self.sigma_log_px is not None:
            label += f" of the basis's camera, {self.sigma_log_px:.3g} px in the log's"
        return label

    @property
    def no_estimate_fraction(self) -> float:
        """Return the share of the counted reference pixels that have no stored estimate."""
        return self.no_estimate / max(self.reference_counted, 1)

    @property
    def no_estimate_note(self) -> str:
        """Return the sentence on the pixels left out for want of an estimate ("": none)."""
        notes = []
        if self.no_estimate:
            notes.append(
                f"{100 * self.no_estimate_fraction:.1f} % of the reference pixels have no "
                "estimate (NaN in the log: outside the rectified box): left out of every method"
            )
        if self.basis_rows_skipped:
            notes.append(
                f"{self.basis_rows_skipped} frames left out of the re-densified rows: their "
                "estimate is NaN outside no box, so the box densify used is unknown"
            )
        return "; ".join(notes)

    @property
    def reference_fraction(self) -> float:
        """Return the share of the references' pixels that hold truth."""
        return self.reference_pixels / max(self.reference_area, 1)

    @property
    def reference_label(self) -> str:
        """Return the reference with its density, e.g. ``/lidar (sparse, 5.1 % of pixels)``."""
        fraction = self.reference_fraction
        density = "sparse" if fraction < SPARSE_BELOW else "dense"
        return f"{self.reference} ({density}, {100 * fraction:.1f} % of pixels)"

    @property
    def sgbm_fill(self) -> float:
        """Return the share of the counted pixels where SGBM has a value (0 without it)."""
        if SGBM not in self.stereo:
            return 0.0
        return self.stereo[SGBM].pixels / max(self.stereo_counted, 1.0)

    def summary(self) -> dict[str, Any]:
        """Return every number as plain JSON-able data (means and the accumulated bins)."""
        return {
            "log": self.log,
            "mode": self.mode,
            "reference": self.reference,
            "reference_label": self.reference_label,
            "reference_kind": self.reference_kind,
            "reference_fraction": self.reference_fraction,
            "skipped_no_reference": self.skipped,
            "measurements": self.measurements,
            "damage": self.damage,
            "notes": list(self.notes),
            "input_pair": self.input_pair,
            "left_out_no_measurement": list(self.no_measurement),
            "left_out_no_truth": list(self.no_truth),
            "left_out_no_estimate": self.no_estimate_fraction,
            "left_out_no_estimate_pixels": self.no_estimate,
            "left_out_of_redensified_rows": self.basis_rows_skipped,
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
            "methods": {name: _stats_json(stats) for name, stats in self.methods.items()},
            "stereo_baselines": {name: _stats_json(stats) for name, stats in self.stereo.items()},
            "stereo_baselines_note": self.stereo_note,
            "sgbm_fill": self.sgbm_fill,
            "calibration": {name: _stats_json(stats) for name, stats in self.calibration.items()},
            "ranges": {
                "mean": self.ranges.summary(),
                "accumulated": dataclasses.asdict(self.ranges),
            },
            "sweep_frames": self.sweep_frames,
            "sweep_frames_reached": {str(p): n for p, n in self.sweep_reached.items()},
            "sweep_corners": list(self.sweep_corners),
            "sigma_px": self.sigma,
            "sigma_log_px": self.sigma_log_px,
            "sweep": {
                str(points): {name: stats.summary() for name, stats in methods.items()}
                for points, methods in self.sweep.items()
            },
            "per_frame": [figures.summary() for figures in self.per_frame],
        }

    @property
    def no_measurement_note(self) -> str:
        """Return the sentence naming the frames left out for want of a measurement ("": none)."""
        count = len(self.no_measurement)
        if not count:
            return ""
        shown = ", ".join(str(index) for index in self.no_measurement[:NAMED_FRAMES])
        more = f" and {count - NAMED_FRAMES} more" if count > NAMED_FRAMES else ""
        return (
            f"{count} {'frame' if count == 1 else 'frames'} left out of every method: no "
            "measurement there (densify matched nothing: black, dark or textureless images, or "
            "a pair it left unmatched, swapped or one view twice, as its warnings say), so "
            "nearest and linear have nothing to interpolate and PCA-MAP has no estimate; "
            f"{'it is' if count == 1 else 'they are'} not in the table "
            f"({'frame' if count == 1 else 'frames'} {shown}{more}, counted from 0)"
        )

    @property
    def no_truth_note(self) -> str:
        """Return the sentence naming the frames whose reference held no truth ("": none)."""
        count = len(self.no_truth)
        if not count:
            return ""
        groups = grouped_causes(self.no_truth, self.no_truth_causes)
        sgbm = self.reference == "SGBM"
        what = "SGBM of the pair" if sgbm else "the reference message is there but"
        return (
            f"{count} {'frame' if count == 1 else 'frames'} left out of every method: "
            f"{what} holds no truth on any pixel to score, so there is nothing to score against; "
            f"{'it is' if count == 1 else 'they are'} not in the table "
            f"({'; '.join(groups)}; counted from 0)"
        )

    def ratio(self) -> float | None:
        """Return PCA-MAP's mean Delta_2D divided by nearest neighbour's (None: undefined)."""
        return mean_ratio(self.methods["pca_map"], self.methods["nearest"])


def grouped_causes(indices: list[int], causes: list[str]) -> list[str]:
    """Return "frame 1: cause" per kind of cause, the other frames of a kind as "likewise".

    Causes of one kind differ in their counts only (digits), so the first is quoted.
    """
    kinds: dict[str, tuple[str, list[int]]] = {}
    for index, cause in zip(indices, causes + [""] * (len(indices) - len(causes)), strict=True):
        kinds.setdefault(re.sub(r"\d+", "#", cause), (cause, []))[1].append(index)
    groups = []
    for cause, frames in kinds.values():
        first, rest = frames[0], frames[1:]
        shown = ", ".join(str(index) for index in rest[:NAMED_FRAMES])
        more = f" and {len(rest) - NAMED_FRAMES} more" if len(rest) > NAMED_FRAMES else ""
        likewise = f"; likewise frame{'s' if len(rest) > 1 else ''} {shown}{more}" if rest else ""
        groups.append(f"frame {first}: {cause}{likewise}" if cause else f"frame {first}{likewise}")
    return groups


def mean_ratio(numerator: MethodStats, denominator: MethodStats) -> float | None:
    """Return the ratio of two methods' mean Delta_2D, None when it is undefined.

    Undefined: the denominator scored no pixel or scored 0 px (e.g. nearest neighbour of no
    measurement, which counts as far, against the zero disparity SGBM finds on black images).
    """
    below = denominator.summary()["delta_2d_mean"]
    if denominator.pixels <= 0 or below <= 0:
        return None
    return float(numerator.summary()["delta_2d_mean"] / below)
