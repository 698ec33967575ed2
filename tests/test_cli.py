"""The command line on bad input (issue #4): one-line errors, exit codes, no partial output.

Most tests run ``pcainterp`` in-process through :func:`pcainterp_stream.cli.main` and read
its output with ``capsys``; the signal tests run it as a subprocess. Every failing run must
print exactly one line ``pcainterp: error: ...`` on stderr (no traceback), return 2 and
leave nothing at the output target, nor a partial file or folder beside it.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import re
import signal
import subprocess
import sys
import time
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import IndexType, Writer

from pcainterp_stream import cli
from pcainterp_stream.cli.common import DOCS_NOTE
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.frontend.matchers import DENSE_SGBM, REFINED_DENSE_SGBM
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.frontend.stereo import compute_disparity
from pcainterp_stream.io import logwriter, rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.io.outputs import MEASUREMENTS_KEY, image_of, recorded_metadata
from pcainterp_stream.pipeline.jobs import LearnOptions, learn, synth

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
needs_realdata = pytest.mark.skipif(
    not REALDATA.is_dir(), reason=f"real data folder {REALDATA} is absent"
)

LEFT = "/stereo/left/image_rect"
RIGHT = "/stereo/right/image_rect"
LEFT_INFO = "/stereo/left/camera_info"
RIGHT_INFO = "/stereo/right/camera_info"
SMALL_FRAMES = 8
SMALL_SIZE = (94, 310)  # (height, width) of a --scale 0.25 synthetic log
Message = tuple[str, Any, int]  # (topic, decoded message, log time ns)


# ----------------------------------------------------------------------------- helpers


@dataclasses.dataclass
class Run:
    """What one ``pcainterp`` run returned and printed."""

    code: int
    out: str
    err: str

    def error_line(self) -> str:
        """Return the one error line, checking the failure contract on the way."""
        assert self.code == 2, f"expected exit 2, got {self.code}; stderr: {self.err}"
        assert "Traceback" not in self.err
        lines = self.err.splitlines()
        assert len(lines) == 1, f"expected one stderr line, got {lines}"
        assert lines[0].startswith("pcainterp: error: ")
        return lines[0]


@pytest.fixture
def pcainterp(capsys: pytest.CaptureFixture[str]) -> Callable[..., Run]:
    """Return a function that runs ``pcainterp ARGS...`` in-process."""

    def run(*args: str | Path) -> Run:
        capsys.readouterr()
        code = cli.main([str(arg) for arg in args])
        captured = capsys.readouterr()
        return Run(code, captured.out, captured.err)

    return run


def assert_nothing_written(target: Path) -> None:
    """Check that neither the target nor a temporary beside it exists."""
    assert not target.exists(), f"{target} was left behind"
    if target.parent.is_dir():
        stray = [p.name for p in target.parent.iterdir() if p.name.startswith(f".{target.name}")]
        assert not stray, f"temporaries left beside {target}: {stray}"


def read_messages(log: Path) -> list[Message]:
    """Return every message of a log, decoded, in file order."""
    with open_log(log) as reader:
        return [(raw.topic, reader.decode(raw), raw.log_time_ns) for raw in reader.messages()]


def write_messages(path: Path, messages: list[Message]) -> Path:
    """Write decoded messages as an MCAP log with the project's writer."""
    with open_writer(path, "mcap") as writer:
        for topic, message, log_time_ns in messages:
            writer.add_message(topic, message, log_time_ns)
    return path


def write_unindexed(path: Path, messages: list[Message]) -> Path:
    """Write decoded messages as an MCAP without chunks or index: it is read in file order."""
    with path.open("wb") as f:
        writer = Writer(f, use_chunking=False, index_types=IndexType.NONE)
        writer.start("ros2", "test")
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for topic, message, log_time_ns in messages:
            msgtype = message.__msgtype__
            if msgtype not in schemas:
                text = rosmsg.schema_text(msgtype).encode()
                schemas[msgtype] = writer.register_schema(msgtype, "ros2msg", text)
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, "cdr", schemas[msgtype])
            data = rosmsg.serialize(message)
            writer.add_message(channels[topic], log_time_ns, data, log_time_ns)
        writer.finish()
    return path


def rewrite(source: Path, target: Path, change: Callable[[str, Any, int], Any | None]) -> Path:
    """Copy a log, passing every message through ``change`` (None drops it)."""
    changed = []
    for topic, message, log_time_ns in read_messages(source):
        new = change(topic, message, log_time_ns)
        if new is not None:
            changed.append((topic, new, log_time_ns))
    return write_messages(target, changed)


def chunk_records(data: bytes) -> list[tuple[int, int]]:
    """Return (offset, length) of the top-level chunk records of an MCAP file."""
    chunks = []
    offset = 8
    while offset + 9 <= len(data):
        opcode = data[offset]
        length = int.from_bytes(data[offset + 1 : offset + 9], "little")
        if opcode == 0x06:
            chunks.append((offset, length))
        if opcode in (0x0F, 0x02):  # data end, footer
            break
        offset += 9 + length
    return chunks


def assert_valid_mcap(path: Path) -> dict[str, int]:
    """Read an MCAP file with mcap's own seeking reader; return messages per topic."""
    counts: dict[str, int] = {}
    with path.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None
        assert summary.statistics is not None
        for _, channel, _ in reader.iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
        assert sum(counts.values()) == summary.statistics.message_count
    with open_log(path) as ours:
        assert sum(1 for _ in ours.messages()) == sum(counts.values())
        assert ours.damage == []
    return counts


def depth_shapes(path: Path) -> list[tuple[int, int]]:
    """Return the (height, width) of every /pcainterp/depth image of a log."""
    with open_log(path) as reader:
        return [
            image_of(reader.decode(raw)).shape[:2] for raw in reader.messages(["/pcainterp/depth"])
        ]


# ----------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="session")
def small_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An 8-frame quarter-size synthetic log written in small chunks (several per frame)."""
    path = tmp_path_factory.mktemp("logs") / "small.mcap"
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(logwriter, "MCAP_CHUNK_SIZE", 16 * 1024)
        synth(path, frames=SMALL_FRAMES, seed=3, scale=0.25, fmt="mcap")
    return path


@pytest.fixture(scope="session")
def small_messages(small_log: Path) -> list[Message]:
    return read_messages(small_log)


@pytest.fixture(scope="session")
def basis_path(small_log: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 5-component basis learned from the small log."""
    path = tmp_path_factory.mktemp("basis") / "basis.npz"
    learn([small_log], path, LearnOptions(n_components=5, fit_prior=False), PairingConfig())
    return path


@pytest.fixture
def out(tmp_path: Path) -> Path:
    """An output path in an empty folder of its own."""
    folder = tmp_path / "out"
    folder.mkdir()
    return folder / "dense.mcap"


def densify_args(log: Path, target: Path, basis: Path, *extra: str | Path) -> list[str | Path]:
    return ["densify", log, "-o", target, "--basis", basis, *extra]


# ----------------------------------------------------------------------------- --help


SUBCOMMANDS = ["synth", "import-kitti", "learn", "densify", "info", "demo"]


@pytest.mark.parametrize("command", SUBCOMMANDS)
def test_help_exits_zero_with_examples(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        cli.main([command, "--help"])
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    assert "examples:" in text
    assert f"pcainterp {command}" in text.split("examples:")[1]


def test_top_level_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["--help"])
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    assert "examples:" in text
    for command in SUBCOMMANDS:
        assert command in text


def _parsers(
    parser: argparse.ArgumentParser, name: str = "pcainterp"
) -> list[tuple[str, argparse.ArgumentParser]]:
    """Return (command, parser) of the top level and of every subcommand, nested ones too."""
    found = [(name, parser)]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for command, sub in action.choices.items():
                found.extend(_parsers(sub, f"{name} {command}"))
    return found


