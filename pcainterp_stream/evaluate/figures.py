"""The figures of an evaluation report (matplotlib, Agg): errors, uncertainty, sweep, examples.

Every figure reads only the accumulated :class:`~pcainterp_stream.evaluate.results.Evaluation`
and the few example frames, so it costs the same for a log of any length.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.evaluate.metrics import DELTA_2D_EDGES, DEPTH_EDGES, STD_EDGES
from pcainterp_stream.evaluate.reference import SPARSE_BELOW
from pcainterp_stream.evaluate.results import Evaluation, Example

FIGURE_NAMES: tuple[str, ...] = (
    "errors.png",
    "uncertainty.png",
    "sweep.png",
    "examples.png",
    "basis.png",
    "variance.png",
)
"""Every figure a report may hold (those without data are not written)."""


def _bar_chart(axis: Any, labels: list[str], series: dict[str, list[float]], ylabel: str) -> None:
    width = 0.8 / max(len(series), 1)
    positions = np.arange(len(labels))
    for i, (name, values) in enumerate(series.items()):
        axis.bar(positions + i * width - 0.4 + width / 2, values, width, label=name)
    axis.set_xticks(positions, labels, rotation=30, fontsize=7)
    axis.set_ylabel(ylabel)
    axis.legend(fontsize=7)


def uncertainty_label(name: str, sigma: float) -> str:
    """Return the legend label of an uncertainty series: the log's or a re-densification's.

    >>> uncertainty_label("stored", 2.0), uncertainty_label("exact", 2.0)
    ("stored: the log's estimate and std", 'exact: re-densified, --sigma 2')
    """
    if name == "stored":
        return "stored: the log's estimate and std"
    return f"{name}: re-densified, --sigma {sigma:g}"


def _bin_labels(edges: tuple[float, ...], unit: str) -> list[str]:
    labels = []
    for low, high in itertools.pairwise(edges):
        labels.append(f">{low:g}{unit}" if np.isinf(high) else f"{low:g}-{high:g}")
    return labels


def _ratio(sums: list[float], counts: list[float]) -> list[float]:
    return [s / c if c > 0 else 0.0 for s, c in zip(sums, counts, strict=True)]


def _scatter(
    axis: Any, reference: npt.NDArray[np.float64], truth: npt.NDArray[np.bool_], high: float
) -> None:
    """Draw a sparse reference as dots: single pixels vanish when an image is shrunk."""
    rows, columns = np.nonzero(truth)
    axis.scatter(columns, rows, c=reference[truth], s=1.0, cmap="turbo", vmin=0, vmax=high)
    height, width = reference.shape
    axis.set_xlim(-0.5, width - 0.5)
    axis.set_ylim(height - 0.5, -0.5)
    axis.set_aspect("equal")


def write_figures(
    result: Evaluation, examples: list[Example], folder: Path, basis: Basis | None
) -> list[str]:
    """Write the report's PNG figures; return their file names."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names: list[str] = []

    def save(figure: Any, name: str) -> None:
        assert name in FIGURE_NAMES
        figure.tight_layout()
        figure.savefig(folder / name, dpi=90)
        plt.close(figure)
        names.append(name)

    # error distribution, PCA-MAP against nearest neighbour (and the others)
    methods = {**result.methods, **result.stereo}
    figure, axes = plt.subplots(1, 3, figsize=(15, 4))
    labels = _bin_labels(DELTA_2D_EDGES, " px")
    _bar_chart(
        axes[0],
        labels,
        {name: list(np.asarray(s.delta_2d_hist) / max(s.pixels, 1)) for name, s in methods.items()},
        "share of pixels",
    )
    axes[0].set_title("Delta_2D distribution")
    _bar_chart(
        axes[1],
        _bin_labels(DEPTH_EDGES, " m"),
        {n: _ratio(s.by_depth_2d, s.by_depth_count) for n, s in methods.items()},
        "mean Delta_2D (px)",
    )
    axes[1].set_title("Delta_2D by reference depth (m)")
    _bar_chart(
        axes[2],
        _bin_labels(DEPTH_EDGES, " m"),
        {n: _ratio(s.by_depth_3d, s.by_depth_3d_count) for n, s in methods.items()},
        "mean Delta_3D (m)",
    )
    if any(value > 0 for stats in methods.values() for value in stats.by_depth_3d):
        axes[2].set_yscale("log")  # matplotlib warns when no value is positive
    axes[2].set_title("Delta_3D by reference depth (m)")
    save(figure, "errors.png")

    # uncertainty: Delta_2D and |error| by predicted std, coverage
    figure, axes = plt.subplots(1, 2, figsize=(11, 4))
    std_labels = _bin_labels(STD_EDGES, " px")
    _bar_chart(
        axes[0],
        std_labels,
        {
            uncertainty_label(n, result.sigma): _ratio(c.by_std_2d, c.by_std_count)
            for n, c in result.calibration.items()
        },
        "mean Delta_2D (px)",
    )
    # the stored series is the log's own estimate; the others evaluate's re-densifications
    axes[0].set_title("PCA-MAP Delta_2D by predicted disparity std (px)", fontsize=9)
    for name, calibration in result.calibration.items():
        counts = np.asarray(calibration.by_std_count)
        rms = np.where(
            counts > 0, np.sqrt(_ratio(calibration.by_std_sq, calibration.by_std_count)), np.nan
        )  # empty bins are gaps, not zeros on the log axis
        label = uncertainty_label(name, result.sigma)
        axes[1].plot(std_labels, rms, marker="o", label=f"{label}: RMS error")
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
            truth = np.isfinite(example.reference)
            high = float(np.percentile(example.reference[truth], 99)) if truth.any() else 0.0
            high = high or 1.0
            row[0].imshow(example.left, cmap="gray")
            row[0].plot(example.pixels[:, 0], example.pixels[:, 1], "r.", markersize=2)
            row[0].set_title(f"frame {example.index}: input, {len(example.pixels)} points")
            if truth.mean() < SPARSE_BELOW:
                _scatter(row[1], example.reference, truth, high)
            else:
                row[1].imshow(example.reference, cmap="turbo", vmin=0, vmax=high)
            row[2].imshow(example.estimate, cmap="turbo", vmin=0, vmax=high)
            row[4].imshow(example.nearest, cmap="turbo", vmin=0, vmax=high)
            for axis, title in (
                (row[1], "reference"),
                (row[2], "PCA-MAP"),
                (row[4], "nearest neighbour"),
            ):
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
