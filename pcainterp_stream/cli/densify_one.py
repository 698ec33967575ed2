"""``pcainterp densify`` on one log: its ways in and out, and the summary it prints.

Kept apart from the options (:mod:`pcainterp_stream.cli.densify`) because one log has
several ways in and out: a file or standard input (``-``); an MCAP file, standard output
(``-o -``) or none; and a live Foxglove WebSocket server (``--foxglove``), paced
(``--rate``).
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING

from pcainterp_stream.cli.common import STREAM, echo, report_line, settle_heap, warn
from pcainterp_stream.interrupt import InterruptedAfterOutput, end_if_signalled, signalled
from pcainterp_stream.io.foxglove import (
    INTERRUPTED_STOP_TIMEOUT_S,
    FoxgloveLive,
    ServeAddress,
    behind_line,
)

if TYPE_CHECKING:
    from pcainterp_stream.frontend.pairing import PairingConfig
    from pcainterp_stream.io.outputs import OutputTopics
    from pcainterp_stream.pipeline.densify import DensifySummary
    from pcainterp_stream.pipeline.processor import ProcessorConfig


@dataclass(frozen=True)
class LiveOptions:
    """The live-view options of one densify run.

    Attributes:
        address: where the server listens.
        rate: pace (x the log's rate; 0 = as fast as processed).
        wait_for_client: hold the first frame until a client subscribed to an output.
        keep_serving: serve after the last frame until Ctrl-C.
    """

    address: ServeAddress
    rate: float
    wait_for_client: bool
    keep_serving: bool


def densify_one(
    source: Path | list[Path],
    output: Path | None,
    basis: Path | None,
    *,
    processor: ProcessorConfig,
    pairing: PairingConfig,
    topics: OutputTopics,
    live: LiveOptions | None,
    rrd: Path | None = None,
    spawn_viewer: bool = False,
) -> int:
    """Densify one log as the command line asks; print the summary; return the exit code.

    ``source`` and ``output`` may be ``-`` (:data:`STREAM`): standard input and output.
    ``source`` may be a list: the parts of one split recording, read as one log.
    With ``-o -`` everything printed goes to standard error: standard output carries the
    MCAP. With ``live`` (``--foxglove``) the server starts first (its URL is printed), and
    without an output it serves after the last frame until Ctrl-C (exit code 0) unless
    ``--exit-when-done``.

    Raises:
        InterruptedAfterOutput: a signal after the output file was complete at its target
            (while the summary is printed or the server stops): it is kept.
    """
    from pcainterp_stream.pipeline.densify import densify

    settle_heap()
    to_stdout = output == STREAM
    target: Path | IO[bytes] | None = sys.stdout.buffer if to_stdout else output
    reading: Path | list[Path] | IO[bytes] = sys.stdin.buffer if source == STREAM else source
    kept: list[Path] = []  # the output file, once complete at its target
    with _kept_if_interrupted(kept), contextlib.ExitStack() as stack:
        if to_stdout:
            stack.enter_context(contextlib.redirect_stdout(sys.stderr))
        server = None
        if live is not None:
            # the address is checked now (a port in use stops the run before any work); the
            # server starts, and says so, with the first message: once the input is open
            server = stack.enter_context(
                FoxgloveLive(
                    live.address,
                    rate=live.rate,
                    wait_for=topics.all() if live.wait_for_client else (),
                    note=echo,
                    on_start=lambda: _serving(server, live, topics),
                )
            )
        summary = densify(
            reading,
            target,
            basis,
            pairing=pairing,
            processor=processor,
            topics=topics,
            rrd=rrd,
            spawn_viewer=spawn_viewer,
            live=server,
            echo=echo,
        )
        if summary.written is not None and not to_stdout:
            kept.append(summary.written.path)
        _print_summary(summary, processor)
        if rrd is not None and summary.rrd_written:
            echo(f"wrote {rrd}")
        if server is not None:
            stats = server.stats
            skipped = (
                f"; skipped {stats.gaps_skipped} gap(s) in log time ({stats.gap_s_skipped:.1f} s)"
                if stats.gaps_skipped
                else ""
            )
            echo(
                f"foxglove: published {stats.frames} frames ({stats.messages} messages) to "
                f"{stats.clients} client(s){skipped}"
            )
            behind = behind_line(stats)
            if behind is not None:
                echo(behind)
            if live is not None and live.keep_serving:
                try:  # a Ctrl-C right after the line below is caught too
                    echo(f"foxglove: still serving on {server.url}; Ctrl-C to stop")
                    server.serve_forever()
                except KeyboardInterrupt:
                    echo("foxglove: stopped")
                    server.close(drain_s=0.0, stop_timeout_s=INTERRUPTED_STOP_TIMEOUT_S)
                    # Nothing is left to write in this mode (no -o), and the SDK's threads
                    # can still be calling back into Python while the interpreter shuts
                    # down: end here, so that Ctrl-C always ends the process.
                    end_if_signalled(0)
    return 0


@contextlib.contextmanager
def _kept_if_interrupted(kept: list[Path]) -> Iterator[None]:
    """Raise :class:`InterruptedAfterOutput` for an interruption once ``kept`` has the output.

    That error says the complete output is kept; an earlier interruption passes unchanged.
    """
    try:
        yield
    except KeyboardInterrupt as err:
        if not kept or isinstance(err, InterruptedAfterOutput):
            raise
        raise InterruptedAfterOutput(kept[0]) from err
    except Exception as err:
        if kept and signalled():  # a signal inside native code surfaces as its error
            raise InterruptedAfterOutput(kept[0]) from err
        raise


def _serving(server: FoxgloveLive | None, live: LiveOptions, topics: OutputTopics) -> None:
    """Say where the server listens, once it accepts clients."""
    assert server is not None  # started by its first message, after the with block opened it
    pace = f"{live.rate:g}x the log's rate" if live.rate > 0 else "as fast as processed"
    echo(f"foxglove: serving on {server.url} ({pace}); in Foxglove: Open connection")
    if live.wait_for_client:
        prefix = topics.depth.rsplit("/", 1)[0]
        echo(f"foxglove: waiting for a client to subscribe to a {prefix}/* channel")


def _print_summary(summary: DensifySummary, processor: ProcessorConfig) -> None:
    dense = processor.measurements == "dense"
    echo(
        f"densified {summary.frames} frame{'' if summary.frames == 1 else 's'} of "
        f"{summary.input} in {summary.seconds:.1f} s "
        f"({summary.pace}), "
        f"{summary.measurements / max(summary.frames, 1):.0f} points per frame"
        + (", fused with the whole SGBM map (dense)" if dense else "")
    )
    echo(f"pairing: {summary.pairing.summary()}")
    if summary.feature_line is not None:
        echo(summary.feature_line)
    notes = (summary.pairing.camera_note(), summary.pairing.stamp_note())
    for note in (*notes, summary.pairing.camera_info_note()):
        if note is not None:
            echo(note)
    for hint in summary.pairing_hints():
        warn(hint)
    if processor.robust != "none":
        echo(
            f"robust ({processor.robust}): {summary.downweighted} measurements down-weighted "
            f"({summary.downweighted / max(summary.frames, 1):.1f} per frame, at most "
            f"{summary.most_downweighted} in one frame)"
        )
    if processor.temporal:
        echo(f"temporal prior: reset {summary.temporal_resets} times (scene changes)")
    if processor.carry.frames:
        echo(
            f"carried from the {processor.carry.frames} previous frames: "
            f"{summary.carried / max(summary.frames, 1):.0f} points per frame; "
            f"ego-motion lost {summary.carry_resets} times"
        )
    for line in summary.prior_lines:
        report_line(line)  # the fit check's warning on standard error
    for line in summary.written_lines():  # each basis of the log's own saved beside it
        echo(line)
    for line in summary.damage:
        echo(f"damage: {line}")
    for line in summary.warnings:
        warn(line)
    written = summary.written
    if written is not None:
        duration = ((written.end_ns or 0) - (written.start_ns or 0)) / 1e9
        echo(f"wrote {written.path}: {written.message_count} messages, {duration:.1f} s of log")
