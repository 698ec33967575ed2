"""Per-frame figures of an evaluation, the frames that stand out, and the SGBM caveat.

The table averages over the log, so a few broken frames (a swapped pair, a lens cap) vanish
in it, or even improve it: with SGBM of the log's own pairs as the reference, a broken pair
is scored against SGBM's errors on that same pair. Each scored frame's figures are therefore
kept (``results.json``'s ``per_frame``) and the frames far from the log's median are named.

A frame's figures are the difference of the accumulators evaluate fills anyway
(:class:`~pcainterp_stream.evaluate.metrics.MethodStats`,
:class:`~pcainterp_stream.evaluate.metrics.CalibrationStats`, the "too far" counts) before
and after the frame: a few floats per frame, no second pass over the images.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from pcainterp_stream.evaluate.metrics import CalibrationStats, MethodStats

PER_FRAME_METHODS = ("pca_map", "nearest", "linear")
"""The methods whose mean Delta_2D each frame records (those computed)."""

ERROR_FACTOR = 3.0
"""A frame stands out when its PCA-MAP mean Delta_2D exceeds this times the median frame's."""

LOW_COVERAGE = 0.5
"""A frame stands out when its stored std's +-2 sigma covers less than this share."""

FAR_SHARE = 0.5
"""A frame stands out when its reference is too far (depth +inf) on more than this share of
its scored pixels, and on more than :data:`ERROR_FACTOR` times the median frame's share (SGBM
of one view twice finds disparity 0 everywhere); every pixel is still scored (disparity 0)."""

FEW_PIXELS = 1 / 3
"""A frame stands out when it scored fewer pixels than this times the median frame's: its
reference holds truth on few pixels (SGBM of a swapped pair matches little)."""

SHOWN = 8
"""Frames named per line of the summary (the rest are counted)."""


@dataclass(frozen=True)
class FrameFigures:
    """One frame's figures (``results.json``'s ``per_frame``).

    Attributes:
        index: the frame's index (from 0, in log order).
        stamp_ns: its stamp (ns).
        estimate: whether the stored estimate has a value at some pixel (False: NaN, no
            estimate; such a frame is in none of the table's rows).
        measured: whether the frame had a measurement (False: left out of every method).
        truth: whether its reference held truth on some pixel to score (False: left out of
            every method, named by the report's no-truth note).
        pixels: reference pixels scored (PCA-MAP's).
        delta_2d_mean: per method computed, its mean Delta_2D on the frame (px; NaN when no
            pixel was scored).
        coverage_2sigma: share of the reference within +-2 stored std (NaN: none scored).
        reference_far: share of the scored pixels whose reference is too far (depth +inf;
            NaN when the log records no minimum disparity or none was scored).
    """

    index: int
    stamp_ns: int
    estimate: bool
    measured: bool
    pixels: int
    delta_2d_mean: dict[str, float] = field(default_factory=dict)
    coverage_2sigma: float = math.nan
    reference_far: float = math.nan
    truth: bool = True

    def summary(self) -> dict[str, Any]:
        """Return the plain JSON-able row."""
        return {
            "index": self.index,
            "stamp_ns": self.stamp_ns,
            "estimate": self.estimate,
            "measured": self.measured,
            "truth": self.truth,
            "pixels": self.pixels,
            "delta_2d_mean": dict(self.delta_2d_mean),
            "coverage_2sigma": self.coverage_2sigma,
            "reference_far": self.reference_far,
        }


def _ratio(above: float, below: float) -> float:
    return above / below if below > 0 else math.nan


class _Ranges(Protocol):
    counted: int
    reference_far: int


class Scored(Protocol):
    """What :class:`PerFrame` reads and fills: an ``Evaluation`` (no import cycle)."""

    methods: dict[str, MethodStats]
    calibration: dict[str, CalibrationStats]
    per_frame: list[FrameFigures]

    @property
    def ranges(self) -> _Ranges:
        """The "too far" counts."""


