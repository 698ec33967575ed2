"""How evaluate reads a log's truth: REP 118's NaN ("no value") and +inf ("too far") the same
way for ``/ground_truth/depth`` as for a ``--reference-topic``; a reference with no truth at
all is an error, not a report of dashes."""

from __future__ import annotations

import re
import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from mcap_copy import McapCopy

from pcainterp_stream import cli
from pcainterp_stream.errors import LogReadError
from pcainterp_stream.evaluate.metrics import Mode, compare_with_ground_truth
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
from pcainterp_stream.evaluate.tables import results_markdown, summary_table
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.pipeline import jobs

TRUTH = "/ground_truth/depth"
POSE = "/ground_truth/pose"
FEATURES = "/pcainterp/features"
Patch = Callable[[int, npt.NDArray[np.float32]], npt.NDArray[np.float32]]


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("truth_values")
    log, dense = folder / "synth.mcap", folder / "dense.mcap"
    jobs.synth(log, frames=4, seed=41, scale=0.25, fmt="mcap")
    jobs.densify(log, dense)
    return {"folder": folder, "synth": log, "dense": dense}


def _patched(source: Path, target: Path, patch: Patch) -> Path:
    """Copy an MCAP byte for byte but for the 32FC1 data of ``/ground_truth/depth``."""
    index = 0
    with McapCopy(source, target) as copy:
        for topic, channel_id, message in copy.messages():
            data = bytearray(message.data)
            if topic == TRUTH:
                offset = 4 + 8  # CDR header, stamp; then frame_id, height, width
                length = struct.unpack_from("<I", data, offset)[0]
                offset = (offset + 4 + length + 3) & ~3
                height, width = struct.unpack_from("<II", data, offset)
                size = height * width * 4
                values = np.frombuffer(bytes(data[-size:]), np.float32).copy()
                data[-size:] = patch(index, values).astype(np.float32).tobytes()
                index += 1
            copy.add(channel_id, message.log_time, bytes(data))
    return target


