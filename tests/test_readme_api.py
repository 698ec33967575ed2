"""The README's Python API block, extracted from the README and run as written."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def readme_api_block() -> str:
    """Return the python block of the README's "Python API" section."""
    text = (ROOT / "README.md").read_text()
    section = text.split("\n## Python API\n", 1)[1].split("\n## ", 1)[0]
    match = re.search(r"```python\n(.*?)```", section, re.DOTALL)
    assert match, "the README's Python API section has no python example"
    return match.group(1)


def test_readme_api_block_runs_and_gives_what_it_lists(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # it writes basis.npz
    names: dict[str, Any] = {}
    exec(compile(readme_api_block(), "README.md", "exec"), names)
    assert (tmp_path / "basis.npz").is_file()
    basis = names["basis"]
    assert basis.n_components == 2  # "2 here"
    # the results it lists are filled: depth needs the basis's f*b (before: None)
    pixels = names["pixels"]
    first = names["densify"](basis, pixels, names["disparities"], uncertainty="exact")
    for field in ("disparity", "disparity_std", "depth", "depth_std", "coefficients"):
        assert getattr(first, field) is not None, field
    assert first.depth.shape == (94, 310)
    assert names["near"].shape == (94, 310)
    assert np.isfinite(names["res"].depth).any()
