"""The jobs behind the ``pcainterp`` commands: plain functions over paths and configs.

Each job streams (one frame, or a small look-ahead of frames, in memory), shows a progress
bar on a terminal, writes its output atomically (temporary file beside the target, renamed
when complete) and raises only :class:`~pcainterp_stream.errors.PcaInterpError` subclasses
on bad input, which the command line prints as one line.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import itertools
import json
import sys
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from tqdm import tqdm

from pcainterp_stream import rosmsg
from pcainterp_stream.basis import Basis
from pcainterp_stream.errors import (
    BasisError,
    LogReadError,
    LogWriteError,
    PcaInterpError,
    TopicNotFoundError,
)
from pcainterp_stream.learning import learn_basis
from pcainterp_stream.logreader import LogReader, open_log
from pcainterp_stream.logwriter import LogFormat, WriteSummary, open_writer
from pcainterp_stream.outputs import OutputTopics, output_messages
from pcainterp_stream.pairing import PairingConfig, PairingStats, StereoPairer, iter_stereo_frames
from pcainterp_stream.processor import FrameProcessor, MeasurementSource, ProcessorConfig
from pcainterp_stream.records import DensifiedFrame
from pcainterp_stream.rerun_sink import RerunSink
from pcainterp_stream.stereo import GfttConfig, SgbmConfig, SgbmMode, compute_disparity


def _bar(total: int | None, description: str, unit: str = "frame") -> tqdm[Any]:
    # shown on a terminal only, so logs and tests stay clean
    return tqdm(
        total=total, desc=description, unit=unit, disable=None, leave=False, file=sys.stderr
    )


def _echo(text: str) -> None:
    print(text, flush=True)


def _check_output_folder(output: Path) -> None:
    """Refuse an output whose folder is missing before any long work is done."""
    if not output.parent.is_dir():
        raise LogWriteError(
            f"cannot write {output}: folder {output.parent} does not exist; create it first"
        )


_IMAGE_TYPES = (rosmsg.IMAGE, rosmsg.COMPRESSED_IMAGE)


def _check_topic_types(reader: LogReader, checks: list[tuple[str, str, tuple[str, ...]]]) -> None:
    """Check that topics have a usable message type.

    Args:
        reader: the open log.
        checks: (topic, option that names it, accepted types) each; absent topics pass.

    Raises:
        LogReadError: naming the topic, its type, the accepted types, the topics of those
            types in the log and the option to pass.
    """
    topics = reader.topics()
    for topic, option, accepted in checks:
        info = topics.get(topic)
        if info is None or info.msgtype in accepted:
            continue
        candidates = ", ".join(t for t, i in topics.items() if i.msgtype in accepted) or "none"
        raise LogReadError(
            f"topic {topic} in {reader.path.name} has type {info.msgtype or 'unknown'}, not "
            f"{' or '.join(accepted)}; topics of that type: {candidates}; pass {option}"
        )


def _pairing_types(pairing: PairingConfig) -> list[tuple[str, str, tuple[str, ...]]]:
    """Return the type checks of the topics a stereo pairing reads."""
    checks = [
        (pairing.left_topic, "--left-topic", _IMAGE_TYPES),
        (pairing.right_topic, "--right-topic", _IMAGE_TYPES),
        (pairing.left_info_topic, "--left-info-topic", (rosmsg.CAMERA_INFO,)),
        (pairing.right_info_topic, "--right-info-topic", (rosmsg.CAMERA_INFO,)),
    ]
    if pairing.features_topic is not None:
        checks.append((pairing.features_topic, "--features-topic", (rosmsg.POINT_CLOUD2,)))
    return checks


def _require_topics(reader: LogReader, options: dict[str, str], wanted: str) -> None:
    """Check the topics a job reads (topic -> option), naming an empty or damaged log as such.

    Raises:
        LogReadError: the log has no topics at all, or misses a topic and is damaged (then
            the topic may be in the unreadable part: "pass --left-topic" would mislead).
        TopicNotFoundError: an intact log misses a topic (names the topics and the option).
    """
    try:
        reader.require_topics(options)
    except TopicNotFoundError as err:
        topics = reader.topics()
        if reader.damage:
            missing = next(topic for topic in options if topic not in topics)
            raise LogReadError(
                f"no {wanted} found in {reader.path}: it is damaged "
                f"({'; '.join(reader.damage[:2])}) and its readable part has no topic "
                f"{missing}; repair or re-record the log"
            ) from err
        if all(info.message_count == 0 for info in topics.values()):
            listed = f" on topics {', '.join(topics)}" if topics else ""
            raise LogReadError(
                f"no {wanted} found in {reader.path}: it has no messages{listed}; "
                "pass a log recorded with stereo images"
            ) from err
        raise


# ----------------------------------------------------------------------------- synth


def synth(out: Path, *, frames: int, seed: int, scale: float, fmt: str | None) -> WriteSummary:
    """Render a synthetic drive and write it as a log (``pcainterp synth``)."""
    from pcainterp_stream.synth import SynthConfig, generate
    from pcainterp_stream.synthlog import write_synthetic_log

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
    from pcainterp_stream.kitti import import_kitti as convert

    if max_frames is not None and max_frames < 1:
        raise PcaInterpError(f"--max-frames must be at least 1, got {max_frames}")
    with _bar(None, f"import {folder.name}") as bar:

        def progress(done: int, total: int | None) -> None:
            bar.total = total
            bar.update(done - bar.n)

        return convert(folder, out, max_frames=max_frames, progress=progress)


# ----------------------------------------------------------------------------- learn


@dataclass(frozen=True)
class LearnOptions:
    """Options of ``pcainterp learn``.

    Attributes:
        n_components: components to keep (the most, with ``variance``).
        variance: keep the fewest components reaching this explained-variance ratio.
        grid_scale: basis grid pixels per image pixel.
        depth_topic: learn from this depth topic (32FC1, m) instead of SGBM maps.
        every: use every N-th frame.
        sgbm: matcher options for SGBM maps (and the fitting frames' lookups).
        fit_prior: fit the hybrid prior, the noise level and the temporal process noise by
            the evidence on frames the basis does not see (``fitting.py``).
        holdout: with ``fit_prior`` and no ``fit_logs``: the share of each log's frames,
            at its end, kept out of the basis for the fit.
        fit_logs: fit on these logs (all frames) instead of a held-out share.
        gftt: corner options of the fitting frames' measurements.
    """

    n_components: int = 500
    variance: float | None = None
    grid_scale: float = 0.25
    depth_topic: str | None = None
    every: int = 1
    sgbm: SgbmConfig = dataclasses.field(default_factory=SgbmConfig)
    fit_prior: bool = False
    holdout: float = 0.2
    fit_logs: tuple[Path, ...] = ()
    gftt: GfttConfig = dataclasses.field(default_factory=GfttConfig)


@dataclass(frozen=True)
class _MapSource:
    image_size: tuple[int, int]
    focal_baseline: float


def _depth_maps(
    log: Path, options: LearnOptions, pairing: PairingConfig, info: list[_MapSource]
) -> Iterator[npt.NDArray[np.float32]]:
    """Yield disparity maps f*b/depth of a depth topic; no surface (NaN, inf) is d = 0."""
    assert options.depth_topic is not None
    with open_log(log) as reader:
        _require_topics(
            reader,
            {
                options.depth_topic: "--depth-topic",
                pairing.left_info_topic: "--left-info-topic",
                pairing.right_info_topic: "--right-info-topic",
            },
            "depth image",
        )
        _check_topic_types(
            reader,
            [
                (options.depth_topic, "--depth-topic", (rosmsg.IMAGE,)),
                *_pairing_types(dataclasses.replace(pairing, features_topic=None))[2:],
            ],
        )
        infos: dict[str, Any] = {}
        index = 0
        topics = [options.depth_topic, pairing.left_info_topic, pairing.right_info_topic]
        for raw in reader.messages(topics):
            message = reader.decode(raw)
            if raw.topic != options.depth_topic:
                infos[raw.topic] = message
                continue
            index += 1
            if (index - 1) % options.every:
                continue
            if len(infos) < 2:
                continue  # no calibration yet
            try:
                depth = rosmsg.image_array(message).astype(np.float32)
                if depth.ndim != 2:
                    raise ValueError(f"encoding {message.encoding!r} has {depth.shape[2]} channels")
            except ValueError as err:
                raise LogReadError(
                    f"depth image on {options.depth_topic} at log time {raw.log_time_ns} ns in "
                    f"{log.name} is unusable ({err}); pass a 32FC1 depth topic (m) as --depth-topic"
                ) from err
            from pcainterp_stream.pairing import camera_from_infos

            camera = camera_from_infos(
                infos[pairing.left_info_topic],
                infos[pairing.right_info_topic],
                width=depth.shape[1],
                height=depth.shape[0],
                left_topic=pairing.left_info_topic,
                right_topic=pairing.right_info_topic,
                baseline=pairing.baseline,
            )
            if not info:
                info.append(_MapSource(camera.image_size, camera.focal_baseline))
            with np.errstate(divide="ignore", invalid="ignore"):
                disparity = camera.focal_baseline / depth
            yield np.where(np.isfinite(disparity) & (depth > 0), disparity, 0.0).astype(np.float32)


def _sgbm_maps(
    log: Path, options: LearnOptions, pairing: PairingConfig, info: list[_MapSource]
) -> Iterator[npt.NDArray[np.float32]]:
    """Yield SGBM maps of every N-th pair, matching the next pair while this one is used."""
    with open_log(log) as reader, ThreadPoolExecutor(1, thread_name_prefix="sgbm") as pool:
        _require_topics(reader, pairing.required_topics(), "stereo pair")
        _check_topic_types(reader, _pairing_types(pairing))
        pending: list[Future[npt.NDArray[np.float32]]] = []
        for frame in iter_stereo_frames(reader, pairing):
            if frame.index % options.every:
                continue
            if not info:
                info.append(_MapSource(frame.camera.image_size, frame.camera.focal_baseline))
            pending.append(pool.submit(compute_disparity, frame.left, frame.right, options.sgbm))
            if len(pending) > 1:
                yield pending.pop(0).result()
        for future in pending:
            yield future.result()


def _expected_frames(log: Path, topic: str, every: int) -> int | None:
    with contextlib.suppress(PcaInterpError), open_log(log) as reader:
        count = reader.topics().get(topic)
        if count is not None and count.message_count is not None:
            return -(-count.message_count // every)
    return None


def learn(logs: list[Path], output: Path, options: LearnOptions, pairing: PairingConfig) -> Basis:
    """Learn a basis from the disparity maps of logs (``pcainterp learn``)."""
    if options.every < 1:
        raise PcaInterpError(f"--every must be at least 1, got {options.every}")
    for log in logs:
        if log.resolve() == output.resolve():
            raise PcaInterpError(f"output {output} is one of the input logs; choose another -o")
    _check_output_folder(output)
    source = options.depth_topic or pairing.left_topic
    totals = [_expected_frames(log, source, options.every) for log in logs]
    total = None if None in totals else sum(t for t in totals if t is not None)
    info: list[_MapSource] = []

    holding_out = options.fit_prior and not options.fit_logs
    if holding_out and not 0 < options.holdout < 1:
        raise PcaInterpError(f"--holdout must be in (0, 1), got {options.holdout}")
    kept: list[int | None] = [None] * len(logs)
    if holding_out:
        for index, count in enumerate(totals):
            if count is None:
                raise PcaInterpError(
                    f"{logs[index]} does not say how many frames it has, so no share can be held "
                    "out; pass --fit-logs LOG to fit the prior on other logs"
                )
            kept[index] = max(1, int(count * (1.0 - options.holdout)))
        total = sum(k for k in kept if k is not None)

    def maps() -> Iterator[npt.NDArray[np.float32]]:
        for log, keep in zip(logs, kept, strict=True):
            produce = _depth_maps if options.depth_topic else _sgbm_maps
            for disparity in itertools.islice(produce(log, options, pairing, info), keep):
                if disparity.shape != info[0].image_size:
                    raise PcaInterpError(
                        f"{log} has {disparity.shape[1]}x{disparity.shape[0]} images but the "
                        f"first log has {info[0].image_size[1]}x{info[0].image_size[0]}; "
                        "learn one basis per camera"
                    )
                yield disparity

    sgbm = dataclasses.asdict(options.sgbm)
    sgbm["mode"] = options.sgbm.mode.name
    meta = {
        "source": {
            "logs": [str(log) for log in logs],
            "maps": f"depth topic {options.depth_topic}" if options.depth_topic else "SGBM",
            "sgbm": None if options.depth_topic else sgbm,
            "every": options.every,
        }
    }
    with _bar(total, "learn") as bar:
        stream = maps()
        first = next(stream, None)
        if first is None:
            raise LogReadError(
                f"no {'depth image' if options.depth_topic else 'stereo pair'} found in "
                f"{', '.join(map(str, logs))}; check the topic options (pcainterp info LOG)"
            )
        try:
            basis = learn_basis(
                itertools.chain([first], stream),
                n_components=options.n_components,
                variance=options.variance,
                grid_scale=options.grid_scale,
                focal_baseline=info[0].focal_baseline,
                progress=lambda done: bar.update(done - bar.n),
                meta=meta,
            )
        except ValueError as err:
            raise PcaInterpError(f"cannot learn a basis from {len(logs)} log(s): {err}") from err
    if options.fit_prior:
        if holding_out:
            sources = [
                (log, (keep or 0) * options.every) for log, keep in zip(logs, kept, strict=True)
            ]
        else:
            sources = [(log, 0) for log in options.fit_logs]
        fitted = fit_prior(basis, sources, options, pairing)
        basis = dataclasses.replace(basis, meta={**basis.meta, "prior": fitted})
    basis.save(output)
    return basis


FIT_MAX_FRAMES = 16
"""Frames used by the evidence fit of the local prior (evenly spread over the fit frames)."""

CALIBRATION_EVERY = 4
"""Every N-th held-out frame is densified to calibrate the std (``fitting.fit_std_scale``)."""


FIT_SEQUENCE_FRAMES = 16
"""Consecutive held-out frames measured per log (with --fit-logs: per fit log); they are the
fit's frames and the sequences of the temporal process-noise fit."""


def fit_prior(
    basis: Basis, sources: list[tuple[Path, int]], options: LearnOptions, pairing: PairingConfig
) -> dict[str, Any]:
    """Fit the hybrid prior, sigma and the process noise on frames outside the basis.

    Args:
        basis: the learned basis.
        sources: (log, first pair index) to measure: GFTT + SGBM lookups of every pair from
            that index on, as ``densify`` measures them.
        options: the learning options (SGBM and GFTT settings).
        pairing: topics of the stereo pairs.

    Returns:
        The JSON-ready ``meta["prior"]`` of the basis.
    """
    from pcainterp_stream import fitting
    from pcainterp_stream.stereo import StereoFrontEnd

    front_end = StereoFrontEnd(options.gftt, options.sgbm)
    sequences: list[list[fitting.FitFrame]] = []
    calibration: list[fitting.CalibrationFrame] = []
    started = time.perf_counter()
    with _bar(None, "fit prior (measure held-out frames)") as bar:
        for log, first in sources:
            sequence: list[fitting.FitFrame] = []
            with open_log(log) as reader:
                _require_topics(reader, pairing.required_topics(), "stereo pair")
                for frame in iter_stereo_frames(reader, pairing):
                    if frame.index < first:
                        continue
                    if len(sequence) >= FIT_SEQUENCE_FRAMES:
                        break
                    measured = front_end.measure(frame.left, frame.right)
                    size, fb = frame.camera.image_size, frame.camera.focal_baseline
                    sequence.append(
                        fitting.fit_frame(
                            basis,
                            measured.pixels,
                            measured.disparities,
                            image_size=size,
                            focal_baseline=fb,
                        )
                    )
                    if (frame.index - first) % CALIBRATION_EVERY == 0:
                        calibration.append(
                            fitting.CalibrationFrame(
                                measured.pixels,
                                measured.disparities,
                                size,
                                fb,
                                measured.disparity_map,
                            )
                        )
                    bar.update(1)
            sequences.append(sequence)
    if not any(frame.residual.size for sequence in sequences for frame in sequence):
        raise PcaInterpError(
            "no held-out stereo pair with measurements to fit the prior on; use more frames, a "
            "larger --holdout or --fit-logs LOG"
        )
    _echo("fitting the prior by the evidence on the held-out frames")
    fitted = fitting.fit_prior(
        basis,
        sequences,
        calibration,
        max_frames=FIT_MAX_FRAMES,
        sequence_frames=FIT_SEQUENCE_FRAMES,
        robust=ProcessorConfig().robust,
    )
    fitted.update(
        {
            "std_scale_reference": "SGBM maps of the held-out frames",
            "fit_logs": [str(log) for log, _ in sources],
            "seconds": round(time.perf_counter() - started, 1),
        }
    )
    return fitted


# ----------------------------------------------------------------------------- densify


@dataclass
class DensifySummary:
    """What ``densify`` did.

    Attributes:
        input: the input log.
        output: the written log.
        frames: frames densified.
        seconds: wall time of the whole run.
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
    """

    input: Path
    output: Path
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

    @property
    def frames_per_second(self) -> float:
        """Return densified frames per wall-clock second."""
        return self.frames / self.seconds if self.seconds > 0 else 0.0


def densify(
    input_path: Path,
    output: Path,
    basis: Basis | Path,
    *,
    pairing: PairingConfig | None = None,
    processor: ProcessorConfig | None = None,
    topics: OutputTopics | None = None,
    rrd: Path | None = None,
    spawn_viewer: bool = False,
    on_frame: Callable[[DensifiedFrame], None] | None = None,
) -> DensifySummary:
    """Densify a stereo log into a copy with the ``/pcainterp/*`` channels (``densify``).

    One pass over the input: every message is copied to the output, stereo pairs are
    formed by header stamp, stereo-matched ahead in a worker thread and densified in
    batches, and their outputs written at the left image's log time.
    """
    started = time.perf_counter()
    pairing = pairing or PairingConfig()
    processor = processor or ProcessorConfig()
    topics = topics or OutputTopics()
    if isinstance(basis, Path):
        basis = Basis.load(basis)
    if processor.source is MeasurementSource.FEATURES and pairing.features_topic is None:
        raise PcaInterpError("measurement source 'features' needs --features-topic")
    measurements = 0
    frames = 0
    robust = {"downweighted": 0, "most": 0, "resets": 0, "carried": 0, "carry_resets": 0}
    with contextlib.ExitStack() as stack:
        reader = stack.enter_context(open_log(input_path))
        _require_topics(reader, pairing.required_topics(), "stereo pair")
        _check_topic_types(reader, _pairing_types(pairing))
        clash = sorted(set(topics.all()) & set(reader.topics()))
        if clash:
            raise PcaInterpError(
                f"{input_path} already has {', '.join(clash)}; densify the original log or "
                "pass --output-prefix to write under another name"
            )
        left = reader.topics().get(pairing.left_topic)
        total = left.message_count if left is not None else None
        writer = stack.enter_context(open_writer(output, LogFormat.MCAP, inputs=[input_path]))
        sink = (
            stack.enter_context(RerunSink(rrd_path=rrd, spawn=spawn_viewer))
            if rrd is not None or spawn_viewer
            else None
        )
        engine = stack.enter_context(FrameProcessor(basis, processor))
        pairer = StereoPairer(pairing)
        bar = stack.enter_context(_bar(total, f"densify {input_path.name}"))

        def emit(results: list[DensifiedFrame]) -> None:
            nonlocal measurements, frames
            for result in results:
                for topic, message in output_messages(result, topics):
                    writer.add_message(topic, message, result.frame.log_time_ns)
                if sink is not None:
                    sink.log(result)
                if on_frame is not None:
                    on_frame(result)
                measurements += int(result.pixels.shape[0])
                frames += 1
                robust["downweighted"] += result.counts.get("downweighted", 0)
                robust["most"] = max(robust["most"], result.counts.get("downweighted", 0))
                robust["resets"] += result.counts.get("temporal_reset", 0)
                robust["carried"] += result.counts.get("carried", 0)
                robust["carry_resets"] += result.counts.get("carry_reset", 0)
                bar.update(1)

        for raw in reader.messages():
            writer.add_raw(raw)
            if pairer.wants(raw.topic):
                for frame in pairer.push_raw(raw, reader.decode):
                    emit(engine.submit(frame, pairer.features_for(frame)))
        for frame in pairer.flush():
            emit(engine.submit(frame, pairer.features_for(frame)))
        emit(engine.finish())
        stats = pairer.finish()
        if frames == 0:
            raise LogReadError(_no_pair_message(input_path, pairing, stats, reader.damage))
    return DensifySummary(
        input=input_path,
        output=output,
        frames=frames,
        seconds=time.perf_counter() - started,
        measurements=measurements,
        pairing=stats,
        damage=list(reader.damage),
        written=writer.summary(),
        warnings=list(reader.warnings),
        downweighted=robust["downweighted"],
        most_downweighted=robust["most"],
        temporal_resets=robust["resets"],
        carried=robust["carried"],
        carry_resets=robust["carry_resets"],
    )


def _no_pair_message(
    path: Path, pairing: PairingConfig, stats: PairingStats, damage: list[str]
) -> str:
    """Return the one-line error of a log without a single usable stereo pair."""
    details = "; ".join([stats.summary(), *stats.problems[:1], *damage[:2]])
    if stats.undecodable:
        fix = "convert the images to mono8, rgb8 or bgr8 (or png/jpeg CompressedImage)"
    elif stats.size_mismatches:
        fix = "left and right images of a rectified pair must have the same size"
    elif damage:
        fix = "the readable part of the log has no complete pair; repair or re-record it"
    else:
        fix = (
            f"left {pairing.left_topic} and right {pairing.right_topic} need images with "
            "matching header stamps and camera infos on both sides (see pcainterp info, "
            "--stamp-tolerance-ms)"
        )
    return f"no stereo pair found in {path} ({details}); {fix}"


# ----------------------------------------------------------------------------- evaluate


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
    from pcainterp_stream.evaluation import Mode
    from pcainterp_stream.report import EvaluateOptions, summary_table, write_report

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


# ----------------------------------------------------------------------------- info


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
    from pcainterp_stream.loginfo import describe, format_info

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


# ----------------------------------------------------------------------------- demo


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
    from pcainterp_stream.processor import resolve_settings

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


# ----------------------------------------------------------------------------- dispatch


def _sgbm_config(args: argparse.Namespace) -> SgbmConfig:
    changes: dict[str, Any] = {}
    if args.num_disparities is not None:
        if args.num_disparities < 16 or args.num_disparities % 16:
            raise PcaInterpError(
                f"--num-disparities must be a positive multiple of 16, got {args.num_disparities}"
            )
        changes["num_disparities"] = args.num_disparities
    if args.block_size is not None:
        if args.block_size < 1 or args.block_size % 2 == 0:
            raise PcaInterpError(f"--block-size must be odd and positive, got {args.block_size}")
        changes["block_size"] = args.block_size
    if args.sgbm_mode is not None:
        changes["mode"] = SgbmMode[args.sgbm_mode.upper()]
    if args.stereo_downscale is not None:
        changes["downscale"] = args.stereo_downscale
    return dataclasses.replace(SgbmConfig(), **changes)


def _gftt_config(args: argparse.Namespace) -> GfttConfig:
    changes: dict[str, Any] = {}
    if args.corners is not None:
        if args.corners < 1:
            raise PcaInterpError(f"--corners must be at least 1, got {args.corners}")
        changes["max_corners"] = args.corners
    if args.quality is not None:
        if not 0 < args.quality < 1:
            raise PcaInterpError(f"--quality must be in (0, 1), got {args.quality}")
        changes["quality_level"] = args.quality
    if args.min_distance is not None:
        if not args.min_distance >= 0:
            raise PcaInterpError(f"--min-distance must be >= 0 px, got {args.min_distance}")
        changes["min_distance"] = args.min_distance
    return dataclasses.replace(GfttConfig(), **changes)


def _pairing_config(args: argparse.Namespace, features_topic: str | None = None) -> PairingConfig:
    if args.left_topic == args.right_topic:
        raise PcaInterpError(
            f"--left-topic and --right-topic are both {args.left_topic}; a stereo pair needs the "
            "images of two cameras: pass the right camera's topic as --right-topic"
        )
    if not 0 <= args.stamp_tolerance_ms < float("inf"):
        raise PcaInterpError(f"--stamp-tolerance-ms must be >= 0, got {args.stamp_tolerance_ms}")
    if args.baseline is not None and not 0 < args.baseline < float("inf"):
        raise PcaInterpError(f"--baseline must be a finite number > 0 m, got {args.baseline}")
    return PairingConfig(
        left_topic=args.left_topic,
        right_topic=args.right_topic,
        left_info_topic=args.left_info_topic,
        right_info_topic=args.right_info_topic,
        features_topic=features_topic,
        tolerance_ns=round(args.stamp_tolerance_ms * 1e6),
        baseline=args.baseline,
    )


def _sigma_option(value: str) -> float | str:
    if value in ("auto", "evidence"):
        return value
    try:
        sigma = float(value)
    except ValueError:
        sigma = float("nan")
    if not 0 < sigma < float("inf"):
        raise PcaInterpError(f"--sigma must be a number > 0 px, 'evidence' or 'auto', got {value}")
    return sigma


def _check_estimate(processor: ProcessorConfig, basis_path: Path) -> None:
    """Refuse estimate options that do not fit the basis, before any work is done."""
    if (processor.prior == "paper" and not processor.temporal) or not basis_path.is_file():
        return  # a missing basis is reported where it is loaded
    from pcainterp_stream.processor import resolve_settings

    try:
        settings = resolve_settings(Basis.load(basis_path), processor)
    except ValueError as err:
        raise PcaInterpError(f"--prior {processor.prior} with {basis_path}: {err}") from err
    if processor.uncertainty == "paper" and (settings.local_prior or processor.temporal):
        raise PcaInterpError(
            "--uncertainty paper is the paper's diagonal approximation of its own prior, but "
            f"{basis_path} has a fitted local prior or --temporal is on; pass --prior paper "
            "--no-temporal with it, or use --uncertainty exact"
        )


def _print_written(summary: WriteSummary) -> None:
    duration = ((summary.end_ns or 0) - (summary.start_ns or 0)) / 1e9
    _echo(f"wrote {summary.path}: {summary.message_count} messages, {duration:.1f} s of log")


def _densify_many(args: argparse.Namespace, processor: ProcessorConfig) -> int:
    """Densify several logs into ``--out-dir`` on Dask; exit code 1 if any log failed."""
    from pcainterp_stream import distributed

    if args.rrd is not None or args.rerun:
        raise PcaInterpError("--rrd/--rerun take one log; use -o OUTPUT without --out-dir")
    if args.workers is not None and args.workers < 1:
        raise PcaInterpError(f"--workers must be at least 1, got {args.workers}")
    if not args.basis.exists():
        raise PcaInterpError(f"basis {args.basis} does not exist; learn one with pcainterp learn")
    started = time.perf_counter()
    with distributed.connect(args.scheduler, args.workers) as client:
        outcomes = distributed.densify_many(
            [path.resolve() for path in args.input],  # workers may run in another folder
            args.out_dir.resolve(),
            args.basis.resolve(),
            client,
            pairing=_pairing_config(args, args.features_topic),
            processor=processor,
            topics=OutputTopics.with_prefix(args.output_prefix, depth_mm=args.depth_mm),
        )
    failed = 0
    for outcome in outcomes:
        if outcome.error is None:
            _echo(f"densified {outcome.frames} frames of {outcome.input} -> {outcome.output}")
        else:
            failed += 1
            error = outcome.error
            if outcome.input.name not in error:
                error = f"{outcome.input}: {error}"
            print(f"pcainterp: error: {error}", file=sys.stderr)
    frames = sum(outcome.frames for outcome in outcomes)
    _echo(
        f"{len(outcomes) - failed} of {len(outcomes)} logs densified, {frames} frames in "
        f"{time.perf_counter() - started:.1f} s"
    )
    return 1 if failed else 0


def run(args: argparse.Namespace) -> int:
    """Run the job a parsed command line asks for; return the exit code."""
    command = args.command
    if command == "synth":
        _print_written(
            synth(args.out, frames=args.frames, seed=args.seed, scale=args.scale, fmt=args.format)
        )
    elif command == "import-kitti":
        _print_written(import_kitti(args.kitti_dir, args.out, max_frames=args.max_frames))
    elif command == "learn":
        if args.components is not None and args.components < 1:
            raise PcaInterpError(f"--components must be at least 1, got {args.components}")
        if args.variance is not None and not 0 < args.variance <= 1:  # also refuses nan
            raise PcaInterpError(f"--variance must be in (0, 1], got {args.variance}")
        if args.grid_scale is not None and not 0 < args.grid_scale <= 1:
            raise PcaInterpError(f"--grid-scale must be in (0, 1], got {args.grid_scale}")
        options = LearnOptions(
            n_components=args.components or 500,
            variance=args.variance,
            grid_scale=args.grid_scale or 0.25,
            depth_topic=args.depth_topic,
            every=args.every,
            sgbm=_sgbm_config(args),
            fit_prior=args.fit_prior or bool(args.fit_logs),
            holdout=args.holdout,
            fit_logs=tuple(args.fit_logs),
        )
        if args.workers is not None and args.workers < 1:
            raise PcaInterpError(f"--workers must be at least 1, got {args.workers}")
        if options.fit_prior and (args.scheduler is not None or args.workers is not None):
            raise PcaInterpError(
                "--fit-prior runs in this process; learn on the cluster without it, or drop "
                "--scheduler/--workers"
            )
        if args.scheduler is not None or args.workers is not None:
            from pcainterp_stream import distributed

            with distributed.connect(args.scheduler, args.workers) as client:
                basis = distributed.learn_distributed(
                    [log.resolve() for log in args.logs],
                    args.output,
                    options,
                    _pairing_config(args),
                    client,
                )
        else:
            basis = learn(args.logs, args.output, options, _pairing_config(args))
        _echo(f"wrote {args.output}")
        _echo(describe_basis(args.output))
        del basis
    elif command == "densify":
        source = MeasurementSource.FEATURES if args.features_topic else MeasurementSource.STEREO
        if args.process_noise is not None and not 0 < args.process_noise < float("inf"):
            raise PcaInterpError(f"--process-noise must be > 0, got {args.process_noise}")
        if args.carry_frames < 0:
            raise PcaInterpError(f"--carry-frames must be >= 0, got {args.carry_frames}")
        processor = ProcessorConfig(
            gftt=_gftt_config(args),
            sgbm=_sgbm_config(args),
            sigma=_sigma_option(args.sigma),
            uncertainty=args.uncertainty,
            prior=args.prior,
            robust=args.robust,
            temporal=args.temporal,
            process_noise=args.process_noise,
            carry=dataclasses.replace(ProcessorConfig().carry, frames=args.carry_frames),
            calibrate=args.calibrate,
            source=source,
        )
        _check_estimate(processor, args.basis)
        if args.out_dir is not None:
            return _densify_many(args, processor)
        if len(args.input) > 1:
            raise PcaInterpError(
                f"-o takes one input but {len(args.input)} were given; "
                "pass --out-dir DIR to densify several logs"
            )
        if args.scheduler is not None or args.workers is not None:
            raise PcaInterpError("--scheduler/--workers need --out-dir DIR instead of -o")
        summary = densify(
            args.input[0],
            args.output,
            args.basis,
            pairing=_pairing_config(args, args.features_topic),
            processor=processor,
            topics=OutputTopics.with_prefix(args.output_prefix, depth_mm=args.depth_mm),
            rrd=args.rrd,
            spawn_viewer=args.rerun,
        )
        _echo(
            f"densified {summary.frames} frames of {summary.input} in {summary.seconds:.1f} s "
            f"({summary.frames_per_second:.1f} frames/s), "
            f"{summary.measurements / max(summary.frames, 1):.0f} points per frame"
        )
        _echo(f"pairing: {summary.pairing.summary()}")
        if processor.robust != "none":
            _echo(
                f"robust ({processor.robust}): {summary.downweighted} measurements down-weighted "
                f"({summary.downweighted / max(summary.frames, 1):.1f} per frame, at most "
                f"{summary.most_downweighted} in one frame)"
            )
        if processor.temporal:
            _echo(f"temporal prior: reset {summary.temporal_resets} times (scene changes)")
        if processor.carry.frames:
            _echo(
                f"carried from the {processor.carry.frames} previous frames: "
                f"{summary.carried / max(summary.frames, 1):.0f} points per frame; "
                f"ego-motion lost {summary.carry_resets} times"
            )
        for line in summary.damage:
            _echo(f"damage: {line}")
        for line in summary.warnings:
            _echo(f"warning: {line}")
        if summary.written is not None:
            _print_written(summary.written)
        if args.rrd is not None:
            _echo(f"wrote {args.rrd}")
    elif command == "evaluate":
        folder, table = evaluate(
            args.input,
            args.output,
            basis=args.basis,
            mode=args.mode,
            sigma=args.sigma,
            sweep_every=args.sweep_every,
            max_frames=args.max_frames,
            topics=OutputTopics.with_prefix(args.output_prefix),
        )
        _echo(table)
        _echo(f"wrote {folder}/results.md, results.json and figures")
    elif command == "info":
        _echo(info(args.file))
    elif command == "demo":
        _echo(demo(args.out, spawn_viewer=args.rerun))
    else:  # pragma: no cover - argparse rejects unknown commands
        raise PcaInterpError(f"unknown command {command}")
    return 0
