"""The jobs behind the ``pcainterp`` commands: plain functions over paths and configs.

``learn``/``fit_prior`` live in :mod:`~pcainterp_stream.pipeline.learn` and ``densify`` in
:mod:`~pcainterp_stream.pipeline.densify`; this module holds the others and exports all.

Each job streams (one frame, or a small look-ahead of frames, in memory), shows a progress
bar on a terminal, writes its output atomically (temporary file beside the target, renamed
when complete) and raises only :class:`~pcainterp_stream.errors.PcaInterpError` subclasses
on bad input, which the command line prints as one line.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from pcainterp_stream.errors import (
    BasisError,
    PcaInterpError,
)
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.frontend.pairing import (
    PairingConfig,
)
from pcainterp_stream.io.logwriter import WriteSummary
from pcainterp_stream.io.outputs import OutputTopics
from pcainterp_stream.pipeline.common import _bar, _echo
from pcainterp_stream.pipeline.densify import DensifySummary, densify
from pcainterp_stream.pipeline.learn import LearnOptions, fit_prior, learn
from pcainterp_stream.pipeline.processor import ProcessorConfig

__all__ = [
    "DensifySummary",
    "LearnOptions",
    "demo",
    "densify",
    "describe_basis",
    "evaluate",
    "fit_prior",
    "import_kitti",
    "info",
    "learn",
    "synth",
]


def synth(out: Path, *, frames: int, seed: int, scale: float, fmt: str | None) -> WriteSummary:
    """Render a synthetic drive and write it as a log (``pcainterp synth``)."""
    from pcainterp_stream.synth import SynthConfig, generate
    from pcainterp_stream.synth.log import write_synthetic_log

    if frames < 1:
        raise PcaInterpError(f"--frames must be at least 1, got {frames}")
    if not 0.05 <= scale <= 4.0:  # also refuses nan
        raise PcaInterpError(f"--scale must be in [0.05, 4], got {scale}")
    config = SynthConfig(seed=seed, frames=frames, scale=scale)
    with _bar(frames, f"synth {out.name}") as bar:
        return write_synthetic_log(
            generate(config),
            out,
            format=fmt,
            total=frames,
            progress=lambda done, total: bar.update(done - bar.n),
        )


def import_kitti(folder: Path, out: Path, *, max_frames: int | None) -> WriteSummary:
    """Convert a KITTI folder into an MCAP log (``pcainterp import-kitti``)."""
    from pcainterp_stream.io.kitti import import_kitti as convert

    if max_frames is not None and max_frames < 1:
        raise PcaInterpError(f"--max-frames must be at least 1, got {max_frames}")
    with _bar(None, f"import {folder.name}") as bar:

        def progress(done: int, total: int | None) -> None:
            bar.total = total
            bar.update(done - bar.n)

        return convert(folder, out, max_frames=max_frames, progress=progress)


def evaluate(
    input_path: Path,
    output: Path | None,
    *,
    basis: Path | None = None,
    mode: str | None = None,
    sigma: float = 2.0,
    sweep_every: int = 10,
    max_frames: int | None = None,
    topics: OutputTopics | None = None,
) -> tuple[Path, str]:
    """Evaluate a densified log into a report folder (``pcainterp evaluate``).

    Returns:
        The report folder and the summary table text.
    """
    from pcainterp_stream.evaluate.metrics import Mode
    from pcainterp_stream.evaluate.report import EvaluateOptions, summary_table, write_report

    if not 0 < sigma < float("inf"):
        raise PcaInterpError(f"--sigma must be > 0 px, got {sigma}")
    if sweep_every < 0:
        raise PcaInterpError(f"--sweep-every must be >= 0, got {sweep_every}")
    if max_frames is not None and max_frames < 1:
        raise PcaInterpError(f"--max-frames must be at least 1, got {max_frames}")
    if basis is not None and not basis.is_file():
        raise PcaInterpError(f"basis {basis} does not exist; pass the basis used by densify")
    folder = output or input_path.with_name(input_path.stem + "_report")
    options = EvaluateOptions(
        basis=basis,
        mode=Mode(mode) if mode is not None else None,
        sigma=sigma,
        sweep_every=sweep_every,
        max_frames=max_frames,
    )
    with _bar(None, f"evaluate {input_path.name}") as bar:
        result = write_report(
            input_path,
            folder,
            options,
            topics=topics,
            progress=lambda done: bar.update(done - bar.n),
        )
    return folder, summary_table(result)


def describe_basis(path: Path) -> str:
    """Return a text description of a basis file."""
    basis = Basis.load(path)
    height, width = basis.image_size
    grid_height, grid_width = basis.grid_size
    ratio = basis.explained_variance_ratio
    learning = basis.meta.get("learning", {}) if isinstance(basis.meta, dict) else {}
    lines = [
        f"{path}: pcainterp basis",
        f"  image size       {width}x{height} px",
        f"  grid             {grid_width}x{grid_height} ({grid_width * grid_height} pixels)",
        f"  components       {basis.n_components}",
        f"  variance         {100 * ratio:.2f} % of the training variance explained",
        f"  first eigenvalue {basis.eigenvalues[0]:.4g} px^2",
        f"  focal*baseline   {basis.focal_baseline:.4g} px*m",
        f"  training maps    {basis.n_train}",
        f"  method           {learning.get('method', '?')}",
    ]
    fitted = basis.meta.get("prior") if isinstance(basis.meta, dict) else None
    if isinstance(fitted, dict):
        local = fitted.get("local")
        kernel = (
            f"{local['kernel']} kernel, {local['length_scale']:g} px, {local['variance']:.3g} px^2"
            if isinstance(local, dict)
            else "none (the paper's prior had the best evidence)"
        )
        lines += [
            f"  fitted prior     {kernel}; sigma {fitted.get('sigma', float('nan')):.3g} px; "
            f"process noise {fitted.get('process_noise', float('nan')):g}; "
            f"std scale {fitted.get('std_scale', 1.0):.3g}"
            + (
                f" ({fitted['innovation_std_scale']:.3g} with the per-frame covariance scale)"
                if "innovation_std_scale" in fitted
                else ""
            ),
        ]
    return "\n".join(lines)


def info(path: Path) -> str:
    """Return the ``pcainterp info`` text of a log or a basis file."""
    from pcainterp_stream.io.loginfo import describe, format_info

    if path.suffix == ".npz":
        return describe_basis(path)
    if path.is_file():
        with path.open("rb") as handle:
            if handle.read(4) == b"PK\x03\x04":
                try:
                    return describe_basis(path)
                except BasisError:
                    pass
    return format_info(describe(path))


def demo(out: Path, *, spawn_viewer: bool = False) -> str:
    """Run the whole job on generated logs and return a summary (``pcainterp demo``)."""
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    train_logs = [out / f"train_{seed}.mcap" for seed in DEMO_TRAIN_SEEDS]
    test_log = out / "heldout.mcap"
    basis_path, dense_log, rrd = out / "basis.npz", out / "heldout_dense.mcap", out / "heldout.rrd"
    _echo(
        f"1/5 rendering {len(train_logs)} training drives of {DEMO_TRAIN_FRAMES} frames "
        f"-> {out}/train_*.mcap"
    )
    for seed, train_log in zip(DEMO_TRAIN_SEEDS, train_logs, strict=True):
        synth(train_log, frames=DEMO_TRAIN_FRAMES, seed=seed, scale=DEMO_SCALE, fmt="mcap")
    _echo(f"2/5 rendering a {DEMO_TEST_FRAMES}-frame held-out drive (another seed) -> {test_log}")
    synth(test_log, frames=DEMO_TEST_FRAMES, seed=DEMO_TEST_SEED, scale=DEMO_SCALE, fmt="mcap")
    # Like the paper's Virtual KITTI experiment, the synthetic basis is learned from the
    # true depth; on real logs `pcainterp learn` uses SGBM maps (docs/results.md has both).
    _echo(
        f"3/5 learning a basis from the training drives' true depth, fitting the hybrid prior "
        f"on the last {100 * DEMO_HOLDOUT:.0f} % of each drive -> {basis_path}"
    )
    basis = learn(
        train_logs,
        basis_path,
        LearnOptions(
            n_components=DEMO_COMPONENTS,
            grid_scale=0.25,
            depth_topic="/ground_truth/depth",
            fit_prior=True,
            holdout=DEMO_HOLDOUT,
        ),
        PairingConfig(),
    )
    _echo(f"4/5 densifying the held-out drive -> {dense_log}, {rrd}")
    summary = densify(test_log, dense_log, basis, rrd=rrd, spawn_viewer=spawn_viewer)
    report_dir = out / "report"
    _echo(f"5/5 evaluating the densified drive against ground truth -> {report_dir}/results.md")
    _, table = evaluate(dense_log, report_dir, basis=basis_path, sweep_every=DEMO_SWEEP_EVERY)
    report = json.loads((report_dir / "results.json").read_text())
    means = {name: m["mean"]["delta_2d_mean"] for name, m in report["methods"].items()}
    # "stored": the std densify wrote (the default estimate's calibrated posterior std)
    coverage = report["calibration"].get("stored", {}).get("mean", {}).get("coverage_2sigma")
    elapsed = time.perf_counter() - started
    height, width = basis.image_size
    return "\n".join(
        [
            "",
            f"demo finished in {elapsed:.0f} s; everything is in {out}/",
            f"  basis            {basis.n_components} components from {basis.n_train} depth maps"
            f" ({100 * basis.explained_variance_ratio:.1f} % variance), {width}x{height} px",
            f"  estimate         {_estimate_line(basis)}",
            f"  densified        {summary.frames} frames at {summary.frames_per_second:.1f}"
            f" frames/s, {summary.measurements / max(summary.frames, 1):.0f} points per frame",
            f"  mean Delta_2D ({report['mode']} mode, paper IV-B), same sparse points:",
            f"    PCA-MAP           {means['pca_map']:.3f} px",
            f"    nearest neighbour {means['nearest']:.3f} px  (PCA-MAP / NN ="
            f" {means['pca_map'] / max(means['nearest'], 1e-12):.2f}; paper 0.61-0.63)",
            f"    linear            {means['linear']:.3f} px",
            "  truth inside +-2 sigma (the std densify wrote): "
            + (f"{100 * coverage:.1f} %" if coverage is not None else "n/a"),
            f"  report           {report_dir}/results.md (figures, results.json)",
            f"  view it: rerun {rrd}   (or open {dense_log} in Foxglove)",
            "",
            table,
        ]
    )


def _estimate_line(basis: Basis) -> str:
    """Describe the estimate densify uses by default with this basis."""
    from pcainterp_stream.pipeline.processor import resolve_settings

    settings = resolve_settings(basis, ProcessorConfig())  # what densify does by default
    parts = []
    if settings.local_prior is not None:
        local = settings.local_prior
        parts.append(
            f"hybrid prior ({local.kernel.value} kernel, {local.length_scale:g} px, "
            f"{local.variance:.2g} px^2, fitted by evidence)"
        )
    else:
        parts.append("paper's prior")
    sigma = settings.sigma
    parts.append(f"sigma {sigma:.2f} px" if isinstance(sigma, float) else f"sigma {sigma}")
    config = ProcessorConfig()
    parts.append(f"robust {config.robust}")
    parts.append("temporal prior" if config.temporal else "no temporal prior")
    if config.carry.frames:
        parts.append(f"points carried from the {config.carry.frames} previous frames")
    if settings.scale_by_innovation:
        parts.append(f"std x {settings.std_scale:.3g} x per-frame covariance scale")
    elif settings.std_scale != 1.0:
        parts.append(f"std x {settings.std_scale:.3g}")
    return ", ".join(parts)


DEMO_SCALE = 1.0


DEMO_TRAIN_SEEDS = (1, 3, 4, 5)


DEMO_TRAIN_FRAMES = 200


DEMO_TEST_SEED = 2


DEMO_TEST_FRAMES = 50


DEMO_COMPONENTS = 300


DEMO_HOLDOUT = 0.2


DEMO_SWEEP_EVERY = 10
