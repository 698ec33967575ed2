"""What ``pcainterp evaluate`` writes: the frames it scores, the report folder, results.json."""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
from pathlib import Path
from typing import Any

import pytest
from blanked_log import blanked, dense_and_blanked

from pcainterp_stream import cli
from pcainterp_stream.evaluate import report as report_module
from pcainterp_stream.evaluate import report_folder
from pcainterp_stream.evaluate.metrics import Mode
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
from pcainterp_stream.evaluate.tables import results_markdown, summary_table
from pcainterp_stream.pipeline import jobs


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return dense_and_blanked(tmp_path_factory.mktemp("report_output"))


def test_frames_without_a_measurement_are_left_out_of_every_method(
    logs: dict[str, Path],
) -> None:
    # before: nearest and linear (NaN there) were charged huge errors on the black frames,
    # so PCA-MAP / nearest fell (0.66 -> 0.38 on a bug hunt log) and the report was silent
    options = EvaluateOptions(mode=Mode.STEREO, sweep_every=0, linear=True)
    blank, _ = evaluate_log(logs["blank_dense"], options)
    assert blank.no_measurement == [1, 2]
    assert blank.frames == 4
    for name in ("pca_map", "nearest", "linear"):
        stats = blank.methods[name]
        assert stats.pixels > 0
        assert stats.summary()["delta_2d_mean"] < 20.0  # no NaN estimate charged as far
    # every method on the same frames: the same counted pixels
    pixels = {name: stats.pixels for name, stats in blank.methods.items() if name != "oracle"}
    assert len(set(pixels.values())) == 1
    note = "2 frames left out of every method: no measurement there"
    assert note in summary_table(blank)
    assert "(frames 1, 2, counted from 0)" in summary_table(blank)
    assert note in results_markdown(blank, [])
    assert blank.summary()["left_out_no_measurement"] == [1, 2]
    full, _ = evaluate_log(logs["dense"], options)
    assert full.no_measurement == []
    assert "left out" not in summary_table(full)


def test_a_log_without_any_measurement_cannot_be_evaluated(tmp_path: Path) -> None:
    from pcainterp_stream.errors import LogReadError

    log = tmp_path / "drive.mcap"
    jobs.synth(log, frames=2, seed=32, scale=0.25, fmt="mcap")
    dense = tmp_path / "dense.mcap"
    jobs.densify(blanked(log, tmp_path / "black.mcap", {0, 1}), dense)
    with pytest.raises(
        LogReadError, match=r"\(2 densified frames read, 2 without a measurement\)$"
    ):
        evaluate_log(dense, EvaluateOptions(mode=Mode.STEREO, sweep_every=0, linear=False))


FAST = ["--no-basis", "--no-linear", "--max-frames", "2"]


