"""The ``densify`` job: a log in, the same log with the dense depth channels out."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import sys
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from pcainterp_stream.errors import (
    LogReadError,
    PcaInterpError,
)
from pcainterp_stream.estimate.basis import (
    BUILT_IN,
    BUILTIN_LABELS,
    IN_MEMORY,
    Basis,
    builtin_basis,
    builtin_kind,
)
from pcainterp_stream.evaluate.tuning import tuning_json
from pcainterp_stream.frontend.discovery import resolve_pairing
from pcainterp_stream.frontend.far import FarZeros
from pcainterp_stream.frontend.frame_checks import BeyondRange, StaleRight
from pcainterp_stream.frontend.image_limits import empty_cause, small_images_cause, too_narrow
from pcainterp_stream.frontend.pairing import PairingConfig, StereoPairer
from pcainterp_stream.frontend.pairing_stats import PairingStats
from pcainterp_stream.frontend.sgbm_resolution import by_camera
from pcainterp_stream.frontend.stereo import SgbmConfig
from pcainterp_stream.io import reader_base, rosmsg
from pcainterp_stream.io.densify_record import (
    DENSIFY_RECORD,
    FRONT_END_KEY,
    IMAGES,
    OUTPUT_PREFIX_KEY,
    FrontEnd,
    option_value,
    options_json,
)
from pcainterp_stream.io.foxglove import FoxgloveLive, LiveMessage
from pcainterp_stream.io.log_time_hold import CamerasRead, LogTimeHold
from pcainterp_stream.io.logreader import LogReader, open_log
from pcainterp_stream.io.logwriter import (
    LogFormat,
    LogWriter,
    McapLogWriter,
    WriteSummary,
    open_writer,
)
from pcainterp_stream.io.output_cameras import CAMERAS_RECORD, CamerasInForce
from pcainterp_stream.io.outputs import (
    BASES_RECORD,
    BASIS_FINGERPRINT_KEY,
    BASIS_KEY,
    BASIS_SCOPE,
    BASIS_SCOPE_KEY,
    BASIS_TUNING_KEY,
    BasisInForce,
    OutputTopics,
    bases_record,
    channel_metadata,
    frame_metadata,
    output_messages,
    pairing_metadata,
    topic_metadata,
)
from pcainterp_stream.io.path_text import path_text
from pcainterp_stream.io.path_text import shown as shown_name
from pcainterp_stream.io.pipes import STDIN_NAME, McapStreamWriter, spool
from pcainterp_stream.io.rerun_sink import RerunSink
from pcainterp_stream.pipeline.blas_threads import restoring_blas_threads
from pcainterp_stream.pipeline.common import (
    _bar,
    _check_topic_types,
    _pairing_types,
    _require_topics,
    _Unshown,
    no_pair_message,
)
from pcainterp_stream.pipeline.feature_check import FeatureStreamCheck
from pcainterp_stream.pipeline.own_bases import (
    RELEARNED,
    adoption_lines,
    matched_alone,
    own_bases,
    own_basis_label,
    save_own_bases,
)
from pcainterp_stream.pipeline.own_bases import final_basis_path as final_basis_path
from pcainterp_stream.pipeline.own_bases import own_basis_path as own_basis_path
from pcainterp_stream.pipeline.processor import FrameProcessor, MeasurementSource, ProcessorConfig
from pcainterp_stream.records import DensifiedFrame, StereoFrame

ENCODE_WORKERS = 2
"""Threads building (and PNG-encoding) the output messages of densified frames."""
ENCODE_AHEAD = 4
"""Frames whose output messages may be in the making at once (bounds their memory)."""


@dataclass
class DensifySummary:
    """What ``densify`` did.

    Attributes:
        input: the input log (``stdin`` for standard input).
        output: the written log (``<stdout>`` for standard output), None when only served.
        frames: frames densified.
        seconds: wall time of the whole run, but the wait for a Rerun viewer at its end.
        measurements: sparse measurements used, summed over frames.
        pairing: the pairer's counts.
        damage: damage found in the input (one line each).
        written: the writer's summary.
        warnings: notes on the input that are not damage (non-monotonic log times).
        downweighted: measurements the robust loss down-weighted (weight < 0.5), all frames.
        most_downweighted: the most down-weighted measurements of one frame.
        temporal_resets: frames whose temporal prior failed the innovation test.
        carried: measurements carried over from earlier frames, summed over frames.
        carry_resets: frames where the ego-motion was lost (carrying started over).
        prior_lines: the fit check of the prior and the self-supervised adaptation, one
            line each (:mod:`~pcainterp_stream.pipeline.adaptation`).
        basis_written: where the log's own basis adopted first was saved (beside the
            output; the output channels name it when it densified the first frames), None
            when the run did not adapt.
        final_basis_written: where that basis's last relearned one was saved, None when it
            was never relearned.
        bases_saved: every basis of the log's own saved beside the output (those two, and
            those a check made again adopted: ``OUTPUT.basis-2.npz``...), with what it is.
        rrd_written: whether the ``.rrd`` recording was written whole.
        feature_line: with a feature stream, what it gave (points used, dropped by reason);
            None when the measurements came from the stereo pair.
    """

    input: Path
    output: Path | None
    frames: int
    seconds: float
    measurements: int
    pairing: PairingStats
    damage: list[str]
    written: WriteSummary | None
    warnings: list[str] = dataclasses.field(default_factory=list)
    downweighted: int = 0
    most_downweighted: int = 0
    temporal_resets: int = 0
    carried: int = 0
    carry_resets: int = 0
    prior_lines: list[str] = dataclasses.field(default_factory=list)
    rrd_written: bool = False
    basis_written: Path | None = None
    final_basis_written: Path | None = None
    bases_saved: list[tuple[Path, str]] = dataclasses.field(default_factory=list)
    feature_line: str | None = None

    def written_lines(self) -> list[str]:
        """Return a "wrote OUTPUT.basis.npz: ..." line for each basis saved beside the output."""
        return [f"wrote {path}: {what}" for path, what in self.bases_saved]

    def pairing_hints(self) -> list[str]:
        """Return the pairing's warnings (repeated stamps, near misses, late camera infos)."""
        pairing = self.pairing
        hints = (
            pairing.row_check_hint(),
            pairing.baseline_hint(),
            pairing.stamp_hint(),
            pairing.hold_hint(),
            pairing.tolerance_hint(),
            pairing.camera_info_hint(),
        )
        return [hint for hint in hints if hint is not None]

    def warning_lines(self) -> list[str]:
        """Return every warning of the run, one line each, without the ``warning:`` prefix.

        The pairing's, the damage found in the input, the input's notes and the fit check's
        (a prior worse than linear interpolation): what a run of several logs reports per log.
        """
        prior = [
            line.removeprefix("warning: ")
            for line in self.prior_lines
            if line.startswith("warning: ")
        ]
        damage = [f"damage: {line}" for line in self.damage]
        return self.pairing_hints() + damage + list(self.warnings) + prior

    def adapted_line(self) -> str | None:
        """Return why the run densified with a basis of the log's own, or None.

        The fit check's ``adapted:`` line without its prefix; None when no such basis was
        saved (the run kept the given or a built-in basis, or had no file to save it beside).
        """
        if self.basis_written is None:
            return None
        reasons = [line for line in self.prior_lines if line.startswith("adapted: ")]
        return reasons[0].removeprefix("adapted: ") if reasons else "learned from this log"

    @property
    def frames_per_second(self) -> float:
        """Return densified frames per wall-clock second."""
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    @property
    def pace(self) -> str:
        """Return the rate for the summary line, never ``0.0`` for a slow run.

        ``12.3 frames/s``; below 1 frame/s with two digits and the seconds per frame
        (``0.0075 frames/s, 134 s per frame``).
        """
        rate = self.frames_per_second
        if rate >= 1 or rate == 0:
            return f"{rate:.1f} frames/s"
        return f"{rate:.2g} frames/s, {self.seconds / self.frames:.3g} s per frame"


