"""Where the commands write: devices, pipes, links and folders in the way as outputs, and a
standard output that cannot be written.

Every refusal is one line (exit 2) before any work, and leaves the target as it was. A
device node is made in ``tmp_path`` (root only), never the real ``/dev/null``; standard
output is reached through a private link to ``/proc/self/fd/1``, never ``/dev/stdout``.
"""

from __future__ import annotations

import dataclasses
import errno
import os
import stat
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from pcainterp_stream import cli
from pcainterp_stream.errors import PcaInterpError
from pcainterp_stream.io import output_paths
from pcainterp_stream.pipeline.jobs import synth


@dataclasses.dataclass
class Run:
    code: int
    out: str
    err: str

    def error_line(self) -> str:
        assert self.code == 2, f"expected exit 2, got {self.code}; stderr: {self.err}"
        assert "Traceback" not in self.err
        lines = self.err.splitlines()
        assert len(lines) == 1, f"expected one stderr line, got {lines}"
        assert lines[0].startswith("pcainterp: error: ")
        return lines[0]


@pytest.fixture
def pcainterp(capsys: pytest.CaptureFixture[str]) -> Callable[..., Run]:
    def run(*args: str | Path) -> Run:
        capsys.readouterr()
        code = cli.main([str(arg) for arg in args])
        captured = capsys.readouterr()
        return Run(code, captured.out, captured.err)

    return run


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("logs") / "a.mcap"
    synth(path, frames=2, seed=3, scale=0.25, fmt="mcap")
    return path


def _fifo(path: Path) -> Path:
    os.mkfifo(path)
    return path


def _assert_fifo_alone(fifo: Path) -> None:
    assert stat.S_ISFIFO(fifo.lstat().st_mode), f"{fifo} was replaced"
    stray = [p.name for p in fifo.parent.iterdir() if p.name.startswith(".")]
    assert not stray, f"partials left beside {fifo}: {stray}"


# ----------------------------------------------------------------------------- H1


@pytest.mark.parametrize(
    ("command", "name"),
    [
        (("densify", "{log}", "-o", "{target}"), "out.mcap"),
        (("densify", "{log}", "-o", "{dir}/x.mcap", "--rrd", "{target}"), "out.rrd"),
        (("learn", "{log}", "-o", "{target}"), "out.npz"),
        (("golden", "save", "{log}", "-o", "{target}"), "g.json"),
        (("synth", "{target}", "--frames", "1", "--scale", "0.25"), "s.mcap"),
    ],
)
def test_a_fifo_output_is_refused_up_front(
    pcainterp: Callable[..., Run], log: Path, tmp_path: Path, command: tuple[str, ...], name: str
) -> None:
    fifo = _fifo(tmp_path / name)
    args = [part.format(log=log, target=fifo, dir=tmp_path) for part in command]
    line = pcainterp(*args).error_line()
    assert f"cannot write {fifo}: it is a named pipe (FIFO), not a regular file" in line
    assert "Not a directory" not in line
    _assert_fifo_alone(fifo)
    assert not (tmp_path / "x.mcap").exists()


