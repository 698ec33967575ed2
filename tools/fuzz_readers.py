"""Fuzz the log readers: damaged logs must read as far as they can or fail cleanly.

The property checked for every input, by the hypothesis tests in
``tests/io/test_fuzz_readers.py`` and by the coverage-guided fuzzer this script runs (atheris,
libFuzzer's mutation engine): the whole read path -- :func:`~logreader.open_log`,
``topics()``, ``message_stats()``, ``messages()`` of all topics and of one, ``decode()`` of
every message, stereo pairing, :func:`~loginfo.describe` with a full count and ``pcainterp
info`` -- finishes with success or a :class:`~errors.PcaInterpError` (the CLI: exit 0, or
exit 2 with a one-line message). Any other exception, a hang, or an allocation that a
length field talked the reader into is a finding.

Usage::

    pip install -e '.[fuzz]'
    python tools/fuzz_readers.py --format mcap --seconds 300 fuzz_out/mcap
    python tools/fuzz_readers.py --format ros1 --runs 20000 fuzz_out/ros1
    python tools/fuzz_readers.py --format rosbag2 --seconds 60 fuzz_out/rosbag2

``DIR`` gets ``corpus/`` (seeded with a small synthetic log written by ``pcainterp synth``
when empty; libFuzzer adds the inputs that reach new code) and ``crashes/`` (each finding:
the input, and a ``.txt`` with its traceback). Findings are de-duplicated by exception type
and the innermost frame; the run goes on after a finding unless ``--stop-on-crash``. Hangs
(``--timeout``) and memory blow-ups (``--rss-limit-mb``) are libFuzzer's: it writes the
input as ``timeout-*`` / ``oom-*`` into ``crashes/`` and stops. See docs/fuzzing.md.
"""

from __future__ import annotations

import argparse
import contextlib
import enum
import hashlib
import importlib
import io
import random
import resource
import shutil
import struct
import subprocess
import sys
import time
import traceback
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

try:
    import harness
except ModuleNotFoundError:  # loaded by its path (the fuzz tests): tools/ is not on sys.path
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import harness

FORMATS = ("mcap", "mcap-ros1", "ros1", "rosbag2", "rosbag2-sqlite3")
"""Seed kinds: an MCAP file (ros2 profile, zstd chunks), an MCAP file with the ros1 profile
(uncompressed chunks, made from the ROS 1 seed), a ROS 1 bag, and rosbag2 folders with
mcap / sqlite3 storage."""

SEED_FRAMES = 2
SEED_SCALE = 0.1  # 124x38 px: small inputs, so mutations land on structure, not pixels

_MCAP_MAGIC = b"\x89MCAP0\r\n"
_ROS1_MAGIC_LINE = b"#ROSBAG V2.0\n"


Field = tuple[int, int]
"""A length field: (byte offset, width in bytes), little-endian."""


class PropertyViolation(AssertionError):
    """The read path ended in a way the fuzz property forbids (not an exception of ours)."""


# --- the read path under test ------------------------------------------------------------


STAGES = ("read", "one topic", "pairs", "count", "info")
"""The stages of :func:`read_everything`, in order."""


