"""Helpers the jobs share: progress bars, messages, checks of output folders and topics."""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Self, TextIO

from pcainterp_stream.errors import (
    LogReadError,
    PcaInterpError,
    TopicNotFoundError,
)
from pcainterp_stream.frontend.pairing import (
    PairingConfig,
)
from pcainterp_stream.frontend.pairing_stats import PairingStats
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.depth_image import (
    DEPTH_TYPES,
    depth_metres,
    depth_topics,
    first_message,
)
from pcainterp_stream.io.logreader import LogReader, open_log
from pcainterp_stream.io.output_paths import check_output_file

if TYPE_CHECKING:
    from tqdm import tqdm


PLAIN_PROGRESS_EVERY_S = 60.0
"""Off a terminal, the longest a job stays silent: one plain progress line at most this often.

CI services end a step that prints nothing for 10 minutes (CircleCI's ``no_output_timeout``,
Travis); a minute keeps well inside that, and a job shorter than a minute prints no such
line at all."""


class _Unshown:
    """The progress bar where there is no standard error: counts as ``tqdm`` does."""

    def __init__(self, total: int | None) -> None:
        self.total = total
        self.n = 0

    def update(self, n: int = 1) -> None:
        self.n += n

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


class _PlainProgress(_Unshown):
    """The progress bar off a terminal: a plain line (no carriage return) every ``every_s``.

    ``densify x.mcap: 1200/72000 frames, 20.1 frames/s, ETA 59 min`` on ``stream``, so a
    CI log shows that a long job is alive and how far it is; none in the first
    ``every_s`` seconds, so a short job's output is unchanged.

    Args:
        total: the count expected, None if unknown (then no ETA).
        description: the line's start (the job and its input).
        unit: what is counted (``frame``; ``s`` is appended for the plural).
        every_s: seconds between two lines (:data:`PLAIN_PROGRESS_EVERY_S` if None).
        clock: monotonic seconds (a fake one in tests).
        stream: where the lines go (standard error by default).
    """

    def __init__(
        self,
        total: int | None,
        description: str,
        unit: str = "frame",
        *,
        every_s: float | None = None,
        clock: Callable[[], float] = time.monotonic,
        stream: TextIO | None = None,
    ) -> None:
        super().__init__(total)
        self.description = description
        self.unit = unit
        self.every_s = PLAIN_PROGRESS_EVERY_S if every_s is None else every_s
        self.clock = clock
        self.stream = stream
        self.started = clock()
        self._next = self.started + self.every_s

    def update(self, n: int = 1) -> None:
        super().update(n)
        now = self.clock()
        if now < self._next:
            return
        self._next = now + self.every_s
        stream = self.stream if self.stream is not None else sys.stderr
        print(self.line(now), file=stream, flush=True)

    def line(self, now: float) -> str:
        """Return the progress line at clock time ``now``."""
        elapsed = max(now - self.started, 1e-9)
        rate = self.n / elapsed
        plural = f"{self.unit}s"
        done = f"{self.n}/{self.total}" if self.total else f"{self.n}"
        text = f"{self.description}: {done} {plural}, {rate:.1f} {plural}/s"
        if self.total and rate > 0 and self.n <= self.total:
            text += f", ETA {_duration((self.total - self.n) / rate)}"
        return text


