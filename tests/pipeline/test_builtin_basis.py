"""Issue 16 through the jobs and the command line: the built-in basis where no basis is
given (densify, evaluate, info, the processor), the prior fitted by default, and
``learn --with-synthetic`` (``auto`` by default: the built-in basis of the logs' camera,
street or indoor, merged into few maps)."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from pcainterp_stream import cli
from pcainterp_stream.estimate import basis as basis_module
from pcainterp_stream.estimate.basis import BUILT_IN, Basis
from pcainterp_stream.estimate.learning import learn_basis
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.io.outputs import (
    BASIS_FINGERPRINT_KEY,
    BASIS_KEY,
    MEASUREMENTS_KEY,
    recorded_metadata,
)
from pcainterp_stream.pipeline import jobs
from pcainterp_stream.pipeline import learn as learn_module
from pcainterp_stream.pipeline.learn import AUTO_MAX_MAPS, AUTO_PRIOR_MAPS
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
    assert {key: recorded[key] for key in (BASIS_KEY, BASIS_FINGERPRINT_KEY, MEASUREMENTS_KEY)} == {
        BASIS_KEY: BUILT_IN,
        BASIS_FINGERPRINT_KEY: Basis.default().fingerprint,
        MEASUREMENTS_KEY: "sparse",
    }
    recorded = recorded_metadata(folder / "own_dense.mcap")
    # bug hunt 10A F6 / review 58a R1: relative to the output's folder (here beside it), not
    # the path as typed (no machine folder)
    assert recorded[BASIS_KEY] == "own.npz"
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
    assert "built-in basis" in err
    assert "--basis" in err
    assert not target.exists()


# ----------------------------------------------------------------------------- evaluate


def _report(folder: Path) -> dict[str, object]:
    report: dict[str, object] = json.loads((folder / "results.json").read_text())
    return report


def test_evaluate_uses_the_basis_the_log_records(
    folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, _ = run(
        capsys,
        "evaluate",
        folder / "builtin_dense.mcap",
        "-o",
        tmp_path / "a",
        "--sweep-every",
        "0",
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
    # the report names the file, not "in-memory" (bug hunt 6A F10)
    assert _report(tmp_path / "b")["basis"]["path"] == str(folder / "own.npz")  # type: ignore[index]
    assert f"Basis: `{folder / 'own.npz'}`" in (tmp_path / "b" / "results.md").read_text()


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
    assert f"densified with {recorded}, fingerprint" in out
    assert "not found beside the log nor in the working folder" in out
    report = _report(tmp_path / "r")
    assert report["basis"] is None
    assert "oracle" not in report["methods"]  # type: ignore[operator]
    # --basis names it explicitly
    code, out, _ = run(
        capsys,
        "evaluate",
        log,
        "-o",
        tmp_path / "s",
        "--sweep-every",
        "0",
        "--basis",
        tmp_path / "own_elsewhere.npz",
    )
    assert code == 0
    assert "(given)" in out


def test_evaluate_no_basis_and_no_linear_skip_rows(
    folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["evaluate", folder / "builtin_dense.mcap", "-o", tmp_path / "q"]
    code, _out, _ = run(capsys, *args, "--no-basis", "--no-linear")
    assert code == 0
    methods = _report(tmp_path / "q")["methods"]
    assert set(methods) == {"pca_map", "nearest"}  # type: ignore[arg-type]
    code, _, err = run(capsys, *args, "--no-basis", "--basis", folder / "own.npz")
    assert code == 2
    assert "--no-basis and --basis" in err


# ----------------------------------------------------------------------------- info


def test_info_without_a_file_describes_the_built_in_bases(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, out, _ = run(capsys, "info")
    assert code == 0
    street, indoor = out.split("\n\nbuilt-in indoor basis (")
    assert street.startswith("built-in street basis (")
    assert f"components       {Basis.default().n_components}" in street
    assert "1241x376 px" in street
    assert "synthetic streets only" in street
    assert "matches the file" in street  # the sidecar's sha256
    assert f"components       {Basis.indoor().n_components}" in indoor
    assert "752x480 px" in indoor
    assert "synthetic indoor walks only" in indoor
    assert "hand-held, drone and ground-robot" in indoor
    assert "fisheye-752x480" in indoor  # the cameras it was seen by
    assert "matches the file" in indoor


# ----------------------------------------------------------------------------- learn


def test_learn_fits_the_prior_by_default_and_no_fit_prior_is_the_paper(
    folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = folder / "drive.mcap"
    fitted, paper, alias = tmp_path / "fitted.npz", tmp_path / "paper.npz", tmp_path / "a.npz"
    alone = ["--components", "3", "--with-synthetic", "0"]  # the maps alone, as the paper
    assert run(capsys, "learn", log, "-o", fitted, *alone)[0] == 0
    assert "prior" in Basis.load(fitted).meta
    assert Basis.load(fitted).n_train == 4  # the last 20 % held out for the fit
    assert Basis.load(fitted).meta["source"]["with_synthetic_rule"] == "off: --with-synthetic 0"
    assert run(capsys, "learn", log, "-o", paper, *alone, "--no-fit-prior")[0] == 0
    assert "prior" not in Basis.load(paper).meta
    assert Basis.load(paper).n_train == FRAMES
    assert run(capsys, "learn", log, "-o", alias, *alone, "--fit-prior")[0] == 0
    assert "prior" in Basis.load(alias).meta
    parser = cli.build_parser()
    defaults = parser.parse_args(["learn", "x.mcap", "-o", "b.npz"])
    assert defaults.fit_prior is None
    assert defaults.with_synthetic == "auto"


def test_learn_with_no_flags_merges_the_built_in_basis_into_few_maps(
    folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "auto.npz"
    code, text, err = run(capsys, "learn", folder / "drive.mcap", "-o", out, "--components", "20")
    assert code == 0, err
    notes = [line for line in text.splitlines() if line.startswith("note:")]
    assert len(notes) == 1  # one line: what it did and how to turn it off
    assert f"4 maps of your own are few (< {AUTO_MAX_MAPS})" in notes[0]
    assert f"counted as {AUTO_PRIOR_MAPS} maps" in notes[0]
    assert "--with-synthetic 0" in notes[0]
    assert "and keeping its local kernel;" in notes[0]  # it does: see prior["local"] below
    tuned, built_in = Basis.load(out), Basis.default()
    assert tuned.n_train == AUTO_PRIOR_MAPS + 4  # 2 of the 6 frames held out for the fit
    assert tuned.image_size == built_in.image_size
    record = tuned.meta["finetune"]
    assert record["n_prior"] == AUTO_PRIOR_MAPS
    assert record["n_maps"] == 4
    assert record["prior_basis"]["fingerprint"] == built_in.fingerprint
    source = tuned.meta["source"]
    assert source["with_synthetic"] == AUTO_PRIOR_MAPS
    assert source["with_synthetic_rule"].startswith(f"auto: 4 maps, fewer than {AUTO_MAX_MAPS}")
    # the fit keeps the built-in basis's kernel (sigma, process noise, std scale fitted)
    prior = tuned.meta["prior"]
    assert prior["local"] == built_in.meta["prior"]["local"]
    assert prior["local_fixed"] is True
    assert "local_kept_from" in prior
    assert "fine-tuned       4 maps merged" in text  # learn describes what it wrote
    code, text, _ = run(capsys, "info", out)
    assert code == 0
    assert f"auto: 4 maps, fewer than {AUTO_MAX_MAPS}" in text
    assert "64 px, 40 px^2 (kept)" in text


@pytest.mark.parametrize(("max_maps", "merged"), [(FRAMES, False), (FRAMES + 1, True)])
def test_auto_merges_below_the_threshold_only(
    max_maps: int,
    merged: bool,
    folder: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.setattr(learn_module, "AUTO_MAX_MAPS", max_maps)
    options = jobs.LearnOptions(n_components=3, fit_prior=False, with_synthetic="auto")
    capsys.readouterr()
    basis = jobs.learn([folder / "drive.mcap"], tmp_path / "b.npz", options, PairingConfig())
    printed = capsys.readouterr().out
    assert ("finetune" in basis.meta) is merged
    assert basis.n_train == FRAMES + (AUTO_PRIOR_MAPS if merged else 0)
    assert basis.meta["source"]["with_synthetic"] == (AUTO_PRIOR_MAPS if merged else 0)
    assert ("note:" in printed) is merged  # a long log: nothing to say
    assert "prior" not in basis.meta  # fit_prior=False: no kernel, kept or fitted
    if merged:  # so the note does not say it keeps the built-in basis's kernel
        assert "keeping its local kernel" not in printed
        assert "keeping no local kernel (--no-fit-prior: no fitted prior);" in printed
    if not merged:
        rule = f"auto: {FRAMES} maps, not fewer than {max_maps}"
        assert basis.meta["source"]["with_synthetic_rule"] == rule
        assert basis.image_size == (94, 310)  # the log's own camera
        assert f"synthetic maps   not merged ({rule})" in jobs.describe_basis(tmp_path / "b.npz")


def _square_basis() -> Basis:
    """A basis of a 40x40 px camera: aspect ratio 1, unlike the logs' 3.3."""
    rng = np.random.default_rng(3)
    maps = [rng.normal(20.0, 1.0, size=(10, 10)).astype(np.float32) for _ in range(5)]
    return learn_basis(
        maps, n_components=3, preprocessed=True, image_size=(40, 40), focal_baseline=12.0
    )