def read_everything(path: Path, stages: Sequence[str] = STAGES) -> str:
    """Run the whole read path on one log and return a one-line summary of what it did.

    Every stage runs even when an earlier one raised a project error (each stage opens the
    log again), so one damaged byte does not hide the next stage's behaviour.

    Args:
        path: an MCAP file, a ROS 1 bag, a rosbag2 folder or storage file.
        stages: which of :data:`STAGES` to run: ``read`` (open, topics, index stats, every
            message and its decode), ``one topic`` (the messages of the first topic alone),
            ``pairs`` (stereo pairing), ``count`` (``describe(count=True)``) and ``info``
            (``pcainterp info``). Each opens the log (rosbags takes ~0.3 s to open a bag).

    Returns:
        The stages and their outcomes, e.g. ``read: 12 msgs, 0 undecodable; pairs: 2; ...``.

    Raises:
        PropertyViolation: the CLI exited other than 0, or 2 with a one-line message; or a
            reader swallowed a ``MemoryError`` as damage (a length field made it try to
            allocate more than the memory limit).
        Exception: anything that is not a :class:`~errors.PcaInterpError` propagates: that
            is a finding. Warnings are raised as errors here, so they are findings too.
    """
    from pcainterp_stream.errors import PcaInterpError

    outcomes: list[str] = []
    runners: dict[str, Callable[[Path], str]] = {
        "read": _stage_read,
        "one topic": _stage_one_topic,
        "pairs": _stage_pairs,
        "count": _stage_count,
        "info": _stage_cli_info,
    }
    for name in stages:
        stage = runners[name]
        try:
            with warnings.catch_warnings():  # a warning (numpy overflow...) is a finding too
                warnings.simplefilter("error")
                outcome = stage(path)
        except PcaInterpError as err:
            if "MemoryError" in str(err):
                raise PropertyViolation(f"{name}: a MemoryError was reported as: {err}") from err
            outcome = f"{type(err).__name__}"
        outcomes.append(f"{name}: {outcome}")
    return "; ".join(outcomes)


def _check_notes(notes: Sequence[str]) -> None:
    for note in notes:
        if "MemoryError" in note:
            raise PropertyViolation(f"the reader swallowed a MemoryError as damage: {note}")


def _stage_read(path: Path) -> str:
    from pcainterp_stream.errors import LogReadError
    from pcainterp_stream.io.logreader import open_log

    with open_log(path) as reader:
        reader.topics()
        reader.message_stats()
        count = undecodable = 0
        for raw in reader.messages():
            count += 1
            try:
                reader.decode(raw)
            except LogReadError:
                undecodable += 1
        _check_notes(reader.damage)
        return f"{count} msgs, {undecodable} undecodable, {len(reader.damage)} damage"


def _stage_one_topic(path: Path) -> str:
    from pcainterp_stream.io.logreader import open_log

    with open_log(path) as reader:
        topics = sorted(reader.topics())
        if not topics:
            return "no topics"
        count = sum(1 for _ in reader.messages([topics[0]]))
        _check_notes(reader.damage)
        return f"{count} msgs"


def _stage_pairs(path: Path) -> str:
    from pcainterp_stream.frontend.pairing import StereoPairer, iter_stereo_frames
    from pcainterp_stream.io.logreader import open_log

    with open_log(path) as reader:
        pairer = StereoPairer()
        frames = sum(1 for _ in iter_stereo_frames(reader, pairer=pairer))
        _check_notes(reader.damage)
        return f"{frames} pairs"


def _stage_count(path: Path) -> str:
    from pcainterp_stream.io.loginfo import describe, format_info

    info = describe(path, count=True)
    _check_notes(info.damage)
    format_info(info)
    return f"{info.message_count} msgs"


def _stage_cli_info(path: Path) -> str:
    from pcainterp_stream.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["info", str(path)])
    message = err.getvalue()
    if code == 0:
        return "exit 0"
    lines = message.strip().splitlines()
    if code != 2 or len(lines) != 1 or not lines[0].startswith("pcainterp: error: "):
        raise PropertyViolation(f"`pcainterp info` exited {code} with stderr {message!r}")
    if "Traceback" in message or "MemoryError" in message:
        raise PropertyViolation(f"`pcainterp info` printed {message!r}")
    return "exit 2"


# --- running one input in a child process ------------------------------------------------


@dataclass(frozen=True)
class Verdict:
    """How the read path ended on one input (run in a child process).

    Attributes:
        problem: None when the property holds; else what broke it (a traceback, "timed out
            after 10 s", "memory grew by ... bytes").
        outcome: :func:`read_everything`'s summary (empty when it did not finish).
        seconds: wall time of the child.
        peak_growth_bytes: growth of the child's peak resident set over its start (bytes);
            -1 where /proc does not say.
    """

    problem: str | None
    outcome: str
    seconds: float
    peak_growth_bytes: int


