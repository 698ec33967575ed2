"""A rosbag2 folder with MCAP storage reads as its storage files do (bug hunt 6B M7).

The folders are written by ``pcainterp synth --format rosbag2`` (rosbags' writer), then
their storage file is rewritten as ``ros2 bag record`` and ``mcap add attachment`` leave
one: publish times before the log times, sequences, a metadata record, an attachment;
split in two files for a split bag.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
import zstandard
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from pcainterp_stream import cli
from pcainterp_stream.errors import LogReadError
from pcainterp_stream.io.loginfo import describe
from pcainterp_stream.io.logreader import LogFormat, open_log
from pcainterp_stream.pipeline.jobs import synth

URDF = b'<robot name="r"/>'


@pytest.fixture(scope="module")
def synth_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 4-frame eighth-size synthetic drive as a rosbag2 folder with MCAP storage."""
    path = tmp_path_factory.mktemp("r2") / "drive"
    synth(path, frames=4, seed=5, scale=0.125, fmt="rosbag2")
    return path


def recorded(source: Path, target: Path, *, parts: int = 1, compression: str = "") -> Path:
    """Copy a rosbag2 folder, its storage rewritten as a recorder leaves it (``parts`` files).

    Publish time = log time - 5 ms, sequence = 1000 + n; every file gets a ``rosbag2``
    metadata record; the last one also ``calibration_info`` and the attachment robot.urdf.
    ``compression``: "message" or "file" as ``ros2 bag record --compression-mode`` (zstd).
    """
    (storage,) = source.glob("*.mcap")
    target.mkdir()
    with storage.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        messages = [(channel, message) for _, channel, message in reader.iter_messages()]
    names = [f"{target.name}_{i}.mcap" for i in range(parts)]
    share = -(-len(messages) // parts)
    for i, name in enumerate(names):
        with (target / name).open("wb") as f:
            writer = Writer(f, compression=CompressionType.ZSTD)
            writer.start(profile="ros2", library="test")
            schemas = {
                key: writer.register_schema(s.name, s.encoding, s.data)
                for key, s in summary.schemas.items()
            }
            channels = {
                key: writer.register_channel(
                    c.topic, c.message_encoding, schemas[c.schema_id], dict(c.metadata)
                )
                for key, c in summary.channels.items()
            }
            for n, (channel, message) in enumerate(messages[i * share : (i + 1) * share]):
                writer.add_message(
                    channels[channel.id],
                    message.log_time,
                    zstandard.compress(message.data) if compression == "message" else message.data,
                    message.log_time - 5_000_000,
                    1000 + i * share + n,
                )
            writer.add_metadata("rosbag2", {"serialized_metadata": f"file {i}"})
            if i == parts - 1:
                writer.add_metadata("calibration_info", {"rig": "A7"})
                writer.add_attachment(7, 8, "robot.urdf", "application/xml", URDF)
            writer.finish()
    if compression == "file":
        for i, name in enumerate(names):
            data = (target / name).read_bytes()
            (target / name).unlink()
            names[i] = name + ".zstd"
            (target / names[i]).write_bytes(zstandard.compress(data))
    text = (source / "metadata.yaml").read_text().replace(storage.name, names[0])
    if compression:
        text = text.replace("compression_format: ''", "compression_format: zstd")
        text = text.replace("compression_mode: ''", f"compression_mode: {compression}")
        assert f"compression_mode: {compression}" in text
    listed = "\n".join(f"  - {name}" for name in names)
    text = text.replace(
        f"  relative_file_paths:\n  - {names[0]}", f"  relative_file_paths:\n{listed}"
    )
    (target / "metadata.yaml").write_text(text)
    return target


@pytest.mark.parametrize(
    ("parts", "compression"), [(1, ""), (2, ""), (2, "message"), (1, "file"), (2, "file")]
)
def test_a_folder_keeps_publish_times_sequences_attachments_and_metadata(
    synth_folder: Path, tmp_path: Path, parts: int, compression: str
) -> None:
    """Before: publish time = log time, sequence 0, no attachment or metadata record.

    A compressed folder too (bug hunt 17A F4): it was read through rosbags, which kept none.
    """
    folder = recorded(synth_folder, tmp_path / "rec", parts=parts, compression=compression)
    with open_log(folder) as reader:
        assert reader.format is LogFormat.ROSBAG2
        raws = list(reader.messages())
        extras = reader.extras()
        assert reader.damage == []
    assert len(raws) == 24
    assert [raw.log_time_ns for raw in raws] == sorted(raw.log_time_ns for raw in raws)
    assert all(raw.publish_time_ns == raw.log_time_ns - 5_000_000 for raw in raws)
    assert sorted(raw.sequence for raw in raws) == list(range(1000, 1024))
    assert extras is not None
    assert [(m.name, m.metadata) for m in extras.metadata] == [
        *(("rosbag2", {"serialized_metadata": f"file {i}"}) for i in range(parts)),
        ("calibration_info", {"rig": "A7"}),
    ]
    assert [(a.name, a.media_type, a.size) for a in extras.attachments] == [
        ("robot.urdf", "application/xml", len(URDF))
    ]
    assert len(extras.channels) == 6  # a split bag's repeated channels listed once
    info = describe(folder)
    assert [a.name for a in info.attachments] == ["robot.urdf"]
    assert [m.name for m in info.metadata][-1] == "calibration_info"
    if compression == "message":  # each payload decompressed: they decode
        with open_log(folder) as reader:
            image = next(reader.messages(["/stereo/left/image_rect"]))
            assert reader.decode(image).height > 0


def test_densify_of_a_folder_copies_its_attachments_and_metadata_records(
    synth_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = recorded(synth_folder, tmp_path / "rec", parts=2)
    out = tmp_path / "dense.mcap"
    run: Callable[[list[str]], int] = cli.main
    code = run(["densify", str(folder), "-o", str(out)])
    assert code == 0, capsys.readouterr().err
    with out.open("rb") as f:
        reader = make_reader(f)
        attachments = [(a.name, a.data) for a in reader.iter_attachments()]
        names = [m.name for m in reader.iter_metadata()]
        publish = {
            (m.log_time - m.publish_time, m.sequence >= 1000)
            for _, c, m in reader.iter_messages()
            if not c.topic.startswith("/pcainterp/")
        }
    assert attachments == [("robot.urdf", URDF)]
    assert names == [
        "rosbag2",
        "rosbag2",
        "calibration_info",
        "pcainterp.densify",
        "pcainterp.basis",
    ]
    assert publish == {(5_000_000, True)}


@pytest.mark.parametrize("beside", [True, False])
def test_the_storage_file_of_a_message_compressed_bag_alone_is_refused_in_one_line(
    synth_folder: Path, tmp_path: Path, beside: bool
) -> None:
    """Bug hunt 17A F3: every message failed as "damaged message?" (convert to mono8...)."""
    folder = recorded(synth_folder, tmp_path / "rec", compression="message")
    (storage,) = folder.glob("*.mcap")
    if not beside:  # no metadata.yaml: the payloads' zstd magic tells
        storage = storage.rename(tmp_path / storage.name)
    with pytest.raises(LogReadError) as caught:
        open_log(storage)
    text = str(caught.value)
    assert "\n" not in text
    assert text.startswith(f"{storage} is the storage file of a rosbag2 bag recorded with ")
    assert "per-message zstd compression" in text
    where = f"its folder {folder} " if beside else "the bag's folder (with its metadata.yaml)"
    assert f"pass {where}" in text
    with open_log(recorded(synth_folder, tmp_path / "plain")) as reader:  # not compressed
        assert reader.damage == []


@pytest.mark.parametrize("chunked", [True, False])
def test_a_first_message_of_zstd_data_on_a_non_cdr_channel_reads(
    synth_folder: Path, tmp_path: Path, chunked: bool
) -> None:
    """Review 17c R2: any MCAP whose first payload was zstd data was refused as rosbag2's."""
    (storage,) = synth_folder.glob("*.mcap")
    with storage.open("rb") as f:
        messages = [(s, c, m) for s, c, m in make_reader(f).iter_messages(log_time_order=True)]
    blob = tmp_path / "blob.mcap"
    with blob.open("wb") as f:
        writer = Writer(
            f,
            compression=CompressionType.ZSTD if chunked else CompressionType.NONE,
            use_chunking=chunked,
        )
        writer.start(profile="ros2", library="test")
        first = messages[0][2].log_time - 1
        channel = writer.register_channel("/blob", "application/zstd", 0, {})
        writer.add_message(channel, first, zstandard.compress(b"x" * 100), first, 0)
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, chan, message in messages:
            assert schema is not None
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(
                    schema.name, schema.encoding, schema.data
                )
            if chan.id not in channels:
                channels[chan.id] = writer.register_channel(
                    chan.topic, chan.message_encoding, schemas[schema.id], dict(chan.metadata)
                )
            writer.add_message(
                channels[chan.id], message.log_time, message.data, message.log_time, 0
            )
        writer.finish()
    with open_log(blob) as reader:
        assert sum(1 for _ in reader.messages()) == len(messages) + 1


def test_a_file_compressed_storage_file_alone_says_zstd(synth_folder: Path, tmp_path: Path) -> None:
    """Bug hunt 17A F3: "not a log (no MCAP, ROS 1 bag or SQLite magic bytes)"."""
    folder = recorded(synth_folder, tmp_path / "rec", compression="file")
    (storage,) = folder.glob("*.mcap.zstd")
    with pytest.raises(LogReadError, match=r"is zstd-compressed \(a rosbag2 bag recorded with "):
        open_log(storage)
    with pytest.raises(LogReadError, match=rf"pass its folder {folder}, or decompress it first"):
        open_log(storage)


@pytest.mark.parametrize("beside", [True, False])
def test_the_db3_of_a_message_compressed_bag_alone_is_refused_in_one_line(
    tmp_path: Path, beside: bool
) -> None:
    """Bug hunt 17A F3, sqlite3 storage: "SerdeError ... (damaged message?)" before."""
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    string = store.types["std_msgs/msg/String"]
    writer = Writer(tmp_path / "bag", version=9, storage_plugin=StoragePlugin.SQLITE3)
    writer.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with writer:
        connection = writer.add_connection("/chatter", string.__msgtype__, typestore=store)
        writer.write(connection, 1, store.serialize_cdr(string(data="hi"), string.__msgtype__))
    (storage,) = (tmp_path / "bag").glob("*.db3")
    if not beside:
        storage = storage.rename(tmp_path / storage.name)
    with pytest.raises(LogReadError, match="per-message zstd compression") as caught:
        open_log(storage)
    found = "metadata.yaml says compression_mode" if beside else "starts with the zstd magic"
    assert found in str(caught.value)
    if beside:
        with open_log(tmp_path / "bag") as reader:  # the folder reads
            (raw,) = reader.messages()
            assert reader.decode(raw).data == "hi"


def test_the_decompressed_copy_is_owner_named_tracked_and_a_killed_runs_is_removed(
    synth_folder: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Review 17c R3: a SIGKILLed run's bare mkdtemp copy stayed in TMPDIR for good."""
    import os
    import subprocess
    import sys
    import tempfile

    from pcainterp_stream import interrupt
    from pcainterp_stream.io.output_paths import temporary_prefix

    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    folder = recorded(synth_folder, tmp_path / "rec", compression="file")
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    prefix = temporary_prefix("pcainterp-rosbag2")
    killed = scratch / (prefix.replace(f"-{os.getpid()}@", f"-{process.pid}@") + "t1x6e3v1")
    killed.mkdir()
    (killed / "rec_0.mcap").write_bytes(bytes(1000))
    live = scratch / (prefix.replace(f"-{os.getpid()}@", f"-{os.getppid()}@") + "abcdefgh")
    live.mkdir()  # a run still going
    with open_log(folder) as reader:
        assert sum(1 for _ in reader.messages()) > 0
        (mine,) = (p for p in scratch.iterdir() if p != live)
        assert mine.name.startswith(prefix)
        assert mine in interrupt._partials  # removed if a signal forces the end
    assert not killed.exists()
    assert sorted(os.listdir(scratch)) == [live.name]
    assert mine not in interrupt._partials


def test_no_room_to_decompress_is_said_before_writing_with_the_size_needed(
    synth_folder: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Review 17c R5: the free room was read after the copy filled the disk (always 0 GB)."""
    import shutil
    import tempfile

    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    folder = recorded(synth_folder, tmp_path / "rec", compression="file")
    (storage,) = folder.glob("*.mcap.zstd")
    size = zstandard.frame_content_size(storage.read_bytes()[:18])
    assert size > 1000
    usage = shutil.disk_usage(scratch)
    monkeypatch.setattr(shutil, "disk_usage", lambda _path: usage._replace(free=1000))
    with pytest.raises(LogReadError) as caught:
        open_log(folder)
    plain = folder / storage.name.removesuffix(".zstd")
    needs = f"{size / 1e6:.0f} MB" if size >= 1e6 else f"{size / 1e3:.0f} kB"
    assert str(caught.value) == (
        f"cannot decompress {storage} (a rosbag2 bag recorded with --compression-mode file) "
        f"into the temporary folder {scratch}: it needs {needs}, it has 1 kB free; set TMPDIR "
        f"to a folder with room for it, or run `zstd -d {storage}` and pass the decompressed "
        f"{plain} (the folder still lists the .zstd)"
    )
    assert list(scratch.iterdir()) == []


@pytest.mark.parametrize("keep", [5, 7])
def test_a_cut_zstd_header_is_one_line_not_a_traceback(
    synth_folder: Path, tmp_path: Path, keep: int
) -> None:
    """Review 17e R3: a `.mcap.zstd` cut inside its frame header raised ZstdError ("error
    when determining content size") out of the reader: a traceback, exit 1."""
    folder = recorded(synth_folder, tmp_path / "rec", compression="file")
    (storage,) = folder.glob("*.mcap.zstd")
    storage.write_bytes(storage.read_bytes()[:keep])
    with pytest.raises(LogReadError, match="a damaged or cut file"):
        with open_log(folder) as reader:
            list(reader.messages())
