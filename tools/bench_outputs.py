"""Output-side CPU of ``densify``: each piece from the finished estimate to bytes on disk.

Densifies a log with the defaults (in this process, keeping every ``--every``-th frame's
result), then times each piece of what the job does with a frame after its estimate, on one
thread (``time.thread_time``: user + system CPU of the calling thread, so a file write's
kernel time counts):

- ``encoders``: the whole ``io/outputs.output_messages`` (what the encoder pool runs per
  frame) and its parts: quantising depth and std, the "Up"-filtered PNGs deflated by each
  candidate (ISA-L, zlib-ng; bytes per frame too), the ``depth_mm`` viewer copy;
- ``writer``: what the MCAP writer thread does per frame: serialising the output messages,
  and writing (mcap + zstd at the writer's level + CRC + the file write) the input copy
  alone and the outputs alone; and zstd alone on the input's message bytes (what a copy of
  the input's compressed chunks would save of the input copy's cost).

Each figure is the best of ``--repeat`` runs per frame, then the median over frames; the
machine may be loaded, so read them as relative. Before them, the CPU (user and system) of
each thread of the densify run itself, per frame, sampled from ``/proc/self/task`` (Linux;
threads grouped by their Python name: the encoder pool, the writer, the stereo workers...).

Example::

    python tools/bench_outputs.py kitti_odometry.mcap --work-dir /tmp/bench_outputs --every 4
"""

from __future__ import annotations

import re
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import harness
import numpy as np
import zstandard
from isal import isal_zlib
from zlib_ng import zlib_ng

from pcainterp_stream.io import depth_codec, logwriter, outputs, rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.pipeline.densify import densify
from pcainterp_stream.records import DensifiedFrame, RawMessage

DEFLATERS: dict[str, Callable[[bytes | memoryview], bytes]] = {
    "ISA-L 0": lambda data: isal_zlib.compress(data, 0),
    "ISA-L 1 (default)": lambda data: isal_zlib.compress(data, 1),
    "ISA-L 2": lambda data: isal_zlib.compress(data, 2),
    "zlib-ng 1": lambda data: zlib_ng.compress(data, 1),
    "zlib-ng 2 (before)": lambda data: zlib_ng.compress(data, 2),
    "zlib-ng 3": lambda data: zlib_ng.compress(data, 3),
}


def best_ms(repeat: int, run: Callable[..., Any], *args: Any, **kwargs: Any) -> tuple[float, Any]:
    """Return the least thread CPU (ms) of ``repeat`` calls of ``run`` and the last result."""
    best = float("inf")
    result: Any = None
    for _ in range(repeat):
        started = time.thread_time()
        result = run(*args, **kwargs)
        best = min(best, time.thread_time() - started)
    return 1000.0 * best, result


def serialise_all(messages: list[Any]) -> list[bytes]:
    """Return the CDR bytes of typestore messages."""
    return [rosmsg.serialize(message) for message in messages]


def compress_all(compressor: zstandard.ZstdCompressor, items: list[bytes]) -> list[bytes]:
    """Return each item compressed."""
    return [compressor.compress(item) for item in items]


def up_filtered(code: np.ndarray) -> bytes:
    """Return the PNG scanlines of a uint16 image, every row filtered "Up" (as ``png16``)."""
    height, width = code.shape
    rows = np.ascontiguousarray(code, dtype=">u2").view(np.uint8).reshape(height, 2 * width)
    filtered = np.empty((height, 2 * width + 1), dtype=np.uint8)
    filtered[:, 0] = 2
    filtered[0, 1:] = rows[0]
    np.subtract(rows[1:], rows[:-1], out=filtered[1:, 1:])
    return filtered.tobytes()


def codes(result: DensifiedFrame) -> dict[str, np.ndarray]:
    """Return the 16-bit codes of a frame's compact depth and disparity std."""
    camera = result.frame.camera
    nearest = outputs._finite_extreme(result.depth, np.min)
    quant_a = depth_codec.inverse_depth_scale(
        camera.focal_baseline,
        outputs.depth_step(result.disparity_std),
        float(camera.focal_baseline / nearest) if nearest is not None else 1.0,
    )
    std_a = outputs.std_scale(result.disparity_std)
    return {
        "depth": depth_codec.quantise_inverse_depth(result.depth, quant_a),
        "disparity_std": depth_codec.quantise_inverse_depth(result.disparity_std, std_a),
    }


def encoders(results: list[DensifiedFrame], repeat: int) -> str:
    """Return the table of the encoder pool's pieces per frame."""
    topics = outputs.OutputTopics().compact()
    cpu: dict[str, list[float]] = defaultdict(list)
    size: dict[str, list[int]] = defaultdict(list)
    for result in results:
        cpu["output_messages (whole)"].append(
            best_ms(repeat, outputs.output_messages, result, topics)[0]
        )
        for channel, code in codes(result).items():
            image = result.depth if channel == "depth" else result.disparity_std
            cpu[f"quantise {channel}"].append(
                best_ms(repeat, depth_codec.quantise_inverse_depth, image, 100.0)[0]
            )
            filtered = up_filtered(code)
            for name, deflate in DEFLATERS.items():
                ms, packed = best_ms(repeat, deflate, filtered)
                cpu[f"deflate {channel}: {name}"].append(ms)
                size[f"deflate {channel}: {name}"].append(len(packed))
        cpu["depth_mm viewer copy"].append(
            best_ms(
                repeat,
                outputs.display_millimetres,
                result.depth,
                step_mm=outputs.DISPLAY_DEPTH_STEP_MM,
            )[0]
        )
    lines = [harness.table_header(["piece", "CPU ms/frame", "KB/frame"])]
    for name, values in cpu.items():
        kb = f"{np.mean(size[name]) / 1e3:.0f}" if name in size else ""
        lines.append(harness.table_row([name, f"{np.median(values):.2f}", kb]))
    return "\n".join(lines)