def _status_bytes(field: str) -> int:
    """A size field of ``/proc/self/status`` (``VmRSS``...) in bytes; -1 where it is absent."""
    kib = harness.proc_status_kib(field)
    return -1 if kib is None else int(kib) * 1024


def _child(path: Path, memory_limit_bytes: int, conn: Connection) -> None:
    """Run :func:`read_everything` under an address-space limit and send back the result."""
    try:  # reset the peak RSS inherited from the parent (Linux >= 4.0)
        Path("/proc/self/clear_refs").write_text("5")
        rss_start = _status_bytes("VmRSS")
    except OSError:
        rss_start = -1
    address_space = _status_bytes("VmSize")
    if address_space > 0:
        limit = address_space + memory_limit_bytes
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    start = time.perf_counter()
    problem: str | None = None
    outcome = ""
    try:
        outcome = read_everything(path)
    except BaseException:  # everything is a finding here, and must reach the parent
        problem = traceback.format_exc()
    peak = _status_bytes("VmHWM")
    growth = peak - rss_start if rss_start >= 0 and peak >= 0 else -1
    conn.send((problem, outcome, time.perf_counter() - start, growth))
    conn.close()


def run_isolated(
    path: Path, *, timeout_s: float = 20.0, memory_limit_bytes: int = 1 << 30
) -> Verdict:
    """Run :func:`read_everything` on ``path`` in a forked child with a time and memory bound.

    Args:
        path: the log to read.
        timeout_s: wall-time bound (s); the child is killed after it.
        memory_limit_bytes: address space the child may add to what it inherits (bytes);
            beyond it allocations fail with ``MemoryError``, which is a finding.

    Returns:
        The verdict; ``problem`` is None when the property holds.
    """
    import multiprocessing

    context = multiprocessing.get_context("fork")
    receiver, sender = context.Pipe(duplex=False)
    with warnings.catch_warnings():  # Python >= 3.12 warns on fork with threads running
        warnings.simplefilter("ignore", DeprecationWarning)
        process = context.Process(target=_child, args=(path, memory_limit_bytes, sender))
        process.start()
    sender.close()
    start = time.perf_counter()
    try:
        if not receiver.poll(timeout_s):
            process.kill()
            process.join()
            return Verdict(f"timed out after {timeout_s:.0f} s", "", timeout_s, -1)
        try:
            problem, outcome, seconds, growth = receiver.recv()
        except EOFError:
            process.join()
            return Verdict(
                f"child died (exit code {process.exitcode}) without a result",
                "",
                time.perf_counter() - start,
                -1,
            )
    finally:
        receiver.close()
    process.join()
    return Verdict(problem, outcome, seconds, growth)


# --- mutations -------------------------------------------------------------------------


class MutationKind(enum.Enum):
    """The ways an input is damaged."""

    FLIP = "flip"  # flip one bit
    OVERWRITE = "overwrite"  # overwrite bytes in place
    TRUNCATE = "truncate"  # cut the file
    DELETE = "delete"  # remove a range
    DUPLICATE = "duplicate"  # copy a range and insert it elsewhere
    INFLATE = "inflate"  # set a length field to a huge or off-by-one value


@dataclass(frozen=True)
class Mutation:
    """One mutation; positions are reduced modulo the input's length when applied.

    Attributes:
        kind: what to do.
        position: byte offset (FLIP, OVERWRITE, TRUNCATE, DELETE, DUPLICATE source) or the
            index of a length field (INFLATE).
        size: bit index (FLIP), range length (DELETE, DUPLICATE) or value index (INFLATE).
        target: where DUPLICATE inserts its copy.
        payload: the bytes OVERWRITE writes.
    """

    kind: MutationKind
    position: int
    size: int = 1
    target: int = 0
    payload: bytes = b""


