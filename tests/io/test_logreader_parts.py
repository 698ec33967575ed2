"""The parts of one split recording (``rosbag record --split``) read as one log."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer as McapWriter
from rosbags.rosbag1 import Reader, Writer

from pcainterp_stream import cli
from pcainterp_stream.errors import LogReadError
from pcainterp_stream.io.logreader import LogFormat, open_log
from pcainterp_stream.pipeline.jobs import synth

FRAMES = 6


def split_bag(source: Path, at_ns: int, names: tuple[Path, Path]) -> None:
    """Write ``source`` as two bags, before and from log time ``at_ns``, as rosbag does."""
    with Reader(source) as reader:
        writers = [Writer(name) for name in names]
        for writer in writers:
            writer.open()
        connections: list[dict[int, object]] = [{}, {}]
        for connection, log_ns, data in reader.messages():
            part = int(log_ns >= at_ns)
            added = connections[part].get(connection.id)
            if added is None:
                added = connections[part][connection.id] = writers[part].add_connection(
                    connection.topic,
                    connection.msgtype,
                    msgdef=connection.msgdef.data,
                    md5sum=connection.digest,
                )
            writers[part].write(added, log_ns, data)  # type: ignore[arg-type]
        for writer in writers:
            writer.close()


@pytest.fixture(scope="module")
def split(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("split")
    whole = folder / "run.bag"
    synth(whole, frames=FRAMES, seed=5, scale=0.25, fmt="ros1")
    with open_log(whole) as reader:
        times = sorted({raw.log_time_ns for raw in reader.messages()})
    middle = times[len(times) // 2]
    first, second = folder / "run_0.bag", folder / "run_1.bag"
    split_bag(whole, middle, (first, second))
    return {"whole": whole, "first": first, "second": second, "folder": folder}


def messages(paths: Path | list[Path]) -> list[tuple[str, int, bytes]]:
    with open_log(paths) as reader:
        return [(raw.topic, raw.log_time_ns, raw.data) for raw in reader.messages()]


def test_parts_read_as_one_log_in_log_time_order(split: dict[str, Path]) -> None:
    whole = messages(split["whole"])
    # in either order (a shell's a_*.bag puts a_10.bag before a_2.bag): log-time order
    for order in ([split["first"], split["second"]], [split["second"], split["first"]]):
        assert messages(order) == whole
    with open_log([split["second"], split["first"]]) as reader:
        assert reader.format is LogFormat.ROS1
        assert reader.path.name == "run_0.bag + run_1.bag"
        with open_log(split["whole"]) as one:
            assert {t: i.message_count for t, i in reader.topics().items()} == {
                t: i.message_count for t, i in one.topics().items()
            }
            assert reader.message_stats() == one.message_stats()


def test_parts_that_are_no_split_recording_are_refused(split: dict[str, Path]) -> None:
    with pytest.raises(LogReadError, match=r"run\.bag \(.* overlap by 200\.000 ms: they are not"):
        open_log([split["whole"], split["second"]])
    with pytest.raises(LogReadError, match=r"run_0\.bag is given twice; pass each part"):
        open_log([split["first"], split["first"]])
    mcap = split["folder"] / "other.mcap"
    synth(mcap, frames=1, seed=6, scale=0.25, fmt="mcap")
    with pytest.raises(LogReadError, match=r"is a ROS 1 bag but .*other\.mcap is an MCAP file"):
        open_log([split["first"], mcap])


def densified(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    found: dict[str, list[tuple[int, bytes]]] = {}
    with path.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=True):
            found.setdefault(channel.topic, []).append((message.log_time, message.data))
    return found


def test_densify_reads_the_parts_as_one_log(
    split: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # refused before ("-o takes one input but 2 were given"); --out-dir densified each part
    # alone (fit check, temporal state and carried points restarted at the split)
    out, one = tmp_path / "parts.mcap", tmp_path / "whole.mcap"
    assert cli.main(["densify", str(split["first"]), str(split["second"]), "-o", str(out)]) == 0
    said = capsys.readouterr().out
    assert f"densified {FRAMES} frames of {split['first']} + run_1.bag" in said
    assert cli.main(["densify", str(split["whole"]), "-o", str(one)]) == 0
    parts, whole = densified(out), densified(one)
    assert sorted(parts) == sorted(whole)
    assert parts["/pcainterp/depth"] == whole["/pcainterp/depth"]  # the same frames, bytes
    assert parts["/stereo/left/image_rect"] == whole["/stereo/left/image_rect"]


def test_densify_refuses_overlapping_parts_in_one_line(
    split: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "x.mcap"
    code = cli.main(["densify", str(split["whole"]), str(split["first"]), "-o", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1
    assert "overlap" in err[0]
    assert "--out-dir DIR" in err[0]
    assert not out.exists()
    code = cli.main(["densify", str(split["first"]), "-", "-o", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert err == [
        "pcainterp: error: standard input (-) is one whole log, not a part of one; pass the "
        "parts of a split recording as files (densify a_0.bag a_1.bag -o OUTPUT)"
    ]


def jittered_split(source: Path, at_ns: int, names: tuple[Path, Path], late_ns: int) -> None:
    """Split as ``rosbag record --split`` when receive stamps are out of queue order at the seam.

    The first message of log time ``at_ns`` goes into the first part stamped ``late_ns`` later;
    the others of that time stay in the second part: the parts overlap by ``late_ns``.
    """
    with Reader(source) as reader:
        writers = [Writer(name) for name in names]
        for writer in writers:
            writer.open()
        connections: list[dict[int, object]] = [{}, {}]
        moved = False
        for connection, log_ns, data in reader.messages():
            part = int(log_ns >= at_ns)
            if log_ns == at_ns and not moved:
                part, log_ns, moved = 0, log_ns + late_ns, True
            added = connections[part].get(connection.id)
            if added is None:
                added = connections[part][connection.id] = writers[part].add_connection(
                    connection.topic,
                    connection.msgtype,
                    msgdef=connection.msgdef.data,
                    md5sum=connection.digest,
                )
            writers[part].write(added, log_ns, data)  # type: ignore[arg-type]
        for writer in writers:
            writer.close()


def test_parts_overlapping_by_microseconds_at_the_seam_are_merged(split: dict[str, Path]) -> None:
    # review 57b R1: refused before ("overlap: they are not the parts of one split recording",
    # both times printed as ...453.600)
    with open_log(split["whole"]) as reader:
        times = sorted({raw.log_time_ns for raw in reader.messages()})
    middle = times[len(times) // 2]
    folder = split["folder"]
    first, second = folder / "jit_0.bag", folder / "jit_1.bag"
    jittered_split(split["whole"], middle, (first, second), 30_000)
    got = messages([second, first])
    whole = messages(split["whole"])
    assert len(got) == len(whole)
    assert [t for _, t, _ in got] == sorted(t for _, t, _ in got)  # merged in log-time order
    assert sorted((topic, data) for topic, _, data in got) == sorted(
        (topic, data) for topic, _, data in whole
    )
    # much overlap is still refused, with the times to the microsecond and the overlap
    late = folder / "late_0.bag"
    jittered_split(split["whole"], middle, (late, folder / "late_1.bag"), 2_000_000_000)
    with pytest.raises(LogReadError, match=r"\.\d{6} s\) overlap by 2\.000 s: they are not"):
        open_log([late, second])


def test_parts_far_apart_are_read_with_a_warning(split: dict[str, Path]) -> None:
    # review 57b R3: two recordings an hour apart were joined without a word
    folder = split["folder"]
    shifted = folder / "later.bag"
    with Reader(split["second"]) as reader:
        writer = Writer(shifted)
        writer.open()
        added: dict[int, object] = {}
        for connection, log_ns, data in reader.messages():
            if connection.id not in added:
                added[connection.id] = writer.add_connection(
                    connection.topic,
                    connection.msgtype,
                    msgdef=connection.msgdef.data,
                    md5sum=connection.digest,
                )
            writer.write(added[connection.id], log_ns + 3600 * 10**9, data)  # type: ignore[arg-type]
        writer.close()
    with open_log([split["first"], shifted]) as reader:
        assert len(list(reader.messages())) == len(messages(split["whole"]))
        (warning,) = [w for w in reader.warnings if "later.bag starts" in w]
        assert "after run_0.bag ends" in warning
        assert "--out-dir DIR" in warning
    with open_log([split["first"], split["second"]]) as reader:  # one recording: no word
        assert not [w for w in reader.warnings if "starts" in w]


def test_rosbag2_folder_with_its_own_mcap_storage_is_one_log_given_twice(tmp_path: Path) -> None:
    # review 57b R4: refused as "a rosbag2 bag but ... an MCAP file" (two formats)
    folder = tmp_path / "r2"
    synth(folder, frames=1, seed=5, scale=0.125, fmt="rosbag2")
    (storage,) = folder.glob("*.mcap")
    with pytest.raises(LogReadError, match=r"r2 and .*\.mcap are one log given twice"):
        open_log([folder, storage])


def test_help_and_docs_say_foxglove_alone_takes_parts_too(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # review 57b R7: "with -o" only, while --foxglove alone reads several inputs as parts too
    with pytest.raises(SystemExit):
        cli.main(["densify", "--help"])
    said = " ".join(capsys.readouterr().out.split())
    assert "with -o or --foxglove, several are the parts of one split recording" in said
    root = Path(__file__).resolve().parents[2]
    readme = " ".join((root / "README.md").read_text().split())
    assert "Several inputs with `-o`, or with `--foxglove` alone, are not several logs" in readme
    raw_logs = " ".join((root / "docs" / "raw_logs.md").read_text().split())
    assert "Give `densify` the parts with `-o` (or with `--foxglove` alone" in raw_logs


def string_mcap(path: Path, times_ns: list[int]) -> None:
    """Write an MCAP log of one std_msgs/String message at each log time."""
    with path.open("wb") as stream:
        writer = McapWriter(stream)
        writer.start()
        schema = writer.register_schema(
            name="std_msgs/msg/String", encoding="ros2msg", data=b"string data"
        )
        channel = writer.register_channel(
            topic="/chatter", message_encoding="cdr", schema_id=schema
        )
        for t in times_ns:
            data = b"\x00\x01\x00\x00\x02\x00\x00\x00a\x00"
            writer.add_message(channel_id=channel, log_time=t, publish_time=t, data=data)
        writer.finish()


def test_a_last_part_of_one_message_overlapping_at_the_seam_is_merged(tmp_path: Path) -> None:
    # review 57d D5: refused before ("overlap by 0.030 ms: they are not the parts of one split
    # recording"): half of a one-message part's span (0) allowed no seam jitter at all
    first, last = tmp_path / "p_0.mcap", tmp_path / "p_1.mcap"
    string_mcap(first, [k * 100_000_000 for k in range(11)])  # 0 to 1.0 s
    string_mcap(last, [1_000_000_000 - 30_000])  # stamped 30 us before the first part's end
    got = [t for _, t, _ in messages([last, first])]
    assert got == sorted([k * 100_000_000 for k in range(11)] + [1_000_000_000 - 30_000])
    # a one-message part further inside the other is still refused, naming the allowance
    inside = tmp_path / "in_1.mcap"
    string_mcap(inside, [1_000_000_000 - 20_000_000])
    with pytest.raises(LogReadError, match=r"overlap by 20\.000 ms: .*10\.000 ms for a shorter"):
        open_log([first, inside])


def test_out_dir_hints_at_the_parts_of_one_split_recording(
    split: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    # `densify a_0.bag a_1.bag --out-dir DIR` densified the parts apart with no word
    from pcainterp_stream.cli.densify import _hint_split
    from pcainterp_stream.io.logreader_parts import seams

    first, second, whole = split["first"], split["second"], split["whole"]
    (((a, b), (gap,)),) = seams([second, first], open_log)
    assert (a, b) == (first, second)
    assert 0 <= gap < 10**9
    assert seams([first, whole], open_log) == []  # the whole log overlaps its first part
    assert seams([first, split["folder"] / "missing.bag"], open_log) == []
    _hint_split([first, second])
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("warning: run_1.bag starts ")
    assert "look like the parts of one split recording" in line
    assert line.endswith(f"pcainterp densify {first} {second} -o OUTPUT")


def test_out_dir_hints_once_at_the_three_parts_of_one_recording(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # review 58a R5: three parts gave two warnings, `densify part0 part1 -o OUTPUT` and
    # `densify part1 part2 -o OUTPUT`: following either read two of the three parts
    from pcainterp_stream.cli.densify import _hint_split
    from pcainterp_stream.io.logreader_parts import seams

    s = 1_000_000_000
    parts = [tmp_path / f"part{i}.mcap" for i in range(3)]
    for i, part in enumerate(parts):
        string_mcap(part, [i * s + k * s // 10 for k in range(10)])  # 0.1 s from the next
    alone = tmp_path / "other.mcap"
    string_mcap(alone, [3600 * s, 3601 * s])  # an hour later: no part of them
    ((chain, gaps),) = seams([parts[2], alone, parts[0], parts[1]], open_log)
    assert chain == tuple(parts)
    assert gaps == (s // 10, s // 10)
    _hint_split([parts[2], parts[0], alone, parts[1]])
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(
        "warning: part0.mcap, part1.mcap and part2.mcap follow each other (each starting at "
        "most 0.1 s after the one before ends): they look like the parts of one split recording"
    )
    assert line.endswith(f"pcainterp densify {parts[0]} {parts[1]} {parts[2]} -o OUTPUT")
