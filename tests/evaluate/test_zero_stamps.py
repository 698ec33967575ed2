"""Cameras that leave every header stamp at 0 (bug hunt 7A F6).

densify pairs their images by log time; its outputs carry the left image's log time, and
evaluate matches the input images by log time as densify paired them. A log densified
before that (outputs stamped 0) is refused in one line, and no report advises a stamp
tolerance of a second or more. A ``--reference-topic`` stamped 0 is placed by log time as
truth is, and an input image logged twice (densify drops the copy) is skipped, not taken
for a frame of its own (review 55b R55b-7, R55b-2).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace
from typing import Any, cast

import pytest
from mcap_copy import McapCopy

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.evaluate.left_out import LeftOut, no_reference_message
from pcainterp_stream.evaluate.log_frames import Frame, ReadState
from pcainterp_stream.evaluate.metrics import Mode
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
from pcainterp_stream.frontend.pairing import StereoPairer
from pcainterp_stream.io.stereo_log import DEPTH as TRUTH
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
    return {"folder": folder, "zero": zero, "synth": log}


def _scores(path: Path, options: EvaluateOptions = OPTIONS) -> dict[str, tuple[float, float]]:
    result, _ = evaluate_log(path, options)
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
    # nor for a frame without truth whose right image is a second or more away (bug hunt 14C
    # F4: "pass --stamp-tolerance-ms 1699999999901")
    for gap, advice in ((far, False), (3_000_000, True)):
        frame = cast(Frame, SimpleNamespace(index=1, right_gap_ns=gap))
        message = no_reference_message(frame, RIGHT_IMAGE, state)
        assert ("--stamp-tolerance-ms" in message) is advice
    assert message.endswith("; pass --stamp-tolerance-ms 3 (as densify was given)")
    assert "a second or more: the right images are not this frame's" in no_reference_message(
        cast(Frame, SimpleNamespace(index=1, right_gap_ns=far)), RIGHT_IMAGE, state
    )


def test_a_reference_topic_stamped_zero_is_placed_by_log_time(logs: dict[str, Path]) -> None:
    # before: the reference messages kept stamp 0 while the frames took their log time: no
    # frame found its reference ("no frame ... could be evaluated"), and all but the first
    # were named "messages with the stamp of an earlier one of their topic" (R55b-7)
    folder = logs["folder"]
    zero = folder / "zero_reference.mcap"
    with McapCopy(logs["zero"], zero) as copy:  # the stampless stack's depth topic too
        for topic, channel_id, message in copy.messages():
            data = bytearray(message.data)
            if topic == TRUTH:
                data[4:12] = bytes(8)
            copy.add(channel_id, message.log_time, bytes(data))
    jobs.densify(zero, folder / "zero_reference_dense.mcap")
    options = dataclasses.replace(OPTIONS, reference_topic=TRUTH)
    result, _ = evaluate_log(folder / "zero_reference_dense.mcap", options)
    assert not any("stamp of an earlier one" in note for note in result.notes)
    scores = _scores(folder / "zero_reference_dense.mcap", options)
    assert scores == _scores(folder / "dense.mcap", options)


def test_an_image_logged_twice_is_skipped_as_densify_drops_it(logs: dict[str, Path]) -> None:
    # before: the left copy (its original's stamp) was keyed by log time, waited for outputs
    # densify never wrote and gave "at least 1 frame left out: their densified channels are
    # incomplete" although no frame was left out (R55b-2)
    folder = logs["folder"]
    copies = folder / "copies.mcap"
    seen = dict.fromkeys((LEFT_IMAGE, RIGHT_IMAGE), 0)
    with McapCopy(logs["synth"], copies) as copy:  # the 2nd left, 3rd right image twice
        for topic, channel_id, message in copy.messages():
            copy.add(channel_id, message.log_time, message.data)
            if topic in seen:
                seen[topic] += 1
                if seen[topic] == (2 if topic == LEFT_IMAGE else 3):
                    copy.add(channel_id, message.log_time + 1_000, message.data)
    jobs.densify(copies, folder / "copies_dense.mcap")
    result, _ = evaluate_log(folder / "copies_dense.mcap", OPTIONS)
    assert result.notes == [
        f"images logged again right after themselves were skipped (1 on {LEFT_IMAGE}, "
        f"1 on {RIGHT_IMAGE}), as densify did"
    ]
    assert _scores(folder / "copies_dense.mcap") == _scores(folder / "dense.mcap")


def test_a_stampless_image_logged_twice_at_one_log_time_is_skipped(logs: dict[str, Path]) -> None:
    # review 14b R5: densify drops a stampless copy logged at its original's log time (a merge
    # of overlapping bags); evaluate took it for a frame and said "give each frame its own stamp"
    folder = logs["folder"]
    copies = folder / "zero_copies.mcap"
    seen = dict.fromkeys((LEFT_IMAGE, RIGHT_IMAGE), 0)
    with McapCopy(logs["zero"], copies) as copy:  # the 2nd pair twice, at the same log times
        for topic, channel_id, message in copy.messages():
            copy.add(channel_id, message.log_time, message.data)
            if topic in seen:
                seen[topic] += 1
                if seen[topic] == 2:
                    copy.add(channel_id, message.log_time, message.data)
    jobs.densify(copies, folder / "zero_copies_dense.mcap")
    result, _ = evaluate_log(folder / "zero_copies_dense.mcap", OPTIONS)
    assert result.notes == [
        f"images logged again right after themselves were skipped (1 on {LEFT_IMAGE}, "
        f"1 on {RIGHT_IMAGE}), as densify did"
    ]
    assert _scores(folder / "zero_copies_dense.mcap") == _scores(folder / "zero_dense.mcap")


def test_a_clock_that_starts_at_zero_is_evaluated(tmp_path: Path) -> None:
    # KITTI's odometry times start at 0.0 s: import-kitti stamps and logs its first frame at
    # 0, whose outputs densify stamps with that log time, 0; evaluate refused the whole log
    # as one an earlier densify had stamped 0 (this session's fix-STAMP)
    log, shifted = tmp_path / "synth.mcap", tmp_path / "from_zero.mcap"
    jobs.synth(log, frames=4, seed=43, scale=0.25, fmt="mcap")
    start = 1_317_046_453_000_000_000  # synth's first stamp and log time
    with McapCopy(log, shifted) as copy:  # every stamp and log time moved back by it
        for _, channel_id, message in copy.messages():  # (each of synth's topics: a header)
            data = bytearray(message.data)
            sec, nanosec = (int.from_bytes(data[i : i + 4], "little") for i in (4, 8))
            stamp = sec * 1_000_000_000 + nanosec - start
            data[4:8] = (stamp // 1_000_000_000).to_bytes(4, "little")
            data[8:12] = (stamp % 1_000_000_000).to_bytes(4, "little")
            copy.add(channel_id, message.log_time - start, bytes(data))
    jobs.densify(log, tmp_path / "dense.mcap")
    jobs.densify(shifted, tmp_path / "from_zero_dense.mcap")
    assert _scores(tmp_path / "from_zero_dense.mcap") == _scores(tmp_path / "dense.mcap")


def test_a_clock_that_starts_at_zero_pairs_its_first_frame_as_densify(tmp_path: Path) -> None:
    # bug hunt 14C F4: a simulator's header stamps from 0.0 s, log times on the wall clock, the
    # right image logged 3 ms and the truth 2 ms after the left image. densify pairs the first
    # images by their equal stamps (0) and stamps the frame's outputs with its log time;
    # evaluate placed the right image at its own log time, 3 ms off, and refused the whole
    # log (no SGBM reference; and frame 1, released before its own right image was read, was
    # advised a tolerance of 41 years)
    log, sim = tmp_path / "synth.mcap", tmp_path / "sim.mcap"
    jobs.synth(log, frames=4, seed=43, scale=0.25, fmt="mcap")
    start = 1_317_046_453_000_000_000  # synth's first stamp
    lags = {RIGHT_IMAGE: 3_000_000, TRUTH: 2_000_000}
    with McapCopy(log, sim) as copy:  # (each of synth's topics: a header)
        for topic, channel_id, message in copy.messages():
            data = bytearray(message.data)
            sec, nanosec = (int.from_bytes(data[i : i + 4], "little") for i in (4, 8))
            stamp = sec * 1_000_000_000 + nanosec - start
            data[4:8] = (stamp // 1_000_000_000).to_bytes(4, "little")
            data[8:12] = (stamp % 1_000_000_000).to_bytes(4, "little")
            copy.add(channel_id, message.log_time + lags.get(topic, 0), bytes(data))
    jobs.densify(log, tmp_path / "dense.mcap")
    jobs.densify(sim, tmp_path / "sim_dense.mcap")
    for options in (OPTIONS, dataclasses.replace(OPTIONS, sgbm_reference=True)):
        scores = _scores(tmp_path / "sim_dense.mcap", options)
        assert scores == _scores(tmp_path / "dense.mcap", options)


def test_a_coarse_clock_keeps_every_frame_on_it(logs: dict[str, Path]) -> None:
    # bug hunt 12C F2: every header stamp (images, infos, truth) from a clock at 1000 s that
    # ticks every 200 ms, the camera at 10 Hz: each stamp twice. densify stamped each repeat's
    # outputs with the wall-clock log time, 41 years from the others, and evaluate left those
    # frames out blaming the clocks; now on the images' clock, scored as the stamped log
    folder = logs["folder"]
    coarse = folder / "coarse.mcap"
    seen: dict[str, int] = {}
    with McapCopy(logs["synth"], coarse) as copy:
        for topic, channel_id, message in copy.messages():  # (each of synth's: a header)
            index = seen[topic] = seen.get(topic, -1) + 1
            stamp = 1000 * 10**9 + (index // 2) * 200_000_000
            data = bytearray(message.data)
            data[4:8] = (stamp // 10**9).to_bytes(4, "little")
            data[8:12] = (stamp % 10**9).to_bytes(4, "little")
            copy.add(channel_id, message.log_time, bytes(data))
    jobs.densify(coarse, folder / "coarse_dense.mcap")
    assert _scores(folder / "coarse_dense.mcap") == _scores(folder / "dense.mcap")
