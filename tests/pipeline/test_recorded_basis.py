"""Review 58a R1 / R2: how a densified log records its basis file, and how evaluate finds it.

densify records the path relative to the output's folder (the bytes do not depend on how
the paths were spelled nor on the working folder); evaluate looks there (from any working
folder), then beside the log, then in the working folder; a file of that name with another
fingerprint is "another basis", not "changed", unless it is at the recorded place.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from pcainterp_stream import cli
from pcainterp_stream.estimate.basis import Basis, default_basis_path
from pcainterp_stream.io.outputs import BASIS_FINGERPRINT_KEY, BASIS_KEY, recorded_metadata
from pcainterp_stream.pipeline import densify as densify_module
from pcainterp_stream.pipeline.jobs import evaluation_basis

DATA = Path(__file__).resolve().parents[1] / "data"


@pytest.fixture
def proj(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """``proj/in.mcap``, ``proj/bases/my.npz``, ``proj/out/``; the working folder is ``proj``."""
    proj = tmp_path / "proj"
    (proj / "bases").mkdir(parents=True)
    (proj / "out").mkdir()
    shutil.copy(DATA / "golden_synth.mcap", proj / "in.mcap")
    shutil.copy(DATA / "golden_basis.npz", proj / "bases" / "my.npz")
    monkeypatch.chdir(proj)
    return proj


def _densify(log: str | Path, output: str | Path, basis: str | Path) -> None:
    assert cli.main(["densify", str(log), "-o", str(output), "--basis", str(basis)]) == 0


def test_the_recorded_basis_is_relative_to_the_outputs_folder(
    proj: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    for name in "abc":
        (proj / "out" / name).mkdir()
    _densify("in.mcap", "out/a/d.mcap", "bases/my.npz")  # as typed from the project
    _densify(proj / "in.mcap", proj / "out" / "b" / "d.mcap", proj / "bases" / "my.npz")
    monkeypatch.chdir(proj / "bases")
    _densify("../in.mcap", "../out/c/d.mcap", "my.npz")  # from another folder
    recorded = recorded_metadata(proj / "out" / "a" / "d.mcap")
    assert recorded[BASIS_KEY] == "../../bases/my.npz"
    assert recorded[BASIS_FINGERPRINT_KEY] == Basis.load(proj / "bases" / "my.npz").fingerprint
    written = {(proj / "out" / x / "d.mcap").read_bytes() for x in "abc"}
    assert len(written) == 1  # bug hunt 10A F6: the same bytes however it was spelled
    assert str(proj) not in (proj / "out" / "a" / "d.mcap").read_bytes().decode("latin-1")


def test_a_basis_beside_the_output_is_recorded_by_its_name(proj: Path) -> None:
    shutil.copy(proj / "bases" / "my.npz", proj / "out" / "my.npz")
    _densify("in.mcap", "out/d.mcap", "out/my.npz")
    assert recorded_metadata(proj / "out" / "d.mcap")[BASIS_KEY] == "my.npz"


def test_evaluate_finds_the_basis_from_the_same_and_from_another_folder(
    proj: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _densify("in.mcap", "out/d.mcap", "bases/my.npz")
    chosen, note = evaluation_basis(Path("out/d.mcap"))
    assert chosen == Path("bases/my.npz"), note
    assert note == "bases/my.npz (recorded in the log)"
    # the review's repro: the rows that re-densify with the basis are there
    args = ["evaluate", "out/d.mcap", "-o", "out/rep", "--sweep-every", "0", "--max-frames", "2"]
    assert cli.main(args) == 0
    methods = json.loads((proj / "out" / "rep" / "results.json").read_text())["methods"]
    assert "oracle" in methods
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    chosen, note = evaluation_basis(proj / "out" / "d.mcap")
    assert isinstance(chosen, Path), note
    assert chosen.resolve() == (proj / "bases" / "my.npz").resolve()


def test_another_file_of_the_name_is_another_basis_not_a_changed_one(
    proj: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _densify("in.mcap", "out/d.mcap", "out/../bases/my.npz")
    other = tmp_path / "other"
    other.mkdir()
    shutil.copy(default_basis_path(), other / "my.npz")  # a basis of another content
    (proj / "bases" / "my.npz").rename(proj / "bases" / "away.npz")
    monkeypatch.chdir(other)
    chosen, note = evaluation_basis(proj / "out" / "d.mcap")
    assert chosen is None
    assert "./my.npz is another basis of that name (fingerprint" in note
    assert "changed" not in note
    assert "--basis" in note
    # the file at the recorded place with another content: that one did change
    shutil.copy(default_basis_path(), proj / "bases" / "my.npz")
    chosen, note = evaluation_basis(proj / "out" / "d.mcap")
    assert chosen is None
    assert f"{proj / 'bases' / 'my.npz'} changed since the log was densified" in note
    # and a right one beside the log is found though a wrong one is at the recorded place
    shutil.copy(proj / "bases" / "away.npz", proj / "out" / "my.npz")
    chosen, note = evaluation_basis(proj / "out" / "d.mcap")
    assert chosen == proj / "out" / "my.npz", note


def test_a_missing_basis_note_says_where_evaluate_looked(proj: Path) -> None:
    _densify("in.mcap", "out/d.mcap", "bases/my.npz")
    (proj / "bases" / "my.npz").unlink()
    chosen, note = evaluation_basis(Path("out/d.mcap"))
    assert chosen is None
    assert "densified with ../bases/my.npz, fingerprint" in note
    assert "not found at bases/my.npz, nor as my.npz beside the log or in the working folder" in (
        note
    )


@pytest.mark.parametrize("older", ["absolute", "as typed", "name"])
def test_older_records_are_still_found(
    proj: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, older: str
) -> None:
    """Older versions recorded the path as densify was given it, then the file's name."""
    label = {"absolute": str(proj / "bases" / "my.npz"), "as typed": "bases/my.npz"}
    monkeypatch.setattr(
        densify_module, "basis_label", lambda basis, output: label.get(older, basis.name)
    )
    _densify("in.mcap", "out/d.mcap", "bases/my.npz")
    if older == "name":  # found in the working folder
        shutil.copy(proj / "bases" / "my.npz", proj / "my.npz")
    chosen, note = evaluation_basis(Path("out/d.mcap"))
    assert isinstance(chosen, Path), note
    assert chosen.resolve() == Path("my.npz" if older == "name" else "bases/my.npz").resolve()
