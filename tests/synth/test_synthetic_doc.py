"""docs/synthetic.md's Python runs as written, and the names it calls are where it says."""

from __future__ import annotations

import importlib
import pkgutil
import re
from pathlib import Path

import pytest

import pcainterp_stream.synth

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "synthetic.md"


def _python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", PAGE.read_text(), re.DOTALL)


def _synth_names() -> set[str]:
    """The public names defined in the ``pcainterp_stream.synth`` package's modules."""
    names = set(dir(pcainterp_stream.synth))
    package = pcainterp_stream.synth
    for info in pkgutil.iter_modules(package.__path__, f"{package.__name__}."):
        names |= set(dir(importlib.import_module(info.name)))
    return {name for name in names if not name.startswith("_")}


def test_page_python_blocks_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # a block writes drive.mcap
    blocks = _python_blocks()
    assert len(blocks) >= 2, "the generate example and the log writer example"
    for block in blocks:
        exec(compile(block, str(PAGE), "exec"), {})
    assert (tmp_path / "drive.mcap").is_file()


def test_page_calls_import_from_where_it_says() -> None:
    """A call in inline code imports from the module it names, else ``pcainterp_stream.synth``.

    The page imports from ``pcainterp_stream.synth``; ``write_synthetic_log(...)`` named bare
    read as that package's, where it is not (it lives in ``synth.log``).
    """
    ours = _synth_names()
    missing = []
    for call in re.findall(r"`([A-Za-z_][A-Za-z_0-9.]*)\(", PAGE.read_text()):
        module_name, _, name = call.rpartition(".")
        if name not in ours:  # round(), numpy's default_rng(), a formula's H(x)
            continue
        module = importlib.import_module(module_name or "pcainterp_stream.synth")
        if not hasattr(module, name):
            missing.append(call)
    assert not missing, f"docs/synthetic.md calls {missing}: not importable as named"