def provenance(
    channels: dict[str, str],
    pairing: PairingConfig,
    processor: ProcessorConfig,
    stats: PairingStats,
    prefix: str | None = None,
) -> dict[str, str]:
    """Return the record of what made a densified log (``pcainterp.densify``), run complete.

    Args:
        channels: the metadata the output channels were written with: the record names
            their basis (the first outputs'), with the same words and fingerprint.
        pairing: the pairing in force (the pair found in the log, if discovered).
        processor: the processor's options.
        stats: the pairing's counts (the pairs ``--rectify`` remapped).
        prefix: the output topics' prefix (``output_prefix``; None: not recorded).

    Returns:
        ``version``, ``basis``, ``basis_fingerprint``, ``basis_scope``, ``basis_tuning`` (only
        when the fit check tuned the channels' basis: ``evaluate.tuning``), ``output_prefix`` and,
        as JSON of option values, ``front_end`` (:func:`front_end`), ``pairing`` and
        ``processor``.
    """
    from pcainterp_stream.version import __version__

    return {
        "version": __version__,
        "basis": channels[BASIS_KEY],
        "basis_fingerprint": channels[BASIS_FINGERPRINT_KEY],
        "basis_scope": BASIS_SCOPE,
        **({"basis_tuning": channels[BASIS_TUNING_KEY]} if BASIS_TUNING_KEY in channels else {}),
        FRONT_END_KEY: front_end(pairing, processor, stats).to_json(),
        "pairing": options_json(pairing),
        "processor": options_json(processor),
        **({} if prefix is None else {OUTPUT_PREFIX_KEY: prefix}),
    }


