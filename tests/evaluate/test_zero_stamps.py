"""Cameras that leave every header stamp at 0 (bug hunt 7A F6).

densify pairs their images by log time; its outputs carry the left image's log time, and
evaluate matches the input images by log time as densify paired them. A log densified
before that (outputs stamped 0) is refused in one line, and no report advises a stamp
tolerance of a second or more.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from mcap_copy import McapCopy

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.evaluate.left_out import LeftOut
from pcainterp_stream.evaluate.log_frames import ReadState
from pcainterp_stream.evaluate.metrics import Mode
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
from pcainterp_stream.frontend.pairing import StereoPairer
from pcainterp_stream.io.stereo_log import LEFT_IMAGE, LEFT_INFO, RIGHT_IMAGE, RIGHT_INFO
from pcainterp_stream.pipeline import jobs

CAMERA_TOPICS = (LEFT_IMAGE, RIGHT_IMAGE, LEFT_INFO, RIGHT_INFO)
OPTIONS = EvaluateOptions(mode=Mode.STEREO, sweep_every=0, linear=False)


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("zero_stamps")
    log, zero = folder / "synth.mcap", folder / "zero.mcap"
    jobs.synth(log, frames=4, seed=43, scale=0.25, fmt="mcap")
    with McapCopy(log, zero) as copy:  # the camera's stamps 0, the right images 3 ms late
        for topic, channel_id, message in copy.messages():
            data, log_time = bytearray(message.data), message.log_time
            if topic in CAMERA_TOPICS:
                data[4:12] = bytes(8)  # CDR header, then the stamp's sec and nanosec
                log_time += 3_000_000 if topic == RIGHT_IMAGE else 0
            copy.add(channel_id, log_time, bytes(data))
    jobs.densify(log, folder / "dense.mcap")
    jobs.densify(zero, folder / "zero_dense.mcap")
    return {"folder": folder, "zero": zero}


def _scores(path: Path) -> dict[str, tuple[float, float]]:
    result, _ = evaluate_log(path, OPTIONS)
    assert result.frames == 4
    return {name: (s.pixels, s.delta_2d_sum) for name, s in result.methods.items()}


def test_a_log_whose_camera_stamps_are_zero_scores_as_the_stamped_one(
    logs: dict[str, Path],
) -> None:
    # before: no frame evaluated, and the advice --stamp-tolerance-ms of 41 years; taking it
    # matched the frames to arbitrary truths
    folder = logs["folder"]
    assert _scores(folder / "zero_dense.mcap") == _scores(folder / "dense.mcap")


def test_a_log_densified_with_its_outputs_stamped_zero_is_refused(
    logs: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    full_result = StereoPairer.full_result

    def as_before(self: StereoPairer, result: Any) -> Any:  # outputs at the header stamp, 0
        result = full_result(self, result)
        return result._replace(frame=result.frame._replace(stamp_ns=0))

    monkeypatch.setattr(StereoPairer, "full_result", as_before)
    old = logs["folder"] / "old_dense.mcap"
    jobs.densify(logs["zero"], old)
    monkeypatch.undo()
    with pytest.raises(LogReadError) as error:
        evaluate_log(old, OPTIONS)
    message = str(error.value)
    assert "\n" not in message
    assert message.startswith(f"{old}: /pcainterp/")
    assert f"has header stamp 0: the input images ({LEFT_IMAGE}) have no header stamps" in message
    assert message.endswith("densify now stamps such frames with their left image's log time)")


def test_no_tolerance_of_a_second_or_more_is_advised() -> None:
    state = ReadState()
    far = 1_317_046_453_000 * 10**6  # 41 years: truth on the epoch, frames at 0
    one_stamp = LeftOut(stamps=[0] * 12)
    for _ in range(12):
        one_stamp.see(far, "truth")
    (note,) = one_stamp.notes(state, "/ground_truth/depth")
    assert "--stamp-tolerance-ms" not in note
    assert "all 12 frames have header stamp 0 ns" in note
    assert "the input images have no header stamps" in note
    other_clock = LeftOut(stamps=[k * 100_000_000 for k in range(3)])
    other_clock.see(2_000_000_000, "truth")
    (note,) = other_clock.notes(state, "/ground_truth/depth")
    assert "--stamp-tolerance-ms" not in note
    assert "a second or more, so /ground_truth/depth and the images are stamped on" in note
    # a single frame (no period): a gap under a second is still advised
    single = LeftOut(stamps=[5])
    single.see(30_000_000, "truth")
    (note,) = single.notes(state, "/ground_truth/depth")
    assert note.endswith("pass --stamp-tolerance-ms 30 to take it")