def test_a_help_that_cites_the_docs_says_where_they_are(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """An installed package has no docs/ folder (bug hunt 6B L11): a help citing a page
    says it is the source repository's, and every page it cites is there."""
    docs = Path(__file__).resolve().parents[1] / "docs"
    citing = []
    for name, parser in _parsers(cli.build_parser()):
        text = parser.format_help()
        pages = set(re.findall(r"docs/(\w+)\.md", text))
        if pages:
            citing.append(name)
            assert " ".join(text.split()).endswith(" ".join(DOCS_NOTE.split())), name
        assert [page for page in pages if not (docs / f"{page}.md").is_file()] == [], name
    assert sorted(citing) == ["pcainterp densify", "pcainterp learn"]
    assert "source repository" in " ".join(DOCS_NOTE.split())


def test_every_option_and_command_has_help() -> None:
    parsers = _parsers(cli.build_parser())
    assert {"pcainterp evaluate", "pcainterp golden", "pcainterp info"} <= dict(parsers).keys()
    bare = [
        f"{name}: {'/'.join(action.option_strings) or action.metavar or action.dest}"
        for name, parser in parsers
        for action in parser._actions
        if not isinstance(action, argparse._SubParsersAction) and not (action.help or "").strip()
    ]
    assert bare == []  # before: learn LOG, -o, --components, ...; evaluate --sigma, ...
    undescribed = [name for name, parser in parsers[1:] if not parser.description]
    assert undescribed == []  # before: pcainterp info


def _help(command: str, capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit):
        cli.main([command, "--help"])
    return " ".join(capsys.readouterr().out.split())


def test_stereo_options_state_their_defaults_and_learn_no_densify_modes(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from pcainterp_stream.frontend.stereo import GfttConfig, SgbmConfig

    gftt, sgbm = GfttConfig(), SgbmConfig()
    for command in ("densify", "learn"):
        text = _help(command, capsys)
        assert f"(default {gftt.quality_level:g})" in text
        assert f"two corners, px (default {gftt.min_distance:g})" in text
        assert f"multiple of 16 (default {sgbm.num_disparities}" in text
        assert f"odd (default {sgbm.block_size})" in text
        assert f"{sgbm.mode.name.lower()} (3, parallel over strips; the default)" in text
    learn_help = _help("learn", capsys)
    assert "--measurements" not in learn_help  # a densify option
    assert "(default 1; docs/benchmarks.md)" in learn_help  # --stereo-downscale
    densify_help = " ".join(_help("densify", capsys).split())
    assert "(default auto: 1 when the camera's f*b is below 90 px*m" in densify_help
    assert "its images at most 1280x720, else 2; --measurements dense: 1;" in densify_help
    info_help = _help("info", capsys)
    assert "the built-in bases" in info_help
    assert "built-in basis" not in info_help.replace("built-in bases", "")


# ----------------------------------------------------------------------------- the good path


def test_densify_succeeds(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path
) -> None:
    run = pcainterp(*densify_args(small_log, out, basis_path))
    assert run.code == 0, run.err
    assert run.err == ""
    assert f"densified {SMALL_FRAMES} frames" in run.out
    assert "damage" not in run.out
    counts = assert_valid_mcap(out)
    assert counts["/pcainterp/depth"] == SMALL_FRAMES
    assert [p.name for p in out.parent.iterdir()] == [out.name]
    assert "carried from the 4 previous frames" in run.out


def test_densify_dense_measurements(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path
) -> None:
    run = pcainterp(
        *densify_args(small_log, out, basis_path, "--measurements", "dense", "--precision", "full")
    )
    assert run.code == 0, run.err
    assert "fused with the whole SGBM map (dense)" in run.out
    counts = assert_valid_mcap(out)
    assert counts["/pcainterp/depth"] == SMALL_FRAMES
    assert recorded_metadata(out)[MEASUREMENTS_KEY] == "dense"
    messages = read_messages(out)
    disparity = next(m for t, m, _ in messages if t == "/pcainterp/disparity")
    fused = rosmsg.image_array(disparity.image)
    assert np.isfinite(fused).all()
    # the default matcher (REFINED_DENSE_SGBM) matches the left band too: where it finds a
    # value there, it is kept
    left, right = (
        rosmsg.image_array(next(m for t, m, _ in messages if t == f"/stereo/{side}/image_rect"))
        for side in ("left", "right")
    )
    matched = compute_disparity(left, right, REFINED_DENSE_SGBM)
    band = np.zeros(matched.shape, bool)
    band[:, : DENSE_SGBM.band] = True
    found = band & np.isfinite(matched)
    assert found.sum() > 0.3 * band.sum()
    assert np.median(np.abs(fused - matched)[found]) < 0.1
    # a feature stream is sparse: dense mode refuses it in one line
    other = out.parent / "other.mcap"
    run = pcainterp(
        *densify_args(small_log, other, basis_path, "--measurements", "dense"),
        "--features-topic",
        "/features",
    )
    assert run.code == 2
    assert "drop --features-topic" in run.err
    assert not other.exists()


def test_densify_dense_full_matcher(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path
) -> None:
    run = pcainterp(
        *densify_args(small_log, out, basis_path, "--measurements", "dense", "--precision", "full"),
        "--dense-matcher",
        "full",
    )
    assert run.code == 0, run.err
    messages = read_messages(out)
    fused = rosmsg.image_array(next(m for t, m, _ in messages if t == "/pcainterp/disparity").image)
    assert np.isfinite(fused).all()
    # where the whole-range matcher matched, dense mode keeps its value
    left, right = (
        rosmsg.image_array(next(m for t, m, _ in messages if t == f"/stereo/{side}/image_rect"))
        for side in ("left", "right")
    )
    matched = compute_disparity(left, right, DENSE_SGBM)
    found = np.isfinite(matched)
    assert found.mean() > 0.5
    assert np.median(np.abs(fused - matched)[found]) < 0.1
    # the matcher of dense mode only: without it, one line naming the fix
    other = out.parent / "other.mcap"
    run = pcainterp(*densify_args(small_log, other, basis_path), "--dense-matcher", "full")
    assert run.code == 2
    assert "add --measurements dense" in run.err
    assert len(run.err.strip().splitlines()) == 1
    assert not other.exists()


def test_densify_outputs_chooses_the_channels(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path
) -> None:
    chosen = "disparity, disparity_std,features,camera_info"
    run = pcainterp(*densify_args(small_log, out, basis_path, "--outputs", chosen))
    assert run.code == 0, run.err
    counts = assert_valid_mcap(out)
    written = {topic for topic in counts if topic.startswith("/pcainterp/")}
    assert written == {
        "/pcainterp/disparity",
        "/pcainterp/disparity_std",
        "/pcainterp/features",
        "/pcainterp/camera_info",
    }
    assert all(counts[topic] == SMALL_FRAMES for topic in written)
    assert counts[LEFT] == SMALL_FRAMES  # the input is still copied whole


def test_densify_outputs_may_name_depth_mm(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path
) -> None:
    # refused as an unknown channel, though written by default
    run = pcainterp(*densify_args(small_log, out, basis_path, "--outputs", "features,depth_mm"))
    assert run.code == 0, run.err
    counts = assert_valid_mcap(out)
    written = {topic for topic in counts if topic.startswith("/pcainterp/")}
    assert written == {"/pcainterp/features", "/pcainterp/depth_mm"}


@pytest.mark.parametrize(
    ("value", "expected"),
    [
        ("depth,dpeth", "--outputs: unknown output channel dpeth; choose from depth, depth_std"),
        (",", "--outputs: no output channel chosen"),
    ],
)
def test_densify_outputs_rejects_bad_names(
    pcainterp: Callable[..., Run],
    value: str,
    expected: str,
    small_log: Path,
    basis_path: Path,
    out: Path,
) -> None:
    line = pcainterp(*densify_args(small_log, out, basis_path, "--outputs", value)).error_line()
    assert expected in line
    assert_nothing_written(out)


def test_densify_writer_failure_is_one_error_and_writes_nothing(
    pcainterp: Callable[..., Run],
    small_log: Path,
    basis_path: Path,
    out: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The writer runs in a thread of its own: its failure still ends the job cleanly."""
    calls = 0
    original = logwriter.McapLogWriter._add_message

    def failing(self: logwriter.McapLogWriter, *args: Any) -> None:
        nonlocal calls
        calls += 1
        if calls == 10:
            raise OSError(28, "No space left on device")
        original(self, *args)

    monkeypatch.setattr(logwriter.McapLogWriter, "_add_message", failing)
    line = pcainterp(*densify_args(small_log, out, basis_path)).error_line()
    assert f"writing {out} failed: OSError" in line
    assert "No space left on device" in line
    assert_nothing_written(out)


def test_densify_rejects_negative_carry_frames(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path
) -> None:
    run = pcainterp(*densify_args(small_log, out, basis_path), "--carry-frames", "-1")
    assert run.code != 0
    assert "--carry-frames must be >= 0, got -1" in run.err
    assert not out.exists()


URDF = b'<robot name="r2d2"/>'
ROSBAG2_RECORD = ("rosbag2", {"serialized_metadata": "x", "ros_distro": "humble"})


def with_extras(source: Path, target: Path) -> Path:
    """Copy an MCAP log adding an attachment, a metadata record and a channel without messages."""
    with source.open("rb") as f, target.open("wb") as g:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        writer = Writer(g)
        writer.start("ros2", "test")
        schemas = {
            s.id: writer.register_schema(s.name, s.encoding, s.data)
            for s in summary.schemas.values()
        }
        channels = {
            c.id: writer.register_channel(c.topic, c.message_encoding, schemas[c.schema_id])
            for c in summary.channels.values()
        }
        writer.register_channel("/empty_topic", "cdr", next(iter(schemas.values())))
        writer.add_metadata(*ROSBAG2_RECORD)
        writer.add_attachment(2, 1, "robot.urdf", "application/xml", URDF)
        for _, channel, message in reader.iter_messages():
            writer.add_message(
                channels[channel.id], message.log_time, message.data, message.publish_time
            )
        writer.finish()
    return target


def extras_of(data: bytes) -> tuple[list[Any], list[Any], list[str]]:
    """Return the attachments, metadata records and topics of an MCAP file's bytes."""
    reader = make_reader(io.BytesIO(data))
    summary = reader.get_summary()
    assert summary is not None
    attachments = [
        (a.name, a.media_type, a.log_time, a.create_time, a.data) for a in reader.iter_attachments()
    ]
    metadata = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
    return attachments, metadata, [c.topic for c in summary.channels.values()]


def test_densify_keeps_attachments_metadata_and_channels_without_messages(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, tmp_path: Path, out: Path
) -> None:
    log = with_extras(small_log, tmp_path / "extras.mcap")
    run = pcainterp(*densify_args(log, out, basis_path))
    assert run.code == 0, run.err
    assert "damage" not in run.out
    attachments, metadata, topics = extras_of(out.read_bytes())
    assert attachments == [("robot.urdf", "application/xml", 1, 2, URDF)]  # before: []
    assert metadata[0] == ROSBAG2_RECORD  # before: []
    # what made it, and (written at the end) every basis its outputs were made with
    assert [name for name, _ in metadata[1:]] == ["pcainterp.densify", "pcainterp.basis"]
    assert "/empty_topic" in topics  # before: missing
    assert "/pcainterp/depth" in topics
    for path in (log, out):  # before: info never named them
        text = pcainterp("info", path).out
        assert re.search(r"\n    /empty_topic +0  sensor_msgs/msg/", text)
        assert re.search(r"\n  attachments: 1\n    robot.urdf +20 bytes  application/xml\n", text)
        assert "  metadata records: " in text
        assert re.search(r"\n    rosbag2 +2 keys\n", text)
    assert "attachments" not in pcainterp("info", small_log).out
    # the log's other readers take it as it is: golden files and evaluate
    golden = tmp_path / "dense.golden.json"
    assert pcainterp("golden", "save", out, "-o", golden).code == 0
    run = pcainterp("golden", "check", out, golden)
    assert run.code == 0, run.out + run.err
    fast = ["--no-basis", "--no-linear", "--sweep-every", "0"]
    run = pcainterp("evaluate", out, "-o", tmp_path / "report", *fast)
    assert run.code == 0, run.err


def test_densify_through_pipes_keeps_attachments_and_metadata(
    small_log: Path, basis_path: Path, tmp_path: Path
) -> None:
    from pcainterp_stream.pipeline.densify import densify

    log = with_extras(small_log, tmp_path / "extras.mcap")
    output = io.BytesIO()
    with log.open("rb") as stream:  # a stream, as standard input is: spooled, then read
        densify(stream, output, basis_path)
    attachments, metadata, topics = extras_of(output.getvalue())
    assert attachments == [("robot.urdf", "application/xml", 1, 2, URDF)]
    assert metadata[0] == ROSBAG2_RECORD
    assert [name for name, _ in metadata[1:]] == ["pcainterp.densify", "pcainterp.basis"]
    assert "/empty_topic" in topics


# ----------------------------------------------------------------------------- missing input


def test_densify_missing_input(
    pcainterp: Callable[..., Run], basis_path: Path, out: Path, tmp_path: Path
) -> None:
    missing = tmp_path / "nope.mcap"
    line = pcainterp(*densify_args(missing, out, basis_path)).error_line()
    assert f"{missing} does not exist" in line
    assert "MCAP" in line
    assert_nothing_written(out)


def test_learn_missing_input(pcainterp: Callable[..., Run], tmp_path: Path) -> None:
    target = tmp_path / "basis.npz"
    line = pcainterp("learn", tmp_path / "nope.mcap", "-o", target).error_line()
    assert "nope.mcap does not exist" in line
    assert_nothing_written(target)


def test_info_missing_input(pcainterp: Callable[..., Run], tmp_path: Path) -> None:
    line = pcainterp("info", tmp_path / "nope.mcap").error_line()
    assert "nope.mcap does not exist" in line


def test_import_kitti_missing_folder(pcainterp: Callable[..., Run], out: Path) -> None:
    line = pcainterp("import-kitti", out.parent / "no_such_drive", out).error_line()
    assert "no_such_drive does not exist" in line
    assert_nothing_written(out)


def test_densify_missing_basis(
    pcainterp: Callable[..., Run], small_log: Path, out: Path, tmp_path: Path
) -> None:
    line = pcainterp(*densify_args(small_log, out, tmp_path / "none.npz")).error_line()
    assert "none.npz does not exist" in line
    assert_nothing_written(out)


def test_densify_basis_that_is_a_folder_or_a_log(
    pcainterp: Callable[..., Run], small_log: Path, out: Path, tmp_path: Path
) -> None:
    # a folder "did not exist"; a log leaked numpy's hint to load pickles unsafely
    line = pcainterp(*densify_args(small_log, out, tmp_path)).error_line()
    assert f"basis file {tmp_path} is a folder, not a basis file; pass the path of" in line
    line = pcainterp(*densify_args(small_log, out, small_log)).error_line()
    assert f"basis file {small_log} is not a basis file (.npz): it is an MCAP log; pass" in line
    assert "pickle" not in line
    dense = tmp_path / "dense"
    line = pcainterp("densify", small_log, "--out-dir", dense, "--basis", tmp_path).error_line()
    assert "is a folder, not a basis file" in line
    line = pcainterp("evaluate", small_log, "--basis", tmp_path).error_line()
    assert "is a folder, not a basis file" in line
    assert_nothing_written(out)


@pytest.mark.parametrize("command", ["densify", "evaluate"])
def test_a_misspelt_built_in_basis_name_lists_the_names(
    pcainterp: Callable[..., Run], small_log: Path, out: Path, command: str
) -> None:
    target = ["-o", out] if command == "densify" else ["-o", out.parent / "report"]
    line = pcainterp(command, small_log, *target, "--basis", "builtin-indor").error_line()
    assert line.endswith(
        "basis file builtin-indor does not exist; pass the path of a basis .npz (pcainterp "
        "learn writes one), or one of builtin, builtin-street and builtin-indoor"
    )
    assert list(out.parent.iterdir()) == []


def test_evaluate_takes_the_built_in_basis_names_as_densify_does(
    pcainterp: Callable[..., Run], small_log: Path, tmp_path: Path
) -> None:
    """`evaluate --basis builtin` was refused with an error saying to pass `builtin`
    (bug hunt 6A F13)."""
    dense = tmp_path / "indoor.mcap"
    assert pcainterp("densify", small_log, "-o", dense, "--basis", "builtin-indoor").code == 0
    fast = ["--mode", "stereo", "--max-frames", "1", "--sweep-every", "0", "--no-linear"]
    for name, used in [
        ("builtin", "built-in-indoor"),  # the one the log records densify used
        ("builtin-street", "built-in"),
        ("builtin-indoor", "built-in-indoor"),
    ]:
        run = pcainterp("evaluate", dense, "-o", tmp_path / name, "--basis", name, *fast)
        assert run.code == 0, run.err
        assert f"basis of the re-densified rows: {used} (given), at --sigma" in run.out
    line = pcainterp("evaluate", dense, "--basis", "builtin", "--no-basis").error_line()
    assert "--no-basis and --basis contradict each other" in line


# ----------------------------------------------------------------------------- not a log


def _not_a_log(kind: str, folder: Path) -> Path:
    if kind == "random.mcap":
        path = folder / kind
        path.write_bytes(np.random.default_rng(0).bytes(4096))
    elif kind == "notes.txt":
        path = folder / kind
        path.write_text("this is a text file\nnot a log\n")
    elif kind == "image.png":
        path = folder / kind
        ok, data = cv2.imencode(".png", np.zeros((8, 8), np.uint8))
        assert ok
        path.write_bytes(data.tobytes())
    elif kind == "empty.bag":
        path = folder / kind
        path.write_bytes(b"")
    else:  # a folder with arbitrary files
        path = folder / kind
        path.mkdir()
        (path / "readme.txt").write_text("hello")
    return path


NOT_LOGS = ["random.mcap", "notes.txt", "image.png", "empty.bag", "folder"]


@pytest.mark.parametrize("kind", NOT_LOGS)
def test_densify_not_a_log(
    pcainterp: Callable[..., Run], kind: str, basis_path: Path, out: Path, tmp_path: Path
) -> None:
    path = _not_a_log(kind, tmp_path)
    line = pcainterp(*densify_args(path, out, basis_path)).error_line()
    assert str(path) in line
    assert "pass an MCAP file" in line
    assert_nothing_written(out)


@pytest.mark.parametrize("kind", NOT_LOGS)
def test_learn_not_a_log(pcainterp: Callable[..., Run], kind: str, tmp_path: Path) -> None:
    path = _not_a_log(kind, tmp_path)
    target = tmp_path / "basis.npz"
    line = pcainterp("learn", path, "-o", target).error_line()
    assert str(path) in line
    assert_nothing_written(target)


@pytest.mark.parametrize("kind", ["random.mcap", "notes.txt", "image.png", "folder"])
def test_info_not_a_log(pcainterp: Callable[..., Run], kind: str, tmp_path: Path) -> None:
    path = _not_a_log(kind, tmp_path)
    line = pcainterp("info", path).error_line()
    assert str(path) in line


# ----------------------------------------------------------------------------- KITTI folders


def _fake_kitti_drive(root: Path, *, calibration: bool) -> Path:
    """A tiny KITTI raw drive: two 40x24 grey pairs, timestamps, optional calibration."""
    drive = root / "2011_09_26" / "2011_09_26_drive_0001_sync"
    rng = np.random.default_rng(1)
    for camera in ("image_00", "image_01"):
        (drive / camera / "data").mkdir(parents=True)
        for index in range(2):
            image = rng.integers(0, 255, (24, 40), dtype=np.uint8)
            cv2.imwrite(str(drive / camera / "data" / f"{index:010d}.png"), image)
        (drive / camera / "timestamps.txt").write_text(
            "2011-09-26 13:02:25.964389445\n2011-09-26 13:02:26.067700624\n"
        )
    if calibration:
        (drive.parent / "calib_cam_to_cam.txt").write_text(
            "P_rect_00: 30.0 0.0 20.0 0.0 0.0 30.0 12.0 0.0 0.0 0.0 1.0 0.0\n"
            "P_rect_01: 30.0 0.0 20.0 -16.0 0.0 30.0 12.0 0.0 0.0 0.0 1.0 0.0\n"
        )
    return drive


@pytest.mark.parametrize("level", ["drive", "date"])
def test_densify_kitti_folder_suggests_import(
    pcainterp: Callable[..., Run], level: str, basis_path: Path, out: Path, tmp_path: Path
) -> None:
    drive = _fake_kitti_drive(tmp_path, calibration=True)
    folder = drive if level == "drive" else drive.parent
    line = pcainterp(*densify_args(folder, out, basis_path)).error_line()
    assert str(folder) in line
    assert "pcainterp import-kitti" in line
    assert_nothing_written(out)


def test_info_and_learn_kitti_folder_suggest_import(
    pcainterp: Callable[..., Run], tmp_path: Path
) -> None:
    drive = _fake_kitti_drive(tmp_path, calibration=True)
    assert "pcainterp import-kitti" in pcainterp("info", drive).error_line()
    target = tmp_path / "basis.npz"
    assert "pcainterp import-kitti" in pcainterp("learn", drive, "-o", target).error_line()
    assert_nothing_written(target)


def test_import_kitti_missing_calibration(
    pcainterp: Callable[..., Run], out: Path, tmp_path: Path
) -> None:
    drive = _fake_kitti_drive(tmp_path, calibration=False)
    line = pcainterp("import-kitti", drive, out).error_line()
    assert "calib_cam_to_cam.txt" in line
    assert str(drive) in line
    assert_nothing_written(out)


def test_import_kitti_odometry_missing_calibration(
    pcainterp: Callable[..., Run], out: Path, tmp_path: Path
) -> None:
    sequence = tmp_path / "sequences" / "00"
    for camera in ("image_0", "image_1"):
        (sequence / camera).mkdir(parents=True)
        cv2.imwrite(str(sequence / camera / "000000.png"), np.zeros((24, 40), np.uint8))
    line = pcainterp("import-kitti", sequence, out).error_line()
    assert "calib.txt" in line
    assert str(sequence) in line
    assert_nothing_written(out)


def test_import_kitti_not_kitti(pcainterp: Callable[..., Run], out: Path, tmp_path: Path) -> None:
    folder = tmp_path / "holiday_photos"
    folder.mkdir()
    line = pcainterp("import-kitti", folder, out).error_line()
    assert "is not a KITTI folder" in line
    assert_nothing_written(out)


def test_import_kitti_then_densify(
    pcainterp: Callable[..., Run], basis_path: Path, out: Path, tmp_path: Path
) -> None:
    drive = _fake_kitti_drive(tmp_path, calibration=True)
    log = out.parent / "drive.mcap"
    run = pcainterp("import-kitti", drive, log)
    assert run.code == 0, run.err
    run = pcainterp(*densify_args(log, out, basis_path, "--num-disparities", "16"))
    assert run.code == 0, run.err
    assert depth_shapes(out) == [(24, 40), (24, 40)]


@pytest.mark.parametrize(
    ("name", "format_args"),
    [("s.mcap", []), ("s.bag", []), ("s2", ["--format", "rosbag2"])],
)
def test_synth_and_import_kitti_on_a_full_disk_are_one_error(
    pcainterp: Callable[..., Run],
    full_disk: Callable[[int], None],
    tmp_path: Path,
    name: str,
    format_args: list[str],
) -> None:
    """A disk that fills up mid-way was a traceback here (only densify's threaded writer
    turned it into the one line)."""
    drive = _fake_kitti_drive(tmp_path, calibration=True)
    target = tmp_path / "out" / name
    target.parent.mkdir()
    full_disk(20_000)
    line = pcainterp("synth", target, "--frames", "4", "--scale", "0.2", *format_args).error_line()
    assert line == (
        f"pcainterp: error: writing {target} failed: OSError: [Errno 28] No space left on "
        "device; nothing was written there; free some space, or write it elsewhere"
    )
    assert_nothing_written(target)
    if name.endswith(".mcap"):
        full_disk(1000)  # room for the header, not the two frames
        line = pcainterp("import-kitti", drive, target).error_line()
        assert f"writing {target} failed: OSError: [Errno 28] No space left" in line
        assert_nothing_written(target)


def test_import_kitti_output_missing_folder(pcainterp: Callable[..., Run], tmp_path: Path) -> None:
    drive = _fake_kitti_drive(tmp_path, calibration=True)
    target = tmp_path / "missing" / "drive.mcap"
    line = pcainterp("import-kitti", drive, target).error_line()
    assert "missing does not exist" in line
    assert not target.parent.exists()


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["learn", "LOG", "-o", "-"], "-o is -, but learn writes a basis file (.npz), which "),
        (["import-kitti", "DRIVE", "-"], "OUT is -, but import-kitti writes a log file "),
        (["synth", "-", "--frames", "2"], "OUT is -, but synth writes a log file "),
        (["golden", "save", "LOG", "-o", "-"], "-o is -, but golden save writes a golden "),
    ],
)
def test_an_output_that_cannot_be_a_stream_refuses_dash(
    pcainterp: Callable[..., Run],
    small_log: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    args: list[str],
    expected: str,
) -> None:
    """`-` was a basis file, a rosbag2 folder or a golden file named "-" (bug hunt 6A F10)."""
    drive = _fake_kitti_drive(tmp_path, calibration=True)
    monkeypatch.chdir(tmp_path)
    given = [{"LOG": small_log, "DRIVE": drive}.get(arg, arg) for arg in args]
    line = pcainterp(*given).error_line()
    assert expected in line
    assert "cannot go to standard output; name a path, e.g. " in line
    assert not (tmp_path / "-").exists()


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["info", "-"], "FILE is -, but info does not read standard input (only densify's "),
        (["learn", "-", "-o", "b.npz"], "LOG is -, but learn does not read standard input"),
        (["learn", "LOG", "-o", "b.npz", "--fit-logs", "LOG", "-"], "--fit-logs is -, but "),
        (["evaluate", "-"], "DENSIFIED.mcap is -, but evaluate does not read standard input"),
        (["golden", "check", "LOG", "-"], "GOLDEN.json is -, but golden check does not read "),
        (["import-kitti", "-", "o.mcap"], "KITTI_DIR is -, but import-kitti does not read "),
        (["densify", "LOG", "-o", "o.mcap", "--basis", "-"], "(only its INPUT does); name a "),
    ],
)
def test_an_input_that_is_not_read_from_standard_input_refuses_dash(
    pcainterp: Callable[..., Run],
    small_log: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    args: list[str],
    expected: str,
) -> None:
    """`pcainterp info -` said "- does not exist", as if a file were missing."""
    monkeypatch.chdir(tmp_path)
    line = pcainterp(*[small_log if arg == "LOG" else arg for arg in args]).error_line()
    assert expected in line
    assert "does not exist" not in line
    assert line.endswith("by path (a file named -: ./-)")
    assert sorted(path.name for path in tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ["import-kitti", "synth"])
