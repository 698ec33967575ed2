"""Fuzz the log readers (issue 8): a damaged log reads as far as it can or fails cleanly.

Seeds are tiny synthetic logs written by ``pcainterp synth`` in every input format (and the
real files of ``../shared/realdata`` when present). Each example damages a copy of a seed
(bit flips, overwrites, truncation, deleted or duplicated ranges, inflated length fields)
and runs the whole read path in a forked child with a time and address-space bound
(``tools/fuzz_readers.py``): open, topics, index stats, every message and its decode, one
topic alone, stereo pairing, a full count and ``pcainterp info``. The property: success or
a ``PcaInterpError`` (``pcainterp info``: exit 2 with one line), no other exception, no
hang, no allocation a length field asked for.
"""

from __future__ import annotations

import importlib.util
import shutil
import struct
import subprocess
import sys
import tempfile
import tracemalloc
from pathlib import Path
from types import ModuleType
from typing import Any

import lz4.frame
import pytest
import zstandard
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pcainterp_stream.errors import CalibrationError, LogReadError
from pcainterp_stream.frontend.pairing import iter_stereo_frames
from pcainterp_stream.io import rosbags_reader
from pcainterp_stream.io.logreader import open_log

ROOT = Path(__file__).resolve().parents[2]
REALDATA = ROOT.parent / "shared" / "realdata"
TIMEOUT_S = 30.0  # generous: the machine is shared; a hang is minutes, not seconds
MEMORY_LIMIT = 1 << 30  # address space a child may add; a 2^60 allocation fails far below
PEAK_GROWTH_LIMIT = 192 << 20  # resident memory a child may add reading a < 1 MB input


def _load_tool() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "fuzz_readers", ROOT / "tools" / "fuzz_readers.py"
    )
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["fuzz_readers"] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


FUZZ = _load_tool()
K = FUZZ.MutationKind