LENGTH_VALUES_64 = (1 << 60, (1 << 63) - 1, (1 << 64) - 1, 1 << 32, (1 << 32) + 1)
LENGTH_VALUES_32 = ((1 << 32) - 1, (1 << 31) - 1, 1 << 31, 1 << 24, 0)


def inflate(data: bytes, offset: int, width: int, choice: int) -> bytes:
    """Overwrite the little-endian ``width``-byte length field at ``offset``.

    ``choice`` picks a huge value (2^60, 2^63 - 1, ...) or the field's value plus one or
    times two plus one, so both absurd and plausible-but-wrong lengths are tried.
    """
    if offset + width > len(data):
        return data
    code = "<Q" if width == 8 else "<I"
    (old,) = struct.unpack_from(code, data, offset)
    huge = LENGTH_VALUES_64 if width == 8 else LENGTH_VALUES_32
    values = (*huge, old + 1, old * 2 + 1)
    value = values[choice % len(values)] % (1 << (8 * width))
    return data[:offset] + struct.pack(code, value) + data[offset + width :]


def apply_mutations(data: bytes, mutations: Sequence[Mutation], fields: Sequence[Field]) -> bytes:
    """Return ``data`` with the mutations applied in order.

    Args:
        data: the seed's bytes.
        mutations: what to do.
        fields: the seed's length fields (see :func:`length_fields`); INFLATE is a no-op
            without any. Offsets past the (shrunk) data are skipped.
    """
    out = bytearray(data)
    for mutation in mutations:
        if not out:
            break
        position = mutation.position % len(out)
        kind = mutation.kind
        if kind is MutationKind.FLIP:
            out[position] ^= 1 << (mutation.size % 8)
        elif kind is MutationKind.OVERWRITE:
            payload = mutation.payload[: len(out) - position]
            out[position : position + len(payload)] = payload
        elif kind is MutationKind.TRUNCATE:
            del out[position:]
        elif kind is MutationKind.DELETE:
            del out[position : position + mutation.size]
        elif kind is MutationKind.DUPLICATE:
            chunk = bytes(out[position : position + mutation.size])
            target = mutation.target % (len(out) + 1)
            out[target:target] = chunk
        elif kind is MutationKind.INFLATE and fields:
            offset, width = fields[mutation.position % len(fields)]
            out[:] = inflate(bytes(out), offset, width, mutation.size)
    return bytes(out)


# --- where the length fields are -------------------------------------------------------


def length_fields(data: bytes) -> list[Field]:
    """Return the length fields of an MCAP file or a ROS 1 bag (empty for other data).

    MCAP: every record's length, a chunk's uncompressed size, compression-name length,
    records length and zstd frame content size, the string lengths of schema and channel
    records, the records inside uncompressed chunks, and the first words of each message's
    payload (CDR string and sequence lengths). ROS 1: every record's header and data
    length, each header field's length, records inside uncompressed chunks, and the first
    words of message data.
    """
    fields: list[Field] = []
    if data.startswith(_MCAP_MAGIC):
        _mcap_fields(data, len(_MCAP_MAGIC), len(data), fields, depth=0)
    elif data.startswith(_ROS1_MAGIC_LINE):
        _ros1_fields(data, len(_ROS1_MAGIC_LINE), len(data), fields, depth=0)
    return fields


def _payload_words(start: int, end: int, fields: list[Field]) -> None:
    fields.extend((offset, 4) for offset in range(start, min(end - 3, start + 48), 4))


def _string_fields(data: bytes, position: int, end: int, count: int, fields: list[Field]) -> int:
    """Note ``count`` consecutive u32-length-prefixed strings; return the position after."""
    for _ in range(count):
        if position + 4 > end:
            break
        fields.append((position, 4))
        (length,) = struct.unpack_from("<I", data, position)
        position += 4 + length
    return position