def front_end(pairing: PairingConfig, processor: ProcessorConfig, stats: PairingStats) -> FrontEnd:
    """Return how a run read its stereo pair and matched it (what ``evaluate`` redoes)."""
    calibration, remapped, pairs = pairing.calibration, stats.remapped, stats.pairs
    return FrontEnd(
        left_topic=pairing.left_topic,
        right_topic=pairing.right_topic,
        left_info_topic=pairing.left_info_topic,
        right_info_topic=pairing.right_info_topic,
        stamp_tolerance_ns=pairing.tolerance_ns,
        baseline=pairing.baseline,
        calibration="camera_info" if calibration is None else "files",
        calibration_files=()
        if calibration is None
        else (calibration.left.name, calibration.right.name),
        calibration_values=calibration,
        rectify=pairing.rectify,
        images=IMAGES[0] if not remapped else IMAGES[1] if remapped == pairs else IMAGES[2],
        remapped_pairs=remapped,
        pairs=pairs,
        source=option_value(processor.source),
        features_topic=pairing.features_topic,
        sgbm=json.loads(options_json(processor.sgbm)),
    )


def _bar_description(description: str) -> str:
    """Return the bar's description to fit the terminal: shorter on a narrow one (16C F5).

    A bar needs about 40 columns for its share, count, times and rate; on a narrower
    terminal the description took the whole line and the count was cut off. The log's
    name goes first, then the word ``densify``: the share and count are always shown.
    """
    try:
        width = os.get_terminal_size(sys.stderr.fileno()).columns
    except (AttributeError, OSError, ValueError):  # not a terminal: plain lines, full name
        return description
    if width >= len(description) + 40:
        return description
    short = description.split(" ", 1)[0]
    return short if width >= len(short) + 40 else ""


def _above(shown: list[Any], echo: Callable[[str], None]) -> Callable[[str], None]:
    """Return ``echo`` printing above the progress bar once it is drawn (bug hunt 16C F5).

    A terminal's bar (``tqdm``) is cleared, the line printed, and the bar drawn again below
    it: printed as it is, the line was glued onto the bar's text.
    """

    def said(text: str) -> None:
        bar = shown[0] if shown else None
        clear, refresh = getattr(bar, "clear", None), getattr(bar, "refresh", None)
        if clear is None or refresh is None:  # off a terminal: plain lines, nothing drawn
            echo(text)
            return
        clear()
        echo(text)
        refresh()

    return said