@pytest.fixture(scope="session")
def seeds(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A tiny synthetic log per format (2 frames at scale 0.1), written once."""
    folder = tmp_path_factory.mktemp("fuzz_seeds")
    return {fmt: FUZZ.write_seed(fmt, folder) for fmt in FUZZ.FORMATS}


def _target(log: Path, which: str) -> Path:
    """The file of a log a mutation damages: the log, or a rosbag2 folder's file."""
    if not log.is_dir():
        return log
    return log / "metadata.yaml" if which == "metadata" else FUZZ.storage_file(log)


def _copy(log: Path, into: Path) -> Path:
    copy = into / log.name
    if log.is_dir():
        shutil.copytree(log, copy)
    else:
        shutil.copyfile(log, copy)
    return copy


def _check(log: Path, what: str) -> Any:
    verdict = FUZZ.run_isolated(log, timeout_s=TIMEOUT_S, memory_limit_bytes=MEMORY_LIMIT)
    assert verdict.problem is None, f"{what}\n{verdict.problem}"
    assert verdict.peak_growth_bytes < PEAK_GROWTH_LIMIT, (
        f"{what}: reading grew the resident set by {verdict.peak_growth_bytes} bytes"
    )
    return verdict


def _mutated_check(log: Path, which: str, mutations: list[Any]) -> Any:
    with tempfile.TemporaryDirectory(prefix="fuzz_") as scratch:
        copy = _copy(log, Path(scratch))
        target = _target(copy, which)
        data = target.read_bytes()
        target.write_bytes(FUZZ.apply_mutations(data, mutations, FUZZ.length_fields(data)))
        return _check(copy, f"{log.name} ({target.name}) with {mutations}")


# --- strategies ---------------------------------------------------------------------------

POSITIONS = st.integers(min_value=0, max_value=(1 << 31) - 1)

MUTATION = st.one_of(
    st.builds(FUZZ.Mutation, st.just(K.FLIP), POSITIONS, st.integers(0, 7)),
    st.builds(
        FUZZ.Mutation,
        st.just(K.OVERWRITE),
        POSITIONS,
        payload=st.one_of(
            st.binary(min_size=1, max_size=16),
            st.sampled_from([b"\xff" * 8, b"\x00" * 8, b"\x7f\xff\xff\xff"]),
        ),
    ),
    st.builds(FUZZ.Mutation, st.just(K.TRUNCATE), POSITIONS),
    st.builds(FUZZ.Mutation, st.just(K.DELETE), POSITIONS, st.integers(1, 4096)),
    st.builds(FUZZ.Mutation, st.just(K.DUPLICATE), POSITIONS, st.integers(1, 4096), POSITIONS),
    st.builds(FUZZ.Mutation, st.just(K.INFLATE), POSITIONS, st.integers(0, 15)),
)
MUTATIONS = st.lists(MUTATION, min_size=1, max_size=3)
# a rosbag2 folder: mostly its storage file, sometimes metadata.yaml
WHICH = st.sampled_from(["storage"] * 4 + ["metadata"])

FUZZ_SETTINGS = settings(
    derandomize=True,
    deadline=None,  # the bound is the child's timeout, not hypothesis's deadline
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


# --- synthetic seeds ----------------------------------------------------------------------


@pytest.mark.parametrize("fmt", FUZZ.FORMATS)
def test_seed_reads_cleanly(seeds: dict[str, Path], fmt: str) -> None:
    verdict = _check(seeds[fmt], f"undamaged {fmt} seed")
    assert verdict.outcome.startswith("read: 12 msgs, 0 undecodable, 0 damage; one topic: 2 msgs;")
    assert "pairs: 2 pairs" in verdict.outcome
    assert verdict.outcome.endswith("info: exit 0")


@pytest.mark.slow
@pytest.mark.parametrize(
    ("fmt", "examples"),
    # rosbags opens a log in ~0.3 s (it parses every message definition) against 0.05 s
    # for MCAP: fewer examples for the rosbags formats keep the file under a minute
    [("mcap", 40), ("mcap-ros1", 15), ("ros1", 15), ("rosbag2", 15), ("rosbag2-sqlite3", 12)],
)
def test_damaged_synthetic_log_reads_or_fails_cleanly(
    seeds: dict[str, Path], fmt: str, examples: int
) -> None:
    @settings(FUZZ_SETTINGS, max_examples=examples)
    @given(mutations=MUTATIONS, which=WHICH)
    def damaged(mutations: list[Any], which: str) -> None:
        _mutated_check(seeds[fmt], which, mutations)

    damaged()


@pytest.mark.slow
@pytest.mark.parametrize("fmt", ["mcap", "mcap-ros1", "ros1", "rosbag2"])
def test_huge_length_fields_do_not_allocate(seeds: dict[str, Path], fmt: str) -> None:
    """Ten length fields spread over the seed each claim 2^60 (u64) or 2^32 - 1 (u32) bytes."""
    data = _target(seeds[fmt], "storage").read_bytes()
    fields = FUZZ.length_fields(data)
    assert len(fields) > 20, "the seed's length fields were not found"
    for index in range(0, len(fields), len(fields) // 10):
        _mutated_check(seeds[fmt], "storage", [FUZZ.Mutation(K.INFLATE, index, 0)])


# --- regressions: what the fuzzing found ----------------------------------------------------


@pytest.mark.parametrize(("fmt", "name"), [("ros1", "drive"), ("rosbag2-sqlite3", "drive_db")])
def test_log_named_without_its_suffix_reads(
    seeds: dict[str, Path], tmp_path: Path, fmt: str, name: str
) -> None:
    """Finding 1: rosbags picks its reader by suffix; a ROS 1 bag named ``drive`` (as
    ``pcainterp synth drive --format ros1`` writes it) failed with "Unrecognized storage
    format ''" although its magic bytes say what it is."""
    log = tmp_path / name
    shutil.copyfile(_target(seeds[fmt], "storage"), log)
    verdict = _check(log, f"{fmt} log named {name}")
    assert verdict.outcome.startswith("read: 12 msgs, 0 undecodable, 0 damage")


def _first_field_at_or_after(fields: list[tuple[int, int]], offset: int, width: int) -> int:
    return next(i for i, (at, w) in enumerate(fields) if at >= offset and w == width)


@pytest.mark.parametrize(
    ("fmt", "value_index"),
    [("ros1", 0), ("ros1", 1), ("rosbag2", 0), ("rosbag2", 3)],
)
def test_length_field_does_not_make_rosbags_allocate(
    seeds: dict[str, Path], fmt: str, value_index: int
) -> None:
    """Finding 2: rosbags passes length fields to ``file.read(n)``, which allocates n bytes
    first; a record length of 2^32 - 1 (ROS 1) or 2^60 (rosbag2 MCAP storage) raised
    MemoryError under a memory limit (or took gigabytes of address space without one). The
    reader now clamps every read to the bytes left in the file."""
    data = _target(seeds[fmt], "storage").read_bytes()
    fields = FUZZ.length_fields(data)
    width = 4 if fmt == "ros1" else 8
    # a record header past the file's start (the index or a chunk), and the first one
    for offset in (0, len(data) // 2):
        index = _first_field_at_or_after(fields, offset, width)
        _mutated_check(seeds[fmt], "storage", [FUZZ.Mutation(K.INFLATE, index, value_index)])


def _mcap_records(seed: Path) -> tuple[bytes, bytes]:
    """Return (header record, the records of the first chunk) of an MCAP seed."""
    data = seed.read_bytes()
    position = len(FUZZ._MCAP_MAGIC)
    header = b""
    while True:
        opcode, length = struct.unpack_from("<BQ", data, position)
        body = data[position + 9 : position + 9 + length]
        if opcode == 0x01:
            header = data[position : position + 9 + length]
        elif opcode == 0x06:
            (name_length,) = struct.unpack_from("<I", body, 28)
            compression = body[32 : 32 + name_length].decode()
            frame = body[32 + name_length + 8 :]
            assert compression == "zstd"
            return header, zstandard.ZstdDecompressor().decompress(frame)
        position += 9 + length


def _mcap_with_chunk(
    header: bytes, frame: bytes, compression: str, uncompressed_size: int
) -> bytes:
    """An MCAP file of one chunk (no summary: read linearly); CRC 0 = not checked."""
    name = compression.encode()
    chunk = struct.pack("<QQQI", 0, 0, uncompressed_size, 0)
    chunk += struct.pack("<I", len(name)) + name + struct.pack("<Q", len(frame)) + frame
    data_end = struct.pack("<BQI", 0x0F, 4, 0)
    footer = struct.pack("<BQQQI", 0x02, 20, 0, 0, 0)
    magic = FUZZ._MCAP_MAGIC
    return magic + header + struct.pack("<BQ", 0x06, len(chunk)) + chunk + data_end + footer + magic


def _zstd_frame(records: bytes, *, content_size: int | None) -> bytes:
    """A zstd frame of ``records`` whose header states ``content_size`` (None: no size)."""
    frame = zstandard.ZstdCompressor(write_content_size=False).compress(records)
    assert frame[4] == 0, "expected a frame header with a window descriptor and no size"
    if content_size is None:
        return frame
    # descriptor 0xC0: an 8-byte content size after the window descriptor (RFC 8878 3.1.1.1)
    return frame[:4] + b"\xc0" + frame[5:6] + struct.pack("<Q", content_size) + frame[6:]


def _lz4_frame(records: bytes, *, content_size: int) -> bytes:
    """An lz4 frame of ``records`` whose header states ``content_size``."""
    compressor = lz4.frame.LZ4FrameCompressor(content_checksum=False)
    frame = compressor.begin(source_size=content_size) + compressor.compress(records)
    return frame + b"\x00\x00\x00\x00"  # end mark (compressor.flush() checks the size)


HUGE = 3 << 30  # under the reader's 4 GiB chunk limit, over the children's 1 GiB


@pytest.mark.parametrize(
    ("case", "compression", "stated", "claimed"),
    [
        ("zstd frame without size, chunk claims 3 GiB", "zstd", None, HUGE),
        ("zstd frame claims 3 GiB", "zstd", HUGE, None),
        ("lz4 frame claims 3 GiB", "lz4", HUGE, None),
    ],
)
def test_mcap_chunk_size_claims_do_not_allocate(
    seeds: dict[str, Path], tmp_path: Path, case: str, compression: str, stated: Any, claimed: Any
) -> None:
    """Finding 3: zstandard's ``decompress`` allocates the size a frame header states, or
    ``max_output_size`` (the chunk's uncompressed size) when it states none; python-lz4's
    ``decompress`` allocates the frame's content size. One damaged size made the MCAP reader
    allocate 3 GiB (MemoryError under a limit, reported as damage). Now a frame size that
    disagrees with the chunk header is damage before any allocation, and frames without a
    size are streamed."""
    header, records = _mcap_records(seeds["mcap"])
    if compression == "zstd":
        frame = _zstd_frame(records, content_size=stated)
    else:
        frame = _lz4_frame(records, content_size=stated)
    log = tmp_path / "chunk.mcap"
    log.write_bytes(_mcap_with_chunk(header, frame, compression, claimed or len(records)))
    verdict = _check(log, case)
    assert verdict.outcome.startswith("read: 0 msgs"), verdict.outcome


def test_mcap_zstd_frame_without_size_reads(seeds: dict[str, Path], tmp_path: Path) -> None:
    """The streamed path reads what the one-shot path read (zstd frames without a size are
    what streaming writers produce)."""
    header, records = _mcap_records(seeds["mcap"])
    log = tmp_path / "chunk.mcap"
    log.write_bytes(
        _mcap_with_chunk(header, _zstd_frame(records, content_size=None), "zstd", len(records))
    )
    with open_log(log) as reader:
        assert sum(1 for _ in reader.messages()) == 12
        assert reader.damage == []


def test_rosbags_decompressors_do_not_allocate_stated_sizes() -> None:
    """Finding 3 in rosbags: its ROS 1 lz4 chunks and rosbag2 MCAP chunks were inflated with
    the same allocating calls; the reader bounds its decompressor tables when it opens a bag."""
    from rosbags.rosbag1 import reader as rosbag1_reader
    from rosbags.rosbag2 import storage_mcap

    records = b"x" * 4096
    rosbags_reader._bound_rosbags_decompressors()
    lz4_claim = _lz4_frame(records, content_size=HUGE)
    zstd_claim = _zstd_frame(records, content_size=HUGE)
    tracemalloc.start()
    try:
        for inflate in (
            lambda: rosbag1_reader.decompressors["lz4"](lz4_claim),
            lambda: storage_mcap.decompress(lz4_claim, "lz4", len(records), 0),
            lambda: storage_mcap.decompress(zstd_claim, "zstd", len(records), 0),
        ):
            with pytest.raises((ValueError, RuntimeError)):
                inflate()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 16 << 20
    intact = lz4.frame.compress(records)
    assert rosbag1_reader.decompressors["lz4"](intact) == records
    intact_zstd = zstandard.ZstdCompressor().compress(records)
    assert storage_mcap.decompress(intact_zstd, "zstd", len(records), 0) == records


def test_right_camera_info_with_denormal_fx_is_a_calibration_error(
    seeds: dict[str, Path], tmp_path: Path
) -> None:
    """Finding 4: one flipped exponent bit turns the right camera's fx into a denormal
    (~1e-310); -P[0,3] / fx overflowed with a RuntimeWarning and gave an infinite baseline.
    Now it is the CalibrationError of a missing baseline."""
    with open_log(seeds["ros1"]) as reader:
        raw = next(reader.messages(["/stereo/right/camera_info"]))
        p = [float(v) for v in reader.decode(raw).p]
    data = seeds["ros1"].read_bytes()
    intact = struct.pack("<12d", *p)
    assert data.count(intact) == 2, "expected the right P of both frames in the bag"
    log = tmp_path / "denormal_fx.bag"
    log.write_bytes(data.replace(intact, struct.pack("<12d", 1e-310, *p[1:])))
    verdict = _check(log, "right fx = 1e-310")
    assert "pairs: CalibrationError" in verdict.outcome
    with open_log(log) as reader, pytest.raises(CalibrationError, match=r"gives no baseline"):
        list(iter_stereo_frames(reader))


def _edit_metadata(
    seeds: dict[str, Path], tmp_path: Path, old: str, new: str, fmt: str = "rosbag2-sqlite3"
) -> Path:
    """A copy of a rosbag2 seed with its metadata.yaml edited.

    sqlite3 storage by default: a folder with MCAP storage is read through its storage files
    (bug hunt 6B M7), whose topics and counts its metadata.yaml does not override.
    """
    bag = _copy(seeds[fmt], tmp_path)
    metadata = bag / "metadata.yaml"
    text = metadata.read_text()
    assert old in text
    metadata.write_text(text.replace(old, new, 1))
    return bag


def test_rosbag2_metadata_message_count_not_a_number_is_damage(
    seeds: dict[str, Path], tmp_path: Path
) -> None:
    """Finding 5: rosbags takes a topic's message_count from metadata.yaml as YAML gives it;
    ``message_count: abc`` made ``topics()`` raise ValueError. Now it is damage and the count
    unknown; the messages are still read from the storage file."""
    bag = _edit_metadata(seeds, tmp_path, "message_count: 2", "message_count: abc")
    verdict = _check(bag, "message_count: abc")
    assert verdict.outcome.startswith("read: 12 msgs, 0 undecodable, 1 damage")
    with open_log(bag) as reader:
        assert reader.topics()["/stereo/left/image_rect"].message_count is None
        assert reader.damage == [
            f"{bag.name}: metadata.yaml gives topic /stereo/left/image_rect a message count "
            "of 'abc'"
        ]


def test_rosbag2_metadata_topic_not_text_is_an_error(
    seeds: dict[str, Path], tmp_path: Path
) -> None:
    """Finding 5: a topic ``name: 12`` gave an int topic, which broke sorting and string
    formatting downstream (TypeError). Now opening the bag fails with one line."""
    bag = _edit_metadata(seeds, tmp_path, "name: /stereo/left/image_rect", "name: 12")
    _check(bag, "topic name: 12")
    with pytest.raises(LogReadError, match=r"metadata.yaml has a topic named 12, not text"):
        open_log(bag)


def test_rosbag2_mcap_storage_reads_its_files_whatever_metadata_yaml_says_of_topics(
    seeds: dict[str, Path], tmp_path: Path
) -> None:
    """The topics and counts of a folder with MCAP storage are its storage files'."""
    bag = _edit_metadata(seeds, tmp_path, "message_count: 2", "message_count: abc", "rosbag2")
    verdict = _check(bag, "message_count: abc, MCAP storage")
    assert verdict.outcome.startswith("read: 12 msgs, 0 undecodable, 0 damage")
    with open_log(bag) as reader:
        assert reader.topics()["/stereo/left/image_rect"].message_count == 2


# --- real files written by others --------------------------------------------------------

needs_realdata = pytest.mark.skipif(
    not REALDATA.is_dir(), reason=f"real data not found at {REALDATA} (not in a user's checkout)"
)


def _realdata_logs() -> list[str]:
    conformance = "mcap_conformance/TenMessages/TenMessages-"
    return [
        conformance + "ch-chx-mx-rch-rsh-st-sum.mcap",  # chunked, indexed, full summary
        conformance + "ch-chx-rch.mcap",  # chunked, no message index, partial summary
        conformance + "rch-rsh-st-sum.mcap",  # unchunked
        "ros1/example-lz4.bag",
        "ros1/example-bz2.bag",
        "ros1/example-unsorted-chunks.bag",
        "rosbag2/mcap/cdr_test",
        "rosbag2/sqlite3/talker/talker.db3",
        "rosbag2/standalone/chatter.db3",
    ]


@pytest.mark.slow
@pytest.mark.realdata
@needs_realdata
@pytest.mark.parametrize("name", _realdata_logs())
def test_damaged_real_log_reads_or_fails_cleanly(name: str, tmp_path: Path) -> None:
    log = REALDATA / name
    if not log.exists():
        pytest.skip(f"{log} not found")
    seed = _copy(log, tmp_path)  # never mutate or commit the shared files

    @settings(FUZZ_SETTINGS, max_examples=4)
    @given(mutations=MUTATIONS, which=WHICH)
    def damaged(mutations: list[Any], which: str) -> None:
        _mutated_check(seed, which, mutations)

    damaged()


# --- the coverage-guided fuzzer -----------------------------------------------------------


@pytest.mark.slow
def test_fuzz_tool_short_run(seeds: dict[str, Path], tmp_path: Path) -> None:
    """A few seconds of ``tools/fuzz_readers.py`` (atheris) on MCAP finds nothing."""
    pytest.importorskip("atheris", reason="atheris not installed: pip install -e '.[fuzz]'")
    out = tmp_path / "fuzz"
    (out / "corpus").mkdir(parents=True)
    shutil.copyfile(seeds["mcap"], out / "corpus" / "seed.mcap")  # no second synth run
    result = subprocess.run(
        [
            *(sys.executable, str(ROOT / "tools" / "fuzz_readers.py"), "--format", "mcap"),
            *("--runs", "60", "--seconds", "20", str(out)),
        ],
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-4000:]
    assert "0 findings" in result.stdout
    assert "Done 60 runs" in result.stderr or "DONE" in result.stderr
    assert not (out / "work").exists()
    assert any((out / "corpus").iterdir())