def test_evaluate_refuses_a_folder_holding_other_files(
    logs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # before: a user's results.md was overwritten, and any folder was written into
    notes = tmp_path / "myproj"
    notes.mkdir()
    (notes / "results.md").write_text("my notes")
    assert cli.main(["evaluate", str(logs["dense"]), "-o", str(notes), *FAST]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1
    assert f"cannot write the report to {notes}: its results.md is not an evaluate report's" in err
    assert (notes / "results.md").read_text() == "my notes"
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    assert cli.main(["evaluate", str(logs["dense"]), "-o", str(other), *FAST]) == 2
    err = capsys.readouterr().err
    assert err.strip().endswith(
        f"cannot write the report to {other}: it holds files a report does not write "
        "(notes.txt); pass -o with a new or empty folder, or an earlier report's folder"
    )
    assert sorted(path.name for path in other.iterdir()) == ["notes.txt"]
    assert not list(tmp_path.glob(".*partial*"))


def test_a_rerun_replaces_the_report_and_its_stale_figures(
    logs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # before: basis.png, variance.png and sweep.png of a run with the basis stayed beside
    # the results.md of a run without it
    report = tmp_path / "report"
    with_basis = ["evaluate", str(logs["dense"]), "-o", str(report), "--max-frames", "3"]
    assert cli.main([*with_basis, "--sweep-every", "1", "--no-linear"]) == 0
    assert {"basis.png", "variance.png", "sweep.png"} <= {p.name for p in report.iterdir()}
    empty = tmp_path / "empty"
    empty.mkdir()
    for folder in (report, empty):
        assert cli.main(["evaluate", str(logs["dense"]), "-o", str(folder), *FAST]) == 0
        names = {path.name for path in folder.iterdir()}
        assert names == {
            "results.md",
            "results.json",
            "errors.png",
            "uncertainty.png",
            "examples.png",
        }
    capsys.readouterr()
    assert not list(tmp_path.glob(".*partial*"))


REPORT = {"results.md", "results.json", "errors.png", "uncertainty.png", "examples.png"}


def test_an_existing_folder_is_written_into_not_renamed(
    logs: dict[str, Path],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # before: the folder was renamed away and the staging folder renamed onto it, which a
    # mount point (a container's volume: EBUSY) refuses, after the whole evaluation
    report = tmp_path / "report"
    with_basis = ["evaluate", str(logs["dense"]), "-o", str(report), "--max-frames", "3"]
    assert cli.main([*with_basis, "--sweep-every", "1", "--no-linear"]) == 0
    (report / ".gitkeep").write_text("")  # hidden files are neither refused nor removed
    inode = report.stat().st_ino
    replace = os.replace

    def mount_point(source: Any, target: Any) -> None:
        if Path(source).resolve() == report.resolve():
            raise OSError(errno.EBUSY, os.strerror(errno.EBUSY), str(source))
        replace(source, target)

    monkeypatch.setattr(report_folder.os, "replace", mount_point)
    assert cli.main(["evaluate", str(logs["dense"]), "-o", str(report), *FAST]) == 0
    assert {path.name for path in report.iterdir()} == {*REPORT, ".gitkeep"}
    assert report.stat().st_ino == inode
    assert "methods" in json.loads((report / "results.json").read_text())
    capsys.readouterr()
    assert not list(tmp_path.glob(".*partial*"))


def test_a_folder_that_cannot_be_written_is_refused_before_the_evaluation(
    logs: dict[str, Path],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # before: a folder in a parent evaluate could not write failed only after the evaluation
    def not_run(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("the log was evaluated")

    def denied(*args: Any, **kwargs: Any) -> str:
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES))

    monkeypatch.setattr(report_module, "evaluate_log", not_run)
    monkeypatch.setattr(report_folder.tempfile, "mkdtemp", denied)
    for folder in (tmp_path / "new", tmp_path):
        assert cli.main(["evaluate", str(logs["dense"]), "-o", str(folder), *FAST]) == 2
        err = capsys.readouterr().err
        assert len(err.splitlines()) == 1
        which = f"its folder {tmp_path} is" if folder.name == "new" else "it is"
        assert err.strip().endswith(
            f"cannot write the report to {folder}: {which} not writable "
            "(Permission denied); choose a writable folder"
        )


def test_a_folder_named_like_a_figure_is_refused_before_the_evaluation(
    logs: dict[str, Path],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # the files are moved into an existing folder one by one: a folder errors.png would
    # fail that move after the evaluation (and is no report's, so it is not removed)
    def not_run(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("the log was evaluated")

    monkeypatch.setattr(report_module, "evaluate_log", not_run)
    (tmp_path / "report" / "errors.png").mkdir(parents=True)
    folder = tmp_path / "report"
    assert cli.main(["evaluate", str(logs["dense"]), "-o", str(folder), *FAST]) == 2
    err = capsys.readouterr().err
    assert err.strip().endswith(
        f"cannot write the report to {folder}: it holds files a report does not write "
        "(errors.png); pass -o with a new or empty folder, or an earlier report's folder"
    )


def test_the_current_folder_can_hold_the_report(
    logs: dict[str, Path],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # before: `-o .` staged inside `.` itself and refused its own staging folder, after the
    # whole evaluation
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    for _ in range(2):  # empty, then an earlier report's
        assert cli.main(["evaluate", str(logs["dense"]), "-o", ".", *FAST]) == 0
        assert {path.name for path in here.iterdir()} == REPORT
    (here / "sub").mkdir()
    monkeypatch.chdir(here / "sub")
    assert cli.main(["evaluate", str(logs["dense"]), "-o", "..", *FAST]) == 2  # holds sub/
    err = capsys.readouterr().err
    assert err.strip().endswith(
        "cannot write the report to ..: it holds files a report does not write (sub); "
        "pass -o with a new or empty folder, or an earlier report's folder"
    )
    assert not list(tmp_path.rglob(".*partial*"))


def test_results_json_is_strict_json(logs: dict[str, Path], tmp_path: Path) -> None:
    # before: the histograms' open last bin edges were written as bare Infinity, which
    # JavaScript's JSON.parse (and every RFC 8259 reader) rejects
    report = tmp_path / "report"
    jobs.evaluate(logs["dense"], report, basis_rows=False, linear=False, max_frames=2)
    text = (report / "results.json").read_text()

    def refuse(constant: str) -> None:
        raise ValueError(f"non-standard JSON constant {constant}")

    data = json.loads(text, parse_constant=refuse)
    assert data["bins"]["delta_2d_px"][-1] is None  # the open last bin
    assert data["bins"]["depth_m"][:2] == [0.0, 5.0]


def test_a_log_densified_with_too_few_outputs_names_densify_outputs(
    logs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # before: "...; evaluate needs a log written by `pcainterp densify`", which it was
    dense = tmp_path / "depth_only.mcap"
    assert cli.main(["densify", str(logs["log"]), "-o", str(dense), "--outputs", "depth"]) == 0
    capsys.readouterr()
    assert cli.main(["evaluate", str(dense), "-o", str(tmp_path / "report"), *FAST]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1
    assert err.strip() == (
        f"pcainterp: error: {dense} has no /pcainterp/disparity_std, /pcainterp/features, "
        "/pcainterp/camera_info; densify wrote only depth into it (`pcainterp densify "
        "--outputs`): evaluate needs depth or disparity, disparity_std, features and "
        "camera_info; densify again with --outputs depth,disparity_std,features,camera_info "
        "(or without --outputs)"
    )
    assert not (tmp_path / "report").exists()


def test_the_points_sweep_lists_only_the_counts_it_reached(logs: dict[str, Path]) -> None:
    # before: rows for 400 and 800 points identical to the last reached one (fewer corners
    # were found than asked for), "(1 frames)", and no word on what the sweep measures
    basis, _ = jobs.evaluation_basis(logs["dense"])  # the built-in one densify used
    options = EvaluateOptions(basis, mode=Mode.STEREO, sweep_every=1, max_frames=1, linear=False)
    result, _ = evaluate_log(logs["dense"], options)
    assert result.sweep_frames == 1
    (corners,) = result.sweep_corners
    assert 50 <= corners < 800
    assert sorted(result.sweep) == [p for p in (50, 100, 200, 400, 800) if p <= corners]
    assert all(result.sweep_reached[points] == 1 for points in result.sweep)
    markdown = results_markdown(result, [])
    assert "## Error against the number of points (1 frame)\n" in markdown
    assert f"The frame had {corners} corners with a disparity; larger counts have no row." in (
        markdown
    )
    assert "corners only, none of densify's lattice points" in markdown
    assert "measurement noise --sigma 2 px" in markdown
    rows = [line for line in markdown.splitlines() if line[:2] == "| " and line[2].isdigit()]
    assert [int(row.split("|")[1]) for row in rows] == sorted(result.sweep)


def test_the_uncertainty_figure_says_which_estimate_each_series_is(
    logs: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # before: the log's stored estimate and evaluate's re-densifications (--sigma 2) were
    # drawn as one "PCA-MAP", told apart only by the bare names stored/paper/exact
    from matplotlib.figure import Figure

    legends: dict[str, list[str]] = {}
    save = Figure.savefig

    def savefig(figure: Figure, name: Path, **kwargs: Any) -> None:
        found = [axis.get_legend() for axis in figure.axes]
        legends[Path(name).name] = [t.get_text() for f in found if f for t in f.get_texts()]
        save(figure, name, **kwargs)

    monkeypatch.setattr(Figure, "savefig", savefig)
    basis, _ = jobs.evaluation_basis(logs["dense"])
    report = tmp_path / "report"
    jobs.evaluate(logs["dense"], report, basis=basis, max_frames=2, sweep_every=0, linear=False)
    labels = legends["uncertainty.png"]
    assert "stored: the log's estimate and std" in labels
    assert "exact: re-densified, --sigma 2" in labels
    assert "paper: re-densified, --sigma 2: RMS error" in labels
    assert "`stored` is the log's own estimate and std; `paper`, `exact`, `exact+residual` are" in (
        (report / "results.md").read_text()
    )


@pytest.mark.parametrize(
    ("flags", "closest"),
    [
        (
            ["--reference-topic", "/ground_truth/dept"],
            "/ground_truth/depth: pass it to --reference-topic",
        ),
        (
            ["--left-topic", "/stereo/left/image_rec", "--right-topic", "/stereo/right/image_rect"],
            "/stereo/left/image_rect: set --left-topic to it",
        ),
        (
            ["--left-topic", "/stereo/left/image_rect", "--right-topic", "/stereo/right/image_rec"],
            "/stereo/right/image_rect: set --right-topic to it",
        ),
        (["--left-topic", "/stereo/left/image_rec"], "/stereo/left/image_rect: set --left-topic"),
        (["--right-topic", "/stereo/right/image_rec"], "/stereo/right/image_rect: set --right"),
    ],
)
def test_a_topic_not_found_names_the_closest(
    logs: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    flags: list[str],
    closest: str,
) -> None:
    # as densify's messages do (before: the topics present, or "has no", and no hint); the
    # right topic named wrong was not even an error: the stereo rows were skipped
    code = cli.main(["evaluate", str(logs["dense"]), "-o", str(tmp_path / "r"), *flags])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.splitlines()) == 1
    assert f"; the closest is {closest}" in err
    assert not (tmp_path / "r").exists()


def test_sigma_is_stated_in_the_log_px_too(logs: dict[str, Path], tmp_path: Path) -> None:
    from pcainterp_stream.estimate.basis import Basis
    from pcainterp_stream.io.outputs import FOCAL_BASELINE_KEY, recorded_metadata

    jobs.evaluate(logs["dense"], tmp_path / "r", sigma=1.5, sweep_every=0, linear=False)
    report = json.loads((tmp_path / "r" / "results.json").read_text())
    log_fb = float(recorded_metadata(logs["dense"])[FOCAL_BASELINE_KEY])
    expected = 1.5 * log_fb / Basis.default().focal_baseline  # --sigma is in the basis's px
    assert report["sigma_log_px"] == pytest.approx(expected)
    text = (tmp_path / "r" / "results.md").read_text()
    assert f"--sigma 1.5 px of the basis's camera, {expected:.3g} px in the log's" in text


@pytest.mark.parametrize("existing", [False, True])
def test_a_full_disk_while_the_report_is_written_says_free_some_space(
    tmp_path: Path, existing: bool
) -> None:
    """The figures' write fails (ENOSPC): not "cannot move the finished report ... re-run
    once it is writable" (it was never finished, and the folder is writable)."""
    folder = tmp_path / "rep"
    if existing:
        folder.mkdir()
        (folder / "results.md").write_text("an earlier report")

    def full_disk(staging: Path) -> None:
        (staging / "results.md").write_text("half")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    with pytest.raises(report_folder.PcaInterpError) as raised:
        report_folder.write_report_folder(folder, full_disk)
    assert str(raised.value) == (
        f"writing the report into {folder} failed: No space left on device; "
        "free some space, or write it elsewhere"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == (["rep"] if existing else [])
    if existing:
        assert [p.name for p in folder.iterdir()] == ["results.md"]
        assert (folder / "results.md").read_text() == "an earlier report"


def test_a_failed_move_still_says_cannot_move(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    folder = tmp_path / "rep"
    folder.mkdir()

    def refused(*args: Any, **kwargs: Any) -> None:
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES))

    monkeypatch.setattr(report_folder.os, "replace", refused)
    with pytest.raises(report_folder.PcaInterpError, match=r"cannot move the finished report"):
        report_folder.write_report_folder(folder, lambda s: (s / "results.md").write_text("x"))


@pytest.mark.parametrize(
    ("existing", "when"),
    [
        (False, "before-staging"),  # an existing folder removed then is simply made afresh
        (False, "while-writing"),
        (True, "while-writing"),
        (False, "before-the-move"),
        (True, "before-the-move"),
    ],
)
def test_a_folder_removed_under_the_report_says_so(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, existing: bool, when: str
) -> None:
    """The report's folder removed under evaluate (bug hunt 7B F11a): "folder F no longer
    exists", not "not writable", "choose a writable folder" or "re-run once it is writable"."""
    parent = tmp_path / "runs"
    parent.mkdir()
    folder = parent / "rep"
    if existing:
        folder.mkdir()
    gone = folder if existing else parent  # what holds the staging folder
    if when == "before-staging":
        shutil.rmtree(parent)
    original = report_folder.os.replace

    def move(source: Any, target: Any) -> None:
        if when == "before-the-move":
            shutil.rmtree(gone)
        original(source, target)

    monkeypatch.setattr(report_folder.os, "replace", move)

    def write(staging: Path) -> None:
        if when == "while-writing":
            shutil.rmtree(gone)
        (staging / "results.md").write_text("x")

    with pytest.raises(report_folder.PcaInterpError) as raised:
        report_folder.write_report_folder(folder, write)
    during = "the log was evaluated" if when == "before-staging" else "the report was being written"
    assert str(raised.value) == (
        f"cannot write the report to {folder}: folder {gone} no longer exists "
        f"(removed while {during}); nothing was written"
    )
    assert not re.search(r"writable|permission", str(raised.value))
    assert not gone.exists()


@pytest.mark.usefixtures("umask_027_unchanged")
def test_the_report_folder_mode_is_set_without_changing_the_umask(tmp_path: Path) -> None:
    """Review 55b R55b-5: the umask was set to 0 for a moment while other threads run."""
    folder = tmp_path / "report"
    report_folder.write_report_folder(folder, lambda staging: None)
    assert folder.stat().st_mode & 0o777 == 0o750


def test_a_report_folder_name_too_long_is_one_line(tmp_path: Path) -> None:
    """Review 55c R55c-2: a report folder's name over the file system's limit was a traceback
    (OSError ENAMETOOLONG from a look at it), before any staging folder."""
    limit = os.pathconf(tmp_path, "PC_NAME_MAX")
    folder = tmp_path / ("r" * (limit + 1))
    with pytest.raises(report_folder.PcaInterpError) as caught:
        report_folder.check_report_folder(folder)
    assert str(caught.value) == (
        f"cannot write the report to {folder}: the file name is too long for the file system "
        f"({limit + 1} bytes, at most {limit}): choose a shorter name"
    )
    report_folder.check_report_folder(tmp_path / ("r" * limit))  # the longest: taken


def test_the_basis_file_is_read_once_for_the_rows_and_the_figures(
    logs: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # before (bug hunt 17B F2): write_report loaded the basis again for the figures: a file
    # removed while the log was evaluated threw the finished evaluation away ("basis file
    # ... does not exist", no report); one replaced gave figures of another basis
    from pcainterp_stream.estimate.basis import Basis

    basis_file = tmp_path / "b.npz"
    Basis.default().save(basis_file)
    loads: list[str] = []
    load = Basis.load.__func__  # type: ignore[attr-defined]

    def counting(cls: type[Basis], path: Any) -> Basis:
        loads.append(Path(path).name)
        return load(cls, path)  # type: ignore[no-any-return]

    monkeypatch.setattr(Basis, "load", classmethod(counting))
    evaluate = report_module.evaluate_log

    def then_removed(*args: Any, **kwargs: Any) -> Any:
        evaluated = evaluate(*args, **kwargs)
        basis_file.unlink()  # as `mv b.npz b_old.npz` in another terminal meanwhile
        return evaluated

    monkeypatch.setattr(report_module, "evaluate_log", then_removed)
    options = EvaluateOptions(basis_file, mode=Mode.STEREO, sweep_every=0, max_frames=2)
    report = tmp_path / "report"
    result = report_module.write_report(logs["dense"], report, options)
    assert loads == ["b.npz"]
    assert result.basis is not None
    assert result.basis["path"] == str(basis_file)
    assert {"basis.png", "variance.png", "results.md"} <= {p.name for p in report.iterdir()}
