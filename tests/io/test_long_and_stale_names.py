"""Side and temporary names of outputs (bug hunt 9C F3, F4): they fit the file system's name
limit or are refused before any work, and a killed run's temporaries are removed by the next.

An output name the file system takes (<= NAME_MAX bytes, 255 on ext4/xfs/tmpfs) could have
side or temporary names it does not: ``OUT.final.basis.npz`` (a traceback of
``Path.exists``), ``Basis.save``'s ``.NAME.XXXXXXXX.tmp`` (learn learned, then failed),
``golden save``'s ``.NAME.XXXXXXXX``. Those temporaries also had no owner in their name, so
a SIGKILL left them for ever.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pcainterp_stream import cli
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.golden.replacing import replacing_together
from pcainterp_stream.io import output_paths
from pcainterp_stream.pipeline.jobs import synth

DATA = Path(__file__).resolve().parents[1] / "data"


def _limit(folder: Path) -> int:
    return int(os.pathconf(folder, "PC_NAME_MAX"))


def _dead_pid() -> int:
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


def _killed_runs_partial(target: Path, size: int = 1000) -> Path:
    """A partial file of ``target`` as a run killed mid-write left it."""
    prefix = output_paths.partial_prefix(target).replace(f"-{os.getpid()}@", f"-{_dead_pid()}@")
    stale = target.with_name(prefix + "abc12345")
    stale.write_bytes(bytes(size))
    return stale


def _entries(folder: Path) -> list[str]:
    return sorted(os.listdir(folder))


def test_a_basis_saved_under_a_long_name_fits_and_a_killed_saves_temporary_goes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`learn -o <244 bytes>.npz` learned, then "File name too long; choose a writable
    folder": the temporary, 14 bytes longer than the name, did not fit."""
    basis = Basis.load(DATA / "golden_basis.npz")
    target = tmp_path / ("n" * (_limit(tmp_path) - len(".npz") - 4) + ".npz")
    stale = _killed_runs_partial(target, 2_000_000)
    basis.save(target, partial_file=output_paths.make_partial_file)  # as learn and densify
    assert _entries(tmp_path) == [target.name]  # the killed save's temporary removed
    assert "partial output left by an earlier run that was killed (2.0 MB)" in (
        capsys.readouterr().err
    )
    assert not stale.exists()
    np.testing.assert_array_equal(Basis.load(target).mean, basis.mean)
    assert target.stat().st_mode & 0o777 == 0o666 & ~output_paths.process_umask()


def test_a_golden_file_of_a_long_name_is_written(tmp_path: Path) -> None:
    """`golden save -o <252 bytes>` was refused: "the file name is too long" (its
    temporary's, ``.NAME.XXXXXXXX``, was)."""
    target = tmp_path / ("n" * (_limit(tmp_path) - 3) + ".gj")
    with replacing_together(target) as (temporary,):
        assert len(os.fsencode(temporary.name)) <= _limit(tmp_path)
        temporary.write_text("{}\n")
    assert _entries(tmp_path) == [target.name]
    assert target.read_text() == "{}\n"