@restoring_blas_threads
def densify(
    input_path: Path | Sequence[Path] | IO[bytes],
    output: Path | IO[bytes] | None,
    basis: Basis | Path | None = None,
    *,
    pairing: PairingConfig | None = None,
    processor: ProcessorConfig | None = None,
    topics: OutputTopics | None = None,
    rrd: Path | None = None,
    spawn_viewer: bool = False,
    on_frame: Callable[[DensifiedFrame], None] | None = None,
    live: FoxgloveLive | None = None,
    echo: Callable[[str], None] | None = None,
) -> DensifySummary:
    """Densify a stereo log into a copy with the ``/pcainterp/*`` channels (``densify``).

    One pass over the input: every message is copied to the output, stereo pairs are
    formed by header stamp, stereo-matched ahead in a worker thread and densified in
    batches, and their outputs written at the left image's log time. The output channels'
    metadata names the basis (``io/outputs.channel_metadata``): ``built-in`` when ``basis``
    is None (:meth:`Basis.default`), ``built-in-indoor`` when the fit check chose the
    built-in indoor basis (or ``processor.builtin`` is ``"indoor"``), the log's own basis
    file when it adapted, else the given file (its path relative to the output's folder:
    :func:`basis_label`). When the output is complete, an MCAP output
    gets the metadata records ``pcainterp.densify`` (:func:`provenance`: that basis, the front
    end, the options) and ``pcainterp.basis`` (every basis in force, :func:`bases_in_force`).

    ``input_path`` may be a list of paths: the parts of one split recording, read as one
    log (:func:`io.logreader.open_log`). ``input_path`` and ``output`` may be open binary
    streams (standard input and output,
    ``pcainterp densify - -o -``): the input is spooled to a temporary file first
    (:func:`io.pipes.spool`), the output written as it goes (:class:`io.pipes.McapStreamWriter`).
    With ``live`` (an open :class:`io.foxglove.FoxgloveLive`) the same messages are served
    to Foxglove clients as they are made; ``output`` may then be None.

    A ``pairing`` with ``discover`` set takes the stereo pair found in the log
    (:func:`frontend.discovery.resolve_pairing`); raw images are rectified from their
    calibration (:meth:`frontend.pairing.StereoPairer.rectification`). ``echo`` is given the
    one-line notes of those decisions (the command line prints them).

    BLAS runs at one thread while the job runs (its bytes do not depend on the machine's
    core count); the thread counts the caller had come back when it returns.
    """
    started = time.perf_counter()
    pairing = pairing or PairingConfig()
    processor = processor or ProcessorConfig()
    topics = topics or OutputTopics().compact()
    if not (topics.writes("depth_std") or rrd is not None or spawn_viewer or on_frame is not None):
        # nothing takes the depth's std (the compact output writes the disparity's)
        processor = dataclasses.replace(processor, depth_std=False)
    basis, label = resolve_basis(basis, output)
    kind = builtin_kind(basis)
    if kind is not None and processor.builtin not in ("auto", kind):
        basis = builtin_basis(processor.builtin)
        label = BUILTIN_LABELS[processor.builtin]
    if processor.source is MeasurementSource.FEATURES and pairing.features_topic is None:
        raise PcaInterpError("measurement source 'features' needs --features-topic")
    if output is None and live is None:
        raise PcaInterpError("densify needs an output: pass -o OUTPUT, --foxglove, or both")
    measurements = 0
    frames = 0
    # "empty": frames without a single measurement, so without an estimate (NaN)
    robust = {"downweighted": 0, "most": 0, "resets": 0, "carried": 0, "carry_resets": 0}
    robust["empty"] = robust["stale_empty"] = 0
    small: list[str] = []  # the cause of the first frame without a measurement its size says
    stereo = processor.source is MeasurementSource.STEREO
    stale = StaleRight() if stereo else None  # a right image repeated: not matched
    beyond = (
        BeyondRange(
            processor.sgbm.matched().band * processor.sgbm.downscale, 16 * processor.sgbm.downscale
        )
        if stereo and processor.measurements == "sparse" and processor.near is not None
        else None
    )
    far = FarZeros() if stereo and not processor.sgbm.refine_range else None  # 0: "far"
    check = (
        FeatureStreamCheck(pairing.features_topic, max_points=processor.max_features)
        if processor.source is MeasurementSource.FEATURES and pairing.features_topic is not None
        else None
    )
    committed: list[Path] = []  # the bases saved beside the output, before it is closed

    def drop_bases(kind: type[BaseException] | None, *_: object) -> None:
        """Remove them when the output then fails: "nothing was written there"."""
        for path in committed if kind is not None else ():
            path.unlink(missing_ok=True)

    sink: RerunSink | None = None
    work_ended: list[float] = []  # when the work ended: the wait for a viewer is not counted

    def wait_for_viewer(*_: object) -> None:
        """Wait for a Rerun viewer once the outputs are committed (review 59b F2)."""
        work_ended.append(time.perf_counter())
        if sink is not None:  # a Ctrl-C in this wait keeps them
            sink.wait_for_viewer()

    with contextlib.ExitStack() as stack:
        stack.push(wait_for_viewer)  # the last to run: every output is committed (or failed)
        stack.push(drop_bases)  # after the output's writer closed
        read: list[Path] = []  # the files read, which the output must not replace
        if isinstance(input_path, Path):
            reader = stack.enter_context(open_log(input_path))
            read = [input_path]
        elif isinstance(input_path, list | tuple):  # the parts of one split recording
            read = list(input_path)
            reader = stack.enter_context(open_log(read))
            input_path = reader.path  # "a_0.bag + a_1.bag"
        else:  # standard input: spooled, then named as such, not by the temporary file
            assert not isinstance(input_path, Sequence)
            reader = stack.enter_context(open_log(stack.enter_context(spool(input_path))))
            input_path = Path(STDIN_NAME)
        pairing = resolve_pairing(reader, pairing, echo)
        _require_topics(reader, pairing.required_topics(), "stereo pair")
        _check_topic_types(reader, _pairing_types(pairing))
        clash = sorted(set(topics.all()) & set(reader.topics()))
        if clash:
            raise PcaInterpError(
                f"{input_path} already has {', '.join(clash)}; densify the original log, "
                f"or give --output-prefix a prefix other than {clash[0].rsplit('/', 1)[0]}"
            )
        left = reader.topics().get(pairing.left_topic)
        total = left.message_count if left is not None else None
        writer: LogWriter | None = None
        if isinstance(output, Path):
            writer = stack.enter_context(
                open_writer(output, LogFormat.MCAP, inputs=read or [input_path], threaded=True)
            )
        elif output is not None:
            writer = stack.enter_context(McapStreamWriter(output))
        if isinstance(writer, McapLogWriter) and (extras := reader.extras(verify=True)) is not None:
            # the rest of the copy: attachments, metadata records, channels without messages
            writer.add_extras(extras)
        inputs = LogTimeHold(writer.add_raw) if writer is not None else None
        # the output channels' metadata (f*b, the basis used) is known at the first output
        # (below): the written channels take it then, and so do the live ones, advertised
        # then, before the server starts (with the first frame) so that a client subscribes
        # to them in its first advertisement; topic -> the metadata they were advertised with
        live_metadata: dict[str, dict[str, str]] = {}
        opening: dict[str, str] = {}  # the metadata the output channels were written with
        cameras = CamerasInForce()  # each camera's f*b from its first frame (compact logs)

        def advertise_live(metadata: dict[str, str]) -> None:
            if live is None or live_metadata:
                return
            by_topic = topic_metadata(topics, metadata)
            for topic, msgtype in output_types(topics).items():
                live_metadata[topic] = by_topic.get(topic, {})
                live.advertise(topic, msgtype, metadata=live_metadata[topic])
            live.before_start = None

        if live is not None:
            # more than MAX_HELD_BYTES of input before the first output start the server
            # early: the outputs go out then with what is known (no f*b, the basis given)
            live.before_start = lambda: advertise_live(
                {
                    **channel_metadata(label, basis.fingerprint, processor.measurements),
                    **pairing_metadata(pairing.tolerance_ns),
                }
            )
        # the output messages (quantising and PNG-deflating: numpy and zlib-ng release the
        # GIL) are built in a pool of their own, so the calling thread only reads, pairs and
        # densifies; they are written in frame order, ENCODE_AHEAD frames behind
        encoder = stack.enter_context(ThreadPoolExecutor(ENCODE_WORKERS, "encode-outputs"))
        encoding: deque[tuple[DensifiedFrame, Future[list[tuple[str, Any]]]]] = deque()
        if rrd is not None or spawn_viewer:
            sink = stack.enter_context(
                RerunSink(rrd_path=rrd, spawn=spawn_viewer, defer_viewer_wait=True)
            )
        engine: FrameProcessor | None = None  # made at the first pair (SGBM's resolution)
        matching: str | None = None  # the resolution chosen for the camera, said with it
        sgbm = processor.sgbm  # that resolution (a given one as it is)
        shown: list[Any] = []  # the progress bar, once drawn
        pairer = StereoPairer(pairing, echo=None if echo is None else _above(shown, echo))
        pairer.read_ahead(reader)  # camera infos recorded after the first images
        if stale is not None and stale.watch is not None:  # the row check's corners, not again
            stale.watch.row_corners = pairer.row_corners
        bar_name = shown_name(input_path.name)  # a newline in it would leave a line per redraw
        bar = stack.enter_context(_bar(total, _bar_description(f"densify {bar_name}")))
        shown.append(bar)

        def emit(results: list[DensifiedFrame]) -> None:
            assert engine is not None  # results come from it
            for result in map(pairer.full_result, results):
                if frames == 0 and not encoding and (writer is not None or live is not None):
                    # f*b and the first min disparity: what evaluate needs of a compact log
                    first = {
                        **channel_metadata(label, basis.fingerprint, processor.measurements),
                        **frame_metadata(result),
                        # for evaluate's right images (wider when paired by log time)
                        **pairing_metadata(
                            max(pairing.tolerance_ns, pairer.stats.log_tolerance_ns)
                        ),
                        BASIS_SCOPE_KEY: BASIS_SCOPE,  # later bases: the record at the end
                    }
                    # the basis of the first frames as the densify thread bound it, which the
                    # record of every basis in force starts with (a later re-check moves the
                    # adaptation's state on, not this)
                    started = bases_in_force(engine, basis, label, output)[:1]
                    switched = engine.adaptation.switched
                    if started:
                        first.update(
                            channel_metadata(
                                started[0].basis, started[0].fingerprint, processor.measurements
                            )
                        )
                        if started[0].tuning:  # the check tuned it (only then: as before)
                            first[BASIS_TUNING_KEY] = started[0].tuning
                    elif switched is not None:  # the check chose another built-in basis
                        first.update(
                            channel_metadata(
                                BUILTIN_LABELS[builtin_kind(switched.basis) or "street"],
                                switched.basis.fingerprint,
                                processor.measurements,
                            )
                        )
                        if switched.tuned:
                            first[BASIS_TUNING_KEY] = tuning_json(switched.tuned)
                    if not started and engine.adaptation.adapted:
                        # the first outputs follow the warm-up: name the basis learned from it
                        own = engine.adaptation.first_basis
                        first.update(
                            channel_metadata(
                                own_basis_label(output),
                                (own if own is not None else engine.basis).fingerprint,
                                processor.measurements,
                            )
                        )
                    opening.update(first)
                    if writer is not None:
                        writer.channel_metadata = topic_metadata(topics, first)
                    advertise_live(first)  # the file's, in the live channels too
                cameras.see(result)
                encoding.append((result, encoder.submit(output_messages, result, topics)))
            # by count, never by which future is done: the output's order is deterministic
            while len(encoding) > ENCODE_AHEAD:
                write(*encoding.popleft())

        def write(result: DensifiedFrame, built: Future[list[tuple[str, Any]]]) -> None:
            nonlocal measurements, frames
            messages = built.result()
            if writer is not None:
                assert inputs is not None  # made with the writer
                inputs.release(result.frame.log_time_ns)  # the inputs up to this frame first
                for topic, message in messages:
                    writer.add_message(topic, message, result.frame.log_time_ns)
            if live is not None:
                live.add_frame(
                    result.frame.log_time_ns,
                    [
                        LiveMessage(
                            topic,
                            str(message.__msgtype__),
                            rosmsg.serialize(message),
                            live_metadata.get(topic),  # as advertised
                        )
                        for topic, message in messages
                    ],
                )
            if sink is not None:
                sink.log(result)
            if on_frame is not None:
                on_frame(result)
            measurements += int(result.pixels.shape[0])
            if stale is not None and result.frame.index in stale.stale:
                robust["stale_empty"] += not result.estimated  # warned of on their own
            else:
                robust["empty"] += not result.estimated
                height, width = result.frame.left.shape[:2]
                if not result.estimated:  # its size may say why
                    gftt = processor.gftt if processor.measurements == "sparse" else None
                    if cause := small_images_cause(width, height, gftt, sgbm):
                        small[:] = small or [cause]
                        robust["small"] = robust.get("small", 0) + 1
            if beyond is not None:
                beyond.result(result)
            if far is not None:
                far.result(result.counts)
            frames += 1
            robust["downweighted"] += result.counts.get("downweighted", 0)
            robust["most"] = max(robust["most"], result.counts.get("downweighted", 0))
            robust["resets"] += result.counts.get("temporal_reset", 0)
            robust["carried"] += result.counts.get("carried", 0)
            robust["carry_resets"] += result.counts.get("carry_reset", 0)
            if check is not None:
                check.result(result)
            bar.update(1)

        checked: tuple[int, ...] | None = None  # the image size checked last (stereo)

        def submit(frame: StereoFrame) -> None:
            nonlocal checked, engine, matching, sgbm, far
            if engine is None:
                if stereo:  # --stereo-downscale auto: the first pair's camera decides
                    camera = frame.camera
                    sgbm, matching = by_camera(
                        sgbm, camera.focal_baseline, camera.width, camera.height
                    )
                    far = FarZeros(sgbm.downscale) if far is not None else None  # its px
                    if beyond is not None:  # the range and step of the resolution chosen
                        beyond.match_range = sgbm.matched().band * sgbm.downscale
                        beyond.step = 16 * sgbm.downscale
                config = dataclasses.replace(processor, sgbm=sgbm)
                engine = stack.enter_context(FrameProcessor(basis, config))
            if stereo and frame.left.shape[:2] != checked:  # the first pair, a new size
                _check_size(frame, sgbm, input_path, pairing)
                checked = frame.left.shape[:2]
            features = pairer.features_for(frame)
            refused = check.cloud(frame, features) if check is not None else None
            if refused is not None:  # in the writer's block: no output is left behind
                raise PcaInterpError(f"{input_path}: {refused}")
            emit(engine.submit(stale.check(frame) if stale is not None else frame, features))

        def finish_frames() -> None:
            for frame in pairer.flush():
                submit(frame)
            for batch in engine.finish_batches() if engine is not None else ():
                emit(batch)  # each batch to the encoders as it is done
            while encoding:
                write(*encoding.popleft())

        wanted = reader.topics()  # the frames' topics read whole: their frames finished then
        cameras_read = CamerasRead({t: wanted[t].message_count for t in pairing.required_topics()})
        for raw in reader.messages():
            if cameras_read.read(raw.topic, raw.log_time_ns):
                finish_frames()  # the rest is other topics' messages, said on a terminal's bar
                if not isinstance(bar, _Unshown):
                    bar.set_postfix_str("copying the rest of the log")
            if inputs is not None:
                inputs.add(raw)
                if raw.topic == pairing.left_topic:  # its outputs may come at its log time
                    inputs.expect(raw.log_time_ns)
            if live is not None:
                live.add_raw(raw)
            if pairer.wants(raw.topic):
                for frame in pairer.push_raw(raw, reader.decode):
                    submit(frame)
            if inputs is not None:  # what no output can come before any more goes out
                inputs.passed(raw.log_time_ns)
        finish_frames()
        if inputs is not None:
            inputs.release()
        if live is not None:
            live.flush()
        stats = pairer.finish()
        stats.matching = matching
        if matching is not None:  # chosen on the first camera, kept for the others: said
            stats.matched_alone = matched_alone(stats, processor.sgbm, sgbm)
        if frames == 0 or engine is None:
            raise LogReadError(no_pair_message(input_path, pairing, stats, reader.damage))
        unusable = check.error(stats) if check is not None else None
        if unusable is not None:  # raised in the writer's block: no output is left behind
            raise PcaInterpError(f"{input_path}: {unusable}")
        prior_lines = list(engine.adaptation.lines)
        ended = engine.adaptation.end_line()  # a check made again that the log cut short
        prior_lines.extend([ended] if ended is not None else [])
        # every basis of the log's own that densified frames, saved as the record names it
        owns = own_bases(engine.adaptation, basis, output)
        prior_lines.extend(adoption_lines(owns))
        # a basis that cannot be written is warned of: the output is written all the same
        saved, unsaved = save_own_bases(owns, input_path)
        committed.extend(own.path for own in saved if own.path is not None)
        basis_written = next((o.path for o in saved if o.adoption == 1 and not o.relearned), None)
        final_written = next((o.path for o in saved if o.adoption == 1 and o.relearned), None)
        if owns and not isinstance(output, Path):  # no file to save OUTPUT.basis.npz beside
            where = "standard output" if output is not None else "served live only"
            prior_lines.append(
                f"note: the adapted basis was not saved: the output is {where}, with no "
                "folder to save it in; densify -o FILE.mcap also writes it, as "
                "FILE.basis.npz, for evaluate and for --basis"
            )
        if isinstance(writer, McapLogWriter):  # every basis in force: the channels name the first
            # what made the log, now that the basis of its outputs is decided
            chosen = dataclasses.replace(processor, sgbm=sgbm)  # the resolution chosen
            record = provenance(opening, pairing, chosen, stats, topics.prefix)
            writer.add_metadata(DENSIFY_RECORD, record)
            in_force = bases_in_force(engine, basis, label, output)
            writer.add_metadata(BASES_RECORD, bases_record(in_force, topics.prefix))
            if (changed := cameras.record(topics.prefix)) is not None:  # the channels: one f*b
                writer.add_metadata(CAMERAS_RECORD, changed)
    return DensifySummary(
        input=input_path,
        output=writer.path if writer is not None else None,
        frames=frames,
        seconds=work_ended[0] - started,
        measurements=measurements,
        pairing=stats,
        damage=list(reader.damage),
        written=writer.summary() if writer is not None else None,
        warnings=_order_warnings(reader, stats)
        + (
            check.warnings(stats)
            if check is not None
            else _empty_warning(robust["empty"], frames, small, robust.get("small", 0))
        )
        + (stale.warnings(frames, robust["stale_empty"]) if stale is not None else [])
        + (beyond.warnings(frames, sgbm) if beyond is not None else [])
        + (far.warnings(frames) if far is not None else [])
        + unsaved
        + (inputs.notes() if inputs is not None else [])
        + cameras_read.lines(),
        downweighted=robust["downweighted"],
        most_downweighted=robust["most"],
        temporal_resets=robust["resets"],
        carried=robust["carried"],
        carry_resets=robust["carry_resets"],
        prior_lines=prior_lines,
        basis_written=basis_written,
        final_basis_written=final_written,
        bases_saved=[(own.path, own.described(owns)) for own in saved if own.path is not None],
        rrd_written=sink is not None and sink.written,
        feature_line=check.summary() if check is not None else None,
    )


