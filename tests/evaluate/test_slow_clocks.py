"""Header clocks slower than log time, and a reference topic on the images' clock (review 59a).

A simulator below real time whose stamps repeat (1000.0, 1000.0, 1000.0, 1000.1 ...): the
outputs of the repeats are stamped between the stamps of their own, never on or behind the
next one (F1); a ``--reference-topic`` whose stamps repeat the same way is placed by the same
rule as the frames, truth and poses, so no frame is left out (F2).
"""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from pcainterp_stream.evaluate.metrics import Mode
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
from pcainterp_stream.io.stereo_log import DEPTH as TRUTH
from pcainterp_stream.pipeline import jobs

FRAMES = 6
REFERENCE = "/ref/depth"
OPTIONS = EvaluateOptions(mode=Mode.STEREO, sweep_every=0, linear=False)


def _restamp(source: Path, target: Path, repeats: int, step_ns: int, reference: bool) -> None:
    """Copy a synth log with every topic's stamps 1000 s + (i // repeats) * step (log times
    kept); ``reference``: with REFERENCE, a copy of the truth (stamps and log times too)."""
    seen: dict[str, int] = {}
    with source.open("rb") as stream, target.open("wb") as out:
        writer = Writer(out)
        writer.start()
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        copy_of_truth: int | None = None
        for schema, channel, message in make_reader(stream).iter_messages(log_time_order=True):
            assert schema is not None
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(
                    schema.name, schema.encoding, schema.data
                )
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id], {}
                )
            index = seen[channel.topic] = seen.get(channel.topic, -1) + 1
            stamp = 1000 * 10**9 + (index // repeats) * step_ns
            data = bytearray(message.data)  # (each of synth's topics: a header first)
            data[4:8] = (stamp // 10**9).to_bytes(4, "little")
            data[8:12] = (stamp % 10**9).to_bytes(4, "little")
            writer.add_message(
                channels[channel.id], message.log_time, bytes(data), message.log_time
            )
            if reference and channel.topic == TRUTH:
                if copy_of_truth is None:
                    copy_of_truth = writer.register_channel(
                        REFERENCE, channel.message_encoding, schemas[schema.id], {}
                    )
                writer.add_message(copy_of_truth, message.log_time, bytes(data), message.log_time)
        writer.finish()


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("slow_clocks")
    jobs.synth(folder / "synth.mcap", frames=FRAMES, seed=43, scale=0.25, fmt="mcap")
    jobs.densify(folder / "synth.mcap", folder / "dense.mcap")
    return folder


def _scores(path: Path, options: EvaluateOptions = OPTIONS) -> tuple[int, dict[str, float]]:
    result, _ = evaluate_log(path, options)
    return result.frames, {name: s.delta_2d_sum / s.pixels for name, s in result.methods.items()}


def _depth_stamps(path: Path) -> list[int]:
    with path.open("rb") as stream:
        reader = make_reader(stream)
        return [
            int.from_bytes(m.data[4:8], "little") * 10**9 + int.from_bytes(m.data[8:12], "little")
            for _, _, m in reader.iter_messages(topics=["/pcainterp/depth"])
        ]


def test_a_clock_at_a_third_of_real_time_keeps_the_outputs_in_order(folder: Path) -> None:
    # review 59a F1: output stamps 1000.0, 1000.1, 1000.2, 1000.1 (back), 1000.2 ...
    slow = folder / "slow3.mcap"
    _restamp(folder / "synth.mcap", slow, 3, 100_000_000, reference=False)
    jobs.densify(slow, folder / "slow3_dense.mcap")
    stamps = _depth_stamps(folder / "slow3_dense.mcap")
    assert len(stamps) == FRAMES
    assert all(b > a for a, b in itertools.pairwise(stamps)), stamps
    assert stamps[3] == 1000 * 10**9 + 100_000_000  # a stamp of its own, kept
    assert stamps[2] < stamps[3]
    assert stamps[5] < 1000 * 10**9 + 200_000_000
    assert _scores(folder / "slow3_dense.mcap") == _scores(folder / "dense.mcap")


def test_a_reference_on_the_coarse_clock_of_the_images_keeps_every_frame(folder: Path) -> None:
    # review 59a F2: the reference kept its repeated stamps while the frames went on the
    # clock: 3 of 6 frames left out, "the stream lacks them"
    clean, coarse = folder / "clean_ref.mcap", folder / "coarse_ref.mcap"
    _restamp(folder / "synth.mcap", clean, 1, 100_000_000, reference=True)
    _restamp(folder / "synth.mcap", coarse, 2, 200_000_000, reference=True)
    for log in (clean, coarse):
        jobs.densify(log, log.with_name(log.stem + "_dense.mcap"))
    options = EvaluateOptions(
        mode=Mode.STEREO, sweep_every=0, linear=False, reference_topic=REFERENCE
    )
    result, _ = evaluate_log(folder / "coarse_ref_dense.mcap", options)
    assert result.frames == FRAMES, result.notes
    assert not [note for note in result.notes if "lacks" in note]
    assert _scores(folder / "coarse_ref_dense.mcap", options) == _scores(
        folder / "clean_ref_dense.mcap", options
    )
