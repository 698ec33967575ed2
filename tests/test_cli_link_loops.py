"""A symbolic link loop as an input or output: one line before any work (bug hunt 16A F5).

Python 3.11's ``Path.resolve()`` raises RuntimeError on a loop (3.13: OSError): eight
command lines ended in a traceback, ``info`` and ``--basis`` called the loop missing, and
``evaluate -o LOOP`` ran the whole evaluation before it failed.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import pytest

from pcainterp_stream import cli
from pcainterp_stream.errors import LogWriteError
from pcainterp_stream.io.output_paths import check_not_input, input_bag, symlink_loop
from pcainterp_stream.pipeline.jobs import synth


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with a small log, a KITTI-less folder, and two loops: x -> x, a -> b -> a."""
    place = tmp_path_factory.mktemp("loops")
    synth(place / "small.mcap", frames=2, seed=3, scale=0.25, fmt="mcap")
    for name in ("loop.mcap", "loop.npz", "loop.golden.json", "loopdir"):
        (place / name).symlink_to(name)
    (place / "a.mcap").symlink_to("b.mcap")
    (place / "b.mcap").symlink_to("a.mcap")
    (place / "empty").mkdir()
    return place


@pytest.fixture
def one_line(
    folder: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> Callable[..., str]:
    monkeypatch.chdir(folder)

    def run(*args: str) -> str:
        capsys.readouterr()
        code = cli.main(list(args))
        err = capsys.readouterr().err
        assert code == 2, f"exit {code}: {err}"
        lines = err.splitlines()
        assert len(lines) == 1, lines
        assert lines[0].startswith("pcainterp: error: ")
        return lines[0].removeprefix("pcainterp: error: ")

    return run


LOOP = "loop.mcap is a symbolic link loop; point it at a real file"


@pytest.mark.parametrize(
    "args",
    [
        ("densify", "loop.mcap", "-o", "out.mcap"),
        ("densify", "loop.mcap", "--out-dir", "empty"),
        ("learn", "loop.mcap", "-o", "out.npz"),
        ("golden", "save", "loop.mcap", "-o", "out.golden.json"),
        ("golden", "check", "loop.mcap", "whatever.golden.json"),
        ("info", "loop.mcap"),
        ("evaluate", "loop.mcap", "-o", "report"),
        ("evaluate", "small.mcap", "-o", "loop.mcap"),
        ("densify", "small.mcap", "-o", "loop.mcap"),
        ("synth", "loop.mcap", "--frames", "1"),
        ("import-kitti", "empty", "loop.mcap"),
    ],
)
def test_a_loop_as_input_or_output_is_refused_in_one_line(
    one_line: Callable[..., str], args: tuple[str, ...]
) -> None:
    assert one_line(*args) == LOOP


def test_the_other_paths_and_a_two_link_loop(one_line: Callable[..., str]) -> None:
    npz = "loop.npz is a symbolic link loop; point it at a real file"
    assert one_line("learn", "small.mcap", "-o", "loop.npz") == npz
    assert one_line("densify", "small.mcap", "-o", "o.mcap", "--basis", "loop.npz") == npz
    golden = "loop.golden.json is a symbolic link loop; point it at a real file"
    assert one_line("golden", "save", "small.mcap", "-o", "loop.golden.json") == golden
    assert one_line("golden", "check", "small.mcap", "loop.golden.json") == golden
    assert one_line("info", "a.mcap") == "a.mcap is a symbolic link loop; point it at a real file"
    assert one_line("densify", "small.mcap", "-o", "loopdir/x.mcap") == (
        "loopdir/x.mcap: folder loopdir is a symbolic link loop; point it at a real folder"
    )


def test_library_checks_name_the_loop(folder: Path) -> None:
    """check_not_input and input_bag no longer raise RuntimeError from Path.resolve()."""
    with pytest.raises(LogWriteError, match=r"loop\.mcap is a symbolic link loop"):
        check_not_input(folder / "loop.mcap", [folder / "small.mcap"])
    check_not_input(folder / "out.mcap", [folder / "loop.mcap"])  # not the input: allowed
    assert input_bag(folder / "loop.mcap", folder / "small.mcap") is None


def test_a_long_chain_is_not_called_a_loop(tmp_path: Path) -> None:
    (tmp_path / "real").write_text("x")
    previous = "real"
    for index in range(45):  # more than the 40 links the kernel follows
        os.symlink(previous, tmp_path / f"l{index}")
        previous = f"l{index}"
    assert symlink_loop(tmp_path / "l10") is None
    assert symlink_loop(tmp_path / "missing") is None
    assert symlink_loop(tmp_path / "l44") == (
        f"{tmp_path / 'l44'} is a chain of over 40 symbolic links; point it at a real file"
    )