def _mcap_fields(data: bytes, position: int, end: int, fields: list[Field], *, depth: int) -> None:
    while position + 9 <= end and len(fields) < 10_000:
        opcode = data[position]
        (length,) = struct.unpack_from("<Q", data, position + 1)
        fields.append((position + 1, 8))
        body, body_end = position + 9, min(position + 9 + length, end)
        if opcode == 0x03:  # schema: id, name, encoding, data
            _string_fields(data, body + 2, body_end, 3, fields)
        elif opcode == 0x04:  # channel: id, schema id, topic, message encoding, metadata
            _string_fields(data, body + 4, body_end, 3, fields)
        elif opcode == 0x05:  # message: channel, sequence, log and publish time, data
            _payload_words(body + 22 + 4, body_end, fields)  # after the 4-byte CDR header
        elif opcode == 0x06 and depth == 0 and body + 32 <= body_end:  # chunk
            fields.append((body + 16, 8))
            fields.append((body + 28, 4))
            (name_length,) = struct.unpack_from("<I", data, body + 28)
            records_length_at = body + 32 + name_length
            if records_length_at + 8 <= body_end:
                fields.append((records_length_at, 8))
                compression = data[body + 32 : records_length_at]
                if name_length == 0:
                    _mcap_fields(data, records_length_at + 8, body_end, fields, depth=1)
                elif compression == b"zstd":
                    fields.extend(_zstd_size_field(data, records_length_at + 8))
        elif opcode == 0x02:  # footer
            break
        if length > end - body:
            break
        position = body + length


def _zstd_size_field(data: bytes, start: int) -> list[Field]:
    """Return the content-size field of the zstd frame at ``start`` if it is 4 or 8 bytes."""
    if data[start : start + 4] != b"\x28\xb5\x2f\xfd" or start + 5 > len(data):
        return []
    descriptor = data[start + 4]  # RFC 8878, 3.1.1.1.1: the frame header descriptor
    single_segment = (descriptor >> 5) & 1
    width = (single_segment, 2, 4, 8)[descriptor >> 6]
    offset = start + 5 + (0 if single_segment else 1) + (0, 1, 2, 4)[descriptor & 3]
    return [(offset, width)] if width in (4, 8) and offset + width <= len(data) else []


def _ros1_fields(data: bytes, position: int, end: int, fields: list[Field], *, depth: int) -> None:
    while position + 4 <= end and len(fields) < 10_000:
        fields.append((position, 4))
        (header_length,) = struct.unpack_from("<I", data, position)
        header_start, header_end = position + 4, position + 4 + header_length
        if header_end + 4 > end:
            break
        op, compression = b"", b""
        cursor = header_start
        while cursor + 4 <= header_end:
            fields.append((cursor, 4))
            (field_length,) = struct.unpack_from("<I", data, cursor)
            name, _, value = data[cursor + 4 : cursor + 4 + field_length].partition(b"=")
            if name == b"op":
                op = value
            elif name == b"compression":
                compression = value
            cursor += 4 + field_length
        fields.append((header_end, 4))
        (data_length,) = struct.unpack_from("<I", data, header_end)
        data_start, data_end = header_end + 4, min(header_end + 4 + data_length, end)
        if op == b"\x05" and compression == b"none" and depth == 0:  # chunk
            _ros1_fields(data, data_start, data_end, fields, depth=1)
        elif op == b"\x02":  # message data
            _payload_words(data_start, data_end, fields)
        if data_length > end - data_start:
            break
        position = data_start + data_length


# --- seeds --------------------------------------------------------------------------------


def write_seed(
    fmt: str, folder: Path, *, frames: int = SEED_FRAMES, scale: float = SEED_SCALE
) -> Path:
    """Write a small synthetic log with ``pcainterp synth`` and return its path.

    Args:
        fmt: one of :data:`FORMATS`.
        folder: where to write it (``seed.mcap``, ``seed.bag``, or a folder ``seed_<fmt>``).
        frames: frames to render.
        scale: image scale.
    """
    if fmt == "mcap-ros1":
        bag_folder = folder / "ros1_for_mcap"
        bag_folder.mkdir(exist_ok=True)
        return _ros1_mcap(write_seed("ros1", bag_folder, frames=frames, scale=scale), folder)
    name = {"mcap": "seed.mcap", "ros1": "seed.bag"}.get(fmt, f"seed_{fmt.replace('-', '_')}")
    out = folder / name
    harness.run_cli("synth", out, "--frames", frames, "--scale", scale, "--format", fmt, quiet=True)
    return out


