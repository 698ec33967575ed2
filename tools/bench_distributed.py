"""Benchmark scale-out on Dask: learn and densify throughput with 1 and 2 worker processes.

For each worker count a fresh ``LocalCluster`` (worker processes, one thread each) runs
``distributed.learn_distributed`` over all logs, and another fresh one runs
``distributed.densify_many``; the peak RSS of every worker process is read from
``/proc/self/status`` (VmHWM) inside the worker after the job. The local learner
(``jobs.learn``, this process) is timed once for reference, and one merge of two summaries.
From the measured per-frame costs the tool projects a 23,201-frame basis and 1,000 hours of
10 Hz logs on N workers (one core per worker assumed). Prints a Markdown report.

    python tools/bench_distributed.py --work-dir /tmp/pcd --logs 4 --frames 40
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import harness
import numpy as np
from scipy.linalg import subspace_angles

from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.pipeline import distributed, jobs

JOB_COLUMNS = (
    "job",
    "workers",
    "frames",
    "wall s",
    "frames/s",
    "worker peak RSS MB",
    "vs local learner",
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


def main() -> None:
    """Run the benchmark and print a Markdown report."""
    parser = harness.argument_parser(__doc__)
    harness.add_work_dir(parser, Path("/tmp/pcd"))
    parser.add_argument("--logs", type=int, default=4)
    parser.add_argument("--frames", type=int, default=40, help="frames per log")
    parser.add_argument("--scale", type=float, default=1.0, help="synthetic image scale")
    parser.add_argument("--components", type=int, default=200)
    parser.add_argument("--chunk-frames", type=int, default=distributed.DEFAULT_CHUNK_FRAMES)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    harness.work_dir(args.work_dir)
    logs = _make_logs(args.work_dir, args.logs, args.frames, args.scale)
    n_frames = args.logs * args.frames
    options = jobs.LearnOptions(n_components=args.components)
    pairing = PairingConfig()
    rows: list[dict[str, Any]] = []

    with harness.Stopwatch() as watch:
        local = jobs.learn(logs, args.work_dir / "basis_local.npz", options, pairing)
    local_seconds = watch.wall
    basis_path = args.work_dir / "basis_local.npz"

    for workers in args.workers:
        with distributed.connect(workers=workers) as client:
            with harness.Stopwatch() as watch:
                remote = distributed.learn_distributed(
                    logs,
                    args.work_dir / f"basis_{workers}w.npz",
                    options,
                    pairing,
                    client,
                    chunk_frames=args.chunk_frames,
                )
            peaks = _worker_peaks(client)
        top = min(10, local.n_components, remote.n_components)
        angle = float(
            np.degrees(
                subspace_angles(
                    local.components[:top].reshape(top, -1).T.astype(np.float64),
                    remote.components[:top].reshape(top, -1).T.astype(np.float64),
                ).max()
            )
        )
        rel = float(np.max(np.abs(remote.eigenvalues[:top] / local.eigenvalues[:top] - 1)))
        rows.append(
            {
                "job": "learn",
                "workers": workers,
                "seconds": watch.wall,
                "frames": n_frames,
                "peaks": peaks,
                "angle10": angle,
                "eig_rel10": rel,
            }
        )
        with distributed.connect(workers=workers) as client:
            with harness.Stopwatch() as watch:
                outcomes = distributed.densify_many(
                    logs, args.work_dir / f"dense_{workers}w", basis_path, client, pairing=pairing
                )
            peaks = _worker_peaks(client)
        failed = [o.error for o in outcomes if o.error is not None]
        if failed:
            raise SystemExit(f"densify failed: {failed}")
        rows.append(
            {
                "job": "densify",
                "workers": workers,
                "seconds": watch.wall,
                "frames": sum(o.frames for o in outcomes),
                "peaks": peaks,
            }
        )

    # one full-size merge: two summaries of r = l + oversampling columns on the grid
    s = int(np.prod(local.mean.shape))
    keep = args.components + distributed.DEFAULT_OVERSAMPLING
    rng = np.random.default_rng(0)
    kwargs: dict[str, Any] = {
        "grid_size": local.mean.shape,
        "image_size": local.image_size,
        "focal_baseline": 1.0,
    }
    a = distributed.summarize(rng.normal(size=(keep, s)).astype(np.float32), keep, **kwargs)
    b = distributed.summarize(rng.normal(size=(keep, s)).astype(np.float32), keep, **kwargs)
    with harness.Stopwatch() as watch:
        distributed.merge(a, b, keep)
    merge_seconds = watch.wall

    print(f"logs: {args.logs} x {args.frames} frames, scale {args.scale}, image {local.image_size}")
    print(f"grid {local.mean.shape} (s = {s}), l = {args.components}, r = {keep}")
    print(
        f"local jobs.learn (this process): {local_seconds:.1f} s, "
        f"{n_frames / local_seconds:.2f} frames/s"
    )
    print(f"one merge of two (s x {keep}) summaries: {merge_seconds * 1000:.0f} ms\n")
    print(harness.table_header(JOB_COLUMNS))
    for row in rows:
        check = (
            f"max angle top 10 {row['angle10']:.3f} deg, eig rel {row['eig_rel10']:.1e}"
            if row["job"] == "learn"
            else ""
        )
        rate = f"{row['frames'] / row['seconds']:.2f}"
        worker_peaks = ", ".join(f"{p:.0f}" for p in row["peaks"])
        seconds = f"{row['seconds']:.1f}"
        cells = [row["job"], row["workers"], row["frames"], seconds, rate, worker_peaks, check]
        print(harness.table_row(cells))
    print()
    one = {row["job"]: row for row in rows if row["workers"] == 1}
    if "learn" in one and "densify" in one:
        learn_frame = one["learn"]["seconds"] / one["learn"]["frames"]
        densify_frame = one["densify"]["seconds"] / one["densify"]["frames"]
        chunks = -(-23201 // args.chunk_frames)
        hours_frames = 1000 * 3600 * 10
        print(
            f"per frame on 1 worker: learn {learn_frame * 1000:.0f} ms, "
            f"densify {densify_frame * 1000:.0f} ms"
        )
        columns = ["workers N", "23,201-frame basis (h)", "1,000 h of 10 Hz logs (days)"]
        print("\n" + harness.table_header(columns))
        for n in (1, 2, 8, 32, 128):
            learn_h = (23201 * learn_frame + (chunks - 1) * merge_seconds) / n / 3600
            densify_d = hours_frames * densify_frame / n / 86400
            print(harness.table_row([n, f"{learn_h:.2f}", f"{densify_d:.1f}"]))
        # memory of a merge task at l = 500 on this grid, from the array sizes it holds: two
        # input factors (s x r float32), the stacked (s x 2r+1) float32 and its float64
        # copy inside truncated_product, and the output factor
        r500 = 500 + distributed.DEFAULT_OVERSAMPLING
        merge_mb = s * (2 * r500 * 4 + (2 * r500 + 1) * 12 + r500 * 4) / 1e6
        chunk_mb = args.chunk_frames * s * 4 * 2 / 1e6
        print(
            f"\nmerge task arrays at l = 500 (r = {r500}) on this grid: {merge_mb:.0f} MB; "
            f"chunk task grid maps ({args.chunk_frames} frames): {chunk_mb:.0f} MB"
        )
    print("\nraw:", json.dumps(rows))


if __name__ == "__main__":
    main()
