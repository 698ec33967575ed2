"""A cut-off densified log and a left image that did not decode (bug hunt 16B F4).

evaluate's refusal of a densified log cut at 30 % named incomplete channels and "densify
drops unpaired frames", never the truncation the reader saw; a frame whose JPEG did not
decode (densify skipped it) got the same note. Both are now named.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.evaluate.log_frames import ReadState, _count_incomplete
from pcainterp_stream.evaluate.metrics import Mode
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
from pcainterp_stream.io import rosmsg
from pcainterp_stream.pipeline import jobs


def test_a_cut_off_log_is_refused_naming_the_damage(tmp_path: Path) -> None:
    jobs.synth(tmp_path / "synth.mcap", frames=4, seed=43, scale=0.25, fmt="mcap")
    jobs.densify(tmp_path / "synth.mcap", tmp_path / "dense.mcap")
    data = (tmp_path / "dense.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 30 // 100])
    with pytest.raises(LogReadError) as error:
        evaluate_log(cut, EvaluateOptions(mode=Mode.TEMPORAL, sweep_every=0, linear=False))
    message = str(error.value)
    assert "; damage: " in message
    assert "\n" not in message
    if "incomplete" in message:
        assert "the log is damaged" in message
        assert "densify drops unpaired frames" not in message


def test_a_left_image_that_does_not_decode_is_said_so() -> None:
    left, outputs = "/stereo/left/image_rect", ["/pcainterp/disparity", "/pcainterp/features"]
    state = ReadState()
    broken = rosmsg.compressed_image_message(b"\xff\xd8 not a jpeg", "jpeg", 10**9, "left")
    _count_incomplete({left: broken}, [*outputs, left], state)
    assert state.undecodable_left == 1
    assert not state.incomplete
    assert "left image does not decode" in state.undecodable_left_note
    fine = rosmsg.image_message(np.zeros((8, 8), np.uint8), 10**9, "left", encoding="mono8")
    _count_incomplete({left: fine}, [*outputs, left], state)  # decodes: densify dropped it
    assert state.incomplete == dict.fromkeys(outputs, 1)
    assert "densify drops unpaired frames" in state.incomplete_note
