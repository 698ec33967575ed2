"""Stamps missed on two frames in a row once the clock's rate is known (review 16e R1).

densify places the second and later of such a run within 0.25 % of a tick after the first
(800 ms: 799.5, 799.75 ms), and evaluate gave the 800 ms truth to the 900 ms image and left
out the 800 ms one. A frame placed so close after the frame before it (under 10 % of the
median step) now takes only a message of its exact stamp.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap_copy import McapCopy

from pcainterp_stream.evaluate.metrics import Mode
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
from pcainterp_stream.io.stereo_log import LEFT_IMAGE, LEFT_INFO
from pcainterp_stream.pipeline import jobs

MISSED = (8, 9)
"""The frames whose left image and info repeat frame 7's stamp."""


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The densified log with stamps missed on frames 8 and 9, and the log without."""
    folder = tmp_path_factory.mktemp("missed_stamps")
    log, missed = folder / "synth.mcap", folder / "missed.mcap"
    jobs.synth(log, frames=12, seed=43, scale=0.25, fmt="mcap")
    with open(log, "rb") as stream:
        start = min(message.log_time for _, _, message in make_reader(stream).iter_messages())
    stamps: dict[str, bytes] = {}
    with McapCopy(log, missed) as copy:  # review 16e: retime.py --rep 8,9
        for topic, channel_id, message in copy.messages():
            data = bytearray(message.data)
            frame = round((message.log_time - start) / 100_000_000)
            if topic in (LEFT_IMAGE, LEFT_INFO):
                if frame in MISSED:
                    data[4:12] = stamps[topic]  # CDR header, then the stamp
                else:
                    stamps[topic] = bytes(data[4:12])
            copy.add(channel_id, message.log_time, bytes(data))
    jobs.densify(log, folder / "dense.mcap")
    jobs.densify(missed, folder / "missed_dense.mcap")
    return folder / "missed_dense.mcap", folder / "dense.mcap"


def test_the_first_missed_stamp_keeps_its_truth_and_the_second_is_left_out(
    logs: tuple[Path, Path],
) -> None:
    # before: frame 9 (the 900 ms image) was scored against the 800 ms truth, frame 8 left out
    missed, clean = logs
    options = EvaluateOptions(mode=Mode.STEREO, sweep_every=0, linear=False)
    result, _ = evaluate_log(missed, options)
    reference, _ = evaluate_log(clean, options)
    scored = {frame.index: frame for frame in result.per_frame}
    assert 8 in scored, result.notes
    assert 9 not in scored, result.notes
    truth_8 = next(frame for frame in reference.per_frame if frame.index == 8)
    assert scored[8].delta_2d_mean == pytest.approx(truth_8.delta_2d_mean)
    others = [f for f in reference.per_frame if f.index != 9]
    assert [f.index for f in result.per_frame] == [f.index for f in others]
    for frame, other in zip(result.per_frame, others, strict=True):
        assert frame.delta_2d_mean == pytest.approx(other.delta_2d_mean), frame.index
    note = next(note for note in result.notes if "left out (" in note)
    assert "frame 9 first" in note, note
    assert "1 of them has no time of their own" in note, note
    assert "stamped nearer it" not in note, note
