"""What the fit check and the self-supervised basis cost: densify with and without them.

For each log, the frame processor runs four times in this process: ``adapt="off"`` (the
reference), ``"check"`` (the fit check only: the street basis, and the indoor one when the
street one does not fit), ``"auto"`` (the default: the check, and the log's own basis
learned when neither built-in basis fits well) and ``"auto"`` with ``builtin="street"``
(the street basis or the log's own: the default before the indoor basis), each from
reading the first pair to the last frame out, the built-in bases already loaded. Prints a
Markdown table of wall times and their ratios to the reference of the same run::

    python tools/bench_adapt.py LOG.mcap [LOG.mcap ...]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import harness


def run(log: Path, adapt: str, builtin: str = "auto") -> tuple[float, str]:
    """Densify every pair of ``log`` with the processor; return (seconds, the prior's line)."""
    from pcainterp_stream.frontend.pairing import PairingConfig, iter_stereo_frames
    from pcainterp_stream.io.logreader import open_log
    from pcainterp_stream.pipeline.processor import FrameProcessor, ProcessorConfig

    started = time.perf_counter()
    config = ProcessorConfig(adapt=adapt, builtin=builtin)
    with open_log(log) as reader, FrameProcessor(None, config) as engine:
        frames = 0
        for _ in engine.process(iter_stereo_frames(reader, PairingConfig())):
            frames += 1
        lines = engine.adaptation.lines
    seconds = time.perf_counter() - started
    adapted = any(line.startswith("adapted") for line in lines)
    indoor = any("indoor basis chosen" in line for line in lines)
    what = "adapted" if adapted else "indoor basis" if indoor else "kept"
    return seconds, f"{frames} frames; {what}"


def main(argv: list[str] | None = None) -> int:
    """Time each log three ways and print the table."""
    parser = harness.argument_parser(__doc__)
    parser.add_argument("logs", type=Path, nargs="+", metavar="LOG")
    args = parser.parse_args(argv)
    from pcainterp_stream.estimate.basis import Basis

    Basis.default()  # loaded once, outside the timings
    Basis.indoor()
    headers = ["log", "off (s)", "check/off", "auto/off", "street-or-own/off", "auto", "before"]
    print(harness.table_header(headers))
    for log in args.logs:
        off, _ = run(log, "off")
        check, _ = run(log, "check")
        auto, what = run(log, "auto")
        before, what_before = run(log, "auto", "street")
        print(
            harness.table_row(
                [
                    log.name,
                    f"{off:.1f}",
                    f"{check / off:.2f}",
                    f"{auto / off:.2f}",
                    f"{before / off:.2f}",
                    what,
                    what_before,
                ]
            ),
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
