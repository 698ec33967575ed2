"""evaluate of a log one of whose input messages does not decode (bug hunt 14C F6).

densify skips an image or camera info that does not deserialize (counted ``undecodable`` in
its ``pairing:`` line) and copies it into its output as it was; evaluate skips it the same
way, with a note, instead of refusing the whole log.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap_copy import McapCopy

from pcainterp_stream.evaluate.metrics import Mode
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
from pcainterp_stream.io.stereo_log import LEFT_IMAGE, LEFT_INFO, RIGHT_IMAGE, RIGHT_INFO
from pcainterp_stream.pipeline import jobs

OPTIONS = EvaluateOptions(mode=Mode.STEREO, sweep_every=0, linear=False, examples=0)


@pytest.fixture(scope="module")
def synth(tmp_path_factory: pytest.TempPathFactory) -> Path:
    log = tmp_path_factory.mktemp("damaged") / "synth.mcap"
    jobs.synth(log, frames=4, seed=43, scale=0.25, fmt="mcap")
    return log


@pytest.mark.parametrize(
    ("topic", "frames"), [(LEFT_IMAGE, 3), (RIGHT_IMAGE, 3), (LEFT_INFO, 4), (RIGHT_INFO, 4)]
)
def test_a_damaged_input_message_is_skipped_as_densify_skipped_it(
    synth: Path, tmp_path: Path, topic: str, frames: int
) -> None:
    # before: "cannot decode message on /stereo/left/image_rect ... (damaged message?)" and no
    # report, although no densified frame uses the message
    damaged = tmp_path / "damaged.mcap"
    seen = 0
    with McapCopy(synth, damaged) as copy:  # the 2nd message of the topic cut to 40 bytes
        for name, channel_id, message in copy.messages():
            data = message.data
            if name == topic:
                seen += 1
                data = data[:40] if seen == 2 else data
            copy.add(channel_id, message.log_time, data)
    jobs.densify(damaged, tmp_path / "dense.mcap")
    result, _ = evaluate_log(tmp_path / "dense.mcap", OPTIONS)
    assert result.frames == frames
    assert (
        f"messages that do not decode were skipped (1 on {topic}: damaged, or bytes of "
        "another type), as densify skipped them"
    ) in result.notes


def test_a_right_image_damaged_after_densify_is_not_answered_with_a_tolerance(
    synth: Path, tmp_path: Path
) -> None:
    # review 14c R4: a densified log whose right image went bad afterwards (the frame's outputs
    # are there) was refused with "pass --stamp-tolerance-ms 100": a neighbour's right image
    from pcainterp_stream.errors import LogReadError

    stripped = tmp_path / "no_truth.mcap"  # an SGBM reference: no truth in the log
    with McapCopy(synth, stripped) as copy:
        for _, channel_id, message in copy.messages(drop=("/ground_truth",)):
            copy.add(channel_id, message.log_time, message.data)
    jobs.densify(stripped, tmp_path / "dense.mcap")
    damaged = tmp_path / "damaged.mcap"
    seen = 0
    with McapCopy(tmp_path / "dense.mcap", damaged) as copy:
        for name, channel_id, message in copy.messages():
            seen += name == RIGHT_IMAGE
            cut = name == RIGHT_IMAGE and seen == 2
            copy.add(channel_id, message.log_time, message.data[:40] if cut else message.data)
    with pytest.raises(LogReadError, match="do not decode") as raised:
        evaluate_log(damaged, OPTIONS)
    assert "--stamp-tolerance-ms" not in str(raised.value)