def _duration(seconds: float) -> str:
    """Say a duration as a person reads it: ``40 s``, ``59 min``, ``3.2 h``."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 100 * 60:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _bar(total: int | None, description: str, unit: str = "frame") -> tqdm[Any] | _Unshown:
    """Return a progress bar on standard error: ``tqdm`` on a terminal, plain lines off one.

    Off a terminal (logs, pipes, CI, tests) a redrawn bar would fill the log with
    carriage-return lines, so a plain line is printed every :data:`PLAIN_PROGRESS_EVERY_S`
    instead (:class:`_PlainProgress`), and ``tqdm`` is not even imported: its import and the
    process-wide lock it makes cost a job ~10 ms of start-up.
    """
    isatty = getattr(sys.stderr, "isatty", None)  # None where there is no standard error
    if isatty is None:
        return _Unshown(total)
    if not isatty():
        return _PlainProgress(total, description, unit)
    from tqdm import tqdm

    return tqdm(total=total, desc=description, unit=unit, leave=False, file=sys.stderr)


def _echo(text: str) -> None:
    print(text, flush=True)


def _check_output_folder(output: Path) -> None:
    """Refuse, before any long work, an output that cannot be written.

    Raises:
        LogWriteError: its folder is missing, a file or not writable, or the output is a
            device, a pipe or a socket (:func:`io.output_paths.check_output_file`).
    """
    check_output_file(output)


_IMAGE_TYPES = (rosmsg.IMAGE, rosmsg.COMPRESSED_IMAGE)
_OLD_POINT_CLOUDS = ("sensor_msgs/msg/PointCloud", "sensor_msgs/PointCloud")


def _check_topic_types(reader: LogReader, checks: list[tuple[str, str, tuple[str, ...]]]) -> None:
    """Check that topics have a usable message type.

    Args:
        reader: the open log.
        checks: (topic, option that names it, accepted types) each; absent topics pass.

    Raises:
        LogReadError: naming the topic, its type, the accepted types, the topics of those
            types in the log and the option to pass (none: that the log has no such topic);
            an old ``sensor_msgs/PointCloud`` as a feature stream is named as such.
    """
    topics = reader.topics()
    for topic, option, accepted in checks:
        info = topics.get(topic)
        if info is None or info.msgtype in accepted:
            continue
        candidates = ", ".join(t for t, i in topics.items() if i.msgtype in accepted)
        # another topic of the type to pass, or none: then the option already given cannot help
        other = (
            f"topics of that type: {candidates}; pass {option}"
            if candidates
            else "the log has no topic of that type"
        )
        if info.msgtype in _OLD_POINT_CLOUDS:
            raise LogReadError(
                f"topic {topic} in {reader.path.name} has the old type {info.msgtype} (as VINS "
                "feature_tracker's features: normalized image coordinates, depth unknown); "
                f"{option} needs a {rosmsg.POINT_CLOUD2} of 3-D points in metres in the left "
                "optical frame (VINS's /vins_estimator/point_cloud, say, converted to "
                f"PointCloud2 and transformed into that frame); {other}"
            )
        raise LogReadError(
            f"topic {topic} in {reader.path.name} has type {info.msgtype or 'unknown'}, not "
            f"{' or '.join(accepted)}; {other}"
        )


def _check_depth_topic(reader: LogReader, topic: str) -> None:
    """Check that a ``--depth-topic`` holds depth: its type and its first message.

    Raises:
        LogReadError: a topic of another type, or of camera images (mono8, rgb8, png,
            jpeg): names it and the log's depth topics.
    """
    info = reader.topics().get(topic)
    if info is None:
        return
    problem = None
    if info.msgtype not in DEPTH_TYPES:
        problem = f"has type {info.msgtype or 'unknown'}, not a depth image"
    else:
        raw = first_message(reader, topic)
        try:
            if raw is not None:
                depth_metres(reader.decode(raw))
        except ValueError as err:
            problem = f"is unusable as depth: {err}"
    if problem is not None:
        candidates = ", ".join(t for t in depth_topics(reader) if t != topic) or "none"
        raise LogReadError(
            f"topic {topic} in {reader.path.name} {problem}; depth topics in the log: "
            f"{candidates}; pass a depth topic (32FC1 m, 16UC1 mm or compressedDepth) "
            "as --depth-topic"
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


def damage_at_open(logs: Sequence[Path]) -> list[str]:
    """Return the damage the logs show when opened, one line each.

    A truncated MCAP's missing footer and summary is found without reading the messages.
    """
    lines: list[str] = []
    for log in logs:
        with contextlib.suppress(PcaInterpError), open_log(log) as reader:
            lines += reader.damage
    return lines


def readable_frames(
    log: Path, topic: str, every: int, also: Sequence[str] = ()
) -> tuple[int, list[str]]:
    """Count a topic's messages by reading them (every N-th); return it and the log's damage.

    The damage the reader met on the way reading ``topic`` and the topics ``also`` (a
    cut-off bag, a corrupt chunk skipped), which the log's summary or index does not show
    (bug hunt 16B F3, F11). Raises what opening the log raises.
    """
    with open_log(log) as reader:
        wanted = list(dict.fromkeys([topic, *also]))
        count = sum(1 for message in reader.messages(wanted) if message.topic == topic)
        return -(-count // every), list(reader.damage)


def count_readable(log: Path, topic: str, every: int, read: Sequence[str]) -> int:
    """Count a log's frames by reading them (``learn``); print the damage met on the way.

    Not the count its summary or metadata.yaml lists: a log whose readable part is shorter
    had its held-out share placed past it ("no held-out stereo pair", bug hunt 16B F3),
    and damage met while reading was never printed (16B F11). The damage seen at open is
    printed by the command already (:func:`damage_at_open`); the rest here, as
    densify prints it.
    """
    count, damage = readable_frames(log, topic, every, read)
    listed = _expected_frames(log, topic, every)
    short = listed is not None and count < listed
    of = f" ({count} of the {listed} frames its summary lists)" if short else ""
    at_open = set(damage_at_open([log]))
    for line in damage:
        if line not in at_open:
            _echo(f"damage: {line}; learn uses the frames it could read{of}")
            of = ""
    if of:  # short, and no line said why
        _echo(f"note: {log.name}: {count} of the {listed} frames its summary lists could be read")
    return count


def _expected_frames(log: Path, topic: str, every: int) -> int | None:
    with contextlib.suppress(PcaInterpError), open_log(log) as reader:
        count = reader.topics().get(topic)
        if count is not None and count.message_count is not None:
            return -(-count.message_count // every)
    return None


def no_pair_message(
    path: Path, pairing: PairingConfig, stats: PairingStats, damage: list[str]
) -> str:
    """Return the one-line error of a log without a single usable stereo pair.

    The pairing's summary and the likeliest fix: the image encodings or sizes, damage, a
    stamp tolerance too tight or clocks apart (:class:`PairingStats`' hints), else the topics.
    """
    details = "; ".join([stats.summary(), *stats.problems[:1], *damage[:2]])
    if stats.undecodable:
        fix = stats.undecodable_fix()
    elif stats.size_mismatches:
        fix = "left and right images of a rectified pair must have the same size"
    elif stats.encoding_mismatches:
        fix = (
            "left and right images of a pair must have one encoding, both grey or both "
            "colour of one bit depth (e.g. mono8 and mono8); convert one side"
        )
    elif damage:
        fix = "the readable part of the log has no complete pair; repair or re-record it"
    elif stats.hold_hint() or stats.tolerance_hint() or stats.clock_hint():
        fix = stats.hold_hint() or stats.tolerance_hint() or stats.clock_hint() or ""
    else:
        fix = (
            f"left {pairing.left_topic} and right {pairing.right_topic} need images with "
            "matching header stamps and camera infos on both sides (see pcainterp info, "
            "--stamp-tolerance-ms)"
        )
    return f"no stereo pair found in {path} ({details}); {fix}"
