"""Output targets: devices, pipes and descriptors refused, links written through."""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

import pytest

from pcainterp_stream.errors import LogWriteError
from pcainterp_stream.io import output_paths
from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.io.output_paths import (
    check_output_file,
    check_output_folder,
    is_standard_output,
    write_advice,
)


def _char_device(path: Path) -> Path:
    """A private copy of /dev/null at ``path`` (root only; the real one is never touched)."""
    try:
        os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except PermissionError:
        pytest.skip("making a device node needs root")
    return path


def test_a_new_file_and_a_regular_file_are_their_own_target(tmp_path: Path) -> None:
    assert check_output_file(tmp_path / "new.mcap") == tmp_path / "new.mcap"
    (tmp_path / "old.mcap").write_bytes(b"x")
    assert check_output_file(tmp_path / "old.mcap") == tmp_path / "old.mcap"


def test_a_fifo_is_refused(tmp_path: Path) -> None:
    fifo = tmp_path / "out.mcap"
    os.mkfifo(fifo)
    with pytest.raises(LogWriteError, match=r"out\.mcap: it is a named pipe \(FIFO\), not a regu"):
        check_output_file(fifo)
    assert stat.S_ISFIFO(fifo.lstat().st_mode)


def test_a_char_device_is_refused_with_the_fix(tmp_path: Path) -> None:
    device = _char_device(tmp_path / "nulldev")
    with pytest.raises(LogWriteError, match=r"it is a character device.*to discard the output"):
        check_output_file(device)
    assert stat.S_ISCHR(device.lstat().st_mode)


def test_a_link_to_a_fifo_is_refused(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "out.mcap").symlink_to("fifo")
    with pytest.raises(LogWriteError, match=r"it links to .*fifo, which is a named pipe"):
        check_output_file(tmp_path / "out.mcap")


def test_a_link_is_written_through(tmp_path: Path) -> None:
    (tmp_path / "real").mkdir()
    link = tmp_path / "out.mcap"
    link.symlink_to(Path("real") / "out.mcap")  # dangling: the file is made
    assert check_output_file(link) == (tmp_path / "real" / "out.mcap").resolve()
    with pytest.raises(LogWriteError, match="it is a symbolic link"):
        check_output_file(link, links=False)


def test_a_link_loop_is_refused(tmp_path: Path) -> None:
    (tmp_path / "a").symlink_to("b")
    (tmp_path / "b").symlink_to("a")
    with pytest.raises(LogWriteError, match="a loop of symbolic links"):
        check_output_file(tmp_path / "a")


def test_descriptors_are_refused_and_standard_output_recognised(tmp_path: Path) -> None:
    mine = tmp_path / "mystdout"
    mine.symlink_to("/proc/self/fd/1")  # what /dev/stdout is, privately
    assert is_standard_output(mine)
    assert is_standard_output(Path("/dev/fd/1"))
    assert not is_standard_output(Path("/dev/fd/2"))
    assert not is_standard_output(tmp_path / "out.mcap")
    with pytest.raises(LogWriteError, match="it is standard output, not a regular file"):
        check_output_file(mine)
    with pytest.raises(LogWriteError, match="it is standard error"):
        check_output_file(Path("/dev/fd/2"))


def test_a_file_in_the_way_is_not_called_missing(tmp_path: Path) -> None:
    (tmp_path / "afile").write_text("x")
    with pytest.raises(LogWriteError, match=r"afile is a file, not a folder; move it"):
        check_output_file(tmp_path / "afile" / "out.mcap")
    with pytest.raises(LogWriteError, match=r"afile is a file, not a folder"):
        check_output_file(tmp_path / "afile" / "sub" / "g.json", creates_folders=True)
    with pytest.raises(LogWriteError, match="does not exist; create it first"):
        check_output_file(tmp_path / "no" / "out.mcap")
    assert check_output_file(tmp_path / "no" / "g.json", creates_folders=True)