def bases_in_force(
    engine: FrameProcessor, given: Basis, label: str, output: Path | IO[bytes] | None
) -> list[BasisInForce]:
    """Return every basis ``engine`` densified with, from its first frame, named for the log.

    Named as the output channels name a basis (``built-in``, ``built-in-indoor``, the given
    file), a basis of the log's own by the file it is saved as (:func:`own_bases`:
    ``OUTPUT.basis.npz``, ``OUTPUT.final.basis.npz``, ``OUTPUT.basis-2.npz``...), others
    :data:`RELEARNED`.
    """
    adaptation, entries = engine.adaptation, []
    names = {id(own.basis): own.name for own in own_bases(adaptation, given, output)}
    for start in adaptation.in_force:
        used, kind = start.basis, builtin_kind(start.basis)
        if kind is not None:
            name = BUILTIN_LABELS[kind]
        elif used is given:
            name = label
        else:
            name = names.get(id(used), RELEARNED)
        frame, tuning = start.frame, tuning_json(start.tuning or {})
        entries.append(
            BasisInForce(
                name, used.fingerprint, frame.index, frame.stamp_ns, frame.log_time_ns, tuning
            )
        )
    return entries


def output_types(topics: OutputTopics) -> dict[str, str]:
    """Return output topic -> ROS 2 message type, as ``io/outputs.output_messages`` builds them."""
    channels = ["depth", "depth_std", "disparity", "disparity_std", "features", "camera_info"]
    types = {topics.topic(name): topics.msgtype(name) for name in channels}
    if topics.depth_mm:
        types[topics.depth_mm] = rosmsg.IMAGE
    written = set(topics.all())  # --outputs may leave some out
    return {topic: msgtype for topic, msgtype in types.items() if topic in written}


