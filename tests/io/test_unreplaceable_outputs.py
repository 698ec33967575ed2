"""Outputs the machine refuses late: a file that cannot be replaced, a folder removed, a
file-size limit, a closed standard stream (bug hunt 16C F1, F3, F4, F6, F7, F9)."""

from __future__ import annotations

import errno
import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from pcainterp_stream.errors import GoldenError, LogWriteError
from pcainterp_stream.golden import save_golden
from pcainterp_stream.io import mount_points, output_paths
from pcainterp_stream.io.logwriter import open_writer, write_failed
from pcainterp_stream.io.output_paths import (
    check_output_file,
    full_disk_advice,
    partial_prefix,
    saved_elsewhere,
    write_advice,
)
from pcainterp_stream.pipeline.jobs import synth

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("logs") / "a.mcap"
    synth(path, frames=2, seed=3, scale=0.25, fmt="mcap")
    return path


def _md5(path: Path) -> str:
    return hashlib.md5(path.read_bytes()).hexdigest()


def _chattr(flag: str, path: Path) -> None:
    if shutil.which("chattr") is None:
        pytest.skip("no chattr here")
    done = subprocess.run(["chattr", flag, str(path)], capture_output=True, check=False)
    if done.returncode != 0:
        pytest.skip(f"chattr {flag} refused here (not root, or no such flags on this disk)")


def test_an_immutable_output_is_refused_before_any_work(tmp_path: Path) -> None:
    """16C F1: `densify -o keep.mcap` over an immutable file densified the whole log, then
    said "cannot move the finished output onto keep.mcap: Operation not permitted; check
    the folder's permissions" (the folder was writable)."""
    old = tmp_path / "keep.mcap"
    old.write_bytes(b"an earlier output")
    _chattr("+i", old)
    try:
        with pytest.raises(LogWriteError) as raised:
            check_output_file(old)
    finally:
        subprocess.run(["chattr", "-i", str(old)], check=False)
    assert str(raised.value) == (
        f"cannot replace {old}: it is immutable (chattr +i; lsattr shows it): remove the "
        "flag (chattr -i, as root), or choose another name"
    )