def _sky_as_nan(index: int, values: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """The synthetic logs of earlier versions: sky written as NaN."""
    return np.where(np.isposinf(values), np.float32(np.nan), values)


def _half_nan(index: int, values: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """A truth with holes: every other frame has none (a simulator's or LiDAR's NaN)."""
    return np.full_like(values, np.nan) if index % 2 == 0 else values


def _all_nan(index: int, values: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    return np.full_like(values, np.nan)


def _scores(log: Path, reference_topic: str | None) -> dict[str, tuple[float, float]]:
    options = EvaluateOptions(
        mode=Mode.STEREO, sweep_every=0, reference_topic=reference_topic, linear=False
    )
    result, _ = evaluate_log(log, options)
    return {name: (s.pixels, s.delta_2d_sum) for name, s in result.methods.items()}


def test_synthetic_truth_holds_sky_as_inf(logs: dict[str, Path]) -> None:
    with open_log(logs["synth"]) as reader:
        depths = [rosmsg.image_array(reader.decode(raw)) for raw in reader.messages([TRUTH])]
    assert len(depths) == 4
    assert not any(np.isnan(depth).any() for depth in depths)  # NaN is REP 118's "no value"
    assert all(np.isposinf(depth).any() for depth in depths)  # the street's sky: too far


@pytest.mark.parametrize("patch", [None, _sky_as_nan, _half_nan])
def test_ground_truth_reads_as_the_same_reference_topic(
    logs: dict[str, Path], patch: Patch | None
) -> None:
    log = logs["dense"]
    if patch is not None:
        log = _patched(log, logs["folder"] / f"{patch.__name__}.mcap", patch)
    default, named = _scores(log, None), _scores(log, TRUTH)
    assert default == named
    assert default["pca_map"][0] > 0


def test_nan_truth_is_no_truth_and_the_report_says_so(logs: dict[str, Path]) -> None:
    plain, _ = evaluate_log(logs["dense"], EvaluateOptions(mode=Mode.STEREO, sweep_every=0))
    log = _patched(logs["dense"], logs["folder"] / "old_sky.mcap", _sky_as_nan)
    old, _ = evaluate_log(log, EvaluateOptions(mode=Mode.STEREO, sweep_every=0))
    assert plain.reference_fraction == 1.0  # the sky counts, as disparity 0
    assert plain.notes == []
    assert 0.5 < old.reference_fraction < 1.0  # the NaN sky does not
    assert old.methods["pca_map"].pixels < plain.methods["pca_map"].pixels
    assert len(old.notes) == 1
    assert "pixels are NaN, read as no truth" in old.notes[0]
    assert "synthesize and densify it again" in old.notes[0]


def test_the_quick_comparison_reads_truth_the_same_way(logs: dict[str, Path]) -> None:
    plain = compare_with_ground_truth(logs["dense"])
    old = compare_with_ground_truth(_patched(logs["dense"], logs["folder"] / "q.mcap", _sky_as_nan))
    assert plain.pixels == 4 * 94 * 310
    assert 0 < old.pixels < plain.pixels


def _frame_1_nan(index: int, values: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """Frame 1's truth message is there, but NaN everywhere (a LiDAR drop-out)."""
    return np.full_like(values, np.nan) if index == 1 else values


def _frame_1_one_pixel(index: int, values: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """Frame 1's truth holds one pixel (mid-image: its match is in the right view too)."""
    if index != 1:
        return values
    one = np.full_like(values, np.nan)
    middle = values.size // 2 + 150  # 94 x 310 px: row 47, column 150
    one[middle] = values[middle]
    return one


def test_a_frame_whose_reference_holds_no_truth_is_named_and_not_counted(
    logs: dict[str, Path],
) -> None:
    # bug hunt 15D F2: "4 frames of ..." with frame 1 scored on no pixel and never named
    log = _patched(logs["dense"], logs["folder"] / "frame_1_nan.mcap", _frame_1_nan)
    result, _ = evaluate_log(log, EvaluateOptions(mode=Mode.STEREO, sweep_every=0))
    assert result.frames == 3
    assert result.no_truth == [1]
    table = summary_table(result)
    assert table.startswith("3 frames of ")
    assert (
        "1 frame left out of every method: the reference message is there but holds no truth "
        "on any pixel to score"
    ) in table
    assert (
        "it is not in the table (frame 1: every pixel is NaN, 0 or < 0 (no value, REP 118; "
        "+inf, too far, would count); counted from 0)"
    ) in table
    assert "holds no truth on any pixel to score" in results_markdown(result, [])
    summary = result.summary()
    assert summary["left_out_no_truth"] == [1]
    row = summary["per_frame"][1]
    assert (row["truth"], row["pixels"], row["delta_2d_mean"]) == (False, 0, {})
    assert "stands out" not in table  # the note names it, no line repeats it
    # one pixel of truth: named once, as collapsed, not also for its error and coverage
    log = _patched(logs["dense"], logs["folder"] / "frame_1_one.mcap", _frame_1_one_pixel)
    result, _ = evaluate_log(log, EvaluateOptions(mode=Mode.STEREO, sweep_every=0))
    named = [line for line in summary_table(result).splitlines() if "stands out" in line]
    assert len(named) == 1, named
    assert named[0].startswith("stands out: frame 1: the reference holds truth on 0.00x")
    assert "(1 px of " in named[0]


def test_temporal_mode_says_the_last_frame_is_not_scored(logs: dict[str, Path]) -> None:
    # bug hunt 15D F4: 4 frames scored 3 and --max-frames 2 scored 1, without a word
    note = "the last frame (3) is not scored: temporal mode moves each frame's pixels into the"
    result, _ = evaluate_log(logs["dense"], EvaluateOptions(mode=Mode.TEMPORAL, sweep_every=0))
    assert result.frames == 3
    assert any(n.startswith(note) and "--max-frames" not in n for n in result.notes)
    assert f"note: {note}" in summary_table(result)
    options = EvaluateOptions(mode=Mode.TEMPORAL, sweep_every=0, max_frames=2)
    result, _ = evaluate_log(logs["dense"], options)
    assert result.frames == 1
    assert any(
        n.startswith("the last frame (1) is not scored")
        and n.endswith("(--max-frames N scores N-1)")
        for n in result.notes
    )
    # review 15d R4: --max-frames beyond the log's 4 frames did not bind: no word of it
    options = EvaluateOptions(mode=Mode.TEMPORAL, sweep_every=0, max_frames=100)
    result, _ = evaluate_log(logs["dense"], options)
    assert result.frames == 3
    assert any(n.startswith(note) and "--max-frames" not in n for n in result.notes)
    stereo, _ = evaluate_log(logs["dense"], EvaluateOptions(mode=Mode.STEREO, sweep_every=0))
    assert not any("last frame" in n for n in stereo.notes)


@pytest.mark.parametrize("topic", [None, TRUTH])
def test_a_reference_without_any_truth_is_an_error(
    logs: dict[str, Path], topic: str | None
) -> None:
    log = _patched(logs["dense"], logs["folder"] / "all_nan.mcap", _all_nan)
    options = EvaluateOptions(mode=Mode.STEREO, sweep_every=0, reference_topic=topic)
    with pytest.raises(LogReadError, match=r"/ground_truth/depth holds no truth in any of the 4"):
        evaluate_log(log, options)


def test_cli_a_reference_without_truth_is_one_line(
    logs: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    log = _patched(logs["dense"], logs["folder"] / "all_nan_cli.mcap", _all_nan)
    report = logs["folder"] / "report_all_nan"
    args = [
        "evaluate",
        str(log),
        "-o",
        str(report),
        "--no-basis",
        "--max-frames",
        "2",
        "--mode",
        "stereo",
    ]
    assert cli.main([*args, "--reference-topic", TRUTH]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert "holds no truth in any of the 2 frames evaluated (at most 2: --max-frames)" in err
    assert not report.exists()


# ------------------------------------------- truth and poses matched by stamp (bug hunt 6A F8)


def _restamped(
    source: Path,
    target: Path,
    topic: str,
    *,
    shift_ns: int = 0,
    drop: int = -1,
    to_ns: int | None = None,
    logged_later_ns: int = 0,
) -> Path:
    """Copy an MCAP with ``topic``'s header stamps ``shift_ns`` later and its ``drop``-th
    message left out (another clock, a lost message); with ``to_ns``, every stamp and log
    time of ``topic`` ("*": all) is that one, the densified channels after all the inputs;
    with ``logged_later_ns``, ``topic``'s log times that much later (another recorder)."""
    index = 0
    later: list[tuple[int, bytes]] = []
    with McapCopy(source, target) as copy:
        for name, channel_id, message in copy.messages():
            data = bytearray(message.data)
            if name == topic or topic == "*":
                index += 1
                if index - 1 == drop:
                    continue
                seconds, nanoseconds = struct.unpack_from("<iI", data, 4)  # after the CDR header
                total = seconds * 1_000_000_000 + nanoseconds + shift_ns
                total = total if to_ns is None else to_ns
                struct.pack_into("<iI", data, 4, total // 1_000_000_000, total % 1_000_000_000)
            if to_ns is not None and name.startswith("/pcainterp/"):
                later.append((channel_id, bytes(data)))  # after all the inputs
                continue
            log_time = message.log_time if to_ns is None else to_ns  # all at one instant
            if name == topic:
                log_time += logged_later_ns
            copy.add(channel_id, log_time, bytes(data))
        for channel_id, data in later:
            copy.add(channel_id, to_ns or 0, data)
    return target


def test_poses_of_another_clock_are_not_needed_in_stereo_mode(logs: dict[str, Path]) -> None:
    log = _restamped(logs["dense"], logs["folder"] / "pose_5ms.mcap", POSE, shift_ns=5_000_000)
    stereo, _ = evaluate_log(log, EvaluateOptions(mode=Mode.STEREO, sweep_every=0))
    assert stereo.frames == 4
    assert stereo.notes == []
    with pytest.raises(
        LogReadError,
        match=r"4 without a /ground_truth/pose; temporal mode needs two in a row with poses: "
        r"evaluate with --mode stereo, which scores each frame alone\); "
        r"4 frames left out: no /ground_truth/pose within 1 ms .* 5.00-5.00 ms away: pass "
        r"--stamp-tolerance-ms 5 to take it",
    ):
        evaluate_log(log, EvaluateOptions(mode=Mode.TEMPORAL, sweep_every=0))
    options = EvaluateOptions(mode=Mode.TEMPORAL, sweep_every=0, stamp_tolerance_ns=5_000_000)
    temporal, _ = evaluate_log(log, options)
    assert temporal.frames == 3


def test_a_frame_without_truth_is_skipped_and_counted_not_scored_against_sgbm(
    logs: dict[str, Path],
) -> None:
    log = _restamped(logs["dense"], logs["folder"] / "truth_lost.mcap", TRUTH, drop=1)
    result, _ = evaluate_log(log, EvaluateOptions(mode=Mode.STEREO, sweep_every=0))
    assert (result.frames, result.skipped) == (3, 1)
    assert result.reference == "ground truth"
    assert any(
        note.startswith("1 frame left out: no /ground_truth/depth within 1 ms")
        and "another frame's (100 ms apart): the stream lacks them" in note
        for note in result.notes
    )


def test_truth_logged_long_after_its_images_is_still_matched(tmp_path: Path) -> None:
    # truth written by another recorder a second after the images: 10 frames at 10 Hz (the
    # right image's wait of 8 frames left them out; the truth used to wait 32)
    log, dense = tmp_path / "synth.mcap", tmp_path / "dense.mcap"
    jobs.synth(log, frames=12, seed=41, scale=0.25, fmt="mcap")
    jobs.densify(log, dense)
    late = _restamped(dense, tmp_path / "late.mcap", TRUTH, logged_later_ns=1_000_000_000)
    result, _ = evaluate_log(late, EvaluateOptions(mode=Mode.STEREO, sweep_every=0))
    assert (result.frames, result.skipped) == (12, 0)


def test_frames_with_incomplete_outputs_are_counted(logs: dict[str, Path]) -> None:
    log = _restamped(logs["dense"], logs["folder"] / "features_lost.mcap", FEATURES, drop=2)
    result, _ = evaluate_log(log, EvaluateOptions(mode=Mode.STEREO, sweep_every=0))
    assert result.frames == 3
    assert (
        "at least 1 frame left out: their densified channels are incomplete (missing "
        "/pcainterp/features on 1" in " ".join(result.notes)
    )


def test_frames_sharing_a_stamp_are_said_to_be_merged(logs: dict[str, Path]) -> None:
    # a times.txt of twelve 0.0 lines gave one frame of twelve, silently (bug hunt 6A F15):
    # import-kitti writes log time = stamp, so the frames' messages all come at one instant
    log = _restamped(logs["dense"], logs["folder"] / "one_stamp.mcap", "*", to_ns=10**18)
    result, _ = evaluate_log(log, EvaluateOptions(mode=Mode.STEREO, sweep_every=0))
    assert result.frames < 4
    note = next(note for note in result.notes if "merged" in note)
    assert re.match(r"\d+ densified messages had the stamp of another of their topic", note)
    assert "frames sharing one were merged; give each frame its own stamp" in note


def _truth_twice(source: Path, target: Path, *, later: bool) -> Path:
    """Copy an MCAP with each truth message followed by another of its stamp, depth x 3.

    ``later``: the second one comes a second of log time later (after its frame was read).
    """
    with McapCopy(source, target) as copy:
        for topic, channel_id, message in copy.messages():
            copy.add(channel_id, message.log_time, message.data)
            if topic == TRUTH:
                data = bytearray(message.data)
                offset = 4 + 8  # CDR header, stamp; then frame_id, height, width
                length = struct.unpack_from("<I", data, offset)[0]
                offset = (offset + 4 + length + 3) & ~3
                height, width = struct.unpack_from("<II", data, offset)
                count = height * width * 4
                values = np.frombuffer(bytes(data[-count:]), np.float32) * np.float32(3)
                data[-count:] = values.tobytes()
                copy.add(channel_id, message.log_time + later * 10**9, bytes(data))
    return target


@pytest.mark.parametrize("later", [False, True])
def test_a_repeated_truth_stamp_takes_the_nearest_in_log_time_and_says_so(
    logs: dict[str, Path], later: bool
) -> None:
    # before: a second truth message of a stamp replaced the first if it came before the
    # frame was read, silently, and was ignored if after (review F8): arbitrary by layout.
    # The one nearest the frame in log time is taken (the first of a tie): stamps that
    # restart mid-log repeat earlier ones (bug hunt 9A F3, tests/evaluate/test_gaps_and_restarts)
    log = _truth_twice(logs["dense"], logs["folder"] / f"truth_twice_{later}.mcap", later=later)
    assert _scores(log, None) == _scores(logs["dense"], None)  # the first of each stamp
    result, _ = evaluate_log(log, EvaluateOptions(mode=Mode.STEREO, sweep_every=0, linear=False))
    assert (
        "messages with the stamp of an earlier one of their topic (4 on /ground_truth/depth; "
        "stamps that restart, or a message logged twice): a frame takes the message of its "
        "stamp nearest its own log time"
    ) in result.notes


def test_a_one_frame_log_refused_in_temporal_mode_names_stereo_mode(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    # bug hunt 17G F8: temporal mode (the default with truth and poses) cannot score one
    # frame; the refusal names --mode stereo, which scores it
    folder = tmp_path_factory.mktemp("one_frame")
    log, dense = folder / "one.mcap", folder / "one_dense.mcap"
    jobs.synth(log, frames=1, seed=41, scale=0.25, fmt="mcap")
    jobs.densify(log, dense)
    with pytest.raises(
        LogReadError,
        match=r"\(1 densified frame read; temporal mode needs two in a row with poses: "
        r"evaluate with --mode stereo, which scores each frame alone\)$",
    ):
        evaluate_log(dense, EvaluateOptions(sweep_every=0))
    stereo, _ = evaluate_log(dense, EvaluateOptions(mode=Mode.STEREO, sweep_every=0))
    assert stereo.frames == 1