def resolve_basis(
    basis: Basis | Path | None, output: Path | IO[bytes] | None = None
) -> tuple[Basis, str]:
    """Return the basis a job uses and how a densified log names it.

    Args:
        basis: a basis, its file, or None for the built-in one.
        output: the output the log names it in (a file: the name is relative to its folder).

    Returns:
        The loaded :class:`Basis` and its label: ``built-in``, ``in-memory`` for a basis
        object that is not the built-in one, or the file (:func:`basis_label`).

    Raises:
        BasisError: the file (or the built-in basis) is missing or invalid.
    """
    if basis is None:
        return Basis.default(), BUILT_IN
    if isinstance(basis, Path):
        return Basis.load(basis), basis_label(basis, output)
    kind = builtin_kind(basis)
    return basis, BUILTIN_LABELS[kind] if kind is not None else IN_MEMORY


def basis_label(basis: Path, output: Path | IO[bytes] | None) -> str:
    r"""Return how a densified log names the basis file it was made with.

    Its path relative to the output's folder, both resolved, with ``/``: the bytes of the
    output do not depend on how either path was spelled nor on the working folder
    (``bases/my.npz`` and ``/abs/bases/my.npz`` both give ``../bases/my.npz`` for
    ``out/d.mcap``), and ``evaluate`` finds it from any folder through the log's
    (``jobs.evaluation_basis``). The file's name alone when the output is no file (a
    stream, ``-o -``) or no relative path leads there (another drive). The fingerprint
    recorded beside it identifies the content. Bytes of the path that are not UTF-8 (a
    latin-1 ``caf\xe9.npz``) are escaped (``caf\udce9.npz``): the metadata is UTF-8.
    """
    if not isinstance(output, Path):
        return path_text(basis.name)
    try:
        relative = os.path.relpath(basis.resolve(), output.resolve().parent)
    except (OSError, ValueError):  # another drive (Windows), or an unreadable folder
        return path_text(basis.name)
    return path_text(Path(relative).as_posix())