class PerFrame:
    """Records each scored frame's figures into ``result.per_frame``.

    :meth:`start` before a frame is scored, :meth:`finish` after (or when it is left out).
    """

    def __init__(self, result: Scored) -> None:
        self.result = result
        self._mark: dict[str, tuple[float, float]] = {}

    def _sums(self) -> dict[str, tuple[float, float]]:
        result = self.result
        sums = {
            name: (result.methods[name].pixels, result.methods[name].delta_2d_sum)
            for name in PER_FRAME_METHODS
            if name in result.methods
        }
        stored = result.calibration.get("stored")
        if stored is not None:
            sums["stored"] = (stored.sums["n"], stored.sums["inside_2"])
        sums["far"] = (float(result.ranges.counted), float(result.ranges.reference_far))
        return sums

    def start(self) -> None:
        """Mark the accumulators before a frame is scored."""
        self._mark = self._sums()

    def finish(
        self,
        index: int,
        stamp_ns: int,
        estimate: npt.NDArray[Any],
        *,
        measured: bool = True,
        truth: bool = True,
    ) -> None:
        """Record the frame scored since :meth:`start` (``estimate``: its stored map)."""
        zero = (0.0, 0.0)
        moved = {
            key: (count - self._mark.get(key, zero)[0], total - self._mark.get(key, zero)[1])
            for key, (count, total) in self._sums().items()
        }
        methods = {
            name: _ratio(moved[name][1], moved[name][0])
            for name in PER_FRAME_METHODS
            if name in moved and measured and truth
        }
        stored, far = moved.get("stored", (0.0, 0.0)), moved["far"]
        self.result.per_frame.append(
            FrameFigures(
                index=index,
                stamp_ns=stamp_ns,
                estimate=bool(np.any(~np.isnan(estimate))),
                measured=measured,
                pixels=int(moved["pca_map"][0]) if "pca_map" in moved else 0,
                delta_2d_mean=methods,
                coverage_2sigma=_ratio(stored[1], stored[0]),
                reference_far=_ratio(far[1], far[0]),
                truth=truth,
            )
        )


def frame_ranges(indices: list[int]) -> str:
    """Return frame indices as ranges, e.g. ``5-7, 9``.

    >>> frame_ranges([5, 6, 7, 9])
    '5-7, 9'
    """
    parts: list[str] = []
    start = previous = None
    for index in [*sorted(indices), None]:
        if previous is not None and (index is None or index != previous + 1):
            parts.append(f"{start}" if start == previous else f"{start}-{previous}")
            start = index
        elif start is None:
            start = index
        previous = index
    return ", ".join(parts)


def _named(frames: list[FrameFigures]) -> str:
    shown = frame_ranges([f.index for f in frames[:SHOWN]])
    more = f" and {len(frames) - SHOWN} more" if len(frames) > SHOWN else ""
    return f"{'frame' if len(frames) == 1 else 'frames'} {shown}{more}"


def _span(values: list[float], unit: str, scale: float = 1.0, decimals: int = 2) -> str:
    low, high = min(values) * scale, max(values) * scale
    if f"{low:.{decimals}f}" == f"{high:.{decimals}f}":
        return f"{low:.{decimals}f}{unit}"
    return f"{low:.{decimals}f}-{high:.{decimals}f}{unit}"


