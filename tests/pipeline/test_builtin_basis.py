"""Issue 16 through the jobs and the command line: the built-in basis where no basis is
given (densify, evaluate, info, the processor), the prior fitted by default, and
``learn --with-synthetic``."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from pcainterp_stream import cli
from pcainterp_stream.estimate import basis as basis_module
from pcainterp_stream.estimate.basis import BUILT_IN, Basis
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.io.outputs import (
    BASIS_FINGERPRINT_KEY,
    BASIS_KEY,
    MEASUREMENTS_KEY,
    recorded_metadata,
)
from pcainterp_stream.pipeline import jobs
from pcainterp_stream.pipeline.processor import FrameProcessor

FRAMES = 6


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A quarter-size drive (the built-in basis maps onto its smaller camera), densified
    once with the built-in basis and once with a basis of its own."""
    folder = tmp_path_factory.mktemp("builtin")
    log = folder / "drive.mcap"
    jobs.synth(log, frames=FRAMES, seed=61, scale=0.25, fmt="mcap")
    own = folder / "own.npz"
    jobs.learn([log], own, jobs.LearnOptions(n_components=4, fit_prior=False), PairingConfig())
    assert cli.main(["densify", str(log), "-o", str(folder / "builtin_dense.mcap")]) == 0
    args = ["densify", str(log), "-o", str(folder / "own_dense.mcap"), "--basis", str(own)]
    assert cli.main(args) == 0
    return folder