def _check_size(frame: StereoFrame, sgbm: SgbmConfig, log: Path, pairing: PairingConfig) -> None:
    """Refuse a pair narrower than SGBM's disparity range (it would fail, or crash).

    Checked on the first pair and on each new size. Images too small for sparse mode to
    place a point on are not refused (a camera may change to a larger size later): their
    frames have no estimate, and the warning of such frames says why
    (:func:`~pcainterp_stream.frontend.image_limits.small_images_cause`).

    Raises:
        PcaInterpError: the frame's images are too narrow.
    """
    problem = too_narrow(frame.left.shape[1], sgbm)
    if problem is not None:  # the first pair's, or a changed camera's from its first frame
        since = f" from frame {frame.index} on" if frame.index else ""
        raise PcaInterpError(f"{log}: {pairing.left_topic}'s images{since} are {problem}")


def _empty_warning(empty: int, frames: int, small: list[str], sized: int) -> list[str]:
    """The warning for frames that had no measurement at all (none when there were none).

    For measurements from the stereo pair, sparse or dense (a dense frame whose SGBM map
    matched nothing, as a blank pair's); a feature stream's frames without one are warned
    of by :class:`~pcainterp_stream.pipeline.feature_check.FeatureStreamCheck`, by cause.
    ``small``: the cause of the first such frame whose size says why
    (:func:`~pcainterp_stream.frontend.image_limits.small_images_cause`), ``sized`` how many
    such frames there were; the others are blamed on their content.
    """
    if not empty:
        return []
    return [
        f"{empty} of {frames} frames had no measurement ({_empty_causes(empty, small, sized)}): "
        "they have no estimate, their depth is NaN"
    ]