def test_auto_does_not_merge_into_the_maps_of_another_camera(
    folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    options = jobs.LearnOptions(
        n_components=3, fit_prior=False, with_synthetic="auto", prior_basis=_square_basis()
    )
    capsys.readouterr()
    basis = jobs.learn([folder / "drive.mcap"], tmp_path / "b.npz", options, PairingConfig())
    notes = [line for line in capsys.readouterr().out.splitlines() if line.startswith("note:")]
    assert len(notes) == 1
    assert "not merging" in notes[0]
    assert "aspect ratio 3.30 against 1.00" in notes[0]
    assert "--with-synthetic N merges them anyway" in notes[0]
    assert "finetune" not in basis.meta
    assert basis.n_train == FRAMES
    assert basis.image_size == (94, 310)
    assert basis.meta["source"]["with_synthetic"] == 0
    assert "the camera differs" in basis.meta["source"]["with_synthetic_rule"]


def test_auto_learns_alone_when_the_built_in_basis_is_missing(
    folder: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.setattr(basis_module, "default_basis_path", lambda: tmp_path / "gone.npz")
    options = jobs.LearnOptions(n_components=3, fit_prior=False, with_synthetic="auto")
    capsys.readouterr()
    basis = jobs.learn([folder / "drive.mcap"], tmp_path / "b.npz", options, PairingConfig())
    assert "note: auto: the built-in basis is not installed" in capsys.readouterr().out
    assert "finetune" not in basis.meta
    assert basis.n_train == FRAMES


@pytest.mark.parametrize(("grid_scale", "merged"), [("0.5", False), ("0.25", True)])
def test_auto_keeps_an_explicit_grid_scale_of_another_grid(
    grid_scale: str,
    merged: bool,
    folder: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    out = tmp_path / "b.npz"
    args = ["learn", folder / "drive.mcap", "-o", out, "--components", "3", "--no-fit-prior"]
    code, text, err = run(capsys, *args, "--grid-scale", grid_scale)
    assert code == 0, err
    assert ("finetune" in Basis.load(out).meta) is merged
    if not merged:
        assert "note: auto: --grid-scale 0.5 asks for another grid" in text
        assert Basis.load(out).grid_size == (47, 155)


def test_learn_holds_out_a_share_of_a_log_that_keeps_no_counts(
    folder: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
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
    assert record["n_prior"] == 200
    assert record["n_maps"] == FRAMES
    assert record["prior_basis"]["fingerprint"] == built_in.fingerprint
    assert record["maps_image_size"] == [94, 310]
    assert tuned.meta["source"]["with_synthetic"] == 200
    assert tuned.meta["source"]["with_synthetic_rule"] == "--with-synthetic 200"
    # the tuned basis densifies the log it was tuned on (mapped onto its camera)
    dense = tmp_path / "dense.mcap"
    assert run(capsys, "densify", folder / "drive.mcap", "-o", dense, "--basis", out)[0] == 0


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--with-synthetic", "1"], "--with-synthetic must be at least 2 maps (0: off; or auto)"),
        (["--with-synthetic", "some"], "--with-synthetic must be at least 2 maps"),
        (["--with-synthetic", "50", "--grid-scale", "0.5"], "drop --grid-scale"),
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


# ------------------------------------------------- learn: the built-in basis of the camera


@pytest.fixture(scope="module")
def indoor_logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Quarter-size indoor logs: a VI-sensor camera (188x120, like the indoor basis's
    752x480) and a depth camera (160x120, like no built-in basis's)."""
    folder = tmp_path_factory.mktemp("indoor")
    logs = {"vi": folder / "room.mcap", "depth": folder / "depthcam.mcap"}
    for log, camera in zip(logs.values(), ("752x480", "640x480"), strict=True):
        jobs.synth(log, frames=FRAMES, seed=4, scale=0.25, fmt=None, scene="indoor", camera=camera)
    return logs


def test_auto_merges_the_indoor_basis_into_few_maps_of_a_vi_sensor_camera(
    indoor_logs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "room.npz"
    options = jobs.LearnOptions(n_components=20, fit_prior=False, with_synthetic="auto")
    capsys.readouterr()
    tuned = jobs.learn([indoor_logs["vi"]], out, options, PairingConfig())
    notes = [line for line in capsys.readouterr().out.splitlines() if line.startswith("note:")]
    assert len(notes) == 1
    assert "merging them with the built-in indoor basis's synthetic statistics" in notes[0]
    assert f"counted as {AUTO_PRIOR_MAPS} maps" in notes[0]
    indoor = Basis.indoor()
    assert tuned.image_size == indoor.image_size  # its camera, not the log's 188x120
    assert tuned.grid_size == indoor.grid_size
    assert tuned.n_train == AUTO_PRIOR_MAPS + FRAMES
    assert tuned.meta["finetune"]["prior_basis"]["fingerprint"] == indoor.fingerprint
    assert tuned.meta["source"]["with_synthetic_basis"] == "built-in-indoor"
    assert "and a camera like the indoor basis's" in tuned.meta["source"]["with_synthetic_rule"]
    said = jobs.describe_basis(out)
    assert f"merged into the built-in indoor basis (fingerprint {indoor.fingerprint}" in said
    assert f"counted as {AUTO_PRIOR_MAPS} maps" in said


def test_with_synthetic_n_merges_the_built_in_basis_of_the_camera(
    indoor_logs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "room.npz"
    args = ["learn", indoor_logs["vi"], "-o", out, "--with-synthetic", "200"]
    code, text, err = run(capsys, *args, "--components", "20", "--no-fit-prior")
    assert code == 0, err
    assert "note: merging your 6 maps with the built-in indoor basis's synthetic rooms" in text
    tuned = Basis.load(out)
    assert tuned.meta["finetune"]["prior_basis"]["fingerprint"] == Basis.indoor().fingerprint
    assert tuned.n_train == 200 + FRAMES


def test_a_camera_like_no_built_in_basis_is_merged_only_when_asked(
    indoor_logs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    options = jobs.LearnOptions(n_components=3, fit_prior=False, with_synthetic="auto")
    capsys.readouterr()
    alone = jobs.learn([indoor_logs["depth"]], tmp_path / "a.npz", options, PairingConfig())
    notes = [line for line in capsys.readouterr().out.splitlines() if line.startswith("note:")]
    assert len(notes) == 1
    assert "not merging the built-in bases' synthetic maps into your 6 maps" in notes[0]
    assert "the street basis's KITTI-like 1241x376 (aspect ratio 1.33 against 3.30)" in notes[0]
    assert "the indoor basis's VI-sensor-like 752x480 (aspect ratio 1.33 against 1.57)" in notes[0]
    assert "finetune" not in alone.meta
    assert alone.image_size == (120, 160)
    # asked for, the closest is merged (the indoor basis: 1.33 is nearer 1.57 than 3.30)
    options = dataclasses.replace(options, with_synthetic=200)
    tuned = jobs.learn([indoor_logs["depth"]], tmp_path / "t.npz", options, PairingConfig())
    assert "the closest (aspect ratio 1.33 against 1.57)" in capsys.readouterr().out
    assert tuned.meta["source"]["with_synthetic_basis"] == "built-in-indoor"
    assert tuned.image_size == Basis.indoor().image_size
