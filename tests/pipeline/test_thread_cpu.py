"""``tools/thread_cpu.py`` passes densify's own arguments after ``--`` on to the job."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _tool(monkeypatch: pytest.MonkeyPatch) -> ModuleType:
    monkeypatch.syspath_prepend(str(ROOT / "tools"))  # it imports its harness as tools/ does
    spec = importlib.util.spec_from_file_location("thread_cpu", ROOT / "tools" / "thread_cpu.py")
    assert spec is not None
    assert spec.loader is not None
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    return tool


def test_densify_arguments_after_the_double_dash_reach_the_job(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    tool = _tool(monkeypatch)
    split = tool.split_arguments
    assert split(["a.mcap", "--interval", "1", "--", "--measurements", "dense"]) == (
        ["a.mcap", "--interval", "1"],
        ["--measurements", "dense"],
    )
    assert split(["a.mcap"]) == (["a.mcap"], [])
    assert split(["a.mcap", "--", "--", "x"]) == (["a.mcap"], ["--", "x"])
    # the whole command line: densify is called with them (the job itself is not run)
    log = tmp_path / "a.mcap"
    log.write_bytes(b"")
    called: list[list[str]] = []

    def densify(argv: list[str]) -> int:
        called.append(argv)
        return 0

    monkeypatch.setattr(tool.app, "main", densify)
    assert tool.main([str(log), "--interval", "1", "--", "--measurements", "dense"]) == 0
    assert called[0][0] == "densify"
    assert called[0][1] == str(log)
    assert called[0][-2:] == ["--measurements", "dense"]