def write_ms(
    work: Path, raws: list[RawMessage], built: list[list[tuple[str, Any, int]]], frames: int
) -> tuple[float, float]:
    """Return (thread CPU ms, MB) per frame of one MCAP writer run (not threaded)."""
    path = work / "bench_outputs_write.mcap"
    started = time.thread_time()
    with logwriter.McapLogWriter(path) as writer:
        for raw in raws:
            writer.add_raw(raw)
        for messages in built:
            for topic, message, log_time in messages:
                writer.add_message(topic, message, log_time)
    cpu = 1000.0 * (time.thread_time() - started) / frames
    megabytes = path.stat().st_size / 1e6 / frames
    path.unlink()
    return cpu, megabytes


def writer(log: Path, work: Path, results: list[DensifiedFrame], total: int, repeat: int) -> str:
    """Return the table of the writer thread's pieces per frame.

    The input copy is timed over the whole log (``total`` frames), the outputs over the
    kept frames.
    """
    topics = outputs.OutputTopics().compact()
    with open_log(log) as reader:
        raws = list(reader.messages())
    built = [
        [
            (topic, message, r.frame.log_time_ns)
            for topic, message in outputs.output_messages(r, topics)
        ]
        for r in results
    ]
    frames = len(results)
    serialize = [
        best_ms(repeat, serialise_all, [message for _, message, _ in messages])[0]
        for messages in built
    ]
    compressor = zstandard.ZstdCompressor(level=logwriter.MCAP_ZSTD_LEVEL)
    zstd_input = best_ms(repeat, compress_all, compressor, [raw.data for raw in raws])[0]
    copy = [write_ms(work, raws, [], total) for _ in range(repeat)]
    out = [write_ms(work, [], built, frames) for _ in range(repeat)]
    lines = [harness.table_header(["piece", "CPU ms/frame", "MB/frame"])]
    lines.append(
        harness.table_row(["serialise the output messages", f"{np.median(serialize):.2f}", ""])
    )
    lines.append(
        harness.table_row(
            [
                f"write the input copy (mcap, zstd {logwriter.MCAP_ZSTD_LEVEL}, CRC, file)",
                f"{min(c for c, _ in copy):.2f}",
                f"{copy[0][1]:.3f}",
            ]
        )
    )
    lines.append(
        harness.table_row(
            ["  of which zstd of the input's messages", f"{zstd_input / total:.2f}", ""]
        )
    )
    lines.append(
        harness.table_row(
            [
                "write the outputs (serialise, mcap, zstd, CRC, file)",
                f"{min(c for c, _ in out):.2f}",
                f"{out[0][1]:.3f}",
            ]
        )
    )
    return "\n".join(lines)


class ThreadCpu(harness.ThreadCpu):
    """Each thread's CPU while the densify run runs, reported per frame by thread group."""

    def table(self, frames: int) -> str:
        """Return a Markdown table of user and system CPU ms per frame, by thread group."""
        groups: dict[str, list[float]] = defaultdict(lambda: [0.0, 0.0])
        for tid, (user, system) in self.seconds.items():
            if self.own_thread(tid):
                continue
            name = re.sub(r"[-_]?\d+$", "", self.names.get(tid, "unnamed (native)"))
            groups[name][0] += user
            groups[name][1] += system
        lines = [harness.table_header(["thread(s)", "user ms/frame", "system ms/frame"])]
        for name, (user, system) in sorted(groups.items(), key=lambda item: -sum(item[1])):
            cells = [name, f"{1000 * user / frames:.1f}", f"{1000 * system / frames:.1f}"]
            lines.append(harness.table_row(cells))
        return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; print Markdown tables."""
    parser = harness.argument_parser(__doc__)
    parser.add_argument("log", type=Path, help="the input log (e.g. a KITTI clip's MCAP)")
    harness.add_work_dir(parser, description="folder of the densified output (overwritten)")
    parser.add_argument("--every", type=int, default=4, help="keep every N-th frame's result")
    parser.add_argument("--repeat", type=int, default=3, help="runs per piece (best is kept)")
    args = parser.parse_args(argv)
    work = harness.work_dir(args.work_dir)
    results: list[DensifiedFrame] = []
    count = [0]

    def keep(result: DensifiedFrame) -> None:
        if count[0] % args.every == 0:
            results.append(result)
        count[0] += 1

    with tempfile.TemporaryDirectory(dir=work) as scratch, ThreadCpu() as threads:
        densify(args.log, Path(scratch) / "densified.mcap", on_frame=keep)
    print(f"{args.log}: {len(results)} of {count[0]} frames (every {args.every}-th)\n")
    print("The densify run's threads (per frame):\n")
    print(threads.table(count[0]))
    print()
    print("Encoder pool (per frame):\n")
    print(encoders(results, args.repeat))
    print("\nWriter thread (per frame):\n")
    print(writer(args.log, work, results, count[0], args.repeat))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