def test_a_killed_golden_saves_temporaries_are_removed_by_the_next_save(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A SIGKILL mid `golden save --arrays` left ``.g.golden.npz.XXXXXXXX`` (111 MB) and
    ``.g.golden.json.XXXXXXXX``; every later save kept them, silently."""
    golden, arrays = tmp_path / "g.golden.json", tmp_path / "g.golden.npz"
    stale = [_killed_runs_partial(golden), _killed_runs_partial(arrays, 3_000_000)]
    live = golden.with_name(output_paths.partial_prefix(golden) + "def67890")
    live.write_text("a save still going (this process)")
    with replacing_together(arrays, golden) as (npz_tmp, json_tmp):
        json_tmp.write_text("{}\n")
        npz_tmp.write_bytes(b"npz")
    assert not any(path.exists() for path in stale)
    assert live.exists()
    assert _entries(tmp_path) == sorted([golden.name, arrays.name, live.name])
    assert capsys.readouterr().err.count("left by an earlier run that was killed") == 2


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("logs") / "a.mcap"
    synth(path, frames=2, seed=3, scale=0.25, fmt="mcap")
    return path


def test_densify_refuses_an_output_whose_side_basis_name_is_too_long_before_any_work(
    tmp_path: Path, log: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`densify -o <245 bytes>.mcap`: a 20-line traceback of ``Path.exists`` on
    ``STEM.final.basis.npz`` (256 bytes), the basis a run that adapts writes beside it."""
    stem = "n" * (_limit(tmp_path) - len(".final.basis.npz") + 1)
    output = tmp_path / f"{stem}.mcap"
    capsys.readouterr()
    code = cli.main(["densify", str(log), "-o", str(output)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.splitlines() == [
        f"pcainterp: error: cannot write the adapted basis {stem}.final.basis.npz: the file "
        f"name is too long for the file system ({_limit(tmp_path) + 1} bytes, at most "
        f"{_limit(tmp_path)}): choose a shorter name (a run that adapts its basis writes it "
        "beside the output)"
    ]
    assert _entries(tmp_path) == []


@pytest.mark.parametrize(
    "options", [["--basis", "builtin-street"], ["--measurements", "dense"]], ids=["street", "dense"]
)
def test_densify_takes_a_long_output_name_when_the_run_never_adapts(
    tmp_path: Path, log: Path, capsys: pytest.CaptureFixture[str], options: list[str]
) -> None:
    """Review 57b R5: the same 246-250-byte names were refused as "cannot write the adapted
    basis" for runs that never adapt, so never write it (a basis chosen, dense mode)."""
    stem = "n" * (_limit(tmp_path) - len(".final.basis.npz") + 1)
    output = tmp_path / f"{stem}.mcap"
    capsys.readouterr()
    code = cli.main(["densify", str(log), "-o", str(output), *options])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "adapted basis" not in err
    assert output.exists()


def test_a_learned_basis_a_full_disk_refuses_is_saved_in_tmpdir(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Bug hunt 9C F8: `learn -o` on a disk that filled at the end said "cannot write basis
    small/b.npz: No space left on device", no fix, and the basis the run learned was lost."""
    import errno
    import tempfile

    from pcainterp_stream.errors import BasisError

    basis = Basis.load(DATA / "golden_basis.npz")
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    target = tmp_path / "small" / "b.npz"
    target.parent.mkdir()
    real_savez = np.savez

    def full_there(stream: object, **arrays: object) -> None:
        where = os.readlink(f"/proc/self/fd/{stream.fileno()}")  # type: ignore[attr-defined]
        if where.startswith(str(target.parent)):
            raise OSError(errno.ENOSPC, "No space left on device")
        real_savez(stream, **arrays)  # type: ignore[arg-type]

    monkeypatch.setattr(np, "savez", full_there)
    with pytest.raises(BasisError) as caught:
        basis.save(target, partial_file=output_paths.make_partial_file)
    assert isinstance(caught.value.__cause__, OSError)
    assert output_paths.write_advice(caught.value.__cause__) == (
        "free some space, or write it elsewhere"  # learn adds it to the line
    )
    assert _entries(target.parent) == []
    said = output_paths.saved_elsewhere(target, caught.value, basis.save)
    (kept,) = (tmp_path / "tmp").glob("pcainterp-saved-*/b.npz")
    move = f"move it (mv {kept} {target}) once there is room"
    assert said == f"; it was saved to {kept} instead: {move}"
    np.testing.assert_array_equal(Basis.load(kept).mean, basis.mean)
    assert _entries(target.parent) == []
    other = BasisError("cannot write basis b.npz: Permission denied")
    other.__cause__ = OSError(errno.EACCES, "Permission denied")  # kept too (16C F1)
    assert output_paths.saved_elsewhere(target, other, basis.save).endswith("once that is fixed")
    assert len(list((tmp_path / "tmp").iterdir())) == 2
    refused = BasisError("cannot write basis b.npz: it is not a regular file")  # no OSError
    assert output_paths.saved_elsewhere(target, refused, basis.save) == ""
    assert len(list((tmp_path / "tmp").iterdir())) == 2