def run(capsys: pytest.CaptureFixture[str], *args: str | Path) -> tuple[int, str, str]:
    capsys.readouterr()
    code = cli.main([str(arg) for arg in args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


# ----------------------------------------------------------------------------- densify


def test_densify_without_basis_records_the_built_in_one(folder: Path) -> None:
    recorded = recorded_metadata(folder / "builtin_dense.mcap")
    assert recorded == {
        BASIS_KEY: BUILT_IN,
        BASIS_FINGERPRINT_KEY: Basis.default().fingerprint,
        MEASUREMENTS_KEY: "sparse",
    }
    recorded = recorded_metadata(folder / "own_dense.mcap")
    assert recorded[BASIS_KEY] == str(folder / "own.npz")
    assert recorded[BASIS_FINGERPRINT_KEY] == Basis.load(folder / "own.npz").fingerprint


def test_processor_without_basis_uses_the_built_in_one() -> None:
    with FrameProcessor() as processor:
        assert processor.basis is Basis.default()


def test_densify_without_an_installed_basis_is_one_line(
    folder: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.setattr(basis_module, "default_basis_path", lambda: tmp_path / "gone.npz")
    target = tmp_path / "out.mcap"
    code, _, err = run(capsys, "densify", folder / "drive.mcap", "-o", target)
    assert code == 2
    assert err.count("\n") == 1
    assert "built-in basis" in err and "--basis" in err
    assert not target.exists()


# ----------------------------------------------------------------------------- evaluate


def _report(folder: Path) -> dict[str, object]:
    report: dict[str, object] = json.loads((folder / "results.json").read_text())
    return report


def test_evaluate_uses_the_basis_the_log_records(
    folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, _ = run(
        capsys, "evaluate", folder / "builtin_dense.mcap", "-o", tmp_path / "a", "--sweep-every", "0"
    )
    assert code == 0
    assert "basis of the re-densified rows: built-in (recorded in the log)" in out
    report = _report(tmp_path / "a")
    assert report["basis"]["path"] == BUILT_IN  # type: ignore[index]
    assert "oracle" in report["methods"]  # type: ignore[operator]

    code, out, _ = run(
        capsys, "evaluate", folder / "own_dense.mcap", "-o", tmp_path / "b", "--sweep-every", "0"
    )
    assert code == 0
    assert f"rows: {folder / 'own.npz'} (recorded in the log)" in out
    assert _report(tmp_path / "b")["basis"]["components"] == 4  # type: ignore[index]


def test_evaluate_skips_the_basis_rows_when_the_recorded_basis_is_gone(
    folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    moved = tmp_path / "moved"
    moved.mkdir()
    log = moved / "own_dense.mcap"
    shutil.copy(folder / "own_dense.mcap", log)
    shutil.copy(folder / "own.npz", tmp_path / "own_elsewhere.npz")
    recorded = recorded_metadata(log)[BASIS_KEY]
    (folder / "own.npz").rename(folder / "own.npz.away")
    try:
        code, out, _ = run(capsys, "evaluate", log, "-o", tmp_path / "r", "--sweep-every", "0")
    finally:
        (folder / "own.npz.away").rename(folder / "own.npz")
    assert code == 0
    assert f"densified with {recorded}, not found" in out
    report = _report(tmp_path / "r")
    assert report["basis"] is None
    assert "oracle" not in report["methods"]  # type: ignore[operator]
    # --basis names it explicitly
    code, out, _ = run(
        capsys, "evaluate", log, "-o", tmp_path / "s", "--sweep-every", "0",
        "--basis", tmp_path / "own_elsewhere.npz",
    )
    assert code == 0
    assert "(given)" in out


def test_evaluate_no_basis_and_no_linear_skip_rows(
    folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["evaluate", folder / "builtin_dense.mcap", "-o", tmp_path / "q"]
    code, out, _ = run(capsys, *args, "--no-basis", "--no-linear")
    assert code == 0
    methods = _report(tmp_path / "q")["methods"]
    assert set(methods) == {"pca_map", "nearest"}  # type: ignore[arg-type]
    code, _, err = run(capsys, *args, "--no-basis", "--basis", folder / "own.npz")
    assert code == 2
    assert "--no-basis and --basis" in err


# ----------------------------------------------------------------------------- info


def test_info_without_a_file_describes_the_built_in_basis(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, out, _ = run(capsys, "info")
    assert code == 0
    basis = Basis.default()
    assert out.startswith("built-in basis (")
    assert f"components       {basis.n_components}" in out
    assert "1241x376 px" in out
    assert "matches the file" in out  # the sidecar's sha256


# ----------------------------------------------------------------------------- learn


def test_learn_fits_the_prior_by_default_and_no_fit_prior_is_the_paper(
    folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = folder / "drive.mcap"
    fitted, paper, alias = tmp_path / "fitted.npz", tmp_path / "paper.npz", tmp_path / "a.npz"
    assert run(capsys, "learn", log, "-o", fitted, "--components", "3")[0] == 0
    assert "prior" in Basis.load(fitted).meta
    assert Basis.load(fitted).n_train == 4  # the last 20 % held out for the fit
    args = ["learn", log, "-o", paper, "--components", "3", "--no-fit-prior"]
    assert run(capsys, *args)[0] == 0
    assert "prior" not in Basis.load(paper).meta
    assert Basis.load(paper).n_train == FRAMES
    assert run(capsys, "learn", log, "-o", alias, "--components", "3", "--fit-prior")[0] == 0
    assert "prior" in Basis.load(alias).meta
    parser = cli.build_parser()
    assert parser.parse_args(["learn", "x.mcap", "-o", "b.npz"]).fit_prior is None


def test_learn_holds_out_a_share_of_a_log_that_keeps_no_counts(
    folder: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from pcainterp_stream.pipeline import learn as learn_module

    monkeypatch.setattr(learn_module, "_expected_frames", lambda *args: None)
    options = jobs.LearnOptions(n_components=3)  # the prior fitted: the default
    basis = jobs.learn([folder / "drive.mcap"], tmp_path / "b.npz", options, PairingConfig())
    assert basis.n_train == 4  # the frames counted by reading the log, 20 % held out
    assert basis.meta["prior"]["held_out_frames"] == 2


def test_learn_with_synthetic_fine_tunes_the_built_in_basis(
    folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "tuned.npz"
    args = ["learn", folder / "drive.mcap", "-o", out, "--with-synthetic", "200"]
    code, text, err = run(capsys, *args, "--components", "20", "--no-fit-prior")
    assert code == 0, err
    assert "fine-tuned" in text
    tuned, built_in = Basis.load(out), Basis.default()
    assert tuned.image_size == built_in.image_size  # its camera, not the log's 310x94
    assert tuned.grid_size == built_in.grid_size
    assert tuned.focal_baseline == built_in.focal_baseline
    assert tuned.n_train == 200 + FRAMES
    assert tuned.n_components == min(20, built_in.n_components + FRAMES)
    record = tuned.meta["finetune"]
    assert record["n_prior"] == 200 and record["n_maps"] == FRAMES
    assert record["prior_basis"]["fingerprint"] == built_in.fingerprint
    assert record["maps_image_size"] == [94, 310]
    assert tuned.meta["source"]["with_synthetic"] == 200
    # the tuned basis densifies the log it was tuned on (mapped onto its camera)
    dense = tmp_path / "dense.mcap"
    assert run(capsys, "densify", folder / "drive.mcap", "-o", dense, "--basis", out)[0] == 0


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--with-synthetic", "1"], "--with-synthetic must be at least 2 maps, got 1"),
        (["--with-synthetic", "50", "--grid-scale", "0.5"], "drop --grid-scale"),
        (["--with-synthetic", "50", "--workers", "1"], "drop --scheduler/--workers"),
        (["--no-fit-prior", "--fit-logs", "x.mcap"], "drop --no-fit-prior"),
    ],
)
def test_learn_refuses_contradicting_options(
    extra: list[str],
    message: str,
    folder: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    target = tmp_path / "b.npz"
    code, _, err = run(capsys, "learn", folder / "drive.mcap", "-o", target, *extra)
    assert code == 2
    assert message in err
    assert not target.exists()