def test_a_rosbag2_output_onto_an_existing_file_is_refused_up_front(
    pcainterp: Callable[..., Run],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    command: str,
) -> None:
    """The whole import ran, then "cannot move the finished output onto outfile: Not a
    directory; check the folder's permissions" (bug hunt 6A F10)."""
    from pcainterp_stream.pipeline import jobs

    drive = _fake_kitti_drive(tmp_path, calibration=True)
    target = tmp_path / "outfile"
    target.write_text("notes")
    for job in ("import_kitti", "synth"):  # up front: no job starts
        monkeypatch.setattr(jobs, job, lambda *args, **kwargs: pytest.fail("the job ran"))
    given = [drive, target] if command == "import-kitti" else [target, "--frames", "2"]
    line = pcainterp(command, *given).error_line()
    assert line == (
        f"pcainterp: error: output {target} is an existing file, but a name without a suffix "
        f"writes a rosbag2 bag, which is a folder; name the output {target}.mcap or "
        f"{target}.bag, or remove the file"
    )
    line = pcainterp("synth", target, "--format", "rosbag2-sqlite3").error_line()
    assert "but --format rosbag2-sqlite3 writes a rosbag2 bag, which is a folder; choose " in line
    assert target.read_text() == "notes"
    # import-kitti has no --format for the library's "or pass the format explicitly"
    named = tmp_path / "drive.txt"
    given = [drive, named] if command == "import-kitti" else [named]
    line = pcainterp(command, *given).error_line()
    assert line.endswith(
        f"output {named} is named .txt, which is no log format; name it .mcap or .bag, or "
        "without a suffix for a rosbag2 folder"
        + (", or pass --format" if command == "synth" else "")
    )
    assert not named.exists()


# ----------------------------------------------------------------------------- damaged MCAP


@pytest.mark.parametrize("fraction", [0.02, 0.15, 0.5, 0.8, 0.97, 0.9999])
def test_densify_truncated(
    pcainterp: Callable[..., Run],
    fraction: float,
    small_log: Path,
    basis_path: Path,
    out: Path,
    tmp_path: Path,
) -> None:
    data = small_log.read_bytes()
    cut = int(len(data) * fraction)
    damaged = tmp_path / "cut.mcap"
    damaged.write_bytes(data[:cut])
    run = pcainterp(*densify_args(damaged, out, basis_path))
    if run.code == 0:
        assert run.err == ""
        assert "damage: cut.mcap:" in run.out
        assert "truncated" in run.out
        frames = int(run.out.split("densified ")[1].split()[0])
        assert 0 < frames <= SMALL_FRAMES
        counts = assert_valid_mcap(out)
        assert counts["/pcainterp/depth"] == frames
        assert not [p for p in out.parent.iterdir() if p.name.startswith(".")]
    else:
        line = run.error_line()
        assert "no stereo pair found in" in line
        assert str(damaged) in line
        assert "truncated" in line
        assert_nothing_written(out)
    if fraction >= 0.5:  # half of the log holds complete frames
        assert run.code == 0, run.err
    if fraction <= 0.02:  # not even one image
        assert run.code == 2


def test_learn_and_evaluate_report_a_truncated_log(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path, tmp_path: Path
) -> None:
    data = small_log.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.8)])
    args = ["--no-fit-prior", "--with-synthetic", "0", "--components", "2"]
    run = pcainterp("learn", cut, "-o", tmp_path / "b.npz", *args)
    assert run.code == 0, run.err
    assert "damage: cut.mcap: no MCAP magic at the end" in run.out
    assert "learn uses the frames before it" in run.out
    assert pcainterp(*densify_args(small_log, out, basis_path)).code == 0
    dense = out.read_bytes()
    cut_dense = tmp_path / "cut_dense.mcap"
    cut_dense.write_bytes(dense[: int(len(dense) * 0.8)])
    report = tmp_path / "report"
    run = pcainterp("evaluate", cut_dense, "-o", report, "--no-basis", "--no-linear")
    assert run.code == 0, run.err
    assert "damage: cut_dense.mcap: " in run.out
    assert "only the frames read before it count" in (report / "results.md").read_text()
    assert json.loads((report / "results.json").read_text())["damage"]


@pytest.mark.parametrize("fraction", [0.3, 0.6, 0.95])
def test_densify_truncated_inside_its_only_chunk(
    pcainterp: Callable[..., Run],
    fraction: float,
    small_messages: list[Message],
    basis_path: Path,
    out: Path,
    tmp_path: Path,
) -> None:
    whole = write_messages(tmp_path / "whole.mcap", small_messages)  # default chunks
    data = whole.read_bytes()
    assert len(chunk_records(data)) == 1
    damaged = tmp_path / "cut.mcap"
    damaged.write_bytes(data[: int(len(data) * fraction)])
    run = pcainterp(*densify_args(damaged, out, basis_path))
    assert run.code == 0, run.err
    assert "chunk record claims" in run.out
    frames = int(run.out.split("densified ")[1].split()[0])
    # the frames before the cut: where it falls in a frame's messages depends on how well
    # each compresses (a cut in the last frame's ground truth keeps all 8 stereo pairs)
    assert 0 < frames <= SMALL_FRAMES
    assert abs(frames - fraction * SMALL_FRAMES) <= 2
    counts = assert_valid_mcap(out)
    assert counts["/pcainterp/depth"] == frames
    assert counts[LEFT] >= frames
    copied = sum(n for topic, n in counts.items() if not topic.startswith("/pcainterp/"))
    assert copied < len(small_messages)  # what follows the cut is lost, nothing invented