def _ros1_mcap(bag: Path, folder: Path) -> Path:
    """Copy a ROS 1 bag into an MCAP file with the ros1 profile (uncompressed chunks)."""
    from mcap.writer import CompressionType, Writer
    from rosbags.rosbag1 import Reader

    out = folder / "seed_ros1.mcap"
    with Reader(bag) as reader, out.open("wb") as stream:
        writer = Writer(stream, compression=CompressionType.NONE)
        writer.start("ros1", "fuzz_readers")
        channels: dict[int, int] = {}
        for connection in reader.connections:
            schema = writer.register_schema(
                connection.msgtype, "ros1msg", connection.msgdef.data.encode()
            )
            channels[connection.id] = writer.register_channel(connection.topic, "ros1", schema)
        for connection, timestamp, data in reader.messages():
            writer.add_message(channels[connection.id], timestamp, bytes(data), timestamp)
        writer.finish()  # type: ignore[no-untyped-call]
    return out


def storage_file(folder: Path) -> Path:
    """Return the storage file of a one-file rosbag2 folder (the one fuzzed)."""
    (storage,) = [p for p in folder.iterdir() if p.suffix in (".mcap", ".db3")]
    return storage


# --- the coverage-guided fuzzer ----------------------------------------------------------


@dataclass
class _Target:
    """Writes each fuzz input where the reader expects it and checks the property."""

    fmt: str
    work: Path
    crashes: Path
    stop_on_crash: bool
    template: Path | None  # a rosbag2 folder whose storage file is replaced by the input
    seen: set[str]
    stages: Sequence[str] = STAGES
    executions: int = 0

    def input_path(self) -> Path:
        if self.template is not None:
            return storage_file(self.template)
        return self.work / ("input.bag" if self.fmt == "ros1" else "input.mcap")

    def log_path(self) -> Path:
        return self.template if self.template is not None else self.input_path()

    def __call__(self, data: bytes) -> None:
        self.executions += 1
        self.input_path().write_bytes(data)
        try:
            read_everything(self.log_path(), self.stages)
        except Exception as err:
            if self.stop_on_crash:
                raise
            self.record(data, err)

    def record(self, data: bytes, err: Exception) -> None:
        frames = traceback.extract_tb(err.__traceback__)
        inner = frames[-1] if frames else None
        where = f"{Path(inner.filename).name}:{inner.lineno}" if inner else "?"
        signature = f"{type(err).__name__} at {where}"
        if signature in self.seen:
            return
        self.seen.add(signature)
        digest = hashlib.sha1(data).hexdigest()[:16]
        self.crashes.mkdir(parents=True, exist_ok=True)
        (self.crashes / f"crash-{digest}").write_bytes(data)
        text = "".join(traceback.format_exception(err))
        (self.crashes / f"crash-{digest}.txt").write_text(f"{signature}\n\n{text}")
        print(f"\nFINDING {len(self.seen)}: {signature} -> crashes/crash-{digest}", flush=True)


INSTRUMENTED = ("pcainterp_stream", "rosbags", "mcap")
"""The packages whose code libFuzzer sees (branch coverage and comparisons): ours and the two
log libraries. Only code imported inside :func:`instrument_read_path` is instrumented."""