def _order_warnings(reader: LogReader, stats: PairingStats) -> list[str]:
    """The reader's warnings; a log read out of time order says what that cost the pairing.

    A reader reads an indexed MCAP or bag in log-time order; one it has to read in file
    order (an MCAP without a chunk index, a ROS 1 bag without its index) may hand the pairer,
    which holds what waits a few seconds of log (``--hold-s``), the two images of a pair too
    far apart to meet.
    """
    warnings = list(reader.warnings)
    backwards = reader.backward_log_times
    lost = min(stats.unpaired_left, stats.unpaired_right)
    if not backwards or not lost:
        return warnings
    name = reader.path.name
    plain = reader_base.non_monotonic_warning(name, backwards)
    source = "LOG.mcap" if name == STDIN_NAME else name
    fix = (
        f"index it with the mcap CLI (`mcap recover {source} -o indexed.mcap`) and densify that: "
        "an indexed MCAP is read in log-time order"
        if reader.format is reader_base.LogFormat.MCAP
        else f"restore its index (`rosbag reindex {source}`): an indexed bag is read in log-time "
        "order"
        if reader.format is reader_base.LogFormat.ROS1
        else "rewrite it in log-time order"
    )
    return [warning for warning in warnings if warning != plain] + [
        f"{name}: the log is not stored in log-time order ({backwards} messages have a log time "
        "earlier than the message before them: non-monotonic log times) and has no index to "
        f"read it in that order; this cost up to {lost} stereo pairs ({stats.unpaired_left} "
        f"left and {stats.unpaired_right} right images unpaired); {fix}"
    ]


def _empty_causes(empty: int, small: list[str], sized: int) -> str:
    """Why frames had no measurement: their size (the first such frame's) or their content."""
    if not small:
        return empty_cause(None)
    if sized >= empty:
        return small[0]
    return f"{sized} of them {small[0]}; the others {empty_cause(None)}"
