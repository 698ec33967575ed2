"""Camera clocks that repeat a stamp: stuck (bug hunt 16B F8), paused (review 16b R1, R3).

densify places the repeats within one frame interval of the stamp, and evaluate matched
several frames to one truth and pose message: frames scored against another frame's truth,
D2D 0.000 px for every method (identical poses), exit 0. One truth message now goes to one
frame, the one stamped nearest it (then logged nearest it); the other frames are left out
and said, with the cause: their repeated stamps, or a stamp tolerance of half a frame.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap_copy import McapCopy

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.evaluate.metrics import Mode
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
from pcainterp_stream.io.outputs import OutputTopics
from pcainterp_stream.io.stereo_log import LEFT_IMAGE, LEFT_INFO, RIGHT_IMAGE, RIGHT_INFO
from pcainterp_stream.pipeline import jobs

CAMERA_TOPICS = (LEFT_IMAGE, RIGHT_IMAGE, LEFT_INFO, RIGHT_INFO)


@pytest.fixture(scope="module")
def stuck(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("stuck_clock")
    log, stuck = folder / "synth.mcap", folder / "stuck.mcap"
    jobs.synth(log, frames=6, seed=43, scale=0.25, fmt="mcap")
    first: bytes | None = None
    with McapCopy(log, stuck) as copy:  # the camera's stamps all its first one
        for topic, channel_id, message in copy.messages():
            data = bytearray(message.data)
            if topic in CAMERA_TOPICS:
                first = first or bytes(data[4:12])  # CDR header, then the stamp
                data[4:12] = first
            copy.add(channel_id, message.log_time, bytes(data))
    jobs.densify(stuck, folder / "stuck_dense.mcap")
    return folder / "stuck_dense.mcap"


def test_no_truth_message_is_scored_for_two_frames(stuck: Path) -> None:
    # before: 2 frames scored, frames 3 and 4 against frame 1's truth and pose, D2D 0.000
    options = EvaluateOptions(mode=Mode.TEMPORAL, sweep_every=0, linear=False)
    with pytest.raises(LogReadError, match="no time of their own") as error:
        evaluate_log(stuck, options)
    assert "header stamp repeated or was 0" in str(error.value)
    # review 16e R3: their truth went to no frame, so not "another frame's, stamped nearer it"
    assert "stamped nearer it" not in str(error.value), str(error.value)


def test_in_stereo_mode_each_truth_message_goes_to_one_frame(stuck: Path) -> None:
    options = EvaluateOptions(mode=Mode.STEREO, sweep_every=0, linear=False)
    result, _ = evaluate_log(stuck, options)
    assert result.frames == 1, result.notes  # frame 0; the one nearest 453.1 s is not its
    assert any("no time of their own" in note for note in result.notes), result.notes


PAUSED, COPIES = 3, 8
"""Frame 3's images are re-sent 8 times, one frame interval apart, before frame 4 comes."""


@pytest.fixture(scope="module")
def paused(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[int]]:
    """A simulator paused amid a run, densified; and the stamps of the log's real frames."""
    return _paused(tmp_path_factory.mktemp("paused_clock"), PAUSED)


def _paused(folder: Path, paused_at: int) -> tuple[Path, list[int]]:
    """A log whose frame ``paused_at`` is re-sent :data:`COPIES` times, densified."""
    log, paused = folder / "synth.mcap", folder / "paused.mcap"
    jobs.synth(log, frames=8, seed=43, scale=0.25, fmt="mcap")
    with open(log, "rb") as stream:
        start = min(message.log_time for _, _, message in make_reader(stream).iter_messages())
    step = 100_000_000
    stamps: list[int] = []
    with McapCopy(log, paused) as copy:  # review 16b R1: pause_mid.py
        for topic, channel_id, message in copy.messages():
            frame = round((message.log_time - start) / step)
            if topic == LEFT_IMAGE:
                stamps.append(_stamp(message.data))
            if frame < paused_at:
                copy.add(channel_id, message.log_time, message.data)
                continue
            if frame > paused_at:
                copy.add(channel_id, message.log_time + COPIES * step, message.data)
                continue
            for again in range(COPIES + 1):  # the truth once, the images again and again
                if again and not topic.startswith("/stereo"):
                    continue
                data = bytearray(message.data)
                if again and topic in (LEFT_IMAGE, RIGHT_IMAGE):
                    data[-1] ^= again
                copy.add(channel_id, message.log_time + again * step, bytes(data))
    jobs.densify(paused, folder / "paused_dense.mcap")
    return folder / "paused_dense.mcap", stamps