READ_PATH_MODULES = (
    "pcainterp_stream.io.logreader",
    "pcainterp_stream.io.mcap_reader",
    "pcainterp_stream.io.rosbag1_walk",
    "pcainterp_stream.io.rosbag2_mcap",
    "pcainterp_stream.io.rosbags_reader",
    "pcainterp_stream.io.loginfo",
    "pcainterp_stream.frontend.pairing",
    "pcainterp_stream.cli.app",
    "pcainterp_stream.cli.info",
    "pcainterp_stream.pipeline.jobs",
    "pcainterp_stream.golden.store",
    "rosbags.rosbag1",
    "rosbags.rosbag2",
    "rosbags.convert.converter",
    "rosbags.serde.primitives",
)
"""The modules of :func:`read_everything`'s stages, several of which the readers, rosbags and
the CLI import lazily (on the first log of a format, or of ``pcainterp info``):
:func:`instrument_read_path` imports them all. What the stages import later (rosbags' generated
``rosbags.usertypes``) runs uninstrumented; ``tests/test_tools.py`` checks that no module of the
read path does."""


def instrument_read_path(atheris: Any) -> None:
    """Import the read path's modules under atheris' instrumentation (coverage for libFuzzer).

    ``atheris.instrument_imports`` instruments only the modules first imported inside its
    block: with nothing imported there, libFuzzer mutated blind ("no interesting inputs
    were found so far. Is the code instrumented for coverage?"), printed no ``cov:`` figure
    and never grew the corpus.

    Raises:
        RuntimeError: a module of :data:`INSTRUMENTED` was imported before, so it would run
            uninstrumented (this script's top-level imports reach none of them).
    """
    early = sorted(name for name in sys.modules if name.partition(".")[0] in INSTRUMENTED)
    if early:
        more = " ..." if len(early) > 4 else ""
        raise RuntimeError(
            f"fuzz_readers: {', '.join(early[:4])}{more} imported before atheris could "
            "instrument them (libFuzzer would get no coverage from them); run "
            "tools/fuzz_readers.py as a script in a fresh process"
        )
    with atheris.instrument_imports(include=list(INSTRUMENTED)):
        for name in READ_PATH_MODULES:
            importlib.import_module(name)


def _custom_mutator(atheris: Any, rate: float) -> Callable[[bytes, int, int], bytes]:
    """Return a mutator: libFuzzer's mutations, and now and then an inflated length field."""

    def mutate(data: bytes, max_size: int, seed: int) -> bytes:
        rng = random.Random(seed)
        if rng.random() < rate:
            fields = length_fields(data)
            if fields:
                offset, width = rng.choice(fields)
                return inflate(data, offset, width, rng.randrange(16))
        return bytes(atheris.Mutate(data, max_size))

    return mutate


