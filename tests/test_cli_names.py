"""Names, paths and terminals (bug hunt 17C): what a file's name cannot break.

A name standard output cannot encode (a latin-1 name on a UTF-8 desktop, whose standard
output is strict; any non-ASCII name with ``PYTHONIOENCODING=ascii``) ended commands whose
work was done with a traceback (F1); ``evaluate`` lost its report to such a name (F3), and
``densify --basis`` its output (F4). A name too long for the file system was a traceback
(F2); an unexpanded ``~`` was refused with advice to make a folder ``~``, or one was made
(F5); ``-o NAME/`` wrote a file ``NAME`` (F6); ``./-`` and ``./builtin`` were taken for the
stream and the built-in basis (F9); a trailing space or newline in a name was invisible (F8).
"""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import pytest

from pcainterp_stream import cli
from pcainterp_stream.cli.common import STREAM, basis_option, path_arg, unexpanded_home
from pcainterp_stream.cli.streams import ReportStream
from pcainterp_stream.io.path_text import path_text, shown, too_long
from pcainterp_stream.pipeline.densify import basis_label
from pcainterp_stream.pipeline.jobs import synth

LATIN1 = os.fsdecode(b"caf\xe9")  # a latin-1 name: not UTF-8, held as caf\udce9


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with a small log named ``café.mcap`` (UTF-8) and one with a latin-1 name."""
    place = tmp_path_factory.mktemp("names")
    synth(place / "café.mcap", frames=2, seed=3, scale=0.25, fmt="mcap")
    os.link(place / "café.mcap", place / f"{LATIN1}.mcap")
    return place


def _program(args: list[str], cwd: Path, **env: str) -> subprocess.CompletedProcess[bytes]:
    """Run the ``pcainterp`` program (its own streams: guard()) in ``cwd``."""
    root = str(Path(__file__).resolve().parents[1])
    environment = dict(os.environ, PYTHONPATH=root, **env)
    return subprocess.run(
        [sys.executable, "-m", "pcainterp_stream.cli", *args],
        cwd=cwd,
        env=environment,
        capture_output=True,
        timeout=300,
    )


# ----------------------------------------------------------------------------- F1


def test_a_line_the_encoding_cannot_hold_is_printed_escaped() -> None:
    raw = io.BytesIO()
    strict = io.TextIOWrapper(raw, encoding="ascii", errors="strict")
    stream = ReportStream(strict)
    stream.write(f"wrote {LATIN1}_d.mcap and café.mcap\n")
    stream.flush()
    assert raw.getvalue() == b"wrote caf\\udce9_d.mcap and caf\\xe9.mcap\n"


@pytest.mark.parametrize("encoding", ["ascii", "utf-8"])
def test_info_of_a_name_stdout_cannot_encode_exits_0(folder: Path, encoding: str) -> None:
    """Before: a UnicodeEncodeError traceback, exit 1 (``golden check``: "differs")."""
    name = "café.mcap" if encoding == "ascii" else f"{LATIN1}.mcap"
    done = _program(["info", name], folder, PYTHONIOENCODING=encoding)
    assert done.returncode == 0, done.stderr.decode(errors="replace")
    assert b"Traceback" not in done.stderr
    assert b"caf\\" in done.stdout  # the name, escaped


# ----------------------------------------------------------------------------- F3, F4


def test_evaluate_writes_the_report_of_a_log_with_a_latin1_name(
    folder: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Before: the whole evaluation, then UnicodeEncodeError at results.md and no report."""
    monkeypatch.chdir(folder)
    assert cli.main(["densify", f"{LATIN1}.mcap", "-o", f"{LATIN1}_d.mcap"]) == 0
    assert cli.main(["evaluate", f"{LATIN1}_d.mcap", "-o", "report"]) == 0
    capsys.readouterr()
    markdown = (folder / "report" / "results.md").read_text(encoding="utf-8")
    assert "caf\\udce9_d.mcap" in markdown


def test_a_basis_path_that_is_not_utf8_is_recorded_escaped(tmp_path: Path) -> None:
    """Before: the MCAP writer refused the label at the end (blaming the output)."""
    label = basis_label(tmp_path / f"{LATIN1}.npz", tmp_path / "out.mcap")
    assert label == "caf\\udce9.npz"
    label.encode("utf-8")  # what the MCAP metadata takes
    assert path_text("bases/café.npz") == "bases/café.npz"


# ----------------------------------------------------------------------------- F2


@pytest.mark.parametrize(
    "args",
    [
        ["info", "a" * 300 + ".mcap"],
        ["densify", "a" * 300 + ".mcap", "-o", "y.mcap"],
        ["learn", "café.mcap", "-o", "a" * 300 + ".npz"],
        ["golden", "save", "café.mcap", "-o", "a" * 300 + ".json"],
        ["densify", "café.mcap", "-o", "a" * 300 + "/x.mcap"],
        ["densify", "café.mcap", "-o", "y.mcap", "--basis", "a" * 300 + ".npz"],
        ["import-kitti", "a" * 300, "k.mcap"],
    ],
    ids=["info", "densify-input", "learn-o", "golden-o", "folder", "basis", "kitti"],
)
def test_a_name_too_long_is_one_line(
    folder: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    args: list[str],
) -> None:
    monkeypatch.chdir(folder)
    assert cli.main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert "too long for the file system" in err
    assert "choose a shorter name" in err


