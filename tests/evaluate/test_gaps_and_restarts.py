"""evaluate on logs whose stamps restart mid-log or whose frames pause (bug hunt 9A F1, F3;
14C F3: a restart with the right image and truth logged after the left image)."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from mcap_copy import McapCopy

from pcainterp_stream.evaluate.metrics import Mode
from pcainterp_stream.evaluate.report import EvaluateOptions, Evaluation, evaluate_log
from pcainterp_stream.io.stereo_log import DEPTH, RIGHT_IMAGE
from pcainterp_stream.pipeline import jobs

PERIOD_NS = 100_000_000  # the synthetic logs' 10 Hz
FRAMES = 8


@pytest.fixture(scope="module")
def dense(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("gaps")
    log, out = folder / "synth.mcap", folder / "dense.mcap"
    jobs.synth(log, frames=FRAMES, seed=43, scale=0.25, fmt="mcap")
    jobs.densify(log, out)
    return out


def _edited(
    source: Path,
    target: Path,
    *,
    restart_at: int = -1,
    drop: range = range(0),
    lags: dict[str, int] | None = None,
) -> Path:
    """Copy a densified synthetic log, every message's header stamp from frame ``restart_at``
    on set back by that many frames (stamps that restart, log time going on: a simulator
    restarted mid-recording), the messages of the frames ``drop`` left out (a pause), the
    messages of the topics of ``lags`` logged that many ns later (synth logs a frame's
    messages at one log time; a recorder receives them apart) and all written in log-time
    order, as densify writes its output (a frame's outputs at its left image's log time)."""
    start: int | None = None
    written: list[tuple[int, int, bytes]] = []
    with McapCopy(source, target) as copy:
        for topic, channel_id, message in copy.messages():
            start = message.log_time if start is None else min(start, message.log_time)
            frame = (message.log_time - start + PERIOD_NS // 2) // PERIOD_NS
            if frame in drop:
                continue
            data = bytearray(message.data)
            if 0 <= restart_at <= frame:  # every message of these logs starts with a header
                seconds, nanoseconds = struct.unpack_from("<iI", data, 4)
                stamp = seconds * 1_000_000_000 + nanoseconds - restart_at * PERIOD_NS
                struct.pack_into("<iI", data, 4, stamp // 1_000_000_000, stamp % 1_000_000_000)
            written.append((message.log_time + (lags or {}).get(topic, 0), channel_id, bytes(data)))
        for log_time, channel_id, data in sorted(written, key=lambda one: one[0]):
            copy.add(channel_id, log_time, data)
    return target


def _evaluate(log: Path, mode: Mode) -> Evaluation:
    options = EvaluateOptions(mode=mode, sweep_every=0, linear=False, examples=0)
    return evaluate_log(log, options)[0]


def _rows(result: Evaluation) -> dict[str, tuple[int, float]]:
    rows = {**result.methods, **result.stereo}
    return {name: (stats.pixels, round(stats.delta_2d_sum, 3)) for name, stats in rows.items()}


def test_restarted_stamps_take_the_truth_and_right_image_of_their_own_run(
    dense: Path, tmp_path: Path
) -> None:
    # before: frames 4-7, stamped as frames 0-3 again, took frames 0-3's truth and right
    # image (the first message of a stamp): pca_map and sgbm scored against another frame
    restarted = _edited(dense, tmp_path / "restarted.mcap", restart_at=FRAMES // 2)
    result = _evaluate(restarted, Mode.STEREO)
    assert result.frames == FRAMES
    assert _rows(result) == _rows(_evaluate(dense, Mode.STEREO))
    assert (
        "messages with the stamp of an earlier one of their topic (4 on /ground_truth/depth, "
        "4 on /stereo/right/image_rect; stamps that restart, or a message logged twice): a "
        "frame takes the message of its stamp nearest its own log time"
    ) in result.notes


def test_a_restart_takes_its_own_run_whatever_the_message_order(
    dense: Path, tmp_path: Path
) -> None:
    # bug hunt 14C F3: with the right image and truth logged after the left image (1 and 4
    # us, a recorder's usual order), the first frame after the restart was released before
    # its own were read (the topics' last stamps, frame 3's, were already past its stamp)
    # and scored against frame 0's truth and right image
    lags = {RIGHT_IMAGE: 1_000, DEPTH: 4_000}
    restarted = _edited(dense, tmp_path / "restarted.mcap", restart_at=FRAMES // 2, lags=lags)
    result = _evaluate(restarted, Mode.STEREO)
    assert result.frames == FRAMES
    assert _rows(result) == _rows(
        _evaluate(_edited(dense, tmp_path / "late.mcap", lags=lags), Mode.STEREO)
    )
    assert _rows(result) == _rows(_evaluate(dense, Mode.STEREO))


def test_temporal_mode_does_not_pair_across_a_restart_of_the_stamps(
    dense: Path, tmp_path: Path
) -> None:
    restarted = _edited(dense, tmp_path / "restarted.mcap", restart_at=FRAMES // 2)
    result = _evaluate(restarted, Mode.TEMPORAL)
    assert result.frames == FRAMES - 2  # 0-1, 1-2, 2-3, 4-5, 5-6, 6-7; not 3-4 (backwards)
    assert any(note.startswith("1 frame left unpaired") for note in result.notes)


def test_temporal_mode_does_not_pair_across_a_pause(dense: Path, tmp_path: Path) -> None:
    # before: frame 2 was paired with frame 6, 0.4 s and metres of driving apart, and scored
    # as if consecutive, silently (a recording paused, frames dropped)
    paused = _edited(dense, tmp_path / "paused.mcap", drop=range(3, 6))
    result = _evaluate(paused, Mode.TEMPORAL)
    assert result.frames == 3  # 0-1, 1-2, 6-7
    assert (
        "1 frame left unpaired in temporal mode: the next frame is not one frame interval "
        "after it (more than 1.5 x the median step of 100 ms later, or earlier: a pause, "
        "dropped frames or stamps that go back)"
    ) in result.notes
    assert not any("unpaired" in note for note in _evaluate(dense, Mode.TEMPORAL).notes)


def test_progress_names_the_frames_to_come(
    dense: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # before: evaluate's progress lines gave frames and rate, no total (bug hunt 9A)
    from pcainterp_stream.pipeline import common

    totals: list[int | None] = []

    def bar(total: int | None, description: str, unit: str = "frame") -> common._Unshown:
        totals.append(total)
        return common._Unshown(total)

    monkeypatch.setattr(jobs, "_bar", bar)
    jobs.evaluate(dense, tmp_path / "r", sweep_every=0, linear=False, basis_rows=False)
    jobs.evaluate(dense, tmp_path / "r3", max_frames=3, sweep_every=0, basis_rows=False)
    assert totals == [FRAMES, 3]


def test_truth_logged_seconds_before_the_images_is_still_taken(tmp_path: Path) -> None:
    # review 14c R1: the restart rule's longer wait, applied to every log, held frames past
    # the 32 truth messages kept when truth was logged >= 1.6 s before the images (monotone
    # stamps): 79 -> 31 frames scored; the wait now applies once the left stamps went back
    frames = 40
    log, out = tmp_path / "long.mcap", tmp_path / "long_dense.mcap"
    jobs.synth(log, frames=frames, seed=43, scale=0.15, fmt="mcap")
    jobs.densify(log, out)
    early = _edited(out, tmp_path / "early.mcap", lags={DEPTH: -20 * PERIOD_NS})
    assert _rows(_evaluate(early, Mode.STEREO)) == _rows(_evaluate(out, Mode.STEREO))
    assert _evaluate(early, Mode.STEREO).frames == frames
