"""Output targets: devices, pipes and descriptors refused, links written through."""

from __future__ import annotations

import errno
import os
import shutil
import stat
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
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
        prefix = prefix.replace(f"@{output_paths._host()}~", f"@{host}~")
        assert f"@{host}~" in prefix
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
    assert live.is_dir()
    assert elsewhere.is_dir()
    assert other_target.is_dir()
    err = capsys.readouterr().err
    assert err.strip() == (
        f"note: removed {target}'s partial output left by an earlier run that was killed (9.0 MB)"
    )
    with open_writer(target, "mcap"):
        pass
    assert capsys.readouterr().err == ""  # said once


@pytest.fixture
def pid_namespace(monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[[str | None], None]]:
    """Make this process look as if in PID namespace NS (None: unknown)."""

    def enter(namespace: str | None) -> None:
        monkeypatch.setattr(output_paths, "_pid_namespace", lambda: namespace, raising=False)
        output_paths._scope.cache_clear()

    yield enter
    monkeypatch.undo()
    output_paths._scope.cache_clear()


def test_a_live_writer_in_another_pid_namespace_keeps_its_partial(
    tmp_path: Path,
    pid_namespace: Callable[[str | None], None],
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Review 55b R55b-1: a container sharing the host's name (docker --net=host) saw the
    host's live writer's process id as dead and removed its partial output.

    A writer in namespace 111 whose id is not a process here (as another namespace's live
    one is not) keeps its partial; the same partial in this run's namespace is removed."""
    target = tmp_path / "out.mcap"
    dead = _dead_pid()
    pid_namespace("111")
    theirs = _named(target, dead, "abc12345")
    theirs.mkdir()
    pid_namespace("222")
    assert theirs.name != _named(target, dead, "abc12345").name  # the namespace is named
    with open_writer(target, "mcap"):
        pass
    assert theirs.is_dir()
    assert capsys.readouterr().err == ""
    pid_namespace("111")  # back in its namespace: the writer is dead there
    with open_writer(target, "mcap"):
        pass
    assert not theirs.exists()
    assert "partial output left by an earlier run that was killed" in capsys.readouterr().err


def test_where_the_pid_namespace_is_unknown_no_partial_is_removed(
    tmp_path: Path, pid_namespace: Callable[[str | None], None]
) -> None:
    """No /proc (a sandbox): a process id cannot be told dead, so nothing is removed."""
    target = tmp_path / "out.mcap"
    pid_namespace(None)
    stale = _named(target, _dead_pid(), "abc12345")
    assert "~unknown-" in stale.name
    stale.mkdir()
    with open_writer(target, "mcap"):
        pass
    assert stale.is_dir()


def test_a_partial_named_without_its_namespace_is_kept(tmp_path: Path) -> None:
    """A partial of the naming before (``PID@HOST-``) cannot say its namespace: kept."""
    target = tmp_path / "out.mcap"
    old = target.with_name(f".out.mcap.partial-{_dead_pid()}@{output_paths._host()}-abc12345")
    old.mkdir()
    with open_writer(target, "mcap"):
        pass
    assert old.is_dir()


def test_the_scope_is_this_boot_and_pid_namespace() -> None:
    import hashlib

    if not Path("/proc/self/ns/pid").exists():
        pytest.skip("no /proc here")
    boot = Path("/proc/sys/kernel/random/boot_id").read_text().replace("-", "").strip()
    namespace = os.stat("/proc/self/ns/pid").st_ino
    scope = hashlib.sha256(f"{boot[:12]}.{namespace}".encode()).hexdigest()[:8]
    owner = f"{os.getpid()}@{output_paths._host()}~{scope}-"
    assert output_paths.partial_prefix(Path("x.mcap")) == f".x.mcap.partial-{owner}"
    assert output_paths.temporary_prefix("pcainterp-rrd") == f"pcainterp-rrd-{owner}"


def test_a_long_output_name_is_written_its_partial_named_short(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Review 55c R55c-2: the owner's scope made partial names ~24 characters longer, so a
    208-character output name (one a 40-character host's run took before) failed with
    "File name too long; choose a writable folder". The scope is 8 hex digits, and the
    target's part of a partial's name is shortened where the whole would be too long."""
    monkeypatch.setattr(output_paths, "_host", lambda: "h" * 40)  # the longest kept
    limit = os.pathconf(tmp_path, "PC_NAME_MAX")
    for length in (208, limit - len(".mcap")):
        target = tmp_path / ("n" * length + ".mcap")
        prefix = output_paths.partial_prefix(target)
        assert len(prefix) + 8 <= limit - 3  # a 10-digit process id fits too
        with open_writer(target, "mcap"):
            pass
        assert target.is_file()
        stale = _named(target, _dead_pid(), "abc12345")  # a killed run's, named the same way
        stale.mkdir()
        with open_writer(target, "mcap"):
            pass
        assert not stale.exists()
        assert "partial output left by an earlier run that was killed" in capsys.readouterr().err
    short = output_paths.partial_prefix(tmp_path / ("n" * 250 + ".mcap"))
    other = output_paths.partial_prefix(tmp_path / ("n" * 250 + ".bag"))
    assert short != other  # the whole name's hash tells two names of one start apart
    assert output_paths.partial_prefix(tmp_path / "a.mcap").startswith(".a.mcap.partial-")


def test_a_name_too_long_for_the_file_system_says_so(tmp_path: Path) -> None:
    """ENAMETOOLONG was "choose a writable folder"; the name, not the folder, is the cause."""
    advice = "the file name is too long for the file system: choose a shorter name"
    assert write_advice(OSError(errno.ENAMETOOLONG, "File name too long")) == advice
    limit = os.pathconf(tmp_path, "PC_NAME_MAX")
    name = "n" * (limit + 1)
    with pytest.raises(LogWriteError) as caught:
        check_output_file(tmp_path / name)
    assert str(caught.value) == (
        f"cannot write {tmp_path / name}: the file name is too long for the file system "
        f"({limit + 1} bytes, at most {limit}): choose a shorter name"
    )


def test_a_umask_of_0_is_read_from_proc_not_set_at_import() -> None:
    """Review 55c R55c-3: a umask of 0 read from /proc was taken as none read, and the umask
    was set and restored at import."""
    if output_paths._umask_of_status() is None:
        pytest.skip("no Umask: in /proc/self/status here")
    code = (
        "import os\n"
        "os.umask(0)\n"
        "calls = []\n"
        "real = os.umask\n"
        "os.umask = lambda mask: calls.append(mask) or real(mask)\n"
        "from pcainterp_stream.io import output_paths\n"
        "assert output_paths._START_UMASK == 0, output_paths._START_UMASK\n"
        "assert calls == [], calls\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=Path(__file__).parent)


_LIVE_WRITER = """
import sys
import time
from pathlib import Path
from pcainterp_stream.io.logwriter import open_writer
with open_writer(Path(sys.argv[1]), "mcap"):
    print("open", flush=True)
    sys.stdin.readline()
"""


def test_a_live_writer_of_the_host_survives_a_run_in_a_pid_namespace(tmp_path: Path) -> None:
    """R55b-1 as the review reproduced it: ``unshare -p -f --mount-proc`` (root only)."""
    unshare = shutil.which("unshare")
    if unshare is None:
        pytest.skip("no unshare")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    probe = subprocess.run(
        [unshare, "-p", "-f", "--mount-proc", "true"], capture_output=True, check=False
    )
    if probe.returncode != 0:
        pytest.skip("unshare -p needs privileges")
    target = tmp_path / "out.mcap"
    with subprocess.Popen(
        [sys.executable, "-c", _LIVE_WRITER, str(target)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    ) as writer:
        assert writer.stdout is not None
        assert writer.stdin is not None
        try:
            assert writer.stdout.readline() == "open\n"
            (partial,) = tmp_path.iterdir()
            command = [unshare, "-p", "-f", "--mount-proc", sys.executable, "-c", _LIVE_WRITER]
            other = subprocess.run(
                [*command, str(target)],
                input="\n",
                capture_output=True,
                text=True,
                env=env,
                check=False,
                timeout=120,
            )
            assert other.returncode == 0, other.stderr
            assert "removed" not in other.stderr
            assert partial.is_dir()  # the live writer's, kept
            writer.stdin.write("\n")
            writer.stdin.flush()
            assert writer.wait(timeout=120) == 0
        finally:
            writer.kill()
    assert [p.name for p in tmp_path.iterdir()] == ["out.mcap"]


def test_the_umask_is_read_without_being_changed(monkeypatch: pytest.MonkeyPatch) -> None:
    """Review 55b R55b-5: setting the umask to 0 for a moment gave other threads' files
    mode 0666; it is read from /proc (or, with threads running, taken from the start)."""
    previous = os.umask(0o027)
    try:
        if Path("/proc/self/status").exists():
            monkeypatch.setattr(os, "umask", _no_umask_change)
            assert output_paths.process_umask() == 0o027
        monkeypatch.setattr(output_paths, "_umask_of_status", lambda: None)
        monkeypatch.setattr(output_paths, "_START_UMASK", 0o002)
        monkeypatch.setattr(output_paths.threading, "active_count", lambda: 3)
        monkeypatch.setattr(os, "umask", _no_umask_change)
        assert output_paths.process_umask() == 0o002  # threads: the umask at import
        monkeypatch.undo()
        monkeypatch.setattr(output_paths, "_umask_of_status", lambda: None)
        # (a pytest-xdist worker runs threads of its own: say there is one)
        monkeypatch.setattr(output_paths.threading, "active_count", lambda: 1)
        assert output_paths.process_umask() == 0o027  # one thread: set and restored
        assert os.umask(0o027) == 0o027
    finally:
        os.umask(previous)


def _no_umask_change(mask: int) -> int:
    raise AssertionError(f"os.umask({mask:#o}) while threads may be making files")


def test_a_name_too_long_to_be_looked_at_is_not_a_traceback(tmp_path: Path) -> None:
    """A look at a name over the limit (is it /dev/stdout? the input?) raised ENAMETOOLONG."""
    target = tmp_path / ("n" * (os.pathconf(tmp_path, "PC_NAME_MAX") + 1))
    assert not is_standard_output(target)
    output_paths.check_not_input(target, [tmp_path / "in.mcap"])


def test_a_killed_process_not_yet_reaped_is_dead() -> None:
    """A SIGKILLed writer whose parent has not reaped it yet is a zombie: kill(pid, 0) finds
    it, but it writes nothing more, so its partial output is stale (seen 0.5 s after a kill
    of `cat LOG | pcainterp densify - ...`)."""
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:  # ended, not reaped: Popen.wait not called
        with open(f"/proc/{child.pid}/stat", "rb") as file:
            if file.read().rpartition(b")")[2].split()[0] == b"Z":
                break
        time.sleep(0.02)
    try:
        assert not output_paths.process_alive(child.pid)
        assert output_paths.process_alive(os.getpid())
    finally:
        child.wait()


def test_a_target_inside_an_input_bag_is_refused_a_plain_folder_not(tmp_path: Path) -> None:
    """A rosbag2 bag is a folder whose metadata.yaml lists its files: writing into it replaced
    the storage file (bug hunt 15B F1). Another input folder (a KITTI drive) is no bag."""
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    storage = bag / "bag_0.mcap"
    storage.write_bytes(b"")
    for source in (bag, storage):
        with pytest.raises(LogWriteError, match=r"inside the input bag .*bag: it would replace"):
            output_paths.check_not_input(bag / "new.mcap", [source])
        assert output_paths.input_bag(bag / "new.mcap", source) == bag
    assert output_paths.input_bag(tmp_path / "beside.mcap", bag) is None
    drive = tmp_path / "drive"
    drive.mkdir()
    output_paths.check_not_input(drive / "out.mcap", [drive])
    assert output_paths.input_bag(drive / "out.mcap", drive) is None
