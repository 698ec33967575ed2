"""Benchmark scale-out on Dask: ``learn`` on a cluster against ``learn`` in one process.

Runs the same ``learn`` (the command line's defaults: the prior fitted on the held-out 20 %
of each log, ``--with-synthetic auto``) once in this process and once per worker count on
a fresh ``LocalCluster`` (worker processes, one thread each), and says how far the models
are apart (top-10 principal angle, eigenvalues, the fitted prior). Cluster start-up is
timed apart from the job. Optionally (``--densify``) ``densify --out-dir`` throughput too.
The peak RSS of every worker process is read from ``/proc/self/status`` (VmHWM) inside the
worker after the job. Prints a Markdown report.

    python tools/bench_distributed.py --work-dir /tmp/pcd --logs 4 --frames 500 --scale 1
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import harness
import numpy as np
from scipy.linalg import subspace_angles

from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.pipeline import distributed, jobs

JOB_COLUMNS = (
    "job",
    "where",
    "frames",
    "cluster start s",
    "job wall s",
    "frames/s",
    "one process's time / (start + job)",
    "worker peak RSS MB",
    "model against one process",
)


def _worker_peaks(client: Any) -> list[float]:
    peaks = client.run(harness.peak_rss_mb)
    return sorted(float(value) for value in peaks.values())


def _make_logs(work: Path, count: int, frames: int, scale: float) -> list[Path]:
    return [
        harness.cached(
            work / f"drive{index}_{frames}f_s{scale}.mcap",
            harness.build_synth(frames=frames, seed=100 + index, scale=scale),
        )
        for index in range(count)
    ]


def _difference(here: Basis, there: Basis) -> str:
    """Say how far two bases are apart: shape, maps, top-10 angle, eigenvalues, prior."""
    if there.components.shape != here.components.shape or there.n_train != here.n_train:
        return f"DIFFERENT: {there.components.shape} vs {here.components.shape}"
    top = min(10, here.n_components)
    angle = subspace_angles(
        here.components[:top].reshape(top, -1).T.astype(np.float64),
        there.components[:top].reshape(top, -1).T.astype(np.float64),
    ).max()
    ratio = np.abs(there.eigenvalues / here.eigenvalues - 1)
    text = (
        f"angle top {top} {angle:.1e} rad, eigenvalues top {top} {ratio[:top].max():.1e} "
        f"rel, all {here.n_components} {ratio.max():.1e} rel"
    )
    prior_here, prior_there = here.meta.get("prior"), there.meta.get("prior")
    if prior_here and prior_there:
        local_here, local_there = prior_here["local"] or {}, prior_there["local"] or {}
        same_kernel = local_here.get("kernel") == local_there.get("kernel") and local_here.get(
            "length_scale"
        ) == local_there.get("length_scale")
        sigma = abs(prior_there["sigma"] / prior_here["sigma"] - 1)
        text += f", kernel {'same' if same_kernel else 'DIFFERENT'}, sigma {sigma:.1e} rel"
    return text


def main() -> None:
    """Run the benchmark and print a Markdown report."""
    parser = harness.argument_parser(__doc__)
    harness.add_work_dir(parser, Path("/tmp/pcd"))
    parser.add_argument("--logs", type=int, default=4)
    parser.add_argument("--frames", type=int, default=40, help="frames per log")
    parser.add_argument("--scale", type=float, default=1.0, help="synthetic image scale")
    parser.add_argument("--components", type=int, default=200)
    parser.add_argument("--chunk-frames", type=int, default=distributed.DEFAULT_CHUNK_FRAMES)
    parser.add_argument("--workers", type=int, nargs="+", default=[2])
    parser.add_argument("--densify", action="store_true", help="also time densify --out-dir")
    args = parser.parse_args()
    harness.work_dir(args.work_dir)
    logs = _make_logs(args.work_dir, args.logs, args.frames, args.scale)
    n_frames = args.logs * args.frames
    # the command line's defaults: prior fitted on the held-out share, --with-synthetic auto
    options = jobs.LearnOptions(n_components=args.components, with_synthetic="auto")
    pairing = PairingConfig()
    rows: list[dict[str, Any]] = []

    with harness.Stopwatch() as watch:
        here = jobs.learn(logs, args.work_dir / "basis_here.npz", options, pairing)
    local_seconds = watch.wall
    rows.append(
        {
            "job": "learn",
            "where": "one process",
            "frames": n_frames,
            "start": 0.0,
            "seconds": local_seconds,
            "peaks": [harness.peak_rss_mb()],
            "model": "reference",
        }
    )
    for workers in args.workers:
        with harness.Stopwatch() as start:
            connection = distributed.connect(workers=workers)
            client = connection.__enter__()
        try:
            with harness.Stopwatch() as watch:
                there = distributed.learn_distributed(
                    logs,
                    args.work_dir / f"basis_{workers}w.npz",
                    options,
                    pairing,
                    client,
                    chunk_frames=args.chunk_frames,
                )
            peaks = _worker_peaks(client)
            rows.append(
                {
                    "job": "learn",
                    "where": f"{workers} workers",
                    "frames": n_frames,
                    "start": start.wall,
                    "seconds": watch.wall,
                    "peaks": peaks,
                    "model": _difference(here, there),
                }
            )
            if args.densify:
                with harness.Stopwatch() as watch:
                    outcomes = distributed.densify_many(
                        logs, args.work_dir / f"dense_{workers}w", None, client
                    )
                failed = [o.error for o in outcomes if o.error is not None]
                if failed:
                    raise SystemExit(f"densify failed: {failed}")
                rows.append(
                    {
                        "job": "densify --out-dir",
                        "where": f"{workers} workers",
                        "frames": sum(o.frames for o in outcomes),
                        "start": 0.0,
                        "seconds": watch.wall,
                        "peaks": _worker_peaks(client),
                        "model": "",
                    }
                )
        finally:
            connection.__exit__(None, None, None)

    print(
        f"logs: {args.logs} x {args.frames} frames, scale {args.scale}, image {here.image_size}, "
        f"grid {here.grid_size}, l = {args.components}, chunks of {args.chunk_frames} maps; "
        f"basis: {here.n_train} maps ({here.meta['learning']['method']}), "
        f"{here.meta['source']['with_synthetic_rule']}"
    )
    print(harness.table_header(JOB_COLUMNS))
    for row in rows:
        # start-up included: the cluster's against the one process's (which has none apart)
        ratio = local_seconds / (row["start"] + row["seconds"]) if row["job"] == "learn" else None
        cells = [
            row["job"],
            row["where"],
            row["frames"],
            f"{row['start']:.1f}" if row["start"] else "-",
            f"{row['seconds']:.1f}",
            f"{row['frames'] / row['seconds']:.2f}",
            "-" if ratio is None else f"{ratio:.2f}x",
            ", ".join(f"{p:.0f}" for p in row["peaks"]),
            row["model"],
        ]
        print(harness.table_row(cells))
    print("\nraw:", json.dumps(rows))


if __name__ == "__main__":
    main()