def test_a_path_over_path_max_names_the_whole_path() -> None:
    path = "/".join(["b" * 200] * 22) + "/x.mcap"
    assert too_long(path).startswith("the path is too long for the file system (4428 bytes")


# ----------------------------------------------------------------------------- F5, F6, F9


@pytest.mark.parametrize(
    "args",
    [
        ["densify", "café.mcap", "--output=~/x_dense.mcap"],
        ["golden", "save", "café.mcap", "--output=~/g.json"],
        ["evaluate", "café.mcap", "--output=~/rep"],
        ["synth", "--frames", "2", "~/s.mcap"],
    ],
    ids=["densify", "golden", "evaluate", "synth"],
)
def test_an_unexpanded_tilde_is_refused_and_no_tilde_folder_made(
    folder: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    args: list[str],
) -> None:
    monkeypatch.chdir(folder)
    assert cli.main(args) == 2
    err = capsys.readouterr().err
    assert "the shell did not expand ~" in err
    assert "$HOME/" in err
    assert not (folder / "~").exists()


@pytest.mark.parametrize(
    ("args", "fix"),
    [
        (
            ["densify", "café.mcap", "--basis=~/b.npz", "-o", "o.mcap"],
            "write it unquoted after a space (--basis ~/b.npz, not --basis=~/b.npz nor quoted)",
        ),
        (
            ["densify", "café.mcap", "--calibration=~/c.yaml", "-o", "o.mcap"],
            "(--calibration ~/c.yaml, not --calibration=~/c.yaml nor quoted)",
        ),
        (
            ["densify", "café.mcap", "-o~/o.mcap"],
            "(--output ~/o.mcap, not --output=~/o.mcap nor quoted)",
        ),
        (["synth", "~/s.mcap"], "write it unquoted (~/s.mcap, not '~/s.mcap') or as $HOME/s.mcap"),
        (["info", "~/x.mcap"], "write it unquoted (~/x.mcap, not '~/x.mcap') or as $HOME/x.mcap"),
    ],
    ids=["basis", "calibration", "short-o", "synth-positional", "info-positional"],
)
def test_the_tilde_refusal_names_the_option_that_held_the_path(
    folder: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    args: list[str],
    fix: str,
) -> None:
    """Review 17c R1: every option and positional was told to write ``-o ~/x``."""
    monkeypatch.chdir(folder)
    assert cli.main(args) == 2
    err = capsys.readouterr().err
    assert fix in err, err
    assert "-o ~" not in err
    assert not (folder / "~").exists()


def test_the_tilde_refusal_outside_argparse_names_no_option() -> None:
    text = unexpanded_home("~/x.mcap")
    assert text is not None
    assert text.endswith("write it unquoted at the start of a word or as $HOME/x.mcap")


def test_a_tilde_folder_that_exists_is_taken_as_typed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "~").mkdir()
    assert path_arg("~/x.mcap") == Path("~/x.mcap")
    assert path_arg("~backup.mcap") == Path("~backup.mcap")  # no user named so


@pytest.mark.parametrize(
    ("args", "made"),
    [
        (["densify", "café.mcap", "-o", "dense/"], "dense"),
        (["learn", "café.mcap", "-o", "bases/"], "bases"),
        (["golden", "save", "café.mcap", "-o", "goldens/"], "goldens"),
        (["densify", "café.mcap", "-o", "y.mcap", "--rrd", "rec/"], "rec"),
    ],
    ids=["densify", "learn", "golden", "rrd"],
)
def test_an_output_file_ending_in_a_slash_is_refused(
    folder: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    args: list[str],
    made: str,
) -> None:
    monkeypatch.chdir(folder)
    assert cli.main(args) == 2
    assert f"{made}/ ends with / so names a folder" in capsys.readouterr().err
    assert not (folder / made).exists()


def test_dot_slash_dash_and_builtin_are_files(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "builtin").write_bytes(b"")  # a file named builtin (checked where it is read)
    assert path_arg("-") == STREAM
    assert path_arg("./-") != STREAM
    assert path_arg("./-") == tmp_path / "-"
    assert basis_option(path_arg("builtin")) == (None, "auto")
    assert basis_option(path_arg("./builtin")) == (tmp_path / "builtin", None)


# ----------------------------------------------------------------------------- F8


def test_names_with_hidden_edges_or_controls_are_quoted() -> None:
    assert shown("x_dense.mcap") == "x_dense.mcap"
    assert shown("my drive.mcap") == "my drive.mcap"  # spaces inside: as is
    assert shown("x.mcap ") == "'x.mcap '"
    assert shown("new\nline.mcap") == "$'new\\nline.mcap'"


def test_a_trailing_space_in_the_output_shows_in_the_refusal(
    folder: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Before: "output x_dense.mcap  is named .mcap  but densify writes MCAP; name ... .mcap"."""
    monkeypatch.chdir(folder)
    assert cli.main(["densify", "café.mcap", "-o", "x_dense.mcap "]) == 2
    err = capsys.readouterr().err
    assert "output 'x_dense.mcap ' is named '.mcap '" in err