def test_an_unwritable_folder_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def read_only(where: Path) -> None:
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(where))

    monkeypatch.setattr(output_paths, "_probe", read_only)
    with pytest.raises(LogWriteError, match="Read-only file system; choose a writable folder"):
        check_output_file(tmp_path / "b.npz")
    with pytest.raises(LogWriteError, match=r"into .*Read-only file system; choose a writable"):
        check_output_folder(tmp_path / "out")


def test_output_folders(tmp_path: Path) -> None:
    check_output_folder(tmp_path / "new" / "deeper")  # made by the writer
    (tmp_path / "afile").write_text("x")
    with pytest.raises(LogWriteError, match="afile: it is a file, not a folder; pass a folder"):
        check_output_folder(tmp_path / "afile")
    with pytest.raises(LogWriteError, match=r"sub: .*afile is a file, not a folder"):
        check_output_folder(tmp_path / "afile" / "sub")


def test_write_advice_fits_the_error() -> None:
    assert "free some space" in write_advice(OSError(errno.ENOSPC, "full"))
    assert write_advice(OSError(errno.EROFS, "ro")) == "choose a writable folder"
    assert "free some space" not in write_advice(OSError(errno.EEXIST, "exists"))
    assert "a file is in the way" in write_advice(OSError(errno.ENOTDIR, "not a dir"))


def test_open_writer_refuses_a_fifo_before_writing(tmp_path: Path) -> None:
    fifo = tmp_path / "out.mcap"
    os.mkfifo(fifo)
    with pytest.raises(LogWriteError, match="named pipe"):
        open_writer(fifo, "mcap")
    assert stat.S_ISFIFO(fifo.lstat().st_mode)
    assert [p.name for p in tmp_path.iterdir()] == ["out.mcap"]


def test_open_writer_writes_through_a_link(tmp_path: Path) -> None:
    (tmp_path / "real").mkdir()
    link = tmp_path / "out.mcap"
    link.symlink_to(Path("real") / "out.mcap")
    with open_writer(link, "mcap"):
        pass  # an empty log is enough
    assert link.is_symlink()
    assert (tmp_path / "real" / "out.mcap").stat().st_size > 0


def _dead_pid() -> int:
    import subprocess
    import sys

    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


def _named(target: Path, pid: int, suffix: str, host: str | None = None) -> Path:
    prefix = output_paths.partial_prefix(target).replace(f"-{os.getpid()}@", f"-{pid}@")
    if host is not None:
        prefix = prefix.replace(f"@{output_paths._host()}-", f"@{host}-")
    return target.with_name(prefix + suffix)


def test_a_killed_runs_partial_output_is_removed_when_the_target_is_written_again(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """After a SIGKILL the hidden partial output stayed, and every later run kept quiet.

    Now the next writer of the same target removes it (one line, its size); the partial
    output of a run still going, of another machine, or of another target is never touched.
    """
    target = tmp_path / "out.mcap"
    dead = _dead_pid()
    stale = _named(target, dead, "abc12345")
    stale.mkdir()
    (stale / "out.mcap").write_bytes(bytes(9_000_000))
    live = _named(target, os.getppid(), "def67890")
    live.mkdir()
    elsewhere = _named(target, dead, "ghi13579", host="another_machine")
    elsewhere.mkdir()
    other_target = _named(tmp_path / "other.mcap", dead, "jkl24680")
    other_target.mkdir()
    assert stale.name.startswith(".out.mcap.partial-")
    with open_writer(target, "mcap") as writer:
        assert writer.partial_path.parent.name.startswith(output_paths.partial_prefix(target))
    assert not stale.exists()
    assert live.is_dir() and elsewhere.is_dir() and other_target.is_dir()
    err = capsys.readouterr().err
    assert err.strip() == (
        f"note: removed {target}'s partial output left by an earlier run that was killed (9.0 MB)"
    )
    with open_writer(target, "mcap"):
        pass
    assert capsys.readouterr().err == ""  # said once