def _stamp(data: bytes) -> int:
    """The header stamp (ns) of a CDR message."""
    return int.from_bytes(data[4:8], "little") * 1_000_000_000 + int.from_bytes(
        data[8:12], "little"
    )


def test_a_paused_clock_keeps_the_real_frames_after_the_pause(
    paused: tuple[Path, list[int]],
) -> None:
    # review 16b R1: the paused copies of frame 3 (placed up to one frame after it) took the
    # truth of the frames after the pause, which were left out and said to share it
    log, stamps = paused
    with open(log, "rb") as stream:
        placed = [
            _stamp(message.data)
            for _, channel, message in make_reader(stream).iter_messages()
            if channel.topic == OutputTopics().camera_info
        ]
    assert all(b > a for a, b in itertools.pairwise(placed)), placed  # review 16b R2
    options = EvaluateOptions(mode=Mode.STEREO, sweep_every=0, linear=False)
    result, _ = evaluate_log(log, options)
    assert [frame.stamp_ns for frame in result.per_frame] == stamps, result.notes
    assert any(f"{COPIES} frames left out" in note for note in result.notes), result.notes


def test_a_tolerance_of_half_a_frame_is_named_as_the_cause(tmp_path: Path) -> None:
    # review 16b R3: truth half a frame out of phase with --stamp-tolerance-ms 60 at 10 Hz:
    # the note blamed the camera's header stamps, which were fine
    log, dense, shifted = tmp_path / "s.mcap", tmp_path / "d.mcap", tmp_path / "shifted.mcap"
    jobs.synth(log, frames=8, seed=43, scale=0.25, fmt="mcap")
    jobs.densify(log, dense)
    count = 0
    with McapCopy(dense, shifted) as copy:
        for topic, channel_id, message in copy.messages():
            data = bytearray(message.data)
            if topic.startswith("/ground_truth/"):  # +47 ms, +53 ms, +47 ms ...
                count += topic.endswith("depth")
                stamp = _stamp(data) + (47 if count % 2 else 53) * 1_000_000
                data[4:8] = (stamp // 1_000_000_000).to_bytes(4, "little")
                data[8:12] = (stamp % 1_000_000_000).to_bytes(4, "little")
            copy.add(channel_id, message.log_time, bytes(data))
    options = EvaluateOptions(
        mode=Mode.STEREO, sweep_every=0, linear=False, stamp_tolerance_ns=60_000_000
    )
    result, _ = evaluate_log(shifted, options)
    note = next(note for note in result.notes if "another frame's" in note)
    assert "the stamp tolerance, 60 ms (--stamp-tolerance-ms)" in note, note
    assert "smaller --stamp-tolerance-ms (under 50 ms)" in note, note
    assert "header stamp" not in note, note


def test_a_clock_paused_at_start_pairs_the_real_frames_in_temporal_mode(tmp_path: Path) -> None:
    # review 16b R2: paused 2.5 s at start; the paused copies (placed within one frame of
    # the first stamp, 3 ms apart) took the median frame step, and no real frame paired
    # (refused); with the 1 s stuck rule they were scored against truth 1.1-1.5 s later
    log, stamps = _paused(tmp_path, 0)
    options = EvaluateOptions(mode=Mode.TEMPORAL, sweep_every=0, linear=False)
    result, _ = evaluate_log(log, options)
    scored = [frame.stamp_ns for frame in result.per_frame]
    assert scored == stamps[1:-1], result.notes  # each real frame with the next one