def test_densify_onto_a_char_device_names_the_way_to_discard(
    pcainterp: Callable[..., Run], log: Path, tmp_path: Path
) -> None:
    device = tmp_path / "nulldev"  # a private copy of /dev/null
    try:
        os.mknod(device, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except PermissionError:
        pytest.skip("making a device node needs root")
    line = pcainterp("densify", log, "-o", device).error_line()
    assert "it is a character device, not a regular file" in line
    assert "pass -o - (e.g. -o - > /dev/null)" in line
    assert stat.S_ISCHR(device.lstat().st_mode)


def test_densify_and_golden_write_through_a_link(
    pcainterp: Callable[..., Run], log: Path, tmp_path: Path
) -> None:
    (tmp_path / "real").mkdir()
    for name in ("out.mcap", "g.json"):
        (tmp_path / name).symlink_to(Path("real") / name)
    run = pcainterp("densify", log, "-o", tmp_path / "out.mcap")
    assert run.code == 0, run.err
    assert pcainterp("golden", "save", log, "-o", tmp_path / "g.json").code == 0
    for name in ("out.mcap", "g.json"):
        assert (tmp_path / name).is_symlink()
        assert (tmp_path / "real" / name).is_file()
    assert pcainterp("golden", "check", log, tmp_path / "g.json").code == 0


def test_densify_to_a_link_to_standard_output_writes_the_stream(log: Path, tmp_path: Path) -> None:
    mine = tmp_path / "mystdout"
    mine.symlink_to("/proc/self/fd/1")  # what /dev/stdout is, privately
    out = tmp_path / "o.mcap"
    with out.open("wb") as stdout:
        done = subprocess.run(
            [sys.executable, "-m", "pcainterp_stream.cli", "densify", str(log), "-o", str(mine)],
            stdout=stdout,
            stderr=subprocess.PIPE,
            text=True,
            check=False,
            timeout=300,
        )
    assert done.returncode == 0, done.stderr
    assert mine.is_symlink()
    assert out.read_bytes()[:8] == b"\x89MCAP0\r\n"
    assert "wrote <stdout>" in done.stderr


# ----------------------------------------------------------------------------- M1


@pytest.mark.parametrize(
    ("folder", "expected"),
    [
        ("afile", "cannot write into {dir}/afile: it is a file, not a folder; pass a folder"),
        ("afile/sub", "cannot write into {dir}/afile/sub: {dir}/afile is a file, not a folder"),
    ],
)
def test_out_dir_that_cannot_be_a_folder_is_one_line(
    pcainterp: Callable[..., Run], log: Path, tmp_path: Path, folder: str, expected: str
) -> None:
    (tmp_path / "afile").write_text("x")
    line = pcainterp("densify", log, "--out-dir", tmp_path / folder).error_line()
    assert expected.format(dir=tmp_path) in line


def test_out_dir_not_writable_is_refused_before_the_cluster(
    pcainterp: Callable[..., Run], log: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def read_only(where: Path) -> None:
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(where))

    def no_cluster(*args: object) -> None:
        raise AssertionError("the cluster was started")

    from pcainterp_stream.pipeline import distributed

    monkeypatch.setattr(output_paths, "_probe", read_only)
    monkeypatch.setattr(distributed, "connect", no_cluster)
    line = pcainterp("densify", log, "--out-dir", tmp_path / "od").error_line()
    assert "Read-only file system; choose a writable folder" in line


@pytest.mark.parametrize(
    ("bad", "expected"),
    [
        ("missing.mcap", "missing.mcap does not exist; pass an MCAP file"),
        ("notes.txt", "notes.txt is not a log (no MCAP, ROS 1 bag or SQLite magic bytes)"),
        ("logs", "logs is a folder but not a rosbag2 bag (no metadata.yaml); it holds 2 logs"),
    ],
)
def test_out_dir_inputs_are_checked_before_the_cluster(
    pcainterp: Callable[..., Run],
    log: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    bad: str,
    expected: str,
) -> None:
    """Bug hunt 15E F4: a missing or non-log input was found by its Dask task, after the
    cluster's start, with "(1 of 2 logs done)", and left an empty --out-dir behind."""

    def no_cluster(*args: object, **kwargs: object) -> None:
        raise AssertionError("the cluster was started")

    from pcainterp_stream.pipeline import distributed

    (tmp_path / "notes.txt").write_text("not a log")
    (tmp_path / "logs").mkdir()
    for name in ("a.mcap", "b.mcap"):
        (tmp_path / "logs" / name).write_bytes(log.read_bytes())
    monkeypatch.setattr(distributed, "connect", no_cluster)
    out_dir = tmp_path / "dense"
    line = pcainterp("densify", log, tmp_path / bad, "--out-dir", out_dir).error_line()
    assert expected in line
    assert "logs done" not in line
    # all or nothing, and said (review 15e R3)
    assert line.endswith(
        "none of the 2 logs was densified (every input is checked before the first)"
    )
    assert not out_dir.exists()


def test_out_dir_inputs_are_left_to_a_schedulers_workers(
    pcainterp: Callable[..., Run], log: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A running scheduler's workers may see files this machine does not: each task checks
    its paths on its worker (docs/cluster.md), so no input is refused here."""

    class Connected(Exception):
        pass

    def connect(*args: object, **kwargs: object) -> None:
        raise Connected

    from pcainterp_stream.pipeline import distributed

    monkeypatch.setattr(distributed, "connect", connect)
    with pytest.raises(Connected):
        cli.main(
            [
                "densify",
                str(log),
                str(tmp_path / "on_the_workers.mcap"),
                "--out-dir",
                str(tmp_path / "dense"),
                "--scheduler",
                "tcp://127.0.0.1:8786",
            ]
        )


def test_out_dir_output_that_is_a_fifo_is_refused(
    pcainterp: Callable[..., Run], log: Path, tmp_path: Path
) -> None:
    fifo = _fifo(tmp_path / "a_dense.mcap")
    line = pcainterp("densify", log, "--out-dir", tmp_path).error_line()
    assert "named pipe" in line
    _assert_fifo_alone(fifo)


# ----------------------------------------------------------------------------- L2


@pytest.mark.parametrize(
    "command",
    [
        ("densify", "{log}", "-o", "{dir}/afile/out.mcap"),
        ("learn", "{log}", "-o", "{dir}/afile/b.npz"),
        ("golden", "save", "{log}", "-o", "{dir}/afile/g.json"),
        ("evaluate", "{log}", "-o", "{dir}/afile/rep"),
    ],
)
def test_a_file_in_the_way_is_not_called_a_missing_folder(
    pcainterp: Callable[..., Run], log: Path, tmp_path: Path, command: tuple[str, ...]
) -> None:
    (tmp_path / "afile").write_text("x")
    line = pcainterp(*(part.format(log=log, dir=tmp_path) for part in command)).error_line()
    assert f"{tmp_path}/afile is a file, not a folder" in line
    assert "create it first" not in line
    assert "free some space" not in line


@pytest.mark.parametrize(
    "command",
    [("learn", "{log}", "-o", "{dir}/b.npz"), ("golden", "save", "{log}", "-o", "{dir}/g.json")],
)
def test_a_read_only_folder_is_refused_before_the_work(
    pcainterp: Callable[..., Run],
    log: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    command: tuple[str, ...],
) -> None:
    def read_only(where: Path) -> None:
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(where))

    def no_work(*args: object, **kwargs: object) -> None:
        raise AssertionError("the log was read before the output was checked")

    from pcainterp_stream.golden import store
    from pcainterp_stream.pipeline import learn

    monkeypatch.setattr(output_paths, "_probe", read_only)
    monkeypatch.setattr(learn, "_source_topic", no_work)
    monkeypatch.setattr(store, "summarize_log", no_work)
    line = pcainterp(*(part.format(log=log, dir=tmp_path) for part in command)).error_line()
    assert "Read-only file system; choose a writable folder" in line


# ----------------------------------------------------------------------------- L4


def test_echo_to_a_full_standard_output_is_one_error(monkeypatch: pytest.MonkeyPatch) -> None:
    from pcainterp_stream.cli import common

    class Full:
        def write(self, text: str) -> int:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        def flush(self) -> None:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(sys, "stdout", Full())
    with pytest.raises(PcaInterpError, match="cannot print to standard output: No space left"):
        common.echo("wrote x")


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full on this system")
def test_a_full_standard_output_keeps_the_output(tmp_path: Path) -> None:
    out = tmp_path / "s.mcap"
    with open("/dev/full", "w") as full:  # a device, as a shell's > /dev/full
        done = subprocess.run(
            [
                sys.executable,
                "-m",
                "pcainterp_stream.cli",
                "synth",
                str(out),
                "--frames",
                "1",
                "--scale",
                "0.25",
            ],
            stdout=full,
            stderr=subprocess.PIPE,
            text=True,
            check=False,
            timeout=300,
        )
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    assert done.stderr.splitlines() == [
        "pcainterp: error: cannot print to standard output: No space left on device; redirect "
        "it to a writable file (outputs already complete are kept, partial ones removed)"
    ]
    assert out.is_file()


# ----------------------------------------------------------------------------- bug hunt 6B H1

REPORT_GONE = (
    "pcainterp: standard output was closed by its reader; the rest of the report is not "
    "printed, and the command goes on to write its output"
)


def _command(*args: str | Path) -> list[str]:
    return [sys.executable, "-m", "pcainterp_stream.cli", *(str(arg) for arg in args)]


def test_a_closed_pipe_costs_no_synth(tmp_path: Path) -> None:
    """``synth X | head -0``: the log is written and the exit status is the job's, 0."""
    out = tmp_path / "s.mcap"
    process = subprocess.Popen(
        _command("synth", out, "--frames", "1", "--scale", "0.25"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert process.stdout is not None
    assert process.stderr is not None
    process.stdout.close()  # the reader is gone before the "wrote" line
    with process.stderr:
        error = process.stderr.read().decode()
    assert process.wait(timeout=300) == 0
    assert error.splitlines() == [REPORT_GONE]
    assert out.is_file()
    assert _frames_in(out, "/stereo/left/image_rect") == 1


def _frames_in(log: Path, topic: str) -> int:
    from pcainterp_stream.io.logreader import open_log

    with open_log(log) as reader:
        return sum(1 for _ in reader.messages([topic]))


def test_densify_piped_into_head_writes_its_output(log: Path, tmp_path: Path) -> None:
    """``densify LOG -o OUT | head -1``: the first line is read, the job finishes, OUT is whole."""
    out = tmp_path / "d.mcap"
    process = subprocess.Popen(
        _command("densify", log, "-o", out),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert process.stdout is not None
    assert process.stderr is not None
    first = process.stdout.readline().decode()
    process.stdout.close()  # head -1 has its line and exits; the frames are not densified yet
    with process.stderr:
        error = process.stderr.read().decode()
    assert process.wait(timeout=300) == 0, error
    assert first.startswith("topics: left /stereo/left/image_rect")
    assert "Traceback" not in error
    assert REPORT_GONE in error.splitlines()
    assert _frames_in(out, "/pcainterp/depth") == 2  # the log's 2 frames, a readable MCAP
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_densify_into_a_pipe_of_both_streams_that_closes(log: Path, tmp_path: Path) -> None:
    """``densify LOG -o OUT 2>&1 | head -1``: standard error's lines are dropped as well."""
    out = tmp_path / "d.mcap"
    read, write = os.pipe()
    with os.fdopen(read, "rb") as reader:
        process = subprocess.Popen(
            _command("densify", log, "-o", out, "--left-topic", "/stereo/left/image_rect"),
            stdout=write,
            stderr=write,
        )
        os.close(write)
        reader.readline()
    assert process.wait(timeout=300) == 0
    assert _frames_in(out, "/pcainterp/depth") == 2


def test_report_stream_drops_lines_once_its_reader_is_gone(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from pcainterp_stream.cli.streams import ReportStream

    read, write = os.pipe()
    with open(write, "w", encoding="utf-8") as pipe:
        stream = ReportStream(pipe, note="note: the reader went away")
        stream.write("first\n")
        stream.flush()
        with open(read, "rb") as reader:
            assert reader.readline() == b"first\n"
        for _ in range(3):  # no BrokenPipeError, one note
            print("more", file=stream, flush=True)  # type: ignore[arg-type]
        assert stream.reader_gone
    assert capsys.readouterr().err == "note: the reader went away\n"


# ---------------------------------------------------------------------------- bug hunt 6B M3, L3


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (
            ["-o", "{dir}/out.txt"],
            "output {dir}/out.txt is named .txt but densify writes MCAP; name the output "
            ".mcap, e.g. -o {dir}/out.mcap",
        ),
        (
            ["-o", "{dir}/o.mcap", "--rrd", "{dir}/old.mcap"],
            "--rrd {dir}/old.mcap is named .mcap, as a log is, but the recording is a Rerun "
            "file; name it .rrd, e.g. --rrd {dir}/old.rrd",
        ),
        (
            ["-o", "{dir}/o.mcap", "--rrd", "{dir}/r.db3"],
            "--rrd {dir}/r.db3 is named .db3, as a log is, but the recording is a Rerun file; "
            "name it .rrd, e.g. --rrd {dir}/r.rrd",
        ),
        (
            ["-o", "{dir}/o.mcap", "--rrd", "{dir}/x_rrd"],
            "--rrd {dir}/x_rrd has no suffix but the recording is a Rerun .rrd file; name it "
            ".rrd, e.g. --rrd {dir}/x_rrd.rrd",
        ),
        (
            ["-o", "{dir}/o.mcap", "--rrd", "-"],
            "--rrd - would write a file named '-': the recording cannot go to standard output "
            "(-o - is the MCAP's); name a file, e.g. --rrd densify.rrd, or view it live with "
            "--rerun",
        ),
    ],
)
def test_densify_refuses_a_name_of_the_wrong_kind(
    pcainterp: Callable[..., Run],
    log: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    args: list[str],
    expected: str,
) -> None:
    monkeypatch.chdir(tmp_path)
    old = tmp_path / "old.mcap"
    old.write_bytes(log.read_bytes())  # an earlier output --rrd would have replaced
    run = pcainterp("densify", log, *(arg.format(dir=tmp_path) for arg in args))
    assert run.error_line() == "pcainterp: error: " + expected.format(dir=tmp_path)
    assert old.read_bytes() == log.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.mcap"]


# ----------------------------------------------------------------------------- bug hunt 6B L8


def test_densify_to_a_terminal_is_refused(log: Path, tmp_path: Path) -> None:
    import pty

    primary, terminal = pty.openpty()
    try:
        done = subprocess.run(
            _command("densify", log, "-o", "-"),
            stdout=terminal,
            stderr=subprocess.PIPE,
            text=True,
            check=False,
            timeout=300,
            cwd=tmp_path,
        )
    finally:
        os.close(terminal)
        os.close(primary)
    assert done.returncode == 2
    assert done.stderr.splitlines() == [
        "pcainterp: error: -o - writes the MCAP to standard output, which is a terminal; "
        "redirect it (-o - > out.mcap) or pipe it into a reader"
    ]
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- bug hunt 6B L7


def test_densify_of_a_densified_log_names_the_prefix_to_change(
    pcainterp: Callable[..., Run], log: Path, tmp_path: Path
) -> None:
    dense = tmp_path / "dense.mcap"
    assert pcainterp("densify", log, "-o", dense).code == 0
    again = tmp_path / "again.mcap"
    line = pcainterp("densify", dense, "-o", again, "--output-prefix", "/pcainterp").error_line()
    assert line.startswith("pcainterp: error: ")
    assert line.endswith(
        "; densify the original log, or give --output-prefix a prefix other than /pcainterp"
    )
    assert not again.exists()
    assert pcainterp("densify", dense, "-o", again, "--output-prefix", "/second").code == 0