def build_parser() -> argparse.ArgumentParser:
    """Return the command-line parser."""
    parser = harness.argument_parser(
        __doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=(
            "examples:\n"
            "  python tools/fuzz_readers.py --format mcap --seconds 300 fuzz_out/mcap\n"
            "  python tools/fuzz_readers.py --format ros1 --runs 20000 fuzz_out/ros1\n"
        ),
    )
    parser.add_argument("out", type=Path, metavar="DIR", help="corpus/ and crashes/ go here")
    parser.add_argument("--format", choices=FORMATS, default="mcap", dest="fmt")
    parser.add_argument("--runs", type=int, default=-1, help="inputs to try (-1: no limit)")
    parser.add_argument("--seconds", type=int, default=0, help="stop after this long (0: no limit)")
    parser.add_argument(
        "--seed-file",
        type=Path,
        action="append",
        default=[],
        metavar="FILE",
        help="add this file to the corpus (an MCAP / bag / storage file of the format)",
    )
    parser.add_argument("--timeout", type=int, default=20, help="seconds per input (hang)")
    parser.add_argument("--rss-limit-mb", type=int, default=2048, help="memory bound")
    parser.add_argument(
        "--address-space-mb",
        type=int,
        default=8192,
        help="address space the fuzzer may add once set up (an allocation a length field "
        "asked for then fails with MemoryError, a finding, instead of taking virtual memory; "
        "atheris 3's allocator needs more than 2048 to start its threads)",
    )
    parser.add_argument(
        "--length-rate",
        type=float,
        default=0.2,
        help="share of mutations that inflate a length field (MCAP and ROS 1)",
    )
    parser.add_argument("--stop-on-crash", action="store_true", help="stop at the first finding")
    parser.add_argument(
        "--stages",
        default=",".join(STAGES),
        help="comma-separated stages of the read path to run (default: all: %(default)s); "
        "fewer opens are faster on rosbags formats",
    )
    parser.add_argument("--seed", type=int, default=1, help="libFuzzer's random seed")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the coverage-guided fuzzer; return 1 when it found something, else 0.

    libFuzzer ends the process itself at the end of a run, so the fuzzing runs in a child
    (this script with ``--worker``); this process then lists the findings, removes the
    scratch folder and returns the exit status.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    unknown = {stage.strip() for stage in args.stages.split(",")} - set(STAGES)
    if unknown:
        parser.error(f"unknown --stages {', '.join(sorted(unknown))}; choose from {STAGES}")
    if args.worker:
        return _fuzz(args)
    try:
        import atheris  # noqa: F401
    except ImportError:
        print("atheris is not installed; pip install -e '.[fuzz]'", file=sys.stderr)
        return 2
    out: Path = args.out
    crashes = out / "crashes"
    before = set(crashes.iterdir()) if crashes.is_dir() else set()
    start = time.monotonic()
    try:
        worker = subprocess.run([sys.executable, __file__, *argv, "--worker"], check=False)
    finally:
        shutil.rmtree(out / "work", ignore_errors=True)
    found = sorted(p.name for p in set(crashes.iterdir()) - before if p.suffix != ".txt")
    minutes = (time.monotonic() - start) / 60
    print(f"fuzz_readers --format {args.fmt}: {minutes:.1f} min, {len(found)} findings", end="")
    print(f" in {crashes}: {', '.join(found)}" if found else "")
    if worker.returncode not in (0, 1) and not found:
        print(f"the fuzzer exited {worker.returncode}", file=sys.stderr)
        return 2
    return 1 if found else 0


def _fuzz(args: argparse.Namespace) -> int:
    """Run libFuzzer in this process (it exits the process at the end)."""
    import atheris

    try:
        instrument_read_path(atheris)
    except RuntimeError as err:
        print(err, file=sys.stderr)
        return 2
    out: Path = args.out
    corpus, crashes, work = out / "corpus", out / "crashes", out / "work"
    for folder in (corpus, crashes, work):
        folder.mkdir(parents=True, exist_ok=True)
    template: Path | None = None
    if args.fmt.startswith("rosbag2") or not any(corpus.iterdir()):
        seed = write_seed(args.fmt, work)
        if seed.is_dir():
            template = seed
            seed_bytes = storage_file(seed).read_bytes()
        else:
            seed_bytes = seed.read_bytes()
        if not any(corpus.iterdir()):
            (corpus / f"seed-{args.fmt}").write_bytes(seed_bytes)
    for extra in args.seed_file:
        shutil.copyfile(extra, corpus / f"seed-{extra.name}")
    stages = [stage.strip() for stage in args.stages.split(",")]
    target = _Target(args.fmt, work, crashes, args.stop_on_crash, template, set(), stages)
    libfuzzer_args = [
        sys.argv[0],
        str(corpus),
        f"-artifact_prefix={crashes}/",
        f"-timeout={args.timeout}",
        f"-rss_limit_mb={args.rss_limit_mb}",
        f"-seed={args.seed}",
        f"-runs={args.runs}",
        "-print_final_stats=1",
    ]
    if args.seconds > 0:
        libfuzzer_args.append(f"-max_total_time={args.seconds}")
    if args.address_space_mb > 0:
        limit = _status_bytes("VmSize") + (args.address_space_mb << 20)
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    atheris.Setup(
        libfuzzer_args,
        target,
        custom_mutator=_custom_mutator(atheris, args.length_rate),
    )
    atheris.Fuzz()
    return 0


if __name__ == "__main__":
    sys.exit(main())