def standout_lines(frames: list[FrameFigures]) -> list[str]:
    """Return at most four lines naming the frames far from the log's median frame.

    A frame stands out when it has no estimate (NaN), when its PCA-MAP mean Delta_2D is
    over :data:`ERROR_FACTOR` times the median frame's, when its stored +-2 sigma covers
    under :data:`LOW_COVERAGE`, when its reference is too far on most pixels
    (:data:`FAR_SHARE`), or when its reference collapsed to truth on few pixels
    (:data:`FEW_PIXELS`). A frame whose reference collapsed is named for that alone: its
    error and coverage over the few pixels left say little. A frame whose reference is too
    far is scored on every pixel (truth disparity 0), so its error and coverage lines stay.
    Frames
    left out for want of a measurement or of any truth are named by their own notes, not
    here. Empty when none stands out.
    """
    scored = [f for f in frames if f.pixels > 0]
    lines: list[str] = []
    empty = [f for f in frames if f.measured and f.truth and not f.estimate]
    if empty:  # else named as unmeasured, or as holding no truth
        lines.append(f"{_named(empty)}: no estimate (NaN in the log), scored on no pixel")
    if len(scored) < 2:
        return lines
    collapsed, collapsed_lines = _far_or_few(scored)
    errors = [f.delta_2d_mean.get("pca_map", math.nan) for f in scored]
    median = float(np.nanmedian(errors)) if np.isfinite(errors).any() else math.nan
    worse = [
        f
        for f, e in zip(scored, errors, strict=True)
        if e > ERROR_FACTOR * median > 0 and f.index not in collapsed
    ]
    if worse:
        values = [f.delta_2d_mean["pca_map"] for f in worse]
        lines.append(
            f"{_named(worse)}: PCA-MAP error {_span(values, ' px')}, over {ERROR_FACTOR:g}x "
            f"the median frame's {median:.2f} px"
        )
    low = [f for f in scored if f.coverage_2sigma < LOW_COVERAGE and f.index not in collapsed]
    if low:
        values = [f.coverage_2sigma for f in low]
        lines.append(
            f"{_named(low)}: +-2 sigma covers {_span(values, ' %', 100.0, 1)} of the "
            f"reference (under {100 * LOW_COVERAGE:.0f} %)"
        )
    return lines + collapsed_lines


def _far_or_few(scored: list[FrameFigures]) -> tuple[set[int], list[str]]:
    """Return the frames whose reference collapsed to truth on few, and the standout lines.

    Their error and coverage over the few pixels say little; the lines also name the frames
    whose reference is too far on most pixels (scored on all of them: not left out).
    """
    far_shares = [f.reference_far for f in scored]
    median_far = float(np.nanmedian(far_shares)) if np.isfinite(far_shares).any() else math.nan
    median_pixels = float(np.median([f.pixels for f in scored]))
    few = [f for f in scored if f.pixels < FEW_PIXELS * median_pixels]
    named = {f.index for f in few}
    limit = max(FAR_SHARE, ERROR_FACTOR * median_far)
    far = [f for f in scored if f.reference_far > limit and f.index not in named]
    lines = []
    if far:
        values = [f.reference_far for f in far]
        lines.append(
            f"{_named(far)}: the reference is too far (depth +inf) on "
            f"{_span(values, ' %', 100.0, 0)} of the pixels (median frame "
            f"{100 * median_far:.0f} %); every pixel is still scored, too far as disparity 0"
        )
    if few:
        values = [f.pixels / median_pixels for f in few]
        counts = [float(f.pixels) for f in few]
        lines.append(
            f"{_named(few)}: the reference holds truth on {_span(values, 'x', 1.0, 2)} the "
            f"median frame's pixels ({_span(counts, ' px', 1.0, 0)} of {median_pixels:.0f}): "
            "it collapsed there"
        )
    return named, lines


def own_pair_notes(reference: str) -> list[str]:
    """Return the note on SGBM of the log's own pairs as the reference ([] for another one)."""
    if reference != "SGBM":
        return []
    return [
        "the reference is SGBM of the log's own pairs: a frame whose pair is broken (left and "
        "right swapped, rows misaligned, one view on both topics) is scored against SGBM's "
        "errors on that same pair, which may agree with the estimate's, so the table can look "
        "better for it; per-frame figures are in results.json (per_frame), frames that stand "
        "out are named below; pass --reference-topic with a ground-truth topic to score "
        "against truth"
    ]