def test_another_users_file_in_a_sticky_folder_is_refused_up_front(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """16C F1: in a shared folder with the sticky bit (as /tmp) a colleague's file cannot
    be replaced; every up-front check passed and the job failed at its end."""
    folder = tmp_path / "shared"
    folder.mkdir()
    theirs = folder / "b.npz"
    theirs.write_bytes(b"a colleague's basis")
    folder.chmod(0o1777)
    monkeypatch.setattr(os, "geteuid", lambda: 4242, raising=False)  # not the owner, nor root
    with pytest.raises(LogWriteError) as raised:
        check_output_file(theirs)
    said = str(raised.value)
    assert said.startswith(f"cannot replace {theirs}: it belongs to user ")
    assert f"its folder {folder} is shared with the sticky bit" in said
    assert said.endswith("ask them to remove it, or choose another name")
    assert check_output_file(folder / "new.npz") == folder / "new.npz"  # a new name is fine
    mine = folder / "mine.npz"
    mine.write_bytes(b"ours")
    monkeypatch.setattr(os, "geteuid", lambda: mine.stat().st_uid, raising=False)
    assert check_output_file(mine) == mine  # our own file there is replaced as usual


def test_a_file_mounted_at_the_output_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """16C F1: a file bind-mounted at the output ("Device or resource busy; check the
    folder's permissions", after the whole run)."""
    target = tmp_path / "keep.mcap"
    target.write_bytes(b"x")
    monkeypatch.setattr(mount_points, "_mount_points", lambda: {os.path.realpath(target)})
    mounts = {os.path.realpath(target): 2, os.path.realpath(tmp_path): 1}
    monkeypatch.setattr(mount_points, "_mount_id", mounts.get)
    with pytest.raises(LogWriteError, match="a file system or file is mounted at it"):
        check_output_file(target)


def test_a_mount_listed_at_the_output_but_hidden_under_a_later_one_is_not_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Review 16a R1: a file bind-mounted at t/sub/f.mcap, then a mount on t/sub, is still
    listed in mountinfo; the t/sub/f.mcap one sees is a plain file there (`mv` onto it works)."""
    target = tmp_path / "f.mcap"
    target.write_bytes(b"x")
    monkeypatch.setattr(mount_points, "_mount_points", lambda: {os.path.realpath(target)})
    assert check_output_file(target) == target  # the same mount id as its folder: replaced
    # unreadable ids: the listing is trusted, as before
    monkeypatch.setattr(mount_points, "_mount_id", lambda path: None)
    with pytest.raises(LogWriteError, match="a file system or file is mounted at it"):
        check_output_file(target)


@pytest.mark.skipif(
    not sys.platform.startswith("linux") or os.geteuid() != 0, reason="mounts need root"
)
def test_a_real_bind_mount_and_a_shadowed_one(tmp_path: Path) -> None:
    """Review 16a R1 as the reviewer made it: the mounts themselves (skipped where denied)."""
    source, folder = tmp_path / "src.mcap", tmp_path / "t"
    source.write_bytes(b"src")
    folder.mkdir()
    bound = folder / "b.mcap"
    bound.write_bytes(b"x")
    if subprocess.run(["mount", "--bind", str(source), str(bound)], check=False).returncode:
        pytest.skip("mount is denied here")
    shadow = folder / "sub"
    try:
        with pytest.raises(LogWriteError, match="a file system or file is mounted at it"):
            check_output_file(bound)
        shadow.mkdir()
        (shadow / "f.mcap").write_bytes(b"x")
        subprocess.run(["mount", "--bind", str(source), str(shadow / "f.mcap")], check=True)
        subprocess.run(["mount", "-t", "tmpfs", "tmpfs", str(shadow)], check=True)
        (shadow / "f.mcap").write_bytes(b"plain")
        assert check_output_file(shadow / "f.mcap") == shadow / "f.mcap"
    finally:
        for point in (shadow, shadow / "f.mcap", bound):
            subprocess.run(["umount", str(point)], check=False, capture_output=True)


def test_the_advice_for_a_failed_rename_names_the_real_cause(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """16C F1, F6, F7: EPERM on the rename, a folder removed (ENOENT) and a file-size limit
    (EFBIG) all got "choose a writable folder" (or no fix at all)."""
    target = tmp_path / "b.npz"
    target.write_bytes(b"x")
    monkeypatch.setattr(output_paths, "_inode_flag", lambda path: "immutable")
    refused = OSError(
        errno.EPERM, "Operation not permitted", str(tmp_path / ".t"), None, str(target)
    )
    assert write_advice(refused).startswith("it is immutable")
    gone = tmp_path / "gl"
    missing = OSError(errno.ENOENT, "No such file or directory", str(gone / ".b.npz.partial-x"))
    assert write_advice(missing) == (
        f"folder {gone} no longer exists (removed meanwhile): make it again, or write it elsewhere"
    )
    big = OSError(errno.EFBIG, "File too large")
    assert "a limit (ulimit -f)" in write_advice(big)
    assert "a limit (ulimit -f)" in full_disk_advice(big)
    said = str(write_failed(tmp_path / "o.mcap", big))  # densify, synth
    assert said.endswith("or raise the limit")
    assert "nothing was written there" in said


@pytest.mark.skipif(sys.version_info < (3, 11), reason="sqlite_errorname is Python 3.11's")
def test_a_sqlite_read_error_is_not_put_down_to_a_file_size_limit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Review 16a R4: any "disk I/O error" was blamed on a set ulimit -f, whatever its cause."""
    import sqlite3

    monkeypatch.setattr(output_paths, "_file_size_limit", lambda: 100 * 10**9)  # a batch cap
    # a real read failure: /proc/self/mem reads as EIO at offset 0, as a failing disk does
    with pytest.raises(sqlite3.OperationalError) as caught:
        sqlite3.connect("file:/proc/self/mem?immutable=1", uri=True).execute(
            "SELECT * FROM sqlite_master"
        ).fetchall()
    assert "disk I/O error" in str(caught.value)
    said = str(write_failed(tmp_path / "bag", caught.value))
    assert "file-size limit" not in said
    assert "ulimit" not in said
    assert "could not read or sync the file back (a failing disk or file system, or a " in said
    # a write refused (what a limit causes) still names the limit
    refused = sqlite3.OperationalError("disk I/O error")
    refused.sqlite_errorname = "SQLITE_IOERR_WRITE"  # type: ignore[attr-defined]
    assert "likely the file-size limit: this process may write at most 100000.0 MB" in str(
        write_failed(tmp_path / "bag", refused)
    )
    # review 17b R7: in WAL mode a limit stops the shared-memory file growing
    refused.sqlite_errorname = "SQLITE_IOERR_SHMSIZE"  # type: ignore[attr-defined]
    assert "likely the file-size limit" in str(write_failed(tmp_path / "bag", refused))


@pytest.mark.parametrize("cause", ["EPERM", "ENOENT"])
def test_a_basis_that_cannot_be_written_is_kept_in_the_temporary_folder(
    tmp_path: Path, cause: str
) -> None:
    """16C F1, F6: `learn` dropped the basis it learned for any failure but a full disk."""
    folder = tmp_path / "gl"
    if cause == "EPERM":
        folder.mkdir()
    target = folder / "b.npz"
    error = OSError(getattr(errno, cause), os.strerror(getattr(errno, cause)))
    said = saved_elsewhere(target, error, lambda path: path.write_bytes(b"basis"))
    kept = Path(said.split("saved to ")[1].split(" instead")[0])
    try:
        assert kept.read_bytes() == b"basis"
        if cause == "EPERM":
            assert said.endswith(f"move it (mv {kept} {target}) once that is fixed")
        else:
            assert said.endswith(f"move it (mkdir -p {folder} && mv {kept} {target})")
    finally:
        shutil.rmtree(kept.parent)


def test_a_failed_golden_save_leaves_the_old_pair_whole(
    log: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """16C F9: the arrays were renamed into place before the JSON; when the JSON's rename
    failed the old JSON was left beside the new arrays, and `golden check` of the log it
    was made from failed."""
    golden = tmp_path / "g.golden.json"
    save_golden(log, golden, arrays=True)
    arrays = golden.with_suffix(".npz")
    before = {path.name: _md5(path) for path in (golden, arrays)}
    other = tmp_path / "b.mcap"
    synth(other, frames=3, seed=5, scale=0.25, fmt="mcap")
    real = os.replace

    def replace(source: object, target: object) -> None:
        if Path(str(target)) == golden:
            raise OSError(errno.EPERM, "Operation not permitted", str(source), None, str(target))
        real(source, target)  # type: ignore[arg-type]

    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(GoldenError, match=f"cannot write {golden}"):
        save_golden(other, golden, arrays=True)
    monkeypatch.undo()
    assert {path.name: _md5(path) for path in (golden, arrays)} == before
    assert sorted(os.listdir(tmp_path)) == ["b.mcap", golden.name, arrays.name]


def test_a_new_golden_pair_that_fails_leaves_nothing(
    log: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    golden = tmp_path / "g.golden.json"
    real = os.replace

    def replace(source: object, target: object) -> None:
        if Path(str(target)) == golden:
            raise OSError(errno.ENOSPC, "No space left on device")
        real(source, target)  # type: ignore[arg-type]

    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(GoldenError, match="free some space"):
        save_golden(log, golden, arrays=True)
    assert os.listdir(tmp_path) == []


def test_an_out_dir_removed_mid_run_is_named_not_its_staging_folder(tmp_path: Path) -> None:
    """16C F4: "cannot write DIR/.b_dense.mcap.partial-OWNER-XXXX/b_dense.mcap: folder
    DIR/.b_dense.mcap.partial-OWNER-XXXX no longer exists"."""
    out_dir = tmp_path / "dd"
    out = out_dir / "b_dense.mcap"
    staged = out_dir / (partial_prefix(out, out_dir) + "b2o_zvl0") / out.name
    staged.parent.mkdir(parents=True)
    with pytest.raises(LogWriteError) as raised, open_writer(staged):
        shutil.rmtree(out_dir)  # the close, then the rename, find no folder
    assert str(raised.value) == (
        f"cannot write {out}: folder {out_dir} no longer exists (removed while the output "
        "was being written); nothing was written"
    )


def _cli(args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    environment = {**os.environ, "PYTHONPATH": str(ROOT)}
    command = f"{sys.executable} -m pcainterp_stream.cli {args}"
    return subprocess.run(
        ["bash", "-c", command], cwd=cwd, env=environment, capture_output=True, text=True
    )


def test_a_closed_standard_output_or_input_is_one_line(log: Path, tmp_path: Path) -> None:
    """16C F3: `densify X -o - >&-` and `densify - -o X <&-` were tracebacks
    ('NoneType' object has no attribute 'isatty' / 'buffer')."""
    done = _cli(f"densify {log} -o - >&-", tmp_path)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines()[-1] == (
        "pcainterp: error: -o -: standard output is closed; redirect it to a file "
        "(-o - > out.mcap) or use -o FILE"
    )
    done = _cli(f"densify - -o {tmp_path / 'x.mcap'} <&-", tmp_path)
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines()[-1] == (
        "pcainterp: error: densify -: standard input is closed; pipe a log into it "
        "(densify - < log.mcap) or name the log"
    )
    assert os.listdir(tmp_path) == []


def test_the_rrd_exit_status_is_documented(capsys: pytest.CaptureFixture[str]) -> None:
    """16C F8: a `--rrd` that failed mid-run is a warning and exit 0; neither `--help` nor
    docs/viewing.md said so (a script `densify ... --rrd x.rrd && upload x.rrd`)."""
    from pcainterp_stream import cli

    with pytest.raises(SystemExit):
        cli.main(["densify", "--help"])
    shown = " ".join(capsys.readouterr().out.split())
    assert "is a warning and the exit status stays 0 with the MCAP written" in shown
    viewing = " ".join((ROOT / "docs" / "viewing.md").read_text().split())
    assert "The exit status then stays 0" in viewing
