"""The ``/pcainterp/*`` output messages of one densified frame.

Every output message carries the left image's header (stamp, frame_id); the caller writes
them at the left image's log time. The output channels' MCAP metadata
(:func:`channel_metadata`) names the basis the log was densified with, so that
``evaluate`` can use the same one, and each channel's encoding (:data:`ENCODING_KEY`). A
channel's metadata is fixed when its first message is written: it names the basis of the
first outputs, and the metadata record :data:`BASES_RECORD`, written at the end, every basis
the outputs were made with (the fit check may replace the basis after a standing start, and
a basis learned from the log is relearned as it streams). The record of what made the log,
:data:`~pcainterp_stream.io.densify_record.DENSIFY_RECORD`, names the basis as the channels
do and how the input pair was read and matched (:func:`recorded_front_end` reads it back).

Two precisions (``densify --precision``), chosen by measurement (docs/benchmarks.md,
"Output encodings"):

- ``compact`` (default): ``depth`` as ``sensor_msgs/CompressedImage`` ``32FC1;
  compressedDepth png`` (quantised inverse depth, i.e. the disparity rounded to a multiple
  of a power-of-two step <= 1/32 of the frame's smallest disparity std, so the error is at
  most 1/64 of the posterior std, or half a coarser step where the frame's nearest disparity
  needs one to fit 16 bits; REP 118's NaN and ``+inf`` kept), ``disparity_std`` the
  same way (its reciprocal quantised: relative error <= :data:`STD_RELATIVE_ERROR`; a std
  of 0, which no code decodes to, as NaN: "no value"), a ``16UC1`` millimetre ``depth_mm``
  copy for viewers (to the nearest :data:`DISPLAY_DEPTH_STEP_MM` mm, 0 to the display range),
  ``features`` and ``camera_info``. ``depth_std`` (= f*b / d^2 * disparity_std) and ``disparity``
  (= f*b / depth) follow from those and are written, as float32, only when asked for.
- ``full``: every channel float32 (``depth``, ``depth_std``, ``disparity_std`` as ``32FC1``
  Images, ``disparity`` as a ``stereo_msgs/DisparityImage``), as before.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from pcainterp_stream.defaults import DISPLAY_MAX_DEPTH
from pcainterp_stream.io import depth_codec, rosmsg
from pcainterp_stream.io.densify_record import (
    DENSIFY_RECORD,
    FRONT_END_KEY,
    OUTPUT_PREFIX_KEY,
    FrontEnd,
)
from pcainterp_stream.records import DensifiedFrame

CHANNELS = ("depth", "depth_std", "disparity", "disparity_std", "features", "camera_info")
"""The output channels, by the :class:`OutputTopics` field naming each; ``densify
--outputs`` writes a subset."""

PRECISIONS = ("compact", "full")
"""``densify --precision``: compact standard ROS encodings (default) or float32 channels."""

COMPACT_CHANNELS = ("depth", "disparity_std", "features", "camera_info")
"""The channels written by default at ``compact`` precision (plus the ``depth_mm`` copy)."""

STD_RELATIVE_ERROR = 0.01
"""Largest relative quantisation error of the compact ``disparity_std``."""
DEPTH_STEP_OF_STD = 32.0
"""The compact depth's disparity step is the largest power of two <= the frame's smallest
disparity std / this (error <= step / 2 <= 1/64 of any pixel's std)."""
DEPTH_STEP_RANGE = (1.0 / 1024.0, 1.0 / 16.0)
"""Bounds (px) of that step; the finest one when the frame has no std."""
DISPLAY_DEPTH_STEP_MM = 50
"""The compact ``depth_mm`` viewer copy's rounding (mm): a fifth of one colour of a
256-colour map over 0 to :data:`~pcainterp_stream.defaults.DISPLAY_MAX_DEPTH` m."""


_TOPIC_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def topic_prefix(prefix: str) -> str:
    """Return a prefix of output topics as an absolute ROS 2 name, checked.

    ROS 2 topic names are ``/``-separated tokens of letters, digits and ``_``, none starting
    with a digit, with no empty token (no ``//``) and no trailing ``/``. A relative name
    (``pcainterp``) is resolved in the root namespace, as ROS 2 does (``/pcainterp``).

    Raises:
        ValueError: the prefix is not such a name (``""``, ``"/"``, ``"/a b"``, ``"/a/"``).

    Examples:
        >>> topic_prefix("pcainterp")
        '/pcainterp'
    """
    name = prefix if prefix.startswith("/") else "/" + prefix
    tokens = name[1:].split("/")
    if name == "/":
        problem = "it is empty" if prefix == "" else "it has no name under /"
    elif name.endswith("/"):
        problem = "it ends with /"
    elif "" in tokens:
        problem = "it has an empty name between two /"
    else:
        bad = next((token for token in tokens if not _TOPIC_TOKEN.fullmatch(token)), None)
        if bad is None:
            return name
        problem = f"{bad!r} " + (
            "starts with a digit" if bad[0].isdigit() else "has characters other than A-Z a-z 0-9 _"
        )
    raise ValueError(
        f"{prefix!r} is not a ROS 2 topic name: {problem}; use /-separated names of letters, "
        "digits and _ (not starting with a digit), e.g. /pcainterp"
    )


@dataclass(frozen=True)
class OutputTopics:
    """Names of the output channels; the defaults are the standard ``/pcainterp/*`` names.

    Depth and disparity (and their stds) are each other's reciprocal given f*b, and the
    float32 images dominate what ``densify`` writes and compresses: :meth:`only` keeps a
    subset of :data:`CHANNELS` (``--outputs``); ``evaluate`` needs disparity, disparity_std,
    features and camera_info.
    """

    depth: str = "/pcainterp/depth"
    depth_std: str = "/pcainterp/depth_std"
    disparity: str = "/pcainterp/disparity"
    disparity_std: str = "/pcainterp/disparity_std"
    features: str = "/pcainterp/features"
    camera_info: str = "/pcainterp/camera_info"
    depth_mm: str | None = None
    """When set, also a ``16UC1`` millimetre copy of the depth, which Foxglove's image panel
    colour-maps (it draws ``32FC1`` as grey): 0 = no estimate, depths clipped to the fixed
    range 0 to :data:`~pcainterp_stream.defaults.DISPLAY_MAX_DEPTH` (too far: its end)."""
    skipped: frozenset[str] = frozenset()
    """Channels of :data:`CHANNELS` not written (see :meth:`only`)."""
    precision: str = "full"
    """``full`` (float32 channels) or ``compact`` (compressedDepth; :meth:`compact`)."""

    def compact(self) -> OutputTopics:
        """Return these topics at compact precision with the compact default channels.

        Writes :data:`COMPACT_CHANNELS` and a ``depth_mm`` viewer copy (``<prefix>/depth_mm``
        beside ``depth`` unless one is named already); :meth:`only` may change the set.
        """
        depth_mm = self.depth_mm or self.depth.rsplit("/", 1)[0] + "/depth_mm"
        return replace(
            self,
            precision="compact",
            depth_mm=depth_mm,
            skipped=frozenset(set(CHANNELS) - set(COMPACT_CHANNELS)),
        )

    def encoding(self, channel: str) -> str:
        """Return how a channel of :data:`CHANNELS` (or ``depth_mm``) is encoded."""
        compressed = depth_codec.compressed_format("32FC1", "png")
        if channel == "depth_mm":
            return "sensor_msgs/Image 16UC1 mm"
        if self.precision == "compact" and channel in ("depth", "disparity_std"):
            return f"sensor_msgs/CompressedImage {compressed}"
        return {
            "depth": "sensor_msgs/Image 32FC1",
            "depth_std": "sensor_msgs/Image 32FC1",
            "disparity": "stereo_msgs/DisparityImage 32FC1",
            "disparity_std": "sensor_msgs/Image 32FC1",
            "features": "sensor_msgs/PointCloud2",
            "camera_info": "sensor_msgs/CameraInfo",
        }[channel]

    def msgtype(self, channel: str) -> str:
        """Return the ROS 2 message type of a channel (or ``depth_mm``)."""
        return self.encoding(channel).split(" ", 1)[0].replace("/", "/msg/", 1)

    def only(self, channels: Iterable[str]) -> OutputTopics:
        """Return these topics writing only ``channels`` (of :data:`CHANNELS`, ``depth_mm``).

        ``depth_mm`` names the millimetre viewer copy of the depth (``<prefix>/depth_mm``
        beside ``depth``), at either precision. Not named, it follows ``depth`` at compact
        precision (the copy the compact default writes) and stays as it is at full.

        Raises:
            ValueError: an unknown channel name, or no channel at all.
        """
        chosen = set(channels)
        names = (*CHANNELS, "depth_mm")
        unknown = sorted(chosen - set(names))
        if unknown:
            raise ValueError(
                f"unknown output channel {', '.join(unknown)}; choose from {', '.join(names)}"
            )
        if not chosen:
            raise ValueError(f"no output channel chosen; choose from {', '.join(names)}")
        topics = replace(self, skipped=frozenset(set(CHANNELS) - chosen))
        if "depth_mm" in chosen:
            depth_mm = self.depth_mm or self.depth.rsplit("/", 1)[0] + "/depth_mm"
            topics = replace(topics, depth_mm=depth_mm)
        elif self.precision == "compact" and "depth" not in chosen:
            topics = replace(topics, depth_mm=None)  # the viewers' copy of the depth
        return topics

    def topic(self, channel: str) -> str:
        """Return the topic of a channel of :data:`CHANNELS` (or ``depth_mm``)."""
        return str(getattr(self, channel))

    def writes(self, channel: str) -> bool:
        """Return whether the channel (a name of :data:`CHANNELS`) is written."""
        return channel not in self.skipped

    @classmethod
    def with_prefix(
        cls, prefix: str, *, depth_mm: bool = False, precision: str = "full"
    ) -> OutputTopics:
        """Return the default topics under another prefix (``/pcainterp`` by default).

        ``precision="compact"`` returns :meth:`compact` of them.

        Raises:
            ValueError: an unknown precision, or a prefix that is no ROS 2 topic name
                (:func:`topic_prefix`).
        """
        if precision not in PRECISIONS:
            raise ValueError(f"unknown precision {precision!r}; choose {' or '.join(PRECISIONS)}")
        prefix = topic_prefix(prefix)
        topics = cls(
            depth=f"{prefix}/depth",
            depth_std=f"{prefix}/depth_std",
            disparity=f"{prefix}/disparity",
            disparity_std=f"{prefix}/disparity_std",
            features=f"{prefix}/features",
            camera_info=f"{prefix}/camera_info",
            depth_mm=f"{prefix}/depth_mm" if depth_mm else None,
        )
        return topics.compact() if precision == "compact" else topics

    @property
    def prefix(self) -> str:
        """Return the prefix of the output topics (``/pcainterp``): the camera info's parent."""
        return self.camera_info.rsplit("/", 1)[0]

    def all(self) -> list[str]:
        """Return every output topic in use."""
        topics = [str(getattr(self, name)) for name in CHANNELS if self.writes(name)]
        return topics + ([self.depth_mm] if self.depth_mm else [])


BASIS_KEY = "pcainterp.basis"
"""Channel metadata key: the basis densify used, ``built-in`` or its file's path relative to
the output's folder (its name alone for an output on standard output or on another drive;
``in-memory`` for a basis passed as an object)."""

BASIS_FINGERPRINT_KEY = "pcainterp.basis_fingerprint"
"""Channel metadata key: the basis's content fingerprint (``Basis.fingerprint``)."""

BASIS_TUNING_KEY = "pcainterp.basis_tuning"
"""Channel metadata key, only when the fit check tuned the first outputs' basis: the settings
(JSON, ``evaluate.tuning``) beyond the basis's fitted prior it densified with."""

BASES_RECORD = "pcainterp.basis"
"""Name of the MCAP metadata record listing every basis the outputs were made with, each from
the first frame it densified (:func:`bases_record`); written when the output is complete."""

BASIS_SCOPE_KEY = "pcainterp.basis_scope"
"""Channel metadata key of a written log: what :data:`BASIS_KEY` covers (:data:`BASIS_SCOPE`)."""

BASIS_SCOPE = (
    f"the first outputs; every basis in force, from its first frame: metadata record {BASES_RECORD}"
)
"""The value of :data:`BASIS_SCOPE_KEY`: the channel's basis is the one of the first outputs."""


MEASUREMENTS_KEY = "pcainterp.measurements"
"""Channel metadata key: ``sparse`` (the paper's GFTT lookups or a feature stream) or
``dense`` (the whole SGBM map too; ``/pcainterp/features`` still holds the sparse points
that shaped the estimate)."""


ENCODING_KEY = "pcainterp.encoding"
"""Channel metadata key: how the channel is encoded (:meth:`OutputTopics.encoding`)."""

FOCAL_BASELINE_KEY = "pcainterp.focal_baseline"
"""Channel metadata key: f*b (px*m) of the first outputs, to turn the depth into disparity."""

CAMERAS_RECORD = "pcainterp.cameras"
"""Name of the MCAP metadata record of a log whose camera or min disparity changed: an entry
(f*b, min disparity) from the first frame of each change (``io.output_cameras``); absent,
the channels' hold for all."""

FOCAL_BASELINE_SCOPE_KEY = "pcainterp.focal_baseline_scope"
"""Channel metadata key: what :data:`FOCAL_BASELINE_KEY` covers (:data:`FOCAL_BASELINE_SCOPE`)."""
FOCAL_BASELINE_SCOPE = f"the first outputs; each camera's, when it changed: record {CAMERAS_RECORD}"

MIN_DISPARITY_KEY = "pcainterp.min_disparity"
"""Channel metadata key of compact logs: the smallest resolvable disparity (px) of the
first frame (the ``DisparityImage``'s ``min_disparity``: the noise std of the basis in force,
so it changes with the basis and, with ``--sigma evidence`` (fitted per frame), may change
every frame; each change is in :data:`CAMERAS_RECORD`)."""

STAMP_TOLERANCE_KEY = "pcainterp.stamp_tolerance_ns"
"""Channel metadata key: the largest left/right stamp difference (ns) densify paired
(``--stamp-tolerance-ms``), so that ``evaluate`` finds each frame's right image as densify
did."""


def frame_metadata(result: DensifiedFrame) -> dict[str, str]:
    """Return the per-log values a compact log's channels record (f*b, min disparity)."""
    return {
        FOCAL_BASELINE_KEY: repr(float(result.frame.camera.focal_baseline)),
        MIN_DISPARITY_KEY: repr(float(result.min_disparity)),
        FOCAL_BASELINE_SCOPE_KEY: FOCAL_BASELINE_SCOPE,
    }


def topic_metadata(topics: OutputTopics, metadata: dict[str, str]) -> dict[str, dict[str, str]]:
    """Return each written output topic's channel metadata: ``metadata`` and its encoding."""
    channels = [name for name in CHANNELS if topics.writes(name)]
    if topics.depth_mm:
        channels.append("depth_mm")
    return {
        topics.topic(name): {**metadata, ENCODING_KEY: topics.encoding(name)} for name in channels
    }


def channel_metadata(basis: str, fingerprint: str, measurements: str = "sparse") -> dict[str, str]:
    """Return the metadata of the output channels of a densified log.

    Args:
        basis: the basis used: ``built-in``, a file path or ``in-memory``.
        fingerprint: its content fingerprint.
        measurements: ``sparse`` or ``dense`` (``densify --measurements``).

    Returns:
        {:data:`BASIS_KEY`: basis, :data:`BASIS_FINGERPRINT_KEY`: fingerprint,
        :data:`MEASUREMENTS_KEY`: measurements}.
    """
    return {BASIS_KEY: basis, BASIS_FINGERPRINT_KEY: fingerprint, MEASUREMENTS_KEY: measurements}


class BasisInForce(NamedTuple):
    """One basis a densified log's outputs were made with, from its first frame on.

    Attributes:
        basis: how the log names it (as :data:`BASIS_KEY` does: ``built-in``, a file name...).
        fingerprint: its content fingerprint (``Basis.fingerprint``).
        first_frame: 0-based index of the first stereo pair densified with it.
        first_stamp_ns: that pair's header stamp (ns).
        first_log_time_ns: its log time (ns), the log time of its outputs.
        tuning: the settings the fit check tuned it with beyond its fitted prior (JSON,
            ``evaluate.tuning``; recorded as ``N.tuning``); "": densified as fitted, not recorded.
    """

    basis: str
    fingerprint: str
    first_frame: int
    first_stamp_ns: int
    first_log_time_ns: int
    tuning: str = ""


_BASIS_FIELDS = BasisInForce._fields[:5]


def bases_record(bases: Iterable[BasisInForce], prefix: str | None = None) -> dict[str, str]:
    """Return the :data:`BASES_RECORD` metadata record of the bases in force, in stream order.

    ``prefix``: the output topics' prefix, recorded under
    :data:`~pcainterp_stream.io.densify_record.OUTPUT_PREFIX_KEY` (None: not recorded).

    Examples:
        >>> entry = BasisInForce("built-in", "0123456789abcdef", 0, 5, 7)
        >>> record = bases_record([entry])
        >>> record["count"], record["0.basis"], record["0.first_frame"]
        ('1', 'built-in', '0')
        >>> recorded_bases_of(record) == [entry]
        True
    """
    entries = list(bases)
    record = {"count": str(len(entries))}
    if prefix is not None:
        record[OUTPUT_PREFIX_KEY] = prefix
    for number, entry in enumerate(entries):
        record.update({f"{number}.{name}": str(getattr(entry, name)) for name in _BASIS_FIELDS})
        if entry.tuning:  # only then: an untuned log's record is as before
            record[f"{number}.tuning"] = entry.tuning
    return record


def recorded_bases_of(record: dict[str, str]) -> list[BasisInForce]:
    """Return the bases a :data:`BASES_RECORD` record lists (:func:`bases_record`'s inverse).

    Raises:
        ValueError: the record is not one :func:`bases_record` wrote.
    """
    try:
        return [
            BasisInForce(
                record[f"{number}.basis"],
                record[f"{number}.fingerprint"],
                int(record[f"{number}.first_frame"]),
                int(record[f"{number}.first_stamp_ns"]),
                int(record[f"{number}.first_log_time_ns"]),
                record.get(f"{number}.tuning", ""),  # recorded only when tuned
            )
            for number in range(int(record["count"]))
        ]
    except (KeyError, ValueError) as err:
        raise ValueError(
            f"not a {BASES_RECORD} metadata record: {err!r} missing or invalid"
        ) from err


def recorded_bases(path: Path, prefix: str | None = None) -> list[BasisInForce]:
    """Return the bases a densified MCAP log records (:data:`BASES_RECORD`) for a prefix.

    The record of the output prefix ``prefix`` (:func:`record_of_prefix`; None: the last
    record); [] for a log without one (another format, or densified by an older version).
    """
    record, _ = record_of_prefix(_records(path, BASES_RECORD), prefix)
    return recorded_bases_of(record) if record is not None else []


class RecordedFrontEnd(NamedTuple):
    """The front end a densified log records for a prefix, and what to say of the choice."""

    front_end: FrontEnd | None
    """None: no record (of that prefix) that holds one."""
    note: str
    """Why that record (several records, none naming its prefix), or why none; "" if plain."""


def recorded_front_end(path: Path, prefix: str | None = None) -> FrontEnd | None:
    """Return how ``densify`` made a log's stereo measurements (:class:`FrontEnd`), or None.

    Read from the :data:`DENSIFY_RECORD` of the output prefix ``prefix`` of an MCAP log
    (:func:`front_end_record`); None for a log without one that records it.

    Raises:
        ValueError: the record holds a front end this version cannot read.
    """
    return front_end_record(path, prefix).front_end


def front_end_record(path: Path, prefix: str | None = None) -> RecordedFrontEnd:
    """Return the front end of a log's :data:`DENSIFY_RECORD` for the outputs of ``prefix``.

    A log densified again under another ``--output-prefix`` (a second stereo pair) holds a
    record per prefix; the one naming ``prefix`` is taken (:func:`record_of_prefix`).

    Raises:
        ValueError: the record holds a front end this version cannot read.
    """
    record, note = record_of_prefix(_records(path, DENSIFY_RECORD), prefix)
    if record is None or FRONT_END_KEY not in record:
        return RecordedFrontEnd(None, note)
    return RecordedFrontEnd(FrontEnd.from_json(record[FRONT_END_KEY]), note)


def record_of_prefix(
    records: list[dict[str, str]], prefix: str | None
) -> tuple[dict[str, str] | None, str]:
    """Return the record (of several of one name) about the outputs of ``prefix``, and a note.

    The last record naming ``prefix`` (:data:`~pcainterp_stream.io.densify_record.
    OUTPUT_PREFIX_KEY`); else, of records that name no prefix (older versions), the last one,
    with a note when the log holds several records; else None and a note naming the prefixes
    recorded. ``prefix`` None: the last record, whatever its prefix (as before prefixes).

    Examples:
        >>> record_of_prefix([{"output_prefix": "/a"}, {"output_prefix": "/b"}], "/a")
        ({'output_prefix': '/a'}, '')
        >>> record_of_prefix([{"output_prefix": "/b"}], "/a")[1]
        'the log records densify only for the outputs of /b, none for /a'
    """
    if not records:
        return None, ""
    if prefix is None:
        return records[-1], ""
    named = [record for record in records if record.get(OUTPUT_PREFIX_KEY) == prefix]
    if named:
        return named[-1], ""
    unnamed = [record for record in records if OUTPUT_PREFIX_KEY not in record]
    if unnamed:
        note = (
            ""
            if len(records) == 1
            else (
                f"the log holds {len(records)} densify records, {len(unnamed)} of an older "
                "version that names no output prefix: the last of those was taken"
                + _other_pairs(unnamed)
            )
        )
        return unnamed[-1], note
    prefixes = ", ".join(sorted({record[OUTPUT_PREFIX_KEY] for record in records}))
    return None, f"the log records densify only for the outputs of {prefixes}, none for {prefix}"


def recorded_pairs(path: Path) -> list[str]:
    """Return the input pairs a log's densify records read (``left + right``, each once)."""
    return _pairs(_records(path, DENSIFY_RECORD))


def _pairs(records: list[dict[str, str]]) -> list[str]:
    pairs: list[str] = []
    for record in records:
        try:
            front_end = FrontEnd.from_json(record[FRONT_END_KEY])
        except (KeyError, ValueError):
            continue
        pair = f"{front_end.left_topic} + {front_end.right_topic}"
        pairs += [] if pair in pairs else [pair]
    return pairs


def _other_pairs(unnamed: list[dict[str, str]]) -> str:
    """Say that the outputs may be of another pair than the last unnamed record's ("": no other).

    Records of an older version name no output prefix: a log densified again for a second
    pair holds one per pair, and which one these outputs are of is not recorded.

    Examples:
        >>> _other_pairs([{"front_end": "?"}, {}])
        ''
    """
    pairs = _pairs(unnamed)
    if len(pairs) < 2:
        return ""
    return (
        f", but these outputs may be of another pair (the records read {', '.join(pairs)}): "
        "if the scores look wrong, name the pair densify read for them with --left-topic and "
        "--right-topic"
    )


def _records(path: Path, name: str) -> list[dict[str, str]]:
    """Return the MCAP metadata records ``name`` of a log in file order ([]: none, not MCAP)."""
    from pcainterp_stream.io.logreader import open_log
    from pcainterp_stream.io.mcap_reader import McapLogReader

    with open_log(path) as reader:
        if not isinstance(reader, McapLogReader):
            return []
        return [dict(m.metadata) for m in reader.extras().metadata if m.name == name]


def pairing_metadata(tolerance_ns: int) -> dict[str, str]:
    """Return the metadata that records how the input pair was paired.

    Args:
        tolerance_ns: the largest left/right stamp difference that paired (ns).

    Returns:
        {:data:`STAMP_TOLERANCE_KEY`: tolerance_ns}.
    """
    return {STAMP_TOLERANCE_KEY: str(int(tolerance_ns))}


def recorded_tolerance_ns(metadata: dict[str, str]) -> int | None:
    """Return the pairing tolerance (ns) a densified log's channel metadata records, or None.

    None for logs densified before it was recorded (or with an unreadable value).
    """
    try:
        value = int(metadata[STAMP_TOLERANCE_KEY])
    except (KeyError, ValueError):
        return None
    return value if value >= 0 else None


def recorded_metadata(path: Path, topics: OutputTopics | None = None) -> dict[str, str]:
    """Return the channel metadata of a densified log's disparity (or depth) channel.

    Args:
        path: a log written by ``pcainterp densify``.
        topics: its output topics (default the standard ones).

    Returns:
        The metadata of the first message's channel on ``topics.disparity``, else on
        ``topics.depth`` (compact logs); {} when the log has neither or its format keeps
        no channel metadata.
    """
    from pcainterp_stream.io.logreader import open_log

    topics = topics or OutputTopics()
    with open_log(path) as reader:
        present = reader.topics()
        for topic in (topics.disparity, topics.depth):
            if topic not in present:
                continue
            for raw in reader.messages([topic]):
                return dict(raw.channel_metadata)
    return {}


def output_messages(result: DensifiedFrame, topics: OutputTopics) -> list[tuple[str, Any]]:
    """Build the output messages of one frame.

    Args:
        result: the densified frame.
        topics: output channel names.

    Returns:
        (topic, typestore message) pairs, in a fixed order.
    """
    frame = result.frame
    camera = frame.camera
    stamp, frame_id = frame.stamp_ns, frame.frame_id
    messages: list[tuple[str, Any]] = []
    compact = topics.precision == "compact"
    if topics.writes("depth") and compact:
        step = depth_step(result.disparity_std)
        nearest = _finite_extreme(result.depth, np.min)
        quant_a = depth_codec.inverse_depth_scale(
            camera.focal_baseline,
            step,
            float(camera.focal_baseline / nearest) if nearest is not None else 1.0,
        )
        encoded = depth_codec.encode_depth(result.depth, quant_a=quant_a)
        messages.append((topics.depth, _compressed(encoded, stamp, frame_id)))
    elif topics.writes("depth"):
        depth = rosmsg.image_message(result.depth, stamp, frame_id, encoding="32FC1")
        messages.append((topics.depth, depth))
    if topics.writes("depth_std"):
        depth_std = rosmsg.image_message(result.depth_std, stamp, frame_id, encoding="32FC1")
        messages.append((topics.depth_std, depth_std))
    if topics.writes("disparity"):
        # DisparityImage's valid window starts at the smallest resolvable disparity, so no
        # value <= 0 (nor any below it, "farther than measurable") is valid (REP 118)
        with np.errstate(invalid="ignore"):
            finite = np.isfinite(result.disparity) & (result.disparity >= result.min_disparity)
        min_disparity = result.min_disparity if result.min_disparity > 0 else 0.0
        disparity = rosmsg.disparity_image_message(
            result.disparity,
            stamp,
            frame_id,
            focal=camera.fx,
            baseline=camera.baseline,
            min_disparity=min_disparity,
            max_disparity=(
                float(np.max(result.disparity[finite])) if finite.any() else min_disparity
            ),
        )
        messages.append((topics.disparity, disparity))
    if topics.writes("disparity_std") and compact:
        encoded = depth_codec.encode_depth(  # a std of 0 (certain) as NaN: no code reads 0
            result.disparity_std, quant_a=std_scale(result.disparity_std), zero_as_nan=True
        )
        messages.append((topics.disparity_std, _compressed(encoded, stamp, frame_id)))
    elif topics.writes("disparity_std"):
        disparity_std = rosmsg.image_message(
            result.disparity_std, stamp, frame_id, encoding="32FC1"
        )
        messages.append((topics.disparity_std, disparity_std))
    if topics.writes("features"):
        messages.append((topics.features, _features_message(result)))
    if topics.writes("camera_info"):
        messages.append((topics.camera_info, rosmsg.camera_info_message(camera, stamp, frame_id)))
    if topics.depth_mm:
        depth_mm = display_millimetres(
            result.depth, step_mm=DISPLAY_DEPTH_STEP_MM if compact else 1
        )
        messages.append(
            (topics.depth_mm, rosmsg.image_message(depth_mm, stamp, frame_id, encoding="16UC1"))
        )
    return messages


def depth_step(disparity_std: npt.NDArray[np.float32]) -> float:
    """Return the compact depth's disparity step (px) for a frame's disparity std.

    The largest power of two <= the smallest finite std / :data:`DEPTH_STEP_OF_STD`, within
    :data:`DEPTH_STEP_RANGE` (its fine end when no std is known).
    """
    smallest = _finite_extreme(disparity_std, np.min, positive=True)
    low, high = DEPTH_STEP_RANGE
    if smallest is None:
        return low
    target = smallest / DEPTH_STEP_OF_STD
    return float(np.clip(2.0 ** np.floor(np.log2(max(target, low))), low, high))


def std_scale(std: npt.NDArray[np.float32]) -> float:
    """Return the depthQuantA storing a std image with <= :data:`STD_RELATIVE_ERROR` error.

    Stored as ``A / s + 1``, the relative rounding error is ``s / (2 A)``, largest at the
    largest std: ``A = max(s) / (2 * error)``. A std below ``A / 65534`` (1/1300 of the
    largest) is stored as that value (absolute error <= max(s) / 1300); KITTI's and the
    synthetic drives' stds span < 30x, so this never happens there. A std of 0 is stored as
    NaN ("no value": no code decodes to 0; ``output_messages``), not as ``A / 65534``.
    """
    largest = _finite_extreme(std, np.max, positive=True)
    if largest is None:
        return 1.0
    return largest / (2.0 * STD_RELATIVE_ERROR)


def display_millimetres(depth: npt.NDArray[np.float32], step_mm: int = 1) -> npt.NDArray[np.uint16]:
    """Return the ``16UC1`` viewer copy of a depth image (m): millimetres to ``step_mm``.

    Fixed range: 0 = no estimate (NaN), :data:`~pcainterp_stream.defaults.DISPLAY_MAX_DEPTH`
    for it and beyond (``+inf``: too far). In place on one float32 buffer.
    """
    far_mm = 1000.0 * DISPLAY_MAX_DEPTH
    millimetres = np.multiply(depth, np.float32(1000.0), dtype=np.float32)
    if step_mm != 1:  # to the display step: the copy is for viewers (a third of the bytes)
        millimetres /= np.float32(step_mm)
        np.rint(millimetres, out=millimetres)
        millimetres *= np.float32(step_mm)
    np.rint(millimetres, out=millimetres)
    np.clip(millimetres, 0, far_mm, out=millimetres)  # +inf -> far, -inf -> 0
    millimetres[np.isnan(millimetres)] = 0.0
    return millimetres.astype(np.uint16)


def _finite_extreme(
    image: npt.NDArray[np.floating], reduce: Any, *, positive: bool = False
) -> float | None:
    """Return ``reduce`` (np.min or np.max) of an image's finite (and > 0) values, or None."""
    if image.size == 0:
        return None
    # NaN-skipping reduction first (one pass, no mask): when it is finite (and > 0) no
    # infinity (nor value <= 0) can have been the extreme, so it is the answer
    quick = float(
        np.fmin.reduce(image, axis=None) if reduce is np.min else np.fmax.reduce(image, axis=None)
    )
    if np.isfinite(quick) and (quick > 0 or not positive):
        return quick
    with np.errstate(invalid="ignore"):
        keep = (image > 0) if positive else (image > -np.inf)
        keep &= image < np.inf
    if not keep.any():
        return None
    initial = np.inf if reduce is np.min else -np.inf
    return float(reduce(image, where=keep, initial=initial))


def _compressed(encoded: depth_codec.CompressedDepth, stamp: int, frame_id: str) -> Any:
    return rosmsg.compressed_image_message(encoded.data, encoded.format, stamp, frame_id)


def _features_message(result: DensifiedFrame) -> Any:
    """Return the PointCloud2 of the measurements used (x y z in the left optical frame)."""
    camera = result.frame.camera
    pixels = result.pixels.astype(np.float32, copy=False)
    disparities = result.disparities.astype(np.float32, copy=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(disparities > 0, camera.focal_baseline / disparities, np.nan)
    x = (pixels[:, 0] - camera.cx) * z / camera.fx
    y = (pixels[:, 1] - camera.cy) * z / camera.fy
    return rosmsg.pointcloud2_message(
        {
            "x": x.astype(np.float32),
            "y": y.astype(np.float32),
            "z": z.astype(np.float32),
            "u": pixels[:, 0],
            "v": pixels[:, 1],
            "disparity": disparities,
        },
        result.frame.stamp_ns,
        result.frame.frame_id,
    )


@dataclass(frozen=True)
class EstimateTopics:
    """Where a densified log keeps its estimate: the topics evaluate reads, by form."""

    estimate: str
    """``disparity`` (a full log's DisparityImage) or ``depth`` (a compact log's)."""
    std: str
    """``disparity_std`` (Image 32FC1 or compressedDepth)."""
    compact: bool
    """The estimate is the compressedDepth depth (disparity = f*b / depth)."""


def estimate_topics(present: Iterable[str], topics: OutputTopics) -> EstimateTopics:
    """Return the estimate topics of a log with these topics: disparity if it has it, else depth.

    A log without either gets the full form's names (the caller reports them missing).
    """
    names = set(present)
    if topics.disparity in names or topics.depth not in names:
        return EstimateTopics(topics.disparity, topics.disparity_std, compact=False)
    return EstimateTopics(topics.depth, topics.disparity_std, compact=True)


def densified_prefixes(present: Iterable[str]) -> list[str]:
    """Return the prefixes under which a log has densify's channels, sorted.

    A prefix counts when the log has its ``disparity_std``, ``camera_info`` and ``depth``
    or ``disparity`` (what :func:`estimate_topics` reads, in either form).
    """
    names = set(present)
    found = []
    for name in sorted(names):
        prefix = name.removesuffix("/disparity_std")
        if prefix == name or f"{prefix}/camera_info" not in names:
            continue
        if {f"{prefix}/depth", f"{prefix}/disparity"} & names:
            found.append(prefix)
    return found


def missing_outputs(
    present: Iterable[str], topics: OutputTopics, wanted: Iterable[str]
) -> tuple[list[str], str]:
    """Return the ``wanted`` topics a log lacks and a hint naming where its outputs are.

    The estimate is named in both forms (``/p/disparity or /p/depth``) when the log has
    neither: a compact log has ``depth`` where a full one has ``disparity``.

    Returns:
        The missing topics, and ``""`` or ``"; it has densified channels under /q: pass
        --output-prefix /q"`` when the log has them under other prefixes.
    """
    names = set(present)
    estimates = (topics.disparity, topics.depth)
    missing = []
    for topic in wanted:
        if topic in names:
            continue
        if topic in estimates and not names.intersection(estimates):
            topic = f"{topics.disparity} or {topics.depth}"
        missing.append(topic)
    own = topics.camera_info.rsplit("/", 1)[0]
    others = [prefix for prefix in densified_prefixes(names) if prefix and prefix != own]
    if not missing or not others:
        return missing, ""
    return missing, (
        f"; it has densified channels under {', '.join(others)}: pass --output-prefix {others[0]}"
    )


@dataclass(frozen=True)
class DecodedEstimate:
    """A densified frame's estimate as evaluate uses it, whatever its encoding.

    Attributes:
        disparity: (H, W) float32 (px); a compact log's ``+inf`` depth (too far) reads 0.
        disparity_std: (H, W) float32 (px).
        focal: f (px).
        baseline: b (m).
        min_disparity: the smallest resolvable disparity (px).
    """

    disparity: npt.NDArray[np.float32]
    disparity_std: npt.NDArray[np.float32]
    focal: float
    baseline: float
    min_disparity: float


def image_of(message: Any) -> npt.NDArray[np.generic]:
    """Decode an Image or a compressedDepth CompressedImage into its array."""
    if str(message.__msgtype__) == rosmsg.COMPRESSED_IMAGE:
        return depth_codec.decode(str(message.format), np.asarray(message.data, dtype=np.uint8))
    return rosmsg.image_array(message)


def decode_estimate(
    estimate: Any, std: Any, camera_info: Any, metadata: dict[str, str]
) -> DecodedEstimate:
    """Decode a frame's estimate and std messages (full or compact form).

    Args:
        estimate: the DisparityImage (full) or the compressedDepth depth (compact).
        std: the disparity std (Image or compressedDepth).
        camera_info: the ``camera_info`` output (f of a compact log).
        metadata: the estimate channel's metadata, with the f*b and min disparity of the
            frame's camera for a compact log (``io.output_cameras.FrameCameras.metadata``).

    Raises:
        ValueError: a compact log whose metadata lacks f*b (not written by this version).
    """
    disparity_std = image_of(std).astype(np.float32, copy=False)
    if str(estimate.__msgtype__) == rosmsg.DISPARITY_IMAGE:
        return DecodedEstimate(
            disparity=rosmsg.image_array(estimate.image).astype(np.float32, copy=False),
            disparity_std=disparity_std,
            focal=float(estimate.f),
            baseline=float(estimate.t),
            min_disparity=float(estimate.min_disparity),
        )
    if FOCAL_BASELINE_KEY not in metadata:
        raise ValueError(
            f"the depth channel has no {FOCAL_BASELINE_KEY} metadata, so its disparity is "
            "unknown; densify the log again (or with --precision full)"
        )
    focal_baseline = float(metadata[FOCAL_BASELINE_KEY])
    depth = image_of(estimate).astype(np.float32, copy=False)
    with np.errstate(divide="ignore"):
        disparity = np.float32(focal_baseline) / depth  # +inf -> 0, NaN stays
    focal = float(rosmsg.projection_matrix(camera_info)[0, 0])
    return DecodedEstimate(
        disparity=disparity.astype(np.float32, copy=False),
        disparity_std=disparity_std,
        focal=focal,
        baseline=focal_baseline / focal,
        min_disparity=float(metadata.get(MIN_DISPARITY_KEY, 0.0)),
    )
