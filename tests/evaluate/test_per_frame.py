"""Per-frame figures in evaluate's report, the frames that stand out, the SGBM caveat.

Bug hunt 13A F4: ``evaluate --mode stereo`` scored a log whose frames 5-7 carried one view
on both image topics better than the clean log (0.877 vs 1.068 px): its reference is SGBM
of the same broken pair; no note said so and nothing in the report named the frames.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from blanked_log import dense_and_blanked

from pcainterp_stream.evaluate import report as report_module
from pcainterp_stream.evaluate.log_frames import Frame
from pcainterp_stream.evaluate.metrics import Mode, compare_with_ground_truth
from pcainterp_stream.evaluate.per_frame import FrameFigures, frame_ranges, standout_lines
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
from pcainterp_stream.evaluate.report_folder import report_json
from pcainterp_stream.evaluate.tables import results_markdown, summary_table
from pcainterp_stream.frontend.stereo import SgbmConfig

STEREO_SGBM = EvaluateOptions(mode=Mode.STEREO, sweep_every=0, sgbm_reference=True)
OWN_PAIRS = "the reference is SGBM of the log's own pairs"


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return dense_and_blanked(tmp_path_factory.mktemp("per_frame"))


def test_results_json_has_each_frames_figures_adding_up_to_the_table(
    logs: dict[str, Path],
) -> None:
    # before: results.json had only the log's sums: no way to find a bad frame
    result, _ = evaluate_log(logs["dense"], STEREO_SGBM)
    rows = json.loads(report_json(result.summary()))["per_frame"]
    assert [row["index"] for row in rows] == list(range(6))
    stamps = [row["stamp_ns"] for row in rows]
    assert stamps == sorted(stamps)
    assert len(set(stamps)) == 6
    assert all(row["estimate"] and row["measured"] for row in rows)
    assert set(rows[0]["delta_2d_mean"]) == {"pca_map", "nearest", "linear"}
    pixels = np.array([row["pixels"] for row in rows], dtype=np.float64)
    assert pixels.sum() == result.methods["pca_map"].pixels
    for name in ("pca_map", "nearest", "linear"):  # the pixel-weighted mean is the table's
        per_frame = np.array([row["delta_2d_mean"][name] for row in rows])
        mean = result.methods[name].summary()["delta_2d_mean"]
        assert float(np.sum(per_frame * pixels) / pixels.sum()) == pytest.approx(mean)
    coverage = np.array([row["coverage_2sigma"] for row in rows])
    stored = result.calibration["stored"].summary()["coverage_2sigma"]
    assert float(np.sum(coverage * pixels) / pixels.sum()) == pytest.approx(stored)
    assert all(0.0 <= row["reference_far"] <= 1.0 for row in rows)
    # a clean log: the note on SGBM of the pair, no frame named
    assert any(note.startswith(OWN_PAIRS) for note in result.notes)
    assert "stands out" not in summary_table(result)


def test_the_note_on_sgbm_of_the_own_pairs_only_with_that_reference(
    logs: dict[str, Path],
) -> None:
    truth, _ = evaluate_log(logs["dense"], dataclasses.replace(STEREO_SGBM, sgbm_reference=False))
    assert truth.reference == "ground truth"
    assert not any(OWN_PAIRS in note for note in truth.notes)
    assert len(truth.per_frame) == 6  # per-frame figures with any reference


def test_a_frame_whose_pair_is_one_view_twice_is_named(
    logs: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    # frames 3-4 as evaluate reads them carry the left view on both topics: SGBM of the pair
    # (the reference) finds disparity 0, too far, everywhere (the hunter's KITTI log: 100 %)
    stereo = report_module._stereo

    def one_view_twice(frame: Frame, sgbm: SgbmConfig) -> Any:
        if frame.index in (3, 4):
            frame = dataclasses.replace(frame, right=frame.left)
        return stereo(frame, sgbm)

    monkeypatch.setattr(report_module, "_stereo", one_view_twice)
    result, _ = evaluate_log(logs["dense"], STEREO_SGBM)
    table = summary_table(result)
    assert f"note: {OWN_PAIRS}" in table
    named = [line for line in table.splitlines() if line.startswith("stands out: frames 3-4")]
    assert any("the reference is too far (depth +inf) on 100 % of the pixels" in n for n in named)
    assert len([line for line in table.splitlines() if "stands out" in line]) <= 4
    markdown = results_markdown(result, [])
    assert "stands out: frames 3-4" in markdown
    assert "each frame's figures (`per_frame`): `results.json`" in markdown
    rows = result.summary()["per_frame"]
    assert [row["reference_far"] for row in rows[3:5]] == [1.0, 1.0]


def test_frames_without_an_estimate_are_counted_and_kept_out_of_the_table(
    logs: dict[str, Path],
) -> None:
    # densify left frames 1-2 unmatched (black images; a pair its pair watch flags alike):
    # NaN, no measurement; the report says how many, which, and that the table has none
    result, _ = evaluate_log(logs["blank_dense"], STEREO_SGBM)
    table = summary_table(result)
    assert "2 frames left out of every method" in table
    assert "they are not in the table (frames 1, 2, counted from 0)" in table
    assert "one view twice" in table  # the pair watch's causes, not only black images
    rows = json.loads(report_json(result.summary()))["per_frame"]
    assert [row["index"] for row in rows] == list(range(6))
    for row in rows[1:3]:
        assert not row["measured"]
        assert not row["estimate"]
        assert row["pixels"] == 0
        assert row["delta_2d_mean"] == {}
        assert row["coverage_2sigma"] is None  # NaN, strict JSON
    assert all(row["measured"] and row["pixels"] > 0 for row in rows[:1] + rows[3:])


def test_the_quick_comparison_leaves_pixels_without_an_estimate_out_of_every_method(
    logs: dict[str, Path],
) -> None:
    # bug hunt 15D F7: frames 1-2 have no estimate (NaN); compare_with_ground_truth counted
    # their pixels with error 0 (np.nansum) and kept them in the count: 0.882 px against the
    # clean log's 1.286, nearest 2.975 against 4.043
    dense = compare_with_ground_truth(logs["dense"])
    blank = compare_with_ground_truth(logs["blank_dense"])
    assert (dense.frames, dense.no_estimate, dense.no_estimate_frames) == (6, 0, 0)
    assert (blank.frames, blank.no_estimate_frames) == (4, 2)
    assert blank.pixels == dense.pixels * 4 // 6  # one image size, truth on every pixel
    assert blank.no_estimate == dense.pixels * 2 // 6
    for method in ("pca_map", "nearest", "linear"):  # every method on the same pixels
        assert blank.mean_abs_error(method) > 0.9 * dense.mean_abs_error(method), method


def _figures(index: int, **changes: Any) -> FrameFigures:
    base = FrameFigures(
        index=index,
        stamp_ns=index * 10**8,
        estimate=True,
        measured=True,
        pixels=1000,
        delta_2d_mean={"pca_map": 1.0, "nearest": 2.0},
        coverage_2sigma=0.96,
        reference_far=0.01,
    )
    return dataclasses.replace(base, **changes)


def _standouts(frames: list[FrameFigures]) -> list[str]:
    return standout_lines(frames)


def test_standout_rules() -> None:
    assert _standouts([_figures(i) for i in range(10)]) == []
    frames = [_figures(i) for i in range(20)]
    frames[4] = _figures(4, delta_2d_mean={"pca_map": 3.5})  # > 3x the median 1.0
    frames[5] = _figures(5, coverage_2sigma=0.3)
    frames[6] = _figures(6, pixels=200)  # truth on 0.2x the median frame's pixels
    frames[7] = _figures(7, estimate=False, pixels=0, delta_2d_mean={})
    frames[8] = _figures(8, measured=False, estimate=False, pixels=0, delta_2d_mean={})
    lines = _standouts(frames)
    assert lines == [
        "frame 7: no estimate (NaN in the log), scored on no pixel",
        "frame 4: PCA-MAP error 3.50 px, over 3x the median frame's 1.00 px",
        "frame 5: +-2 sigma covers 30.0 % of the reference (under 50 %)",
        "frame 6: the reference holds truth on 0.20x the median frame's pixels (200 px of "
        "1000): it collapsed there",
    ]  # frame 8 (no measurement) is named by the no-measurement note instead
    many = [_figures(i, coverage_2sigma=0.1 if i % 2 else 0.96) for i in range(40)]
    (line,) = _standouts(many)
    assert line.startswith("frames 1, 3, 5, 7, 9, 11, 13, 15 and 12 more: +-2 sigma covers")


def test_a_collapsed_frame_is_named_once() -> None:
    # bug hunt 15D F2: a frame with one truth pixel was named three times (its error, its
    # coverage, its collapse); a frame left out for want of truth is named by its note only
    frames = [_figures(i) for i in range(5)]
    frames[1] = _figures(1, pixels=1, delta_2d_mean={"pca_map": 17.35}, coverage_2sigma=0.0)
    frames[2] = _figures(2, reference_far=0.9, delta_2d_mean={"pca_map": 9.0})
    frames[3] = _figures(3, truth=False, pixels=0, delta_2d_mean={}, estimate=False)
    assert _standouts(frames) == [
        "frame 2: the reference is too far (depth +inf) on 90 % of the pixels (median frame "
        "1 %); every pixel is still scored, too far as disparity 0",
        "frame 1: the reference holds truth on 0.00x the median frame's pixels (1 px of "
        "1000): it collapsed there",
    ]


def test_a_frame_whose_reference_is_too_far_keeps_its_error() -> None:
    # review 15d R5: a far reference scores every pixel (truth disparity 0), so its error
    # and coverage mean something; it was named only as "collapsed" and its error hidden
    frames = [_figures(i) for i in range(5)]
    frames[2] = _figures(2, reference_far=0.9, delta_2d_mean={"pca_map": 9.0}, coverage_2sigma=0.2)
    lines = _standouts(frames)
    assert "frame 2: PCA-MAP error 9.00 px, over 3x the median frame's 1.00 px" in lines
    assert "frame 2: +-2 sigma covers 20.0 % of the reference (under 50 %)" in lines
    assert not any("collapsed" in line for line in lines)
    # a frame with truth on few pixels that are also far is named once, as collapsed
    frames[2] = _figures(2, pixels=10, reference_far=0.9, delta_2d_mean={"pca_map": 9.0})
    (line,) = _standouts(frames)
    assert line.endswith("it collapsed there")


def test_frame_ranges() -> None:
    assert frame_ranges([5, 6, 7, 9]) == "5-7, 9"
    assert frame_ranges([3]) == "3"
    assert frame_ranges([]) == ""
