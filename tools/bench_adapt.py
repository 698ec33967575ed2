"""What the fit check and the self-supervised basis cost: densify with and without them.

For each log, the frame processor runs three times in this process: ``adapt="off"`` (the
reference), ``"check"`` (the fit check only) and ``"auto"`` (the default: check, and learn
the log's own basis when the built-in one does not fit), each from reading the first pair
to the last frame out, the built-in basis already loaded. Prints a Markdown table of wall
times and their ratios to the reference of the same run::

    python tools/bench_adapt.py LOG.mcap [LOG.mcap ...]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import harness


def run(log: Path, adapt: str) -> tuple[float, str]:
    """Densify every pair of ``log`` with the processor; return (seconds, the prior's line)."""
    from pcainterp_stream.frontend.pairing import PairingConfig, iter_stereo_frames
    from pcainterp_stream.io.logreader import open_log
    from pcainterp_stream.pipeline.processor import FrameProcessor, ProcessorConfig

    started = time.perf_counter()
    with open_log(log) as reader, FrameProcessor(None, ProcessorConfig(adapt=adapt)) as engine:
        frames = 0
        for _ in engine.process(iter_stereo_frames(reader, PairingConfig())):
            frames += 1
        lines = engine.adaptation.lines
    seconds = time.perf_counter() - started
    adapted = next((line for line in lines if line.startswith("adapted")), None)
    return seconds, f"{frames} frames; " + ("adapted" if adapted else "kept")


def main(argv: list[str] | None = None) -> int:
    """Time each log three ways and print the table."""
    parser = harness.argument_parser(__doc__)
    parser.add_argument("logs", type=Path, nargs="+", metavar="LOG")
    args = parser.parse_args(argv)
    from pcainterp_stream.estimate.basis import Basis

    Basis.default()  # loaded once, outside the timings
    print(
        harness.table_header(
            ["log", "off (s)", "check (s)", "auto (s)", "check/off", "auto/off", "auto"]
        )
    )
    for log in args.logs:
        off, _ = run(log, "off")
        check, _ = run(log, "check")
        auto, what = run(log, "auto")
        print(
            harness.table_row(
                [
                    log.name,
                    f"{off:.1f}",
                    f"{check:.1f}",
                    f"{auto:.1f}",
                    f"{check / off:.2f}",
                    f"{auto / off:.2f}",
                    what,
                ]
            )
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