def test_densify_corrupt_chunk(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path, tmp_path: Path
) -> None:
    data = bytearray(small_log.read_bytes())
    chunks = chunk_records(bytes(data))
    assert len(chunks) >= 2 * SMALL_FRAMES  # the fixture writes small chunks
    offset, length = chunks[len(chunks) // 2]
    middle = offset + 9 + length // 2
    data[middle : middle + 64] = bytes(64)
    damaged = tmp_path / "corrupt.mcap"
    damaged.write_bytes(bytes(data))
    run = pcainterp(*densify_args(damaged, out, basis_path))
    assert run.code == 0, run.err
    assert "damage: corrupt.mcap: corrupt chunk skipped" in run.out
    assert f"at byte {offset}" in run.out
    frames = int(run.out.split("densified ")[1].split()[0])
    assert SMALL_FRAMES - 2 <= frames < SMALL_FRAMES
    counts = assert_valid_mcap(out)
    assert counts["/pcainterp/depth"] == frames


def test_densify_corrupt_chunks_everywhere(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path, tmp_path: Path
) -> None:
    data = bytearray(small_log.read_bytes())
    for offset, length in chunk_records(bytes(data)):
        middle = offset + 9 + length // 2
        data[middle : middle + 16] = b"\xff" * 16
    damaged = tmp_path / "ruined.mcap"
    damaged.write_bytes(bytes(data))
    line = pcainterp(*densify_args(damaged, out, basis_path)).error_line()
    assert "ruined.mcap" in line
    assert "corrupt chunk" in line
    assert_nothing_written(out)


def test_info_reports_damage(
    pcainterp: Callable[..., Run], small_log: Path, tmp_path: Path
) -> None:
    damaged = tmp_path / "cut.mcap"
    damaged.write_bytes(small_log.read_bytes()[: small_log.stat().st_size // 2])
    run = pcainterp("info", damaged)
    assert run.code == 0, run.err
    assert "truncated" in run.out


# ----------------------------------------------------------------------------- topics


def test_densify_missing_topic_option(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path
) -> None:
    run = pcainterp(*densify_args(small_log, out, basis_path, "--right-topic", "/cam/right"))
    line = run.error_line()
    assert "topic /cam/right not found in small.mcap" in line
    assert f"topics present: /ground_truth/depth, /ground_truth/pose, {LEFT_INFO}" in line
    assert line.endswith("; set --right-topic to one of them")
    assert_nothing_written(out)


def test_densify_names_the_topic_a_typo_meant(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path
) -> None:
    """A misspelt --left-topic is told the topic it was close to, not to pass --left-topic."""
    typo = LEFT[:-1]
    line = pcainterp(*densify_args(small_log, out, basis_path, "--left-topic", typo)).error_line()
    assert f"topic {typo} not found in small.mcap; topics present: " in line
    assert line.endswith(f"; the closest is {LEFT}: set --left-topic to it")
    assert_nothing_written(out)


def test_the_closest_topic_is_one_the_option_takes(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path
) -> None:
    """Not the other side's image topic, nor a camera info for an image option."""
    left_typo = LEFT[:-1]  # closest to the left image, which --left-topic already names
    line = pcainterp(
        *densify_args(small_log, out, basis_path, "--right-topic", left_typo)
    ).error_line()
    assert line.endswith(f"; the closest is {RIGHT}: set --right-topic to it")
    info_typo = LEFT_INFO[:-1]
    line = pcainterp(
        *densify_args(small_log, out, basis_path, "--right-topic", info_typo)
    ).error_line()
    assert LEFT_INFO not in line.split("; ")[-1]
    assert_nothing_written(out)


def test_densify_log_without_right_images(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path, tmp_path: Path
) -> None:
    log = rewrite(small_log, tmp_path / "mono.mcap", lambda t, m, _: None if t == RIGHT else m)
    line = pcainterp(*densify_args(log, out, basis_path)).error_line()
    assert "no stereo pair found in" in line
    assert "mono.mcap" in line
    assert LEFT in line
    assert "pass --left-topic and --right-topic" in line  # /ground_truth/depth is an image too
    assert_nothing_written(out)


def _two_heads(small_messages: list[Message], path: Path) -> Path:
    """The small log with a second stereo head: every /stereo/* message also on /front/*."""
    messages = []
    for topic, message, log_time_ns in small_messages:
        messages.append((topic, message, log_time_ns))
        if topic.startswith("/stereo/"):
            messages.append((topic.replace("/stereo/", "/front/", 1), message, log_time_ns))
    return write_messages(path, messages)


def test_densify_two_heads_lists_the_heads_not_cross_pairs(
    pcainterp: Callable[..., Run],
    small_messages: list[Message],
    basis_path: Path,
    out: Path,
    tmp_path: Path,
) -> None:
    log = _two_heads(small_messages, tmp_path / "heads.mcap")
    line = pcainterp(*densify_args(log, out, basis_path)).error_line()
    assert "2 stereo pairs in " in line
    assert "heads.mcap are equally good" in line
    assert "--left-topic /front/left/image_rect --right-topic /front/right/image_rect" in line
    assert f"--left-topic {LEFT} --right-topic {RIGHT}" in line
    assert "/front/left/image_rect --right-topic /stereo" not in line
    assert "its --left-topic alone will do" in line
    assert_nothing_written(out)


@pytest.mark.parametrize(
    ("option", "named", "sibling"),
    [
        ("--left-topic", "/front/left/image_rect", "right /front/right/image_rect"),
        ("--left-topic", LEFT, f"right {RIGHT}"),  # the default topic, named
        ("--right-topic", RIGHT, f"left {LEFT}"),
        ("--right-topic", "/front/right/image_rect", "left /front/left/image_rect"),
    ],
)
def test_densify_one_side_named_takes_its_sibling(
    pcainterp: Callable[..., Run],
    small_messages: list[Message],
    basis_path: Path,
    out: Path,
    tmp_path: Path,
    option: str,
    named: str,
    sibling: str,
) -> None:
    log = _two_heads(small_messages, tmp_path / "heads.mcap")
    run = pcainterp(*densify_args(log, out, basis_path, option, named))
    assert run.code == 0, run.err
    assert sibling in run.out.splitlines()[0]
    assert "found by name for the " in run.out.splitlines()[0]
    assert "less preferred" not in run.out
    assert f"densified {SMALL_FRAMES} frames" in run.out


def test_densify_finds_a_pair_of_one_compressed_and_one_raw_side(
    pcainterp: Callable[..., Run],
    small_log: Path,
    small_messages: list[Message],
    basis_path: Path,
    tmp_path: Path,
) -> None:
    left, right = "/cam/left/image_raw/compressed", "/cam/right/image_raw"
    renamed = {
        LEFT: left,
        RIGHT: right,
        LEFT_INFO: "/cam/left/camera_info",
        RIGHT_INFO: "/cam/right/camera_info",
    }
    messages = []
    for topic, message, log_time_ns in small_messages:
        if topic == LEFT:  # PNG: lossless, so the outputs are the original log's
            ok, data = cv2.imencode(".png", image_of(message))
            assert ok
            stamp = rosmsg.stamp_ns(message)
            frame_id = message.header.frame_id
            message = rosmsg.compressed_image_message(data.tobytes(), "png", stamp, frame_id)
        messages.append((renamed.get(topic, topic), message, log_time_ns))
    log = write_messages(tmp_path / "mixed.mcap", messages)
    run = pcainterp(*densify_args(log, tmp_path / "mixed_out.mcap", basis_path))
    assert run.code == 0, run.err
    assert run.out.startswith(
        f"topics: left {left}, right {right} with /cam/left/camera_info and "
        "/cam/right/camera_info (found by name;"
    )
    assert f"densified {SMALL_FRAMES} frames" in run.out
    run = pcainterp(*densify_args(small_log, tmp_path / "small_out.mcap", basis_path))
    assert run.code == 0, run.err
    original = _depth_by_log_time(tmp_path / "small_out.mcap")
    assert _depth_by_log_time(tmp_path / "mixed_out.mcap") == original


def test_learn_finds_each_logs_own_topics(
    pcainterp: Callable[..., Run],
    small_log: Path,
    small_messages: list[Message],
    tmp_path: Path,
) -> None:
    renamed = [(topic.replace("/stereo/", "/cam/", 1), m, t) for topic, m, t in small_messages]
    cam = write_messages(tmp_path / "cam.mcap", renamed)
    target = tmp_path / "basis.npz"
    args = ["--components", "3", "--no-fit-prior", "--with-synthetic", "0"]
    run = pcainterp("learn", small_log, cam, "-o", target, *args)
    assert run.code == 0, run.err
    lines = run.out.splitlines()
    assert lines[0].startswith(f"small.mcap: topics: left {LEFT}, right {RIGHT}")
    assert lines[1].startswith("cam.mcap: topics: left /cam/left/image_rect, right /cam/right")
    assert "training maps    16 (SGBM)" in run.out  # 8 of each log
    # a log with no pair is refused before any work, naming it
    mono = write_messages(tmp_path / "mono.mcap", [m for m in renamed if "/right/" not in m[0]])
    line = pcainterp("learn", small_log, mono, "-o", tmp_path / "b2.npz", *args).error_line()
    assert "no stereo pair found in " in line
    assert "mono.mcap" in line
    assert_nothing_written(tmp_path / "b2.npz")


def test_learn_missing_topic(
    pcainterp: Callable[..., Run], small_log: Path, tmp_path: Path
) -> None:
    target = tmp_path / "basis.npz"
    line = pcainterp("learn", small_log, "-o", target, "--depth-topic", "/depth").error_line()
    assert "topic /depth not found" in line
    assert "set --depth-topic to one of them" in line
    assert_nothing_written(target)


@pytest.mark.parametrize(
    ("option", "topic", "expected"),
    [
        (
            "--left-topic",
            LEFT_INFO,
            "has type sensor_msgs/msg/CameraInfo, not sensor_msgs/msg/Image",
        ),
        (
            "--right-info-topic",
            LEFT,
            "has type sensor_msgs/msg/Image, not sensor_msgs/msg/CameraInfo",
        ),
        (
            "--features-topic",
            "/ground_truth/pose",
            "has type geometry_msgs/msg/PoseStamped, not sensor_msgs/msg/PointCloud2",
        ),
    ],
)
def test_densify_topic_of_wrong_type(
    pcainterp: Callable[..., Run],
    option: str,
    topic: str,
    expected: str,
    small_log: Path,
    basis_path: Path,
    out: Path,
) -> None:
    line = pcainterp(*densify_args(small_log, out, basis_path, option, topic)).error_line()
    assert f"topic {topic} in small.mcap {expected}" in line
    if option == "--features-topic":  # the log has none: passing the option cannot help
        assert line.endswith("; the log has no topic of that type")
    else:
        assert "topics of that type: " in line
        assert line.endswith(f"pass {option}")
    assert_nothing_written(out)


def test_learn_depth_topic_of_wrong_type(
    pcainterp: Callable[..., Run], small_log: Path, tmp_path: Path
) -> None:
    target = tmp_path / "basis.npz"
    args = ["learn", small_log, "-o", target, "--depth-topic", "/ground_truth/pose"]
    line = pcainterp(*args).error_line()
    assert "topic /ground_truth/pose in small.mcap has type geometry_msgs/msg/PoseStamped" in line
    assert "depth topics in the log: /ground_truth/depth;" in line  # no camera image offered
    assert line.endswith("as --depth-topic")
    assert_nothing_written(target)


def test_learn_depth_topic_of_camera_images(
    pcainterp: Callable[..., Run], small_log: Path, tmp_path: Path
) -> None:
    target = tmp_path / "basis.npz"
    line = pcainterp("learn", small_log, "-o", target, "--depth-topic", LEFT).error_line()
    assert line == (
        f"pcainterp: error: topic {LEFT} in small.mcap is unusable as depth: mono8 is a camera "
        "image, not depth (depth is 32FC1, 16UC1, mono16 or compressedDepth); depth topics in "
        "the log: /ground_truth/depth; pass a depth topic (32FC1 m, 16UC1 mm or "
        "compressedDepth) as --depth-topic"
    )
    assert_nothing_written(target)


def test_learn_depth_topic_unusable_encoding(
    pcainterp: Callable[..., Run], small_log: Path, tmp_path: Path
) -> None:
    def change(topic: str, message: Any, _: int) -> Any:
        if topic == "/ground_truth/depth":
            return dataclasses.replace(message, encoding="64FC1")
        return message

    log = rewrite(small_log, tmp_path / "odd_depth.mcap", change)
    target = tmp_path / "basis.npz"
    args = ["learn", log, "-o", target, "--depth-topic", "/ground_truth/depth"]
    line = pcainterp(*args).error_line()
    assert "topic /ground_truth/depth in odd_depth.mcap is unusable as depth" in line
    assert "64FC1 is an image, not depth" in line
    assert line.endswith("(32FC1 m, 16UC1 mm or compressedDepth) as --depth-topic")
    assert_nothing_written(target)


def test_learn_without_a_decodable_pair(
    pcainterp: Callable[..., Run], small_log: Path, tmp_path: Path
) -> None:
    def change(topic: str, message: Any, _: int) -> Any:
        return dataclasses.replace(message, encoding="nv21") if topic == RIGHT else message

    log = rewrite(small_log, tmp_path / "odd.mcap", change)
    target = tmp_path / "basis.npz"
    line = pcainterp("learn", log, "-o", target).error_line()
    assert f"no stereo pair found in {log}" in line
    assert_nothing_written(target)


def test_densify_rrd_folder_missing(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path, tmp_path: Path
) -> None:
    rrd = tmp_path / "no" / "view.rrd"
    line = pcainterp(*densify_args(small_log, out, basis_path, "--rrd", rrd)).error_line()
    assert f"folder {rrd.parent} does not exist" in line
    assert_nothing_written(out)


# ----------------------------------------------------------------------------- images


@pytest.mark.parametrize("encoding", ["nv21", "64FC1"])
def test_densify_unsupported_encoding_everywhere(
    pcainterp: Callable[..., Run],
    encoding: str,
    small_log: Path,
    basis_path: Path,
    out: Path,
    tmp_path: Path,
) -> None:
    def change(topic: str, message: Any, _: int) -> Any:
        return dataclasses.replace(message, encoding=encoding) if topic == LEFT else message

    log = rewrite(small_log, tmp_path / "odd.mcap", change)
    line = pcainterp(*densify_args(log, out, basis_path)).error_line()
    assert "no stereo pair found in" in line
    assert f"unsupported image encoding '{encoding}'" in line
    assert f"{SMALL_FRAMES} undecodable" in line
    assert_nothing_written(out)


def test_densify_refuses_float_images_naming_the_topic(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path, tmp_path: Path
) -> None:
    # a 32FC1 image is depth or disparity, not a camera image: refused at decoding, in one
    # line, not by the stereo front end in the processor thread
    def change(topic: str, message: Any, _: int) -> Any:
        if topic not in (LEFT, RIGHT):
            return message
        image = rosmsg.image_array(message).astype(np.float32) / 255
        return rosmsg.image_message(image, rosmsg.stamp_ns(message), message.header.frame_id)

    log = rewrite(small_log, tmp_path / "float.mcap", change)
    line = pcainterp(*densify_args(log, out, basis_path)).error_line()
    assert f"{SMALL_FRAMES} undecodable (unsupported image encoding '32FC1')" in line
    assert f"{LEFT} at " in line
    assert "camera images are mono8, 8UC1, rgb8, bgr8, 8UC3, bgra8, rgba8, 8UC4, bayer_" in line
    assert_nothing_written(out)


def _blanked(small_log: Path, target: Path, frames: int) -> Path:
    """The small log with its first ``frames`` pairs black (SGBM: disparity 0 all over)."""
    blanked: dict[str, int] = {}

    def change(topic: str, message: Any, _: int) -> Any:
        if topic not in (LEFT, RIGHT) or blanked.get(topic, 0) >= frames:
            return message
        blanked[topic] = blanked.get(topic, 0) + 1
        image = np.zeros_like(rosmsg.image_array(message))
        return rosmsg.image_message(image, rosmsg.stamp_ns(message), message.header.frame_id)

    return rewrite(small_log, target, change)


def test_densify_warns_of_frames_without_a_measurement(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path, tmp_path: Path
) -> None:
    # the first two pairs black (a lens cap, a dark tunnel): no corner, no lookup
    log = _blanked(small_log, tmp_path / "blank.mcap", 2)
    run = pcainterp(*densify_args(log, out, basis_path, "--carry-frames", "0"))
    assert run.code == 0
    assert (
        f"warning: 2 of {SMALL_FRAMES} frames had no measurement (blank, dark or textureless "
        "images): they have no estimate, their depth is NaN" in run.err  # a diagnostic
    )
    assert "had no measurement" not in run.out  # the report alone on standard output
    # ... and they have none: NaN all over (not the prior's mean, a scene never seen)
    with open_log(out) as reader:
        depths = [image_of(reader.decode(raw)) for raw in reader.messages(["/pcainterp/depth"])]
    assert len(depths) == SMALL_FRAMES
    assert all(np.isnan(depth).all() for depth in depths[:2])
    assert all(np.isfinite(depth).mean() > 0.5 for depth in depths[2:])
    plain = pcainterp(*densify_args(small_log, out, basis_path))
    assert "had no measurement" not in plain.err
    assert "could not check" not in plain.err  # the rectified-and-not-swapped check decided


def test_densify_says_when_the_rows_could_not_be_checked(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path, tmp_path: Path
) -> None:
    # black all through (a lens cap): no corner to tell a raw or swapped pair by
    log = _blanked(small_log, tmp_path / "black.mcap", SMALL_FRAMES)
    run = pcainterp(*densify_args(log, out, basis_path))
    assert run.code == 0, run.err
    assert (
        f"warning: could not check that {LEFT} / {RIGHT} is rectified and not swapped: 0 "
        f"matched corners in all {SMALL_FRAMES} frames, 30 needed (dark, blank or unrelated "
        "images); it was densified unchecked" in run.err
    )


def test_densify_a_mono_and_colour_pair_in_grey(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path, tmp_path: Path
) -> None:
    def change(topic: str, message: Any, _: int) -> Any:  # mono8 left, rgb8 right
        if topic != RIGHT:
            return message
        grey = rosmsg.image_array(message)
        colour = np.repeat(grey[:, :, None], 3, axis=2)
        return rosmsg.image_message(colour, rosmsg.stamp_ns(message), message.header.frame_id)

    log = rewrite(small_log, tmp_path / "mixed.mcap", change)
    run = pcainterp(*densify_args(log, out, basis_path))
    assert run.code == 0, run.err
    height, width = SMALL_SIZE
    assert (
        f"encodings: the left images are {width}x{height} uint8, the right ones "
        f"{width}x{height}x3 uint8: both converted to grey" in run.out
    )
    assert f"{SMALL_FRAMES} pairs" in run.out
    # evaluate's SGBM reference takes the pair in grey as densify did (was a traceback)
    fast = ["--no-basis", "--no-linear", "--sweep-every", "0"]
    run = pcainterp("evaluate", out, "-o", tmp_path / "report", *fast)
    assert run.code == 0, run.err
    assert (tmp_path / "report" / "results.md").is_file()


def test_densify_unsupported_encoding_some_frames(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path, tmp_path: Path
) -> None:
    stamps = sorted(
        {
            m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
            for t, m, _ in read_messages(small_log)
            if t == LEFT
        }
    )
    bad = set(stamps[2:4])

    def change(topic: str, message: Any, _: int) -> Any:
        if topic == LEFT and rosmsg.stamp_ns(message) in bad:
            return dataclasses.replace(message, encoding="nv21")
        return message

    log = rewrite(small_log, tmp_path / "mixed.mcap", change)
    run = pcainterp(*densify_args(log, out, basis_path))
    assert run.code == 0, run.err
    assert f"densified {SMALL_FRAMES - 2} frames" in run.out
    assert "2 undecodable (unsupported image encoding 'nv21')" in run.out
    assert assert_valid_mcap(out)["/pcainterp/depth"] == SMALL_FRAMES - 2


@pytest.mark.parametrize("damage", ["empty_jpeg", "zero_image"])
def test_empty_images_are_undecodable_in_densify_and_learn(
    pcainterp: Callable[..., Run],
    small_messages: list[Message],
    basis_path: Path,
    out: Path,
    tmp_path: Path,
    damage: str,
) -> None:
    """Bug hunt 7A F2 / F3: a 0-byte CompressedImage payload was a cv2 traceback; a 0x0
    Image stopped the run (a size error). Both are counted as undecodable, the rest runs."""
    stamps = sorted({rosmsg.stamp_ns(m) for t, m, _ in small_messages if t == LEFT})
    bad = set(stamps[2:4])
    messages = []
    for topic, message, log_time_ns in small_messages:
        stamp = rosmsg.stamp_ns(message) if topic == LEFT else 0
        if topic == LEFT and damage == "empty_jpeg":
            ok, jpeg = cv2.imencode(".jpg", image_of(message))
            assert ok
            data = b"" if stamp in bad else jpeg.tobytes()
            frame_id = message.header.frame_id
            message = rosmsg.compressed_image_message(data, "jpeg", stamp, frame_id)
            topic = f"{LEFT}/compressed"
        elif topic == LEFT and stamp in bad:
            message = rosmsg.image_message(np.zeros((0, 0), np.uint8), stamp, "left")
        messages.append((topic, message, log_time_ns))
    log = write_messages(tmp_path / f"{damage}.mcap", messages)
    reason = "compressed jpeg image is empty" if damage == "empty_jpeg" else "image is empty"
    run = pcainterp(*densify_args(log, out, basis_path))
    assert run.code == 0, run.err
    assert "Traceback" not in run.err
    assert f"densified {SMALL_FRAMES - 2} frames" in run.out
    assert f"2 undecodable ({reason})" in run.out
    assert assert_valid_mcap(out)["/pcainterp/depth"] == SMALL_FRAMES - 2
    learn_args = ["--components", "3", "--no-fit-prior", "--with-synthetic", "0"]
    run = pcainterp("learn", log, "-o", tmp_path / "basis.npz", *learn_args)
    assert run.code == 0, run.err
    assert f"training maps    {SMALL_FRAMES - 2} (SGBM)" in run.out


def _resized_right(every: bool) -> Callable[[str, Any, int], Any]:
    def change(topic: str, message: Any, _: int) -> Any:
        if topic != RIGHT or (not every and message.header.stamp.nanosec != 0):
            return message
        image = rosmsg.image_array(message)
        smaller = cv2.resize(
            np.asarray(image, dtype=np.uint8), (image.shape[1] // 2, image.shape[0] // 2)
        )
        return rosmsg.image_message(
            smaller, rosmsg.stamp_ns(message), message.header.frame_id, encoding="mono8"
        )

    return change


def test_densify_size_mismatch(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path, tmp_path: Path
) -> None:
    log = rewrite(small_log, tmp_path / "sizes.mcap", _resized_right(every=True))
    line = pcainterp(*densify_args(log, out, basis_path)).error_line()
    assert "no stereo pair found in" in line
    height, width = SMALL_SIZE
    assert f"is {width}x{height} uint8 but right image" in line
    assert f"is {width // 2}x{height // 2} uint8" in line
    assert "a rectified pair needs equal sizes" in line
    assert_nothing_written(out)


def test_densify_size_mismatch_some_frames(
    pcainterp: Callable[..., Run],
    small_messages: list[Message],
    small_log: Path,
    basis_path: Path,
    out: Path,
    tmp_path: Path,
) -> None:
    whole_seconds = sum(
        1 for t, m, _ in small_messages if t == RIGHT and m.header.stamp.nanosec == 0
    )
    assert 0 < whole_seconds < SMALL_FRAMES
    log = rewrite(small_log, tmp_path / "sizes.mcap", _resized_right(every=False))
    run = pcainterp(*densify_args(log, out, basis_path))
    assert run.code == 0, run.err
    assert f"densified {SMALL_FRAMES - whole_seconds} frames" in run.out
    assert f"{whole_seconds} size mismatches" in run.out


# ----------------------------------------------------------------------------- calibration


def test_densify_no_baseline_then_baseline_option(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path, tmp_path: Path
) -> None:
    def change(topic: str, message: Any, _: int) -> Any:
        if topic != RIGHT_INFO:
            return message
        p = np.array(message.p, dtype=np.float64)
        p[3] = 0.0
        return dataclasses.replace(message, p=p)

    log = rewrite(small_log, tmp_path / "nobase.mcap", change)
    line = pcainterp(*densify_args(log, out, basis_path)).error_line()
    assert f"camera info on {RIGHT_INFO} gives no baseline" in line
    assert "P[0,3] = 0.0" in line
    assert "pass --baseline" in line
    assert_nothing_written(out)
    run = pcainterp(*densify_args(log, out, basis_path, "--baseline", "0.54"))
    assert run.code == 0, run.err
    assert f"densified {SMALL_FRAMES} frames" in run.out
    assert assert_valid_mcap(out)["/pcainterp/depth"] == SMALL_FRAMES


def test_densify_names_its_camera_and_warns_of_a_baseline_in_millimetres(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path, tmp_path: Path
) -> None:
    def change(topic: str, message: Any, _: int) -> Any:
        if topic != RIGHT_INFO:
            return message
        p = np.array(message.p, dtype=np.float64)
        p[3] *= 1000.0  # Tx in px * mm
        return dataclasses.replace(message, p=p)

    plain = pcainterp(*densify_args(small_log, out, basis_path))
    assert f"baseline 0.5372 m (from P of {RIGHT_INFO})" in plain.out
    assert "beyond any stereo rig" not in plain.out + plain.err
    log = rewrite(small_log, tmp_path / "mm.mcap", change)
    run = pcainterp(*densify_args(log, out, basis_path))
    assert run.code == 0, run.err
    assert f"baseline 537.2 m (from P of {RIGHT_INFO})" in run.out
    assert (
        f"warning: the baseline from P of {RIGHT_INFO} is 537.2 m, beyond any stereo rig's "
        "(< 3 m), and every depth scales with it" in run.err
    )
    assert "if it is in millimetres, pass --baseline 0.5372" in run.err


# ----------------------------------------------------------------------------- basis files


def _broken_basis(kind: str, good: Path, folder: Path) -> tuple[Path, str]:
    """Write a broken basis; return it and a text the error must contain."""
    path = folder / f"{kind}.npz"
    if kind == "not_a_zip":
        path.write_bytes(b"just some bytes, not an npz archive")
        return path, "not_a_zip.npz"
    with np.load(good) as archive:
        arrays = {key: archive[key] for key in archive.files}
    if kind == "empty_zip":
        with zipfile.ZipFile(path, "w"):
            pass
        return path, "'format'"
    if kind == "no_components":
        del arrays["components"]
        np.savez(path, **arrays)
        return path, "'components'"
    if kind == "nan_mean":
        arrays["mean"] = arrays["mean"].copy()
        arrays["mean"][0, 0] = np.nan
        np.savez(path, **arrays)
        return path, "'mean'"
    if kind == "inf_eigenvalues":
        arrays["eigenvalues"] = arrays["eigenvalues"].copy()
        arrays["eigenvalues"][1] = np.inf
        np.savez(path, **arrays)
        return path, "'eigenvalues'"
    assert kind == "truncated"
    path.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    return path, "truncated.npz"


BROKEN_BASES = [
    "not_a_zip",
    "empty_zip",
    "no_components",
    "nan_mean",
    "inf_eigenvalues",
    "truncated",
]


@pytest.mark.parametrize("kind", BROKEN_BASES)
def test_densify_broken_basis(
    pcainterp: Callable[..., Run],
    kind: str,
    small_log: Path,
    basis_path: Path,
    out: Path,
    tmp_path: Path,
) -> None:
    broken, names = _broken_basis(kind, basis_path, tmp_path)
    line = pcainterp(*densify_args(small_log, out, broken)).error_line()
    assert names in line
    assert str(broken) in line
    assert_nothing_written(out)


@pytest.mark.parametrize("kind", ["no_components", "nan_mean"])
def test_info_broken_basis(
    pcainterp: Callable[..., Run], kind: str, basis_path: Path, tmp_path: Path
) -> None:
    broken, names = _broken_basis(kind, basis_path, tmp_path)
    assert names in pcainterp("info", broken).error_line()


@pytest.mark.parametrize("kind", ["no_components", "nan_mean"])
def test_info_broken_basis_under_another_name(
    pcainterp: Callable[..., Run], kind: str, basis_path: Path, tmp_path: Path
) -> None:
    # a basis saved without the .npz suffix is still read as one by its bytes: its damage
    # is named, not "not a log" (review 16a R3)
    broken, names = _broken_basis(kind, basis_path, tmp_path)
    renamed = broken.rename(broken.with_suffix(".basis"))
    line = pcainterp("info", renamed).error_line()
    assert names in line
    assert "not a log" not in line


def test_info_basis(pcainterp: Callable[..., Run], basis_path: Path) -> None:
    run = pcainterp("info", basis_path)
    assert run.code == 0, run.err
    assert "pcainterp basis" in run.out
    assert "components       5" in run.out


def test_densify_basis_of_another_image_size(
    pcainterp: Callable[..., Run], basis_path: Path, out: Path, tmp_path: Path
) -> None:
    log = tmp_path / "other.mcap"
    synth(log, frames=2, seed=4, scale=0.2, fmt="mcap")
    with open_log(log) as reader:
        size = next(rosmsg.image_array(reader.decode(raw)).shape for raw in reader.messages([LEFT]))
    assert size != Basis.load(basis_path).image_size
    run = pcainterp(*densify_args(log, out, basis_path))
    assert run.code == 0, run.err
    assert "densified 2 frames" in run.out
    assert depth_shapes(out) == [size, size]


# ----------------------------------------------------------------------------- stamps, empty


def test_densify_non_monotonic_stamps(
    pcainterp: Callable[..., Run],
    small_messages: list[Message],
    basis_path: Path,
    out: Path,
    tmp_path: Path,
) -> None:
    per_frame = len(small_messages) // SMALL_FRAMES
    frames = [small_messages[i : i + per_frame] for i in range(0, len(small_messages), per_frame)]
    frames[3], frames[4] = frames[4], frames[3]  # frame 4 is written (and logged) before 3
    # without an index: read in file order (an indexed MCAP is read in log-time order)
    log = write_unindexed(tmp_path / "swapped.mcap", [m for frame in frames for m in frame])
    run = pcainterp(*densify_args(log, out, basis_path))
    assert run.code == 0, run.err
    assert f"densified {SMALL_FRAMES} frames" in run.out
    assert "non-monotonic stamps" in run.out
    assert "non-monotonic log times" in run.err  # a warning
    assert assert_valid_mcap(out)["/pcainterp/depth"] == SMALL_FRAMES


def _topic_by_topic(small_messages: list[Message], copies: int) -> list[Message]:
    """The small log ``copies`` times over, stored one topic after another, log times kept."""
    span = small_messages[-1][2] - small_messages[0][2] + 100_000_000
    messages = []
    for copy in range(copies):
        for topic, message, log_time_ns in small_messages:
            stamp = rosmsg.stamp_ns(message) + copy * span
            header = rosmsg.header(stamp, message.header.frame_id)
            shifted = dataclasses.replace(message, header=header)
            messages.append((topic, shifted, log_time_ns + copy * span))
    return sorted(messages, key=lambda m: m[0])  # stable: each topic in time order


def test_densify_reads_an_mcap_stored_topic_by_topic_in_log_time_order(
    pcainterp: Callable[..., Run],
    small_messages: list[Message],
    basis_path: Path,
    out: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # a converter's order, in several chunks: the chunk index puts them back in time order
    monkeypatch.setattr(logwriter, "MCAP_CHUNK_SIZE", 64 * 1024)
    log = write_messages(tmp_path / "by_topic.mcap", _topic_by_topic(small_messages, 3))
    run = pcainterp(*densify_args(log, out, basis_path))
    assert run.code == 0, run.err
    assert f"pairing: {3 * SMALL_FRAMES} pairs, 0 unpaired left, 0 unpaired right\n" in run.out
    assert "warning" not in run.out + run.err
    assert assert_valid_mcap(out)["/pcainterp/depth"] == 3 * SMALL_FRAMES


def test_densify_a_damaged_attachment_keeps_the_log_time_order(
    pcainterp: Callable[..., Run],
    small_messages: list[Message],
    basis_path: Path,
    out: Path,
    tmp_path: Path,
) -> None:
    # the attachment's damage is no damage to the messages: the chunk index still holds
    log = tmp_path / "by_topic_attachment.mcap"
    with log.open("wb") as f:
        writer = Writer(f, chunk_size=64 * 1024)
        writer.start("ros2", "test")
        writer.add_attachment(1, 2, "robot.urdf", "application/xml", b"<robot name='r'/>" * 50)
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for topic, message, log_time_ns in _topic_by_topic(small_messages, 3):
            msgtype = message.__msgtype__
            if msgtype not in schemas:
                text = rosmsg.schema_text(msgtype).encode()
                schemas[msgtype] = writer.register_schema(msgtype, "ros2msg", text)
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, "cdr", schemas[msgtype])
            writer.add_message(channels[topic], log_time_ns, rosmsg.serialize(message), log_time_ns)
        writer.finish()
    data = bytearray(log.read_bytes())
    data[data.find(b"<robot name='r'/>") + 5] ^= 0x20  # one flipped bit of the attachment
    log.write_bytes(bytes(data))
    run = pcainterp(*densify_args(log, out, basis_path))
    assert run.code == 0, run.err
    assert "corrupt attachment left out (CRC mismatch)" in run.out
    assert f"pairing: {3 * SMALL_FRAMES} pairs, 0 unpaired left, 0 unpaired right\n" in run.out
    assert "mcap recover" not in run.out + run.err  # before: 'has no index', pairs lost


def test_densify_of_an_unindexed_log_out_of_time_order_says_what_it_cost(
    pcainterp: Callable[..., Run],
    small_messages: list[Message],
    basis_path: Path,
    out: Path,
    tmp_path: Path,
) -> None:
    log = write_unindexed(tmp_path / "by_topic.mcap", _topic_by_topic(small_messages, 3))
    run = pcainterp(*densify_args(log, out, basis_path))
    assert run.code == 0, run.err  # within --hold-s (3 s) of log of each other: all pair
    assert f"pairing: {3 * SMALL_FRAMES} pairs, 0 unpaired left, 0 unpaired right\n" in run.out
    assert "log-time order" not in run.err
    out.unlink()
    run = pcainterp(*densify_args(log, out, basis_path, "--hold-s", "0"))  # 8 images held
    assert run.code == 0, run.err
    assert "stereo pairs lost" not in run.err  # the lags of a log read out of order mean nothing
    pairing = next(line for line in run.out.splitlines() if line.startswith("pairing: "))
    pairs = int(pairing.split()[1])
    lost = 3 * SMALL_FRAMES - pairs
    assert lost > 0
    (warning,) = [line for line in run.err.splitlines() if "log-time order" in line]
    assert warning.startswith("warning: by_topic.mcap: the log is not stored in log-time order")
    assert f"this cost up to {lost} stereo pairs ({lost} left and {lost} right" in warning
    assert "`mcap recover by_topic.mcap -o indexed.mcap`" in warning
    assert "non-monotonic log times" in warning
    assert run.err.count("non-monotonic log times") == 1  # replaces the plain warning


def _late_infos(small_messages: list[Message]) -> list[Message]:
    """The small log twice (16 frames), its camera infos recorded from the 11th frame on."""
    span = small_messages[-1][2] - small_messages[0][2] + 100_000_000
    messages = list(small_messages)
    for topic, message, log_time_ns in small_messages:
        stamp = rosmsg.stamp_ns(message) + span
        header = rosmsg.header(stamp, message.header.frame_id)
        messages.append((topic, dataclasses.replace(message, header=header), log_time_ns + span))
    per_frame = len(small_messages) // SMALL_FRAMES
    return [
        (topic, message, log_time_ns)
        for index, (topic, message, log_time_ns) in enumerate(messages)
        if index // per_frame >= 10 or topic not in (LEFT_INFO, RIGHT_INFO)
    ]


def test_densify_reads_camera_infos_recorded_late_ahead(
    pcainterp: Callable[..., Run],
    small_messages: list[Message],
    basis_path: Path,
    out: Path,
    tmp_path: Path,
) -> None:
    # an MCAP has an index: the first camera infos are read ahead, every pair is densified
    log = write_messages(tmp_path / "late.mcap", _late_infos(small_messages))
    run = pcainterp(*densify_args(log, out, basis_path))
    assert run.code == 0, run.err
    assert f"densified {2 * SMALL_FRAMES} frames" in run.out
    assert f"pairing: {2 * SMALL_FRAMES} pairs, 0 unpaired left, 0 unpaired right\n" in run.out
    assert (
        "camera info: the first 11 stereo pairs came before the first camera info on "
        f"{LEFT_INFO} and {RIGHT_INFO} (recorded 1.0 s of log later): densified with it, read "
        "ahead (the log's camera infos do not change)\n"
    ) in run.out
    assert "warning" not in run.out + run.err
    assert assert_valid_mcap(out)["/pcainterp/depth"] == 2 * SMALL_FRAMES


def test_densify_warns_of_pairs_dropped_before_the_first_camera_info(
    pcainterp: Callable[..., Run],
    small_messages: list[Message],
    basis_path: Path,
    out: Path,
    tmp_path: Path,
) -> None:
    # a rosbag2 SQLite log is not read ahead: the pairer holds 8 pairs waiting for the
    # infos (each frame's come after its images), the first 3 are dropped
    log = tmp_path / "late"
    with open_writer(log, "rosbag2-sqlite3") as writer:
        for topic, message, log_time_ns in _late_infos(small_messages):
            writer.add_message(topic, message, log_time_ns)
    run = pcainterp(*densify_args(log, out, basis_path))
    assert run.code == 0, run.err
    assert "densified 13 frames" in run.out
    assert "pairing: 13 pairs, 0 unpaired left, 0 unpaired right, 3 without camera info" in run.out
    (warning,) = [line for line in run.err.splitlines() if "camera info had" in line]
    assert warning.startswith(
        f"warning: 3 of 16 stereo pairs were dropped because no camera info had arrived yet on "
        f"{LEFT_INFO} and {RIGHT_INFO} (it came 1.0 s of log after the first dropped pair)"
    )
    assert warning.endswith(
        "pass --calibration LEFT.yaml RIGHT.yaml (the cameras' "
        "camera_info_manager files) to densify every pair"
    )
    assert assert_valid_mcap(out)["/pcainterp/depth"] == 13


def _depth_by_log_time(path: Path) -> dict[int, bytes]:
    with open_log(path) as reader:
        return {
            raw.log_time_ns: image_of(reader.decode(raw)).tobytes()
            for raw in reader.messages(["/pcainterp/depth"])
        }


def test_densify_pairs_images_whose_stamps_are_all_zero_by_log_time(
    pcainterp: Callable[..., Run],
    small_messages: list[Message],
    basis_path: Path,
    tmp_path: Path,
) -> None:
    # the right image of frame 3 is missing: by first-come the left image of frame 3 took
    # the right one of frame 4, and so on
    dropped_ns = small_messages[0][2] + 3 * 100_000_000

    def log(name: str, zero: bool) -> Path:
        messages = []
        for topic, message, log_time_ns in small_messages:
            if topic == RIGHT and log_time_ns == dropped_ns:
                continue
            if zero and topic in (LEFT, RIGHT):
                header = rosmsg.header(0, message.header.frame_id)
                message = dataclasses.replace(message, header=header)
            messages.append((topic, message, log_time_ns))
        return write_messages(tmp_path / name, messages)

    stamped, zero = log("stamped.mcap", False), log("zero.mcap", True)
    run = pcainterp(*densify_args(stamped, tmp_path / "stamped_out.mcap", basis_path))
    assert run.code == 0, run.err
    assert "stamps:" not in run.out
    run = pcainterp(*densify_args(zero, tmp_path / "zero_out.mcap", basis_path))
    assert run.code == 0, run.err
    assert f"pairing: {SMALL_FRAMES - 1} pairs, 1 unpaired left, 0 unpaired right\n" in run.out
    assert (
        f"stamps: the header stamps of {LEFT} repeat 0 (not set), so they do not tell its "
        "images apart: the images were paired by log time after the first 1, within 25 ms "
        "(a quarter frame, or --stamp-tolerance-ms when wider); the outputs of the "
        f"{SMALL_FRAMES - 1} frames whose left header stamp was 0 or its previous image's are "
        "stamped with the left image's log time\n"
    ) in run.out
    assert "warning" not in run.out + run.err
    expected = _depth_by_log_time(tmp_path / "stamped_out.mcap")
    assert dropped_ns not in expected
    assert _depth_by_log_time(tmp_path / "zero_out.mcap") == expected
    # bug hunt 7A F6: every output was stamped 0, and evaluate then advised a tolerance of
    # 41 years, which matched the frames to arbitrary truths; now the outputs carry their
    # left image's log time, and evaluate matches the images by it as densify paired them
    with open_log(tmp_path / "zero_out.mcap") as reader:
        outputs = [
            (raw.log_time_ns, rosmsg.stamp_ns(reader.decode(raw)))
            for raw in reader.messages(["/pcainterp/depth", "/pcainterp/camera_info"])
        ]
    assert len(outputs) == 2 * (SMALL_FRAMES - 1)
    assert all(stamp == log_time_ns for log_time_ns, stamp in outputs)
    fast = ["--no-basis", "--no-linear", "--sweep-every", "0", "--mode", "stereo"]
    tables = []
    for name in ("stamped", "zero"):
        report = tmp_path / f"{name}_report"
        run = pcainterp("evaluate", tmp_path / f"{name}_out.mcap", "-o", report, *fast)
        assert run.code == 0, run.err
        assert run.out.startswith(f"{SMALL_FRAMES - 1} frames of {tmp_path / name}_out.mcap")
        tables.append([line for line in run.out.splitlines() if line.startswith("pca_map ")])
    assert tables[0] == tables[1] != []


def test_densify_pairs_by_stamp_past_a_duplicated_image(
    pcainterp: Callable[..., Run],
    small_messages: list[Message],
    basis_path: Path,
    tmp_path: Path,
) -> None:
    """Bug hunt 7A F11: the left image of frame 2 logged twice (a bag merge), the right images
    3 ms after the left ones: all pairs but 2 were lost to log time at a 1 ms tolerance."""
    twice_ns = small_messages[0][2] + 2 * 100_000_000
    messages = []
    for topic, message, log_time_ns in small_messages:
        late = 3_000_000 if topic == RIGHT else 0
        messages.append((topic, message, log_time_ns + late))
        if topic == LEFT and log_time_ns == twice_ns:
            messages.append((topic, message, log_time_ns + 1_000_000))
    messages.sort(key=lambda item: item[2])
    log = write_messages(tmp_path / "dup.mcap", messages)
    run = pcainterp(*densify_args(log, tmp_path / "dup_out.mcap", basis_path))
    assert run.code == 0, run.err
    assert (
        f"pairing: {SMALL_FRAMES} pairs, 0 unpaired left, 0 unpaired right, "
        "1 duplicate image dropped\n"
    ) in run.out
    assert f"duplicates: 1 image of {LEFT} was logged again (the same message" in run.out
    assert "paired by log time" not in run.out
    assert "warning" not in run.out + run.err


def test_evaluate_pairs_right_images_as_densify_did(
    pcainterp: Callable[..., Run],
    small_messages: list[Message],
    basis_path: Path,
    tmp_path: Path,
) -> None:
    # no ground truth (the reference is SGBM of the pair), the right images 3 ms late
    messages = []
    for topic, message, log_time_ns in small_messages:
        if topic.startswith("/ground_truth/"):
            continue
        if topic == RIGHT:
            header = rosmsg.header(rosmsg.stamp_ns(message) + 3_000_000, message.header.frame_id)
            message = dataclasses.replace(message, header=header)
        messages.append((topic, message, log_time_ns))
    log = write_messages(tmp_path / "late_right.mcap", messages)
    dense = tmp_path / "dense.mcap"
    run = pcainterp(*densify_args(log, dense, basis_path, "--stamp-tolerance-ms", "5"))
    assert run.code == 0, run.err
    assert f"densified {SMALL_FRAMES} frames" in run.out
    report = tmp_path / "report"
    fast = ["--no-basis", "--no-linear", "--sweep-every", "0"]
    run = pcainterp("evaluate", dense, "-o", report, *fast)
    assert run.code == 0, run.err
    assert (report / "results.md").is_file()
    run = pcainterp("evaluate", dense, "-o", tmp_path / "tight", *fast, "--stamp-tolerance-ms", "2")
    assert run.error_line() == (
        "pcainterp: error: frame 0 has no /ground_truth/depth and the right images of "
        f"{RIGHT} did not pair with it within 2 ms (--stamp-tolerance-ms; the nearest is "
        "3.00 ms away), so there is no SGBM reference; pass --stamp-tolerance-ms 3"
    )
    assert_nothing_written(tmp_path / "tight")
    run = pcainterp("evaluate", dense, "-o", tmp_path / "bad", "--stamp-tolerance-ms", "-1")
    assert run.error_line() == "pcainterp: error: --stamp-tolerance-ms must be >= 0, got -1.0"


def test_densify_log_with_channels_but_no_messages(
    pcainterp: Callable[..., Run], basis_path: Path, out: Path, tmp_path: Path
) -> None:
    log = tmp_path / "silent.mcap"
    with log.open("wb") as stream:
        writer = Writer(stream)
        writer.start("ros2", "test")
        for topic, msgtype in (
            (LEFT, rosmsg.IMAGE),
            (RIGHT, rosmsg.IMAGE),
            (LEFT_INFO, rosmsg.CAMERA_INFO),
            (RIGHT_INFO, rosmsg.CAMERA_INFO),
        ):
            schema = writer.register_schema(
                msgtype, "ros2msg", rosmsg.schema_text(msgtype).encode()
            )
            writer.register_channel(topic, "cdr", schema)
        writer.finish()  # type: ignore[no-untyped-call]
    line = pcainterp(*densify_args(log, out, basis_path)).error_line()
    assert f"no stereo pair found in {log}" in line
    assert_nothing_written(out)


def test_densify_empty_log(
    pcainterp: Callable[..., Run], basis_path: Path, out: Path, tmp_path: Path
) -> None:
    log = write_messages(tmp_path / "empty.mcap", [])
    line = pcainterp(*densify_args(log, out, basis_path)).error_line()
    assert f"no stereo pair found in {log}" in line
    assert "no messages" in line
    assert_nothing_written(out)


def test_learn_empty_log(pcainterp: Callable[..., Run], tmp_path: Path) -> None:
    log = write_messages(tmp_path / "empty.mcap", [])
    target = tmp_path / "basis.npz"
    line = pcainterp("learn", log, "-o", target).error_line()
    assert "no stereo pair found in" in line
    assert_nothing_written(target)


# ----------------------------------------------------------------------------- output paths


def test_densify_output_is_input(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, tmp_path: Path
) -> None:
    log = tmp_path / "drive.mcap"
    log.write_bytes(small_log.read_bytes())
    before = log.read_bytes()
    for target in (log, tmp_path / "." / "drive.mcap"):
        line = pcainterp(*densify_args(log, target, basis_path)).error_line()
        assert "refusing to write the output onto the input" in line
        assert "drive.mcap" in line
    assert log.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["drive.mcap"]


def test_densify_output_into_the_input_bag_folder_is_refused(
    pcainterp: Callable[..., Run], basis_path: Path, tmp_path: Path
) -> None:
    """`-o BAG/BAG.mcap` replaced a rosbag2 bag's own storage file: the recording was lost
    (its metadata.yaml still counted the old messages). A new file in the bag, through any
    option, is refused too, before any work (review 15b B1, B2: `--out-dir BAG` wrote another
    input's output into it)."""
    bag = tmp_path / "bag"
    made = pcainterp("synth", bag, "--frames", "2", "--scale", "0.25", "--format", "rosbag2")
    assert made.code == 0
    other = tmp_path / "other.mcap"
    assert pcainterp("synth", other, "--frames", "2", "--scale", "0.25").code == 0
    before = {path.name: path.read_bytes() for path in bag.iterdir()}
    storage = next(path for path in bag.iterdir() if path.suffix == ".mcap")
    for given in (bag, storage):
        for target in (storage, bag / "dense.mcap"):
            line = pcainterp(*densify_args(given, target, basis_path)).error_line()
            if target == storage and given == storage:
                assert "refusing to write the output onto the input" in line
                continue
            assert f"refusing to write the output {target} inside the input bag {bag}" in line
            assert "choose a different output path outside the bag" in line
    runs = {
        "--out-dir": ("densify", other, bag, "--basis", basis_path, "--out-dir", bag),
        "--rrd path": (*densify_args(bag, tmp_path / "d.mcap", basis_path), "--rrd", bag / "x.rrd"),
        "-o path": ("learn", bag, "-o", bag / "b.npz"),
    }
    for fix, args in runs.items():
        line = pcainterp(*args).error_line()
        assert f"inside the input bag {bag}: it would replace or join" in line
        assert f"choose a different {fix} outside the bag" in line
    assert {path.name: path.read_bytes() for path in bag.iterdir()} == before
    assert sorted(path.name for path in tmp_path.iterdir()) == ["bag", "other.mcap"]


def test_an_empty_path_is_named_empty_not_a_folder_dot(
    pcainterp: Callable[..., Run], small_log: Path
) -> None:
    """`-o "$OUT"` with OUT unset said "output . is a folder" (bug hunt 15B F4)."""
    for args in (("densify", small_log, "-o", ""), ("info", ""), ("learn", small_log, "-o", "")):
        run = pcainterp(*args)
        assert run.code == 2
        assert "the path is empty (an unset shell variable?)" in run.err.splitlines()[-1]


def test_learn_output_is_input(
    pcainterp: Callable[..., Run], small_log: Path, tmp_path: Path
) -> None:
    log = tmp_path / "drive.mcap"
    log.write_bytes(small_log.read_bytes())
    line = pcainterp("learn", log, "-o", log).error_line()
    assert "refusing to write the output onto the input" in line
    assert log.read_bytes() == small_log.read_bytes()


def test_densify_output_folder_missing(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, tmp_path: Path
) -> None:
    target = tmp_path / "no" / "such" / "dense.mcap"
    line = pcainterp(*densify_args(small_log, target, basis_path)).error_line()
    assert f"folder {target.parent} does not exist" in line
    assert "create it first" in line
    assert not (tmp_path / "no").exists()


def test_learn_output_folder_missing(
    pcainterp: Callable[..., Run], small_log: Path, tmp_path: Path
) -> None:
    target = tmp_path / "no" / "basis.npz"
    line = pcainterp("learn", small_log, "-o", target, "--components", "3").error_line()
    assert f"folder {target.parent} does not exist" in line
    assert not target.parent.exists()


def test_synth_output_folder_missing(pcainterp: Callable[..., Run], tmp_path: Path) -> None:
    target = tmp_path / "no" / "drive.mcap"
    line = pcainterp("synth", target, "--frames", "1", "--scale", "0.1").error_line()
    assert f"folder {target.parent} does not exist" in line
    assert not target.parent.exists()


def test_synth_unknown_suffix(pcainterp: Callable[..., Run], tmp_path: Path) -> None:
    target = tmp_path / "drive.txt"
    line = pcainterp("synth", target, "--frames", "1", "--scale", "0.1").error_line()
    assert "drive.txt" in line
    assert "name it .mcap or .bag" in line
    assert_nothing_written(target)


@pytest.mark.parametrize("below", [False, True])
def test_demo_output_is_a_file(pcainterp: Callable[..., Run], tmp_path: Path, below: bool) -> None:
    afile = tmp_path / "afile"
    afile.write_text("kept")
    target = afile / "demo" if below else afile
    line = pcainterp("demo", "--out", target).error_line()
    assert f"cannot create the demo folder {target}" in line
    assert "pass --out a folder path" in line
    assert afile.read_text() == "kept"


def test_demo_rerun_without_a_display_is_refused_before_rendering(
    pcainterp: Callable[..., Run], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from pcainterp_stream.io import rerun_sink

    monkeypatch.setattr(rerun_sink.sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    target = tmp_path / "demo"
    line = pcainterp("demo", "--out", target, "--rerun").error_line()
    assert "--rerun starts a Rerun viewer, which needs a display" in line
    assert f"the demo records {target / 'heldout.rrd'} anyway" in line
    assert not target.exists()


def test_densify_output_is_a_folder(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, tmp_path: Path
) -> None:
    target = tmp_path / "results.mcap"
    target.mkdir()
    line = pcainterp(*densify_args(small_log, target, basis_path)).error_line()
    assert "is a folder" in line
    assert list(target.iterdir()) == []


def _copy(source: Path, target: Path) -> Path:
    target.write_bytes(source.read_bytes())
    return target


@pytest.mark.parametrize("onto", ["input", "output"])
def test_densify_rrd_onto_the_input_or_the_output_is_refused(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, tmp_path: Path, onto: str
) -> None:
    log = _copy(small_log, tmp_path / "drive.mcap")
    target = tmp_path / "dense.mcap"
    rrd = log if onto == "input" else target
    line = pcainterp(*densify_args(log, target, basis_path, "--rrd", rrd)).error_line()
    assert f"refusing to write the --rrd recording onto the {onto} {rrd}" in line
    assert "choose a different --rrd path" in line
    assert log.read_bytes() == small_log.read_bytes()
    assert_nothing_written(target)


def test_densify_rrd_folder_is_refused_before_the_job(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path, tmp_path: Path
) -> None:
    folder = tmp_path / "views"
    folder.mkdir()
    line = pcainterp(*densify_args(small_log, out, basis_path, "--rrd", folder)).error_line()
    assert f"--rrd {folder} is a folder" in line
    assert list(folder.iterdir()) == []
    assert_nothing_written(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "views"]  # no .views.partial


def test_densify_output_onto_the_basis_or_a_calibration_file_is_refused(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, tmp_path: Path
) -> None:
    basis = _copy(basis_path, tmp_path / "basis")  # no suffix: -o without one is an MCAP
    line = pcainterp(*densify_args(small_log, basis, basis)).error_line()
    assert f"refusing to write the output onto the --basis file {basis}" in line
    assert basis.read_bytes() == basis_path.read_bytes()
    left, right = tmp_path / "left", tmp_path / "right"
    left.write_text("image_width: 310\n")
    right.write_text("image_width: 310\n")
    line = pcainterp("densify", small_log, "-o", right, "--calibration", left, right).error_line()
    assert f"refusing to write the output onto the --calibration file {right}" in line
    assert right.read_text() == "image_width: 310\n"


def test_densify_adapted_basis_beside_the_output_onto_an_input_is_refused(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, tmp_path: Path
) -> None:
    log = _copy(small_log, tmp_path / "drive.basis.npz")  # drive.mcap's side file
    line = pcainterp("densify", log, "-o", tmp_path / "drive.mcap").error_line()
    assert f"refusing to write the adapted basis drive.basis.npz onto the input {log}" in line
    assert log.read_bytes() == small_log.read_bytes()
    # a run with a --basis file never adapts, so never writes OUTPUT.basis.npz: its own
    # basis file named so is read, not refused (review 57b R5)
    basis = _copy(basis_path, tmp_path / "dense.basis.npz")
    run = pcainterp(*densify_args(small_log, tmp_path / "dense.mcap", basis))
    assert run.code == 0, run.err
    assert basis.read_bytes() == basis_path.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "dense.basis.npz",
        "dense.mcap",
        "drive.basis.npz",
    ]


def test_densify_out_dir_output_onto_another_input_is_refused(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, tmp_path: Path
) -> None:
    first = _copy(small_log, tmp_path / "a.mcap")
    second = _copy(small_log, tmp_path / "a_dense.mcap")  # a.mcap's output in tmp_path
    line = pcainterp(
        "densify", first, second, "--out-dir", tmp_path, "--basis", basis_path, "--workers", "1"
    ).error_line()
    assert f"refusing to write the output onto the input {second}" in line
    assert "choose a different --out-dir" in line
    assert second.read_bytes() == small_log.read_bytes()


@pytest.mark.parametrize("name", ["dense.bag", "dense.db3", "dense.MCAP.txt"])
def test_densify_output_not_named_mcap_is_refused(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, tmp_path: Path, name: str
) -> None:
    target = tmp_path / name
    line = pcainterp(*densify_args(small_log, target, basis_path)).error_line()
    assert f"output {target} is named {target.suffix} but densify writes MCAP" in line
    assert "name the output .mcap" in line
    assert_nothing_written(target)


def test_densify_output_without_a_suffix_is_an_mcap(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, tmp_path: Path
) -> None:
    target = tmp_path / "dense"
    run = pcainterp(*densify_args(small_log, target, basis_path))
    assert run.code == 0
    assert target.read_bytes().startswith(b"\x89MCAP")
    assert run.err.splitlines() == [  # not silently (bug hunt 6B L4)
        f"warning: output {target} has no suffix: it is an MCAP, but Foxglove's file dialog "
        f"and rerun know one by its .mcap suffix; name it {target}.mcap to open it there"
    ]


def test_learn_output_onto_a_fit_log_is_refused(
    pcainterp: Callable[..., Run], small_log: Path, tmp_path: Path
) -> None:
    fit = _copy(small_log, tmp_path / "fit.mcap")
    line = pcainterp(
        "learn", small_log, "-o", fit, "--fit-logs", fit, "--components", "3"
    ).error_line()
    assert f"refusing to write the output onto the --fit-logs log {fit}" in line
    assert fit.read_bytes() == small_log.read_bytes()


def test_learn_output_folder_and_missing_fit_log_are_refused_before_learning(
    pcainterp: Callable[..., Run],
    small_log: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from pcainterp_stream.pipeline import learn as learn_job

    def no_work(*args: object, **kwargs: object) -> None:
        raise AssertionError("learned before checking -o and --fit-logs")

    monkeypatch.setattr(learn_job, "learn_pairing", no_work)
    monkeypatch.setattr(learn_job, "learn", no_work)
    folder = tmp_path / "bases"
    folder.mkdir()
    line = pcainterp("learn", small_log, "-o", folder, "--components", "3").error_line()
    assert f"output {folder} is a folder but learn writes one basis file" in line
    assert list(folder.iterdir()) == []
    missing = tmp_path / "nope.mcap"
    target = tmp_path / "basis.npz"
    line = pcainterp(
        "learn", small_log, "-o", target, "--fit-logs", missing, "--components", "3"
    ).error_line()
    assert f"--fit-logs log {missing} does not exist" in line
    assert_nothing_written(target)


# ----------------------------------------------------------------------------- bad options


@pytest.mark.parametrize(
    ("option", "value", "expected"),
    [
        ("--sigma", "0", "--sigma must be a number > 0 px, 'evidence' or 'auto', got 0"),
        ("--sigma", "-1", "--sigma must be a number > 0 px"),
        ("--sigma", "nan", "--sigma must be a number > 0 px, 'evidence' or 'auto', got nan"),
        ("--sigma", "fitted", "--sigma must be a number > 0 px, 'evidence' or 'auto', got fitted"),
        ("--process-noise", "0", "--process-noise must be finite and > 0, got 0.0"),
        ("--process-noise", "inf", "--process-noise must be finite and > 0, got inf"),
        ("--process-noise", "0.001", "--process-noise 0.001 is the temporal prior's and applies"),
        ("--prior", "hybrid", "--prior hybrid with"),
        ("--num-disparities", "20", "--num-disparities must be a positive multiple of 16, got 20"),
        ("--num-disparities", "0", "--num-disparities must be a positive multiple of 16"),
        ("--block-size", "4", "--block-size must be odd and positive, got 4"),
        ("--corners", "-1", "--corners must be at least 0, got -1"),
        ("--quality", "1.5", "--quality must be in (0, 1), got 1.5"),
        ("--min-distance", "-2", "--min-distance must be >= 0 px, got -2.0"),
        # 1 px never finished on a 310x94 log; 2 px took 28 s for 4 frames
        (
            "--fill-spacing",
            "1",
            "--fill-spacing must be 0 (no lattice) or at least 10 px (GFTT's default min "
            "corner distance; see --help), got 1",
        ),
        ("--fill-spacing", "9.5", "at least 10 px (GFTT's default min corner distance"),
        ("--fill-spacing", "-1", "--fill-spacing must be 0 (no lattice) or at least 10 px"),
        ("--fill-spacing", "nan", "--fill-spacing must be 0 (no lattice) or at least 10 px"),
        ("--baseline", "0", "--baseline must be a finite number > 0 m, got 0.0"),
        # these wrote //depth, //camera_info ... and /a b/depth
        ("--output-prefix", "", "--output-prefix '' is not a ROS 2 topic name: it is empty;"),
        ("--output-prefix", "/", "--output-prefix '/' is not a ROS 2 topic name: it has no name"),
        ("--output-prefix", "/a b", "'a b' has characters other than A-Z a-z 0-9 _; use /-"),
        ("--output-prefix", "//x", "'//x' is not a ROS 2 topic name: it has an empty name"),
        ("--output-prefix", "/p/", "'/p/' is not a ROS 2 topic name: it ends with /"),
        ("--output-prefix", "/p/2d", "'2d' starts with a digit; use /-separated names of"),
        ("--baseline", "inf", "--baseline must be a finite number > 0 m, got inf"),
        ("--stamp-tolerance-ms", "-1", "--stamp-tolerance-ms must be >= 0, got -1.0"),
        ("--hold-s", "-1", "--hold-s must be a finite number >= 0 s, got -1.0"),
        ("--hold-s", "inf", "--hold-s must be a finite number >= 0 s, got inf"),
        ("--hold-mib", "0.5", "--hold-mib must be a finite number >= 1 MiB, got 0.5"),
    ],
)
def test_densify_bad_option(
    pcainterp: Callable[..., Run],
    option: str,
    value: str,
    expected: str,
    small_log: Path,
    basis_path: Path,
    out: Path,
) -> None:
    line = pcainterp(*densify_args(small_log, out, basis_path, option, value)).error_line()
    assert expected in line
    assert_nothing_written(out)


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--components", "0"], "--components must be at least 1, got 0"),
        (["--variance", "1.5"], "--variance must be in (0, 1], got 1.5"),
        (["--variance", "0"], "--variance must be in (0, 1], got 0.0"),
        (["--grid-scale", "2"], "--grid-scale must be in (0, 1], got 2.0"),
        (["--every", "0"], "--every must be at least 1, got 0"),
        (["--num-disparities", "20"], "--num-disparities must be a positive multiple of 16"),
        (["--block-size", "-3"], "--block-size must be odd and positive, got -3"),
        (["--with-synthetic", "1"], "--with-synthetic must be at least 2 maps (0: off; or auto)"),
        (["--with-synthetic", "-4"], "got -4"),
        (["--with-synthetic", "often"], "--with-synthetic must be at least 2 maps"),
    ],
)
def test_learn_bad_option(
    pcainterp: Callable[..., Run], args: list[str], expected: str, small_log: Path, tmp_path: Path
) -> None:
    target = tmp_path / "basis.npz"
    line = pcainterp("learn", small_log, "-o", target, *args).error_line()
    assert expected in line
    assert_nothing_written(target)


def test_learn_passes_its_corner_and_lattice_options_on(
    pcainterp: Callable[..., Run],
    small_log: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # the fitting frames are measured as densify would with the same options
    from pcainterp_stream.pipeline import learn as learning

    seen: list[learning.LearnOptions] = []

    def capture(
        logs: object, output: object, options: learning.LearnOptions, *rest: object
    ) -> None:
        seen.append(options)
        raise SystemExit(0)

    monkeypatch.setattr(learning, "learn", capture)
    args = ["--corners", "120", "--fill-spacing", "36", "--fill-placement", "lattice"]
    with pytest.raises(SystemExit):
        pcainterp("learn", small_log, "-o", tmp_path / "basis.npz", *args)
    gftt = seen[0].gftt
    assert (gftt.max_corners, gftt.fill_spacing, gftt.fill_placement) == (120, 36.0, "lattice")


def test_learn_help_states_the_auto_rule(capsys: pytest.CaptureFixture[str]) -> None:
    from pcainterp_stream.estimate.finetune import ASPECT_TOLERANCE, DISPARITY_TOLERANCE
    from pcainterp_stream.pipeline.learn import AUTO_MAX_MAPS, AUTO_PRIOR_MAPS

    with pytest.raises(SystemExit):
        cli.main(["learn", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert f"N = {AUTO_PRIOR_MAPS} when the logs give fewer than {AUTO_MAX_MAPS} maps" in text
    assert f"aspect ratio within {100 * ASPECT_TOLERANCE:g} %" in text
    assert f"within {DISPARITY_TOLERANCE:g}x" in text
    assert "0: the maps alone" in text


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--frames", "0"], "--frames must be at least 1, got 0"),
        (["--frames", "-5"], "--frames must be at least 1, got -5"),
        (["--scale", "0"], "--scale must be in [0.05, 4], got 0.0"),
        (["--scale", "nan"], "--scale must be in [0.05, 4], got nan"),
        (["--seed", "-1"], "--seed must be >= 0, got -1"),
        (["--seed", "-1", "--raw"], "--seed must be >= 0, got -1"),
    ],
)
def test_synth_bad_option(
    pcainterp: Callable[..., Run], args: list[str], expected: str, tmp_path: Path
) -> None:
    target = tmp_path / "drive.mcap"
    line = pcainterp("synth", target, *args).error_line()
    assert expected in line
    assert_nothing_written(target)


def test_import_kitti_bad_max_frames(
    pcainterp: Callable[..., Run], out: Path, tmp_path: Path
) -> None:
    drive = _fake_kitti_drive(tmp_path, calibration=True)
    line = pcainterp("import-kitti", drive, out, "--max-frames", "0").error_line()
    assert "--max-frames must be at least 1, got 0" in line
    assert_nothing_written(out)


def test_unparsable_option_value_is_a_usage_error(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    # bug hunt 10A F7: main() returns the code (it raised SystemExit(2) out of a caller)
    assert cli.main(["synth", str(tmp_path / "x.mcap"), "--frames", "many"]) == 2
    assert cli.main(["golden", "check", str(tmp_path / "x.mcap")]) == 2  # GOLDEN missing
    err = capsys.readouterr().err
    assert "argument --frames: invalid int value: 'many'" in err
    assert "Traceback" not in err


# ----------------------------------------------------------------------------- real data


def _realdata(relative: str) -> Path:
    return REALDATA / relative


REALDATA_INFO = [
    "ros1/example.bag",
    "ros1/example-lz4.bag",
    "ros1/example-bz2.bag",
    "ros1/example-unsorted-chunks.bag",
    "ros1/no-messages.bag",
    "rosbag2/mcap/talker",
    "rosbag2/mcap/wbag",
    "rosbag2/mcap/bag_with_topics_and_service_events",
    "rosbag2/mcap/cdr_test/cdr_test_0.mcap",
    "rosbag2/sqlite3/empty_bag",
    "rosbag2/sqlite3/cdr_test",
    "rosbag2/standalone/chatter.db3",
    "mcap_conformance/NoData/NoData-st-sum.mcap",
    "mcap_conformance/OneAttachment/OneAttachment-ax-st-sum.mcap",
    "mcap_conformance/OneMetadata/OneMetadata.mcap",
    "mcap_conformance/TenMessages/TenMessages-ch-chx-mx-rch-rsh-st-sum.mcap",
    "mcap_conformance/TenMessages/TenMessages-ch-chx-mx.mcap",
    "mcap_ros2/supported_ros2_messages.mcap",
    "kitti_raw/2011_09_26",
    "kitti_raw/2011_09_26/2011_09_26_drive_0001_sync",
    "kitti_odometry_clip/sequences/a",
    "stereo_aloe/aloe-L.png",
]


@needs_realdata
@pytest.mark.parametrize("relative", REALDATA_INFO)
def test_info_on_realdata(pcainterp: Callable[..., Run], relative: str) -> None:
    path = _realdata(relative)
    if not path.exists():
        pytest.skip(f"{path} is absent")
    run = pcainterp("info", path)
    assert "Traceback" not in run.err
    if run.code == 0:
        assert run.err == ""
        assert run.out.startswith(f"{path}:")
    else:
        run.error_line()
    if relative.startswith("kitti"):
        assert "pcainterp import-kitti" in run.error_line()


REALDATA_DENSIFY = [
    ("ros1/example.bag", "example.bag: it has no camera images; pcainterp densifies logs"),
    ("ros1/no-messages.bag", "no stereo pair found"),
    ("rosbag2/mcap/talker", "talker: it has no camera images"),
    ("rosbag2/sqlite3/empty_bag", "no stereo pair found"),
    ("mcap_conformance/TenMessages/TenMessages-ch-chx-mx.mcap", "it has no camera images"),
    ("mcap_conformance/NoData/NoData-st-sum.mcap", "no stereo pair found"),
    ("mcap_ros2/supported_ros2_messages.mcap", "image topics: /compressed_image, /image"),
    ("kitti_raw/2011_09_26/2011_09_26_drive_0001_sync", "pcainterp import-kitti"),
]


@needs_realdata
@pytest.mark.parametrize(("relative", "expected"), REALDATA_DENSIFY)
def test_densify_on_realdata(
    pcainterp: Callable[..., Run],
    relative: str,
    expected: str,
    basis_path: Path,
    out: Path,
) -> None:
    path = _realdata(relative)
    if not path.exists():
        pytest.skip(f"{path} is absent")
    line = pcainterp(*densify_args(path, out, basis_path)).error_line()
    assert expected in line
    assert_nothing_written(out)


@needs_realdata
def test_densify_rerun_recording_names_its_image_topic(
    pcainterp: Callable[..., Run], basis_path: Path, out: Path
) -> None:
    path = _realdata("mcap_ros2/supported_ros2_messages.mcap")
    line = pcainterp(*densify_args(path, out, basis_path)).error_line()
    assert "no stereo pair found in" in line
    assert "supported_ros2_messages.mcap" in line
    assert "/image" in line
    assert "/camera_info" in line
    assert "pass --left-topic and --right-topic" in line
    assert_nothing_written(out)


@needs_realdata
def test_densify_rerun_recording_with_one_camera(
    pcainterp: Callable[..., Run], basis_path: Path, out: Path
) -> None:
    path = _realdata("mcap_ros2/supported_ros2_messages.mcap")
    topics = ["--left-info-topic", "/camera_info", "--right-info-topic", "/camera_info"]
    args = densify_args(path, out, basis_path, "--left-topic", "/image", *topics)
    line = pcainterp(*args, "--right-topic", "/image").error_line()
    assert "--left-topic and --right-topic are both /image" in line
    assert line.endswith("pass the right camera's topic as --right-topic")
    # the JPEG copy of the image as a (zero-disparity) right view, one camera info for both
    args += ["--right-topic", "/compressed_image"]
    line = pcainterp(*args).error_line()
    assert "camera info on /camera_info gives no baseline" in line
    assert "/camera_info was read for both sides" in line
    assert line.endswith("or --baseline METRES")
    assert_nothing_written(out)
    run = pcainterp(*args, "--baseline", "0.1")
    assert run.code == 0, run.err
    assert "densified 1 frame of" in run.out
    assert assert_valid_mcap(out)["/image"] == 1
    assert depth_shapes(out) == [(480, 640)]


@needs_realdata
def test_import_real_kitti_then_densify(
    pcainterp: Callable[..., Run], basis_path: Path, out: Path
) -> None:
    drive = _realdata("kitti_raw/2011_09_26/2011_09_26_drive_0001_sync")
    log = out.parent / "kitti.mcap"
    run = pcainterp("import-kitti", drive, log, "--max-frames", "2")
    assert run.code == 0, run.err
    run = pcainterp(*densify_args(log, out, basis_path))
    assert run.code == 0, run.err
    assert "densified 2 frames" in run.out
    assert depth_shapes(out) == [(375, 1242), (375, 1242)]


# ----------------------------------------------------------------------------- signals


@pytest.fixture(scope="session")
def long_log(small_log: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The small log repeated to 400 frames (a few seconds of densify)."""
    path = tmp_path_factory.mktemp("long") / "long.mcap"
    with open_log(small_log) as reader:
        raws = list(reader.messages())
    span_ns = raws[-1].log_time_ns - raws[0].log_time_ns + 100_000_000
    repeats = 50
    with open_writer(path, "mcap") as writer:
        for repeat in range(repeats):
            shift = repeat * span_ns
            for raw in raws:
                writer.add_raw(_shifted(raw, shift))
    return path


def _shifted(raw: Any, shift_ns: int) -> Any:
    """Return a raw message with log time and header stamp moved by ``shift_ns``."""
    message = rosmsg.deserialize(raw.data, raw.msgtype)
    stamp = rosmsg.stamp_ns(message) + shift_ns
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, 10**9)
    return raw._replace(
        data=rosmsg.serialize(message),
        log_time_ns=raw.log_time_ns + shift_ns,
        publish_time_ns=raw.publish_time_ns + shift_ns,
    )


def _default_sigint() -> None:
    """Give the child the default SIGINT disposition (runs in the child before exec).

    A shell that starts the test run in the background (``nohup ... &``) leaves SIGINT
    ignored, Python keeps an inherited SIG_IGN, and the child would never see the signal.
    """
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _interrupt(args: list[str], target: Path, sig: signal.Signals) -> tuple[int, str]:
    """Start ``pcainterp ARGS``, wait until it writes, send ``sig``; return (code, stderr)."""
    process = subprocess.Popen(
        [sys.executable, "-m", "pcainterp_stream.cli", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_default_sigint,
    )
    try:
        deadline = time.monotonic() + 30
        while not any(
            p.name.startswith(f".{target.name}.partial") for p in target.parent.iterdir()
        ):
            assert process.poll() is None, process.communicate()
            assert time.monotonic() < deadline, "the output was never started"
            time.sleep(0.05)
        time.sleep(0.5)  # well into the work
        assert process.poll() is None, "finished before the signal; make the job longer"
        process.send_signal(sig)
        _, err = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    return process.returncode, err


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_signal_during_synth(sig: signal.Signals, tmp_path: Path) -> None:
    target = tmp_path / "big.mcap"
    args = ["synth", str(target), "--frames", "200", "--scale", "0.5"]
    code, err = _interrupt(args, target, sig)
    assert code == 130, err
    assert err.strip() == "pcainterp: interrupted; no partial output was left at the target"
    assert_nothing_written(target)
    rerun = subprocess.run(
        [
            sys.executable,
            "-m",
            "pcainterp_stream.cli",
            "synth",
            str(target),
            "--frames",
            "1",
            "--scale",
            "0.1",
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert rerun.returncode == 0, rerun.stderr
    assert target.is_file()


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_signal_during_densify(
    sig: signal.Signals, long_log: Path, small_log: Path, basis_path: Path, out: Path
) -> None:
    out.write_bytes(b"an older result")  # an existing target must be left as it was
    args = ["densify", str(long_log), "-o", str(out), "--basis", str(basis_path)]
    code, err = _interrupt(args, out, sig)
    assert code == 130, err
    said = f"pcainterp: interrupted; {out} was not changed (it holds an earlier run's output)"
    assert err.strip() == said
    assert out.read_bytes() == b"an older result"
    assert [p.name for p in out.parent.iterdir()] == [out.name]
    rerun = subprocess.run(
        [
            sys.executable,
            "-m",
            "pcainterp_stream.cli",
            "densify",
            str(small_log),
            "-o",
            str(out),
            "--basis",
            str(basis_path),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert rerun.returncode == 0, rerun.stderr
    assert assert_valid_mcap(out)["/pcainterp/depth"] == SMALL_FRAMES


def test_densify_refuses_images_narrower_than_the_disparity_range(
    pcainterp: Callable[..., Run], tmp_path: Path, out: Path
) -> None:
    # OpenCV's 3-way SGBM fails, or crashes the process, on images narrower than its range
    log = tmp_path / "narrow.mcap"
    assert pcainterp("synth", log, "--frames", "2", "--scale", "0.05").code == 0
    line = pcainterp("densify", log, "-o", out, "--stereo-downscale", "2").error_line()
    assert f"{log}: /stereo/left/image_rect's images are 62 px wide" in line
    assert "pass --num-disparities 32 (or less, a multiple of 16)" in line
    assert_nothing_written(out)
    args = ("densify", log, "-o", out, "--stereo-downscale", "2", "--num-disparities", "32")
    assert pcainterp(*args).code == 0
    # by default (f*b 19 px*m: full resolution) SGBM also matches its left band, padded: it
    # needs no width of its own
    out.unlink()
    assert pcainterp("densify", log, "-o", out).code == 0


def test_densify_without_corners_or_lattice_is_refused(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path
) -> None:
    args = densify_args(small_log, out, basis_path, "--corners", "0", "--fill-spacing", "0")
    line = pcainterp(*args).error_line()
    assert "--corners 0 --fill-spacing 0 leaves no point to measure" in line
    assert_nothing_written(out)


@pytest.mark.parametrize(
    ("options", "corners", "spacing"),
    [
        ((), 250, 40.0),  # sparse mode: corners and a lattice in their gaps
        (("--measurements", "dense"), 0, 34.0),  # dense mode: the lattice alone
        (("--measurements", "dense", "--corners", "100"), 100, 34.0),
        (("--measurements", "dense", "--stereo-downscale", "2"), 250, 40.0),
        (("--measurements", "dense", "--fill-spacing", "20"), 0, 20.0),
        (("--corners", "0", "--fill-spacing", "25"), 0, 25.0),
    ],
)
def test_points_by_mode_and_by_choice(
    options: tuple[str, ...], corners: int, spacing: float
) -> None:
    from pcainterp_stream.cli import build_parser
    from pcainterp_stream.cli.densify import _processor_config

    args = build_parser().parse_args(["densify", "in.mcap", "-o", "out.mcap", *options])
    config = _processor_config(args, adapt="check")
    assert (config.gftt.max_corners, config.gftt.fill_spacing) == (corners, spacing)


def test_synth_frames_help_gives_each_scenes_rate(capsys: pytest.CaptureFixture[str]) -> None:
    """Bug hunt 15E F7: "10 per second of log" for indoor scenes too, rendered at 20 Hz."""
    from pcainterp_stream.synth import FRAME_PERIOD_NS
    from pcainterp_stream.synth.indoor import INDOOR_FRAME_PERIOD_NS

    with pytest.raises(SystemExit):
        cli.main(["synth", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    street, indoor = (f"{1e9 / period:g}" for period in (FRAME_PERIOD_NS, INDOOR_FRAME_PERIOD_NS))
    assert f"frames to render: {street} per second of log, {indoor} with --scene indoor" in text


@pytest.mark.parametrize(
    ("options", "named"),
    [
        (("--corners", "10"), "--corners 10 applies"),
        (("--quality", "0.5"), "--quality 0.5 applies"),
        (("--min-distance", "50"), "--min-distance 50 applies"),
        (("--fill-spacing", "20"), "--fill-spacing 20 applies"),
        (("--fill-placement", "lattice"), "--fill-placement lattice applies"),
        (("--num-disparities", "32"), "--num-disparities 32 applies"),
        (("--block-size", "11"), "--block-size 11 applies"),
        (("--sgbm-mode", "hh"), "--sgbm-mode hh applies"),
        (("--stereo-downscale", "1"), "--stereo-downscale 1 applies"),
        (("--no-near-reach",), "--no-near-reach applies"),
        (("--edge-aware",), "--edge-aware applies"),
        (("--no-edge-aware", "--block-size", "7"), "--block-size 7, --no-edge-aware apply"),
    ],
)
def test_densify_refuses_stereo_options_with_a_feature_stream(
    pcainterp: Callable[..., Run],
    small_log: Path,
    basis_path: Path,
    out: Path,
    options: tuple[str, ...],
    named: str,
) -> None:
    """A feature stream replaces GFTT + SGBM: their options did nothing, rc 0 (bug hunt
    15E F2); refused in one line before any work, as --max-features without a stream is."""
    line = pcainterp(
        *densify_args(small_log, out, basis_path, "--features-topic", "/features", *options)
    ).error_line()
    assert f"error: {named} to the stereo front end" in line
    assert "--features-topic /features replaces" in line
    assert line.endswith(("drop it or --features-topic", "drop them or --features-topic"))
    assert_nothing_written(out)


@pytest.mark.parametrize(
    ("options", "named"),
    [
        (("--no-edge-aware",), "--no-edge-aware shapes"),
        (("--edge-aware", "--no-near-reach"), "--edge-aware and --no-near-reach shape"),
    ],
)
def test_densify_refuses_sparse_estimate_options_in_dense_mode(
    pcainterp: Callable[..., Run],
    small_log: Path,
    basis_path: Path,
    out: Path,
    options: tuple[str, ...],
    named: str,
) -> None:
    """Dense mode uses neither the edge-aware prior nor the near reach: with them it gave
    the same output, rc 0 (review 15e R2)."""
    args = densify_args(small_log, out, basis_path, "--measurements", "dense", *options)
    line = pcainterp(*args).error_line()
    assert f"error: {named} sparse mode's estimate, which --measurements dense does not use" in line
    assert_nothing_written(out)


@pytest.mark.parametrize(
    ("options", "edge_aware", "near"),
    [((), True, True), (("--no-edge-aware",), False, True), (("--no-near-reach",), True, False)],
)
def test_edge_aware_and_near_reach_are_on_unless_turned_off(
    options: tuple[str, ...], edge_aware: bool, near: bool
) -> None:
    from pcainterp_stream.cli import build_parser
    from pcainterp_stream.cli.densify import _processor_config

    args = build_parser().parse_args(["densify", "in.mcap", "-o", "out.mcap", *options])
    config = _processor_config(args, adapt="check")
    assert (config.edge_aware, config.near is not None) == (edge_aware, near)


@pytest.mark.parametrize(
    ("options", "matcher", "downscale"),
    [
        (("--measurements", "dense"), "refined", 1),
        (("--measurements", "dense", "--dense-matcher", "full"), "full", 1),
        (("--measurements", "dense", "--dense-matcher", "refined"), "refined", 1),
        # at half resolution there is nothing to refine: the whole range, halved
        (("--measurements", "dense", "--stereo-downscale", "2"), "full", 2),
    ],
)
def test_dense_mode_matcher_by_default_and_by_choice(
    options: tuple[str, ...], matcher: str, downscale: int
) -> None:
    import dataclasses

    from pcainterp_stream.cli import build_parser
    from pcainterp_stream.cli.densify import _processor_config
    from pcainterp_stream.frontend.matchers import DENSE_MATCHERS

    args = build_parser().parse_args(["densify", "in.mcap", "-o", "out.mcap", *options])
    config = _processor_config(args, adapt="check")
    expected = dataclasses.replace(DENSE_MATCHERS[matcher], downscale=downscale)
    assert config.sgbm == expected


def test_learn_refuses_an_output_not_named_npz_before_learning(
    pcainterp: Callable[..., Run],
    small_log: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from pcainterp_stream.pipeline import learn as learn_job

    def no_work(*args: object, **kwargs: object) -> None:
        raise AssertionError("learned before checking -o")

    monkeypatch.setattr(learn_job, "learn_pairing", no_work)
    monkeypatch.setattr(learn_job, "learn", no_work)
    target = tmp_path / "basis.mcap"
    line = pcainterp("learn", small_log, "-o", target).error_line()
    assert f"output {target} is named .mcap but learn writes a basis (.npz)" in line
    assert f"-o {tmp_path / 'basis.npz'}" in line
    assert_nothing_written(target)


def test_learn_on_one_pair_advises_only_what_helps(
    pcainterp: Callable[..., Run], tmp_path: Path
) -> None:
    """Bug hunt 15C F5: a one-pair log said "note: 1 maps of your own are few ...: merging
    them" (no merge followed), then advised "a larger --holdout", which no --holdout makes
    work with one pair (--holdout 0.9 failed the same)."""
    log, target = tmp_path / "one.mcap", tmp_path / "basis.npz"
    synth(log, frames=1, seed=3, scale=0.25, fmt="mcap")
    for holdout in ("0.2", "0.9"):
        run = pcainterp("learn", log, "-o", target, "--holdout", holdout)
        line = run.error_line()
        assert line.endswith(
            "no held-out stereo pair to fit the prior on: one.mcap has one stereo pair, whose "
            "map the basis learns; use more frames, --fit-logs LOG (no --holdout leaves both "
            "a map and a pair to fit on), or --no-fit-prior (a basis with no fitted prior)"
        ), line
        assert "merging" not in run.out + run.err
        assert_nothing_written(target)
    # the last advice works (review 15c R5: it was left out)
    assert pcainterp("learn", log, "-o", target, "--no-fit-prior").code == 0
    assert target.is_file()


def test_learn_every_beyond_the_log_names_every(
    pcainterp: Callable[..., Run], small_log: Path, tmp_path: Path
) -> None:
    target = tmp_path / "basis.npz"
    line = pcainterp("learn", small_log, "-o", target, "--every", "50").error_line()
    assert "no held-out stereo pair" in line
    assert "a smaller --every (--every 50 keeps 1 frame in 50)" in line
    assert_nothing_written(target)


@pytest.mark.parametrize(
    ("args", "note"),
    [
        (["--components", "50"], "not --components 50: 8 maps span no more directions"),
        (["--variance", "0.5"], "not the default 500 components: the fewest that explain"),
        (["--components", "2"], None),  # as many as asked: no note
    ],
)
def test_learn_says_why_it_kept_fewer_components(
    pcainterp: Callable[..., Run],
    small_log: Path,
    tmp_path: Path,
    args: list[str],
    note: str | None,
) -> None:
    run = pcainterp(
        "learn",
        small_log,
        "-o",
        tmp_path / "b.npz",
        "--no-fit-prior",
        "--with-synthetic",
        "0",
        *args,
    )
    assert run.code == 0, run.err
    notes = [
        line for line in run.out.splitlines() if line.startswith("note: ") and "component" in line
    ]
    if note is None:
        assert notes == []
    else:
        assert len(notes) == 1, run.out
        assert note in notes[0]


@pytest.mark.parametrize("workers", [None, "1"])
def test_learn_skips_blank_maps_and_refuses_a_log_of_them(
    pcainterp: Callable[..., Run], small_log: Path, tmp_path: Path, workers: str | None
) -> None:
    args = ["--no-fit-prior", "--with-synthetic", "0", *(["--workers", workers] if workers else [])]
    black = _blanked(small_log, tmp_path / "black.mcap", SMALL_FRAMES)
    line = pcainterp("learn", black, "-o", tmp_path / "b.npz", *args).error_line()
    # a cluster's learn says what one process says (bug hunt 16D F6)
    assert line.endswith(
        f"black.mcap: {SMALL_FRAMES} of {SMALL_FRAMES} maps hold no disparity above 0 "
        "(blank, dark or textureless images, or a depth topic without depth); learn from "
        "frames that show the scene"
    )
    assert_nothing_written(tmp_path / "b.npz")
    some = _blanked(small_log, tmp_path / "some.mcap", 2)
    run = pcainterp("learn", some, "-o", tmp_path / "s.npz", *args)
    assert run.code == 0, run.err
    assert f"training maps    {SMALL_FRAMES - 2} (SGBM)" in run.out
    assert f"note: 2 of {SMALL_FRAMES} maps hold no disparity above 0" in run.out


def test_densified_log_says_which_version_and_options_made_it(
    pcainterp: Callable[..., Run], small_log: Path, basis_path: Path, out: Path
) -> None:
    from mcap.reader import make_reader

    from pcainterp_stream.version import __version__

    assert pcainterp(*densify_args(small_log, out, basis_path, "--corners", "150")).code == 0
    with out.open("rb") as stream:
        reader = make_reader(stream)
        assert reader.get_header().library == f"pcainterp_stream {__version__}"
        (record,) = [m for m in reader.iter_metadata() if m.name == "pcainterp.densify"]
    assert record.metadata["version"] == __version__
    processor = json.loads(record.metadata["processor"])
    assert processor["gftt"]["max_corners"] == 150
    assert json.loads(record.metadata["pairing"])["left_topic"] == LEFT


def test_learn_refuses_a_log_given_twice(
    pcainterp: Callable[..., Run], small_log: Path, tmp_path: Path
) -> None:
    link = tmp_path / "link.mcap"
    link.symlink_to(small_log)
    line = pcainterp("learn", small_log, link, "-o", tmp_path / "b.npz").error_line()
    assert line.endswith(
        "link.mcap is " + str(small_log) + " again: its maps would count twice; pass each log once"
    )
    assert_nothing_written(tmp_path / "b.npz")


def test_synth_refuses_a_platform_for_a_street_drive(
    pcainterp: Callable[..., Run], tmp_path: Path
) -> None:
    line = pcainterp("synth", tmp_path / "s.mcap", "--platform", "drone").error_line()
    assert "--platform drone carries the camera of an indoor scene" in line
    assert "add --scene indoor or drop --platform" in line
    assert_nothing_written(tmp_path / "s.mcap")
    for scene in ("indoor", "room", "corridor", "hall"):  # the indoor scenes take it
        target = tmp_path / f"{scene}.mcap"
        args = ["--scene", scene, "--platform", "drone", "--frames", "1", "--scale", "0.1"]
        run = pcainterp("synth", target, *args)
        assert run.code == 0, run.err


@pytest.mark.parametrize(
    ("offset_ns", "fix"),
    [
        (
            33_100_000,
            "33.10-33.10 ms away, beyond the 1 ms tolerance; pass --stamp-tolerance-ms 34",
        ),
        (-1_000_000_000_000, "(the first right image -1000 s from the first left one): the two"),
    ],
)
def test_densify_without_a_pair_names_the_stamp_offset(
    pcainterp: Callable[..., Run],
    small_log: Path,
    basis_path: Path,
    out: Path,
    tmp_path: Path,
    offset_ns: int,
    fix: str,
) -> None:
    def change(topic: str, message: Any, _: int) -> Any:  # an unsynchronised right camera
        if topic not in (RIGHT, RIGHT_INFO):
            return message
        stamp = rosmsg.stamp_ns(message) + offset_ns
        return dataclasses.replace(message, header=rosmsg.header(stamp, message.header.frame_id))

    log = rewrite(small_log, tmp_path / "offset.mcap", change)
    line = pcainterp(*densify_args(log, out, basis_path)).error_line()
    assert "no stereo pair found in" in line
    assert fix in line
    assert_nothing_written(out)


def test_densify_a_log_of_one_camera_says_so(
    pcainterp: Callable[..., Run],
    small_messages: list[Message],
    basis_path: Path,
    out: Path,
    tmp_path: Path,
) -> None:
    camera = [m for m in small_messages if m[0].startswith("/stereo/left/")]  # no truth
    mono = write_messages(tmp_path / "mono.mcap", camera)
    line = pcainterp(*densify_args(mono, out, basis_path)).error_line()
    assert line.endswith(
        f"it has one camera ({LEFT}; camera infos: {LEFT_INFO}); pcainterp needs a stereo pair, "
        "two cameras side by side (--left-topic and --right-topic name them)"
    )
    assert_nothing_written(out)


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["info", "drive.mcap"], "pcainterp: interrupted"),
        (["golden", "check", "drive.mcap", "g.json"], "pcainterp: interrupted"),
        (
            ["golden", "check", "drive.mcap", "g.json", "--update"],
            "pcainterp: interrupted; no partial output was left at the target",
        ),
        (
            ["synth", "drive.mcap"],
            "pcainterp: interrupted; no partial output was left at the target",
        ),
    ],
)
def test_an_interrupted_command_that_only_reads_says_just_interrupted(
    pcainterp: Callable[..., Run], monkeypatch: pytest.MonkeyPatch, args: list[str], said: str
) -> None:
    """``info`` and ``golden check`` write nothing: no word of partial outputs for them."""
    from pcainterp_stream.cli import app

    def interrupted(args: argparse.Namespace) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr(app, "run", interrupted)
    run = pcainterp(*args)
    assert (run.code, run.err.strip()) == (130, said)


def test_an_interruption_says_what_is_at_the_target(
    pcainterp: Callable[..., Run],
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
) -> None:
    """Not "no partial output was left at the target" while the target holds a file: an
    earlier run's output is named as such, a run with no file output wrote nothing, and a
    demo names the steps' files it finished."""
    from pcainterp_stream.cli import app

    written: list[Path] = []

    def interrupted(args: argparse.Namespace) -> int:
        for path in written:
            path.write_bytes(b"this run's")
        raise KeyboardInterrupt

    monkeypatch.setattr(app, "run", interrupted)
    old = tmp_path / "old.mcap"
    old.write_bytes(b"an earlier run's")
    new = tmp_path / "new.mcap"

    def said(*args: str | Path) -> str:
        run = pcainterp(*args)
        assert run.code == 130
        return run.err.strip().removeprefix("pcainterp: interrupted; ")

    earlier = "was not changed (it holds an earlier run's output)"
    assert said("synth", old) == f"{old} {earlier}"
    assert said("synth", new) == "no partial output was left at the target"
    assert said("densify", "in.mcap", "--foxglove", "127.0.0.1:0") == "nothing was written"
    assert said("densify", "in.mcap", "--out-dir", tmp_path) == (
        "no partial output was left at the target"
    )
    rrd = tmp_path / "old.rrd"
    rrd.write_bytes(b"an earlier recording")
    assert said("densify", "in.mcap", "-o", new, "--rrd", rrd) == (
        f"{rrd} {earlier}; nothing was written at {new}"
    )
    report = tmp_path / "rep"
    report.mkdir()
    (report / "results.md").write_text("an earlier report")
    assert said("evaluate", "in.mcap", "-o", report) == f"{report} {earlier}"
    demo = tmp_path / "demo"
    demo.mkdir()
    (demo / "report").mkdir()
    written[:] = [demo / "heldout.mcap", demo / "heldout_dense.mcap"]
    assert said("demo", "--out", demo) == (
        f"{demo / 'heldout.mcap'}, {demo / 'heldout_dense.mcap'} were finished before the "
        f"signal and kept; {demo / 'report'} {earlier}"
    )
