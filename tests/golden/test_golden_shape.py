"""A damaged or hand-edited golden file: one line, exit 2 (bug hunt 16A F3, F9).

``golden check`` crashed (TypeError, exit 1: the code of "the log differs") on a channel
entry that is not an object; ``info`` called a cut-off golden file "not a log".
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from pcainterp_stream.cli import main
from pcainterp_stream.golden.store import save_golden
from pcainterp_stream.pipeline.jobs import synth


@pytest.fixture(scope="module")
def saved(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    folder = tmp_path_factory.mktemp("shape")
    log = folder / "small.mcap"
    synth(log, frames=2, seed=3, scale=0.25, fmt="mcap")
    save_golden(log, folder / "good.golden.json")
    return log, json.loads((folder / "good.golden.json").read_text())


@pytest.fixture
def one_line(capsys: pytest.CaptureFixture[str]) -> Callable[..., str]:
    def run(*args: str | Path) -> str:
        capsys.readouterr()
        code = main([str(arg) for arg in args])
        err = capsys.readouterr().err
        assert code == 2, f"exit {code}: {err}"
        assert "Traceback" not in err
        lines = err.splitlines()
        assert len(lines) == 1, lines
        return lines[0].removeprefix("pcainterp: error: ")

    return run


def _edit(document: dict[str, Any], path: list[Any], value: Any) -> dict[str, Any]:
    edited = json.loads(json.dumps(document))
    place = edited
    for key in path[:-1]:
        place = place[key]
    place[path[-1]] = value
    return edited


TOPIC = "/stereo/left/image_rect"


@pytest.mark.parametrize(
    ("path", "value", "said"),
    [
        (["channels", TOPIC], "x", f"channel {TOPIC} is a string, expected an object"),
        (["channels", TOPIC, "message_count"], "4", "message_count is '4', expected an integer"),
        (["channels", TOPIC, "messages"], {}, "messages is an object, expected a list"),
        (["channels", TOPIC, "schema"], 3, "schema is a number, expected a string"),
        (["channels", TOPIC, "messages", 0], [], "message 0 is a list, expected an object"),
        (["channels", TOPIC, "messages", 1, "log_time_ns"], "1", "log_time_ns is a string"),
        (["channels", TOPIC, "messages", 0, "values"], [], "values is a list, expected an"),
        (["channels", TOPIC, "messages", 0, "arrays", "image"], 1, "array image is a number"),
        (["channels", TOPIC, "messages", 0, "arrays", "image", "mean"], "x", "mean is a string"),
        (["channels", TOPIC, "messages", 0, "arrays", "image", "quantiles"], [1], "quantiles"),
        (["channels", TOPIC, "messages", 0, "arrays", "image", "blocks", "grid"], 4, "no grid"),
        (["topics"], "abc", "topics is a string, expected a list of topic names"),
        (["arrays_file"], 5, "arrays_file is a number, expected a file name"),
    ],
)
def test_golden_check_refuses_a_malformed_file_with_exit_2(
    saved: tuple[Path, dict[str, Any]],
    tmp_path: Path,
    one_line: Callable[..., str],
    path: list[Any],
    value: Any,
    said: str,
) -> None:
    log, document = saved
    bad = tmp_path / "bad.golden.json"
    bad.write_text(json.dumps(_edit(document, path, value)))
    line = one_line("golden", "check", log, bad)
    assert line.startswith(f"{bad} is a malformed golden file (pcainterp-golden/3): ")
    assert said in line
    assert line.endswith("write it again with `pcainterp golden save`")
    assert one_line("info", bad) == line  # info reads the same file the same way


@pytest.mark.parametrize(
    ("name", "content", "what"),
    [
        ("trunc.golden.json", '{"format": 1', "not readable JSON, cut off or edited: Expecting"),
        ("list.golden.json", "[1, 2]", "a list, not an object"),
        ("empty.golden.json", "{}", "no format"),
        ("old.golden.json", '{"format": 1}', "format 1, expected 'pcainterp-golden/3'"),
    ],
)
def test_info_calls_a_damaged_golden_file_so(
    tmp_path: Path, one_line: Callable[..., str], name: str, content: str, what: str
) -> None:
    damaged = tmp_path / name
    damaged.write_text(content)
    line = one_line("info", damaged)
    assert line.startswith(f"{damaged} is a damaged golden file ({what}")
    assert line.endswith(f"write it again with `pcainterp golden save LOG -o {name}`")
    assert "not a log" not in line


def test_info_on_other_json_and_a_log_named_json(
    saved: tuple[Path, dict[str, Any]], tmp_path: Path, one_line: Callable[..., str]
) -> None:
    other = tmp_path / "settings.json"
    other.write_text("[1]")
    assert one_line("info", other).startswith(f"{other} is JSON but not a golden file (a list")
    log = tmp_path / "log.json"
    log.write_bytes(saved[0].read_bytes())
    assert main(["info", str(log)]) == 0  # a log, whatever its name, is described
