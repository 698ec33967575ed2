"""A report replaced in an existing folder is replaced whole or not at all (bug hunt 16C F2).

The new files were moved in one by one: when one move failed (an immutable results.md, a
file of another user in a sticky folder), the folder held the new results.json and figures
beside the earlier results.md. The earlier report is now put back as it was.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import Any

import pytest

from pcainterp_stream.evaluate import report_folder

EARLIER = {
    "results.md": "earlier md",
    "results.json": '{"log": "a.mcap", "mode": "stereo", "methods": {}}',
    "errors.png": "earlier",
}


def _earlier(folder: Path) -> None:
    folder.mkdir()
    for name, text in EARLIER.items():
        (folder / name).write_text(text)
    (folder / ".gitkeep").write_text("")


def _new(staging: Path) -> None:
    for name in ("results.md", "results.json", "errors.png", "examples.png"):
        (staging / name).write_text("new")


def _contents(folder: Path) -> dict[str, str]:
    return {path.name: path.read_text() for path in folder.iterdir() if path.is_file()}


@pytest.mark.parametrize("failing", ["results.md", "errors.png", "examples.png"])
def test_a_move_that_fails_half_way_leaves_the_earlier_report(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, failing: str
) -> None:
    folder = tmp_path / "rep"
    _earlier(folder)
    replace = os.replace

    def immutable(source: Any, target: Any) -> None:
        if Path(target) == folder / failing or Path(source) == folder / failing:
            raise PermissionError(errno.EPERM, os.strerror(errno.EPERM))
        replace(source, target)

    monkeypatch.setattr(report_folder.os, "replace", immutable)
    with pytest.raises(report_folder.PcaInterpError, match="the earlier report in it is as"):
        report_folder.write_report_folder(folder, _new)
    assert _contents(folder) == {**EARLIER, ".gitkeep": ""}
    assert [path.name for path in folder.iterdir() if path.is_dir()] == []


def test_a_report_replaced_whole_leaves_no_earlier_file(tmp_path: Path) -> None:
    folder = tmp_path / "rep"
    _earlier(folder)
    (folder / "examples.png").unlink(missing_ok=True)
    report_folder.write_report_folder(
        folder, lambda staging: (staging / "results.md").write_text("new")
    )
    assert _contents(folder) == {"results.md": "new", ".gitkeep": ""}
    assert [path.name for path in folder.iterdir() if path.is_dir()] == []
