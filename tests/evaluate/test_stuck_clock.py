"""A camera whose header stamps never advance (bug hunt 16B F8).

densify placed the repeats within one frame interval of the stamp, and evaluate then
matched several frames to one truth and pose message: frames scored against another frame's
truth, D2D 0.000 px for every method (identical poses), exit 0. One truth message now goes
to one frame; a frame whose nearest truth an earlier frame took is left out and said.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap_copy import McapCopy

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.evaluate.metrics import Mode
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
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
    with pytest.raises(LogReadError, match="already an earlier frame's") as error:
        evaluate_log(stuck, options)
    assert "header stamps repeat" in str(error.value)


def test_in_stereo_mode_each_truth_message_goes_to_one_frame(stuck: Path) -> None:
    options = EvaluateOptions(mode=Mode.STEREO, sweep_every=0, linear=False)
    result, _ = evaluate_log(stuck, options)
    assert result.frames == 2, result.notes  # frame 0 and the first of those near 453.1 s
    assert any("already an earlier frame's" in note for note in result.notes), result.notes
