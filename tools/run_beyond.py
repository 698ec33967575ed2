"""Experiments beyond the paper (docs/options.md): every addition on held-out synthetic and KITTI.

Stages, each cached in ``--work`` (an interrupted run resumes):

1. ``prepare``: synthetic logs (basis training seeds 101-104, a fitting log of seed 150, a
   test log of seed 201) and the two real KITTI clips of ``../shared/realdata`` as MCAP;
   per frame the measurements of the densify front end (GFTT + SGBM lookups, default
   settings), a dense set of strongest-first lookups for the points sweep, the reference
   (ground truth for synthetic, SGBM for KITTI), poses, and every map preprocessed onto the
   basis grid (SGBM and, for synthetic, ground truth).
2. ``bases``: bases on the synthetic camera's grid (310x94): synthetic ground truth,
   real-only, and synthetic+real mixes; their hyperparameters (local kernel, sigma,
   process noise) fitted by the evidence on frames outside each basis.
3. ``evaluate``: plain PCA-MAP, each addition alone, all together, nearest neighbour and
   linear on the held-out splits; mean Delta_2D (the paper's, via
   ``pcainterp_stream.evaluate.metrics``), depth RMSE, +-2 sigma coverage, time per frame; the
   points sweep (50-800); the training-mix table. Writes ``results.json`` and
   ``results.md``.

    python tools/run_beyond.py --work /tmp/beyond            # all stages
    python tools/run_beyond.py --work /tmp/beyond --stages depth-bins irls   # analyses

Splits: synthetic: basis from seeds 101-104 (ground truth), hyperparameters fitted on
seed 150, tested on seed 201 (temporal mode, ground truth). KITTI A: basis from the raw
drive (first 80 % of its frames; the last 20 % fit the hyperparameters), tested on the
odometry clip (stereo mode, SGBM reference); KITTI B the reverse.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import harness
import numpy as np
import numpy.typing as npt
from beyond_data import (
    DRIVE_SEED,
    LogData,
    fit_hyperparameters,
    learn_grid_basis,
    prepare_log,
    prepare_motions,
    render_drives,
)
from beyond_eval import (
    METHODS,
    Trial,
    carry_sweep,
    depth_bins,
    evaluate_split,
    evaluated_frames,
    irls_iterations,
    sweep_split,
)

from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.frontend.pairing import PairingConfig, iter_stereo_frames
from pcainterp_stream.io.logreader import open_log

KITTI = {
    "raw": harness.REALDATA / harness.KITTI_RAW_0001,
    "odometry": harness.REALDATA / harness.KITTI_ODOMETRY_CLIP,
}
TRAIN_SEEDS = (101, 102, 103, 104)
FIT_SEED = 150
TEST_SEED = 201
IRLS_SPLITS = ("synthetic", "kitti_a", "kitti_b_mix")
"""Splits of the reweighting-count check (``--stages irls``)."""
MAIN_MIX = 1000
"""Synthetic SGBM maps added to the real training frames of the ``*_mix`` splits."""
SWEPT = {
    *(METHODS[i].name for i in (0, 7, 8, 9, 11, 14)),
    "nearest neighbour",
    "linear",
}
"""The methods of the points sweep (``--stages sweep``)."""


# ----------------------------------------------------------------------------- report

HYPERPARAMETER_COLUMNS = (
    "basis",
    "maps",
    "kernel, ell, v",
    "sigma (plain sigma) px",
    "evidence gain, nats",
    "q",
    "std scale (with covariance scale)",
)
METHOD_COLUMNS = (
    "method",
    "mean Delta_2D px",
    "/ nearest",
    "depth RMSE m",
    "+-1 / +-2 sigma %",
    "ms/frame",
    "down-weighted/frame",
    "resets",
)
MIX_COLUMNS = (
    "basis",
    "synthetic maps",
    "real maps",
    "plain",
    "hybrid + Cauchy",
    "nearest",
    "hybrid / nearest",
)
SPLIT_TITLES = {
    "synthetic": "synthetic (temporal, ground truth)",
    "kitti_a": "KITTI A: raw drive -> odometry clip (real-only basis)",
    "kitti_b": "KITTI B: odometry clip -> raw drive (real-only basis)",
    "kitti_a_mix": "KITTI A, basis + 1,000 synthetic maps",
    "kitti_b_mix": "KITTI B, basis + 1,000 synthetic maps",
}


def hyperparameter_table(work: Path) -> list[str]:
    """The fitted hyperparameters of every basis in ``work`` (from their ``meta["prior"]``)."""
    lines = [
        '**Fitted hyperparameters** (`meta["prior"]` of each basis)',
        "",
        harness.table_header(HYPERPARAMETER_COLUMNS, "lrllrrl"),
    ]
    for path in sorted(work.glob("basis_*.npz")):
        basis = Basis.load(path)
        prior = basis.meta.get("prior", {})
        local = prior.get("local")
        kernel = (
            f"{local['kernel']}, {local['length_scale']:g} px, {local['variance']:.2g} px^2"
            if local
            else "none"
        )
        gain = prior.get("log_evidence", 0.0) - prior.get("plain_log_evidence", 0.0)
        nan = float("nan")
        sigma = f"{prior.get('sigma', nan):.2f} ({prior.get('plain_sigma', nan):.2f})"
        std_scale = (
            f"{prior.get('std_scale', nan):.2f} ({prior.get('innovation_std_scale', nan):.2f})"
        )
        cells = [path.stem.removeprefix("basis_"), basis.n_train, kernel, sigma, f"{gain:+.0f}"]
        lines.append(harness.table_row([*cells, f"{prior.get('process_noise', nan):g}", std_scale]))
    return [*lines, ""]


def report(results: dict[str, Any], work: Path | None = None) -> str:
    """Return the Markdown tables of a results.json (and of the bases in ``work``)."""
    lines: list[str] = [] if work is None else hyperparameter_table(work)
    for split, methods in results.get("evaluate", {}).items():
        nearest_mean = methods.get("nearest neighbour", {}).get("delta_2d_mean", float("nan"))
        lines += [
            f"**{SPLIT_TITLES.get(split, split)}**",
            "",
            harness.table_header(METHOD_COLUMNS, "l" + "r" * (len(METHOD_COLUMNS) - 1)),
        ]
        for name, m in methods.items():
            coverage = (
                f"{100 * m['coverage_1']:.1f} / {100 * m['coverage_2']:.1f}"
                if m["coverage_2"] == m["coverage_2"]
                else "-"
            )
            delta = [f"{m['delta_2d_mean']:.2f}", f"{m['delta_2d_mean'] / nearest_mean:.2f}"]
            rest = [f"{m['ms_per_frame']:.0f}", f"{m['downweighted_per_frame']:.1f}"]
            cells = [name, *delta, f"{m['depth_rmse']:.2f}", coverage, *rest]
            lines.append(harness.table_row([*cells, f"{m['temporal_resets']:.0f}"]))
        lines.append("")
    for split, rows in results.get("sweep", {}).items():
        names = list(next(iter(rows.values())).keys())
        lines += [
            f"**Points sweep, {SPLIT_TITLES.get(split, split)}** (mean Delta_2D px)",
            "",
            harness.table_header(["points", *names], "r" * (len(names) + 1)),
        ]
        for points, row in rows.items():
            means = [f"{row.get(n, float('nan')):.2f}" for n in names]
            lines.append(harness.table_row([points, *means]))
        lines.append("")
    if results.get("mix"):
        lines += [
            "**Training mix** (KITTI, SGBM maps; mean Delta_2D px on the other clip)",
            "",
            harness.table_header(MIX_COLUMNS, "l" + "r" * (len(MIX_COLUMNS) - 1)),
        ]
        for name, m in results["mix"].items():
            plain = m[METHODS[0].name]["delta_2d_mean"]
            hybrid = m[METHODS[8].name]["delta_2d_mean"]
            nearest_mean = m["nearest neighbour"]["delta_2d_mean"]
            means = [f"{plain:.2f}", f"{hybrid:.2f}", f"{nearest_mean:.2f}"]
            cells = [name, m["synthetic_maps"], m["real_maps"], *means]
            lines.append(harness.table_row([*cells, f"{hybrid / nearest_mean:.2f}"]))
        lines.append("")
    if results.get("carry"):
        splits = list(results["carry"])
        lines += [
            "**Carried points on the fitting frames** (hybrid + Cauchy; mean Delta_2D px, "
            "+-2 sigma %, carried points/frame)",
            "",
            harness.table_header(
                ["frames / gap px / age std px", *splits], "l" + "r" * len(splits)
            ),
        ]
        for key in results["carry"][splits[0]]:
            cells = [
                "{:.3f} ({:.1f} %, {:.0f})".format(
                    results["carry"][split][key][0],
                    100 * results["carry"][split][key][1],
                    results["carry"][split][key][2],
                )
                for split in splits
            ]
            lines.append(harness.table_row([key, *cells]))
        lines.append("")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    """Run the experiments; return the exit code."""
    parser = harness.argument_parser(__doc__)
    harness.add_work_dir(parser, flag="--work", description="cache and output folder")
    parser.add_argument("--train-frames", type=int, default=300, help="per training seed")
    parser.add_argument(
        "--drives",
        type=int,
        default=400,
        help="synthetic drives rendered for the synthetic basis (0: seeds 101-104 only)",
    )
    parser.add_argument("--drive-frames", type=int, default=300, help="frames per drive")
    parser.add_argument("--drive-step", type=int, default=6, help="every N-th frame kept")
    parser.add_argument("--fit-frames", type=int, default=60)
    parser.add_argument("--test-frames", type=int, default=101)
    parser.add_argument("--components", type=int, default=500)
    parser.add_argument("--max-test-frames", type=int, default=None)
    parser.add_argument("--sweep-frames", type=int, default=20)
    parser.add_argument(
        "--stages", nargs="+", default=["prepare", "bases", "evaluate", "sweep", "mix"]
    )
    parser.add_argument("--methods", nargs="*", default=None, help="names of METHODS to run")
    parser.add_argument(
        "--results",
        nargs="+",
        default=["results.json"],
        help="results file(s) in WORK: a run writes the first; the report merges them all "
        "(runs of different --splits side by side)",
    )
    parser.add_argument(
        "--splits",
        nargs="+",
        default=None,
        help="only these splits: synthetic, kitti_a, kitti_a_mix, kitti_b, kitti_b_mix "
        "(default: all)",
    )
    args = parser.parse_args(argv)
    work: Path = args.work
    if args.stages == ["report"]:
        merged: dict[str, Any] = {}
        for name in args.results:  # runs of different splits, merged by split
            for key, value in harness.read_json(work / name).items():
                if isinstance(value, dict):
                    merged.setdefault(key, {}).update(value)
                else:
                    merged[key] = value
        print(report(merged, work))
        return 0
    harness.work_dir(work)
    results_path = work / args.results[0]
    results: dict[str, Any] = harness.read_json(results_path, {})

    def save() -> None:
        harness.write_json(results_path, results)

    # synthetic logs
    logs = {f"train_{s}": (s, args.train_frames) for s in TRAIN_SEEDS}
    logs[f"fit_{FIT_SEED}"] = (FIT_SEED, args.fit_frames)
    logs[f"test_{TEST_SEED}"] = (TEST_SEED, args.test_frames)
    for name, (seed, frames) in logs.items():
        build = harness.build_synth(frames=frames, seed=seed)
        harness.cached(work / f"{name}.mcap", build, f"synth {name}", echo=harness.log)
    real = {
        name: harness.cached(work / f"kitti_{name}.mcap", harness.build_kitti(folder))
        for name, folder in KITTI.items()
        if folder.is_dir()
    }
    with open_log(work / f"test_{TEST_SEED}.mcap") as reader:
        first = next(iter_stereo_frames(reader, PairingConfig()))
    basis_camera = (first.camera.image_size, first.camera.focal_baseline)

    data: dict[str, LogData] = {}
    for name in logs:
        harness.log(f"prepare {name}")
        data[name] = prepare_log(
            work / f"{name}.mcap", work / f"cache_{name}", basis_camera, truth=True
        )
        if name.startswith("test"):
            data[name] = prepare_motions(work / f"{name}.mcap", work / f"cache_{name}", data[name])
    for name, path in real.items():
        harness.log(f"prepare kitti {name}")
        data[f"kitti_{name}"] = prepare_motions(
            path,
            work / f"cache_kitti_{name}",
            prepare_log(path, work / f"cache_kitti_{name}", basis_camera, truth=False),
        )
    if "prepare" in args.stages and len(args.stages) == 1:
        return 0

    # bases and their hyperparameters
    def basis_for(
        name: str,
        maps: npt.NDArray[np.float32],
        source: str,
        fit_logs: Sequence[tuple[LogData, slice]],
    ) -> tuple[Basis, dict[str, Any]]:
        path = work / f"basis_{name}.npz"
        if not path.is_file():
            harness.log(f"learn {name}")
            basis = learn_grid_basis(maps, basis_camera, args.components, source)
            harness.log(f"fit hyperparameters {name}")
            prior = fit_hyperparameters(basis, fit_logs)
            basis = dataclasses.replace(basis, meta={**basis.meta, "prior": prior})
            basis.save(path)
        basis = Basis.load(path)
        shown = {k: v for k, v in basis.meta["prior"].items() if k not in ("table", "candidates")}
        harness.log(f"{name}: prior {json.dumps(shown)}")
        return basis, basis.meta["prior"]

    synth_sgbm = np.concatenate([data[f"train_{s}"].grid_sgbm for s in TRAIN_SEEDS])
    splits: list[tuple[str, str, str, Basis, dict[str, Any]]] = []

    def wanted(split: str) -> bool:
        return args.splits is None or split in args.splits

    if not wanted("synthetic"):
        pass
    elif args.drives:
        harness.log(f"render {args.drives} drives")
        synth_truth = render_drives(work, args.drives, args.drive_frames, args.drive_step)
        basis_name = f"synthetic_drives{args.drives}"
        source = (
            f"synthetic ground truth, {args.drives} drives (seeds {DRIVE_SEED}-"
            f"{DRIVE_SEED + args.drives - 1}), every {args.drive_step}th of "
            f"{args.drive_frames} frames"
        )
    else:
        synth_truth = np.concatenate([data[f"train_{s}"].grid_truth for s in TRAIN_SEEDS])
        basis_name, source = "synthetic", "synthetic ground truth, seeds 101-104"
    if wanted("synthetic"):
        basis, hyper = basis_for(
            basis_name, synth_truth, source, [(data[f"fit_{FIT_SEED}"], slice(None))]
        )
        splits.append(("synthetic", f"test_{TEST_SEED}", "temporal", basis, hyper))
    if len(real) == 2:
        for split, train, test in (("kitti_a", "raw", "odometry"), ("kitti_b", "odometry", "raw")):
            train_data = data[f"kitti_{train}"]
            cut = round(0.8 * train_data.frames)
            basis, hyper = basis_for(
                f"{split}_real",
                train_data.grid_sgbm[:cut],
                f"SGBM, KITTI {train} frames 0-{cut - 1}",
                [(train_data, slice(cut, None))],
            )
            splits.append((split, f"kitti_{test}", "stereo", basis, hyper))
            # the same real frames with 1,000 synthetic SGBM maps (see the mix stage)
            step = max(1, synth_sgbm.shape[0] // MAIN_MIX)
            synthetic_part = synth_sgbm[::step][:MAIN_MIX]
            basis, hyper = basis_for(
                f"{split}_mix{MAIN_MIX}",
                np.concatenate([synthetic_part, train_data.grid_sgbm[:cut]]),
                f"SGBM: {synthetic_part.shape[0]} synthetic + {cut} KITTI {train}",
                [(train_data, slice(cut, None))],
            )
            splits.append((f"{split}_mix", f"kitti_{test}", "stereo", basis, hyper))

    splits = [split for split in splits if wanted(split[0])]
    methods = [m for m in METHODS if args.methods is None or m.name in args.methods]
    if "evaluate" in args.stages:
        for split, test, mode, basis, hyper in splits:
            harness.log(f"evaluate {split} on {test} ({mode})")
            results.setdefault("evaluate", {}).setdefault(split, {}).update(
                evaluate_split(Trial(basis, hyper, data[test], mode), methods, args.max_test_frames)
            )
            save()
    if "sweep" in args.stages:
        for split, test, mode, basis, hyper in splits:
            harness.log(f"sweep {split}")
            sweep = results.setdefault("sweep", {}).setdefault(split, {})
            swept = sweep_split(
                Trial(basis, hyper, data[test], mode),
                [m for m in methods if m.name in SWEPT],
                args.sweep_frames,
            )
            for points, row in swept.items():
                sweep.setdefault(points, {}).update(row)
            save()
    synthetic = [split for split in splits if split[0] == "synthetic"]
    if "depth-bins" in args.stages and synthetic:
        harness.log("depth bins (synthetic)")
        results["depth_bins"] = depth_bins(synthetic[0][3], data[synthetic[0][1]])
        save()
    if "carry" in args.stages:
        harness.log("carried points on the fitting frames")
        fits = []
        for split, _, mode, basis, hyper in splits:
            if split == "synthetic":
                fit_name = f"fit_{FIT_SEED}"
                data[fit_name] = prepare_motions(
                    work / f"{fit_name}.mcap", work / f"cache_{fit_name}", data[fit_name]
                )
                fit_data = data[fit_name]
                frames = evaluated_frames(fit_data, mode, None)
            else:
                # the held-out 20 % of the training clip the hyperparameters were fitted on
                fit_data = data["kitti_raw" if split.startswith("kitti_a") else "kitti_odometry"]
                frames = list(range(round(0.8 * fit_data.frames), fit_data.frames))
            fits.append((split, basis, hyper, fit_data, mode, frames))
        results["carry"] = carry_sweep(fits)
        save()
    if "irls" in args.stages:
        harness.log("IRLS reweightings")
        results["irls"] = irls_iterations(
            [splits[i] for i in range(len(splits)) if splits[i][0] in IRLS_SPLITS], data
        )
        save()
    if "mix" in args.stages and len(real) == 2 and (wanted("kitti_a") or wanted("kitti_b")):
        mix_methods = [METHODS[0], METHODS[8], METHODS[10]]
        for split, train, test in (("kitti_a", "raw", "odometry"), ("kitti_b", "odometry", "raw")):
            train_data = data[f"kitti_{train}"]
            cut = round(0.8 * train_data.frames)
            real_maps = train_data.grid_sgbm[:cut]
            for share in (0, 250, 1000):
                name = f"{split}_mix{share}"
                step = max(1, synth_sgbm.shape[0] // max(share, 1))
                synthetic_part = synth_sgbm[::step][:share]
                basis, hyper = basis_for(
                    name,
                    np.concatenate([synthetic_part, real_maps]),
                    f"SGBM: {synthetic_part.shape[0]} synthetic + {cut} KITTI {train}",
                    [(train_data, slice(cut, None))],
                )
                harness.log(f"mix {name}")
                results.setdefault("mix", {})[name] = {
                    "synthetic_maps": int(synthetic_part.shape[0]),
                    "real_maps": int(real_maps.shape[0]),
                    **evaluate_split(
                        Trial(basis, hyper, data[f"kitti_{test}"], "stereo"),
                        mix_methods,
                        args.max_test_frames,
                    ),
                }
                save()
            # synthetic only
            name = f"{split}_synthonly"
            basis, hyper = basis_for(
                name,
                synth_sgbm,
                "SGBM: synthetic only",
                [(train_data, slice(cut, None))],
            )
            results.setdefault("mix", {})[name] = {
                "synthetic_maps": int(synth_sgbm.shape[0]),
                "real_maps": 0,
                **evaluate_split(
                    Trial(basis, hyper, data[f"kitti_{test}"], "stereo"),
                    mix_methods,
                    args.max_test_frames,
                ),
            }
            save()
    return 0


if __name__ == "__main__":
    sys.exit(main())
