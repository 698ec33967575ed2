"""The examples in the package's docstrings run as written."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import pcainterp_stream


def _modules_with_examples() -> list[str]:
    names = []
    for info in pkgutil.walk_packages(pcainterp_stream.__path__, "pcainterp_stream."):
        spec = importlib.util.find_spec(info.name)
        if spec is None or spec.origin is None or not spec.origin.endswith(".py"):
            continue
        with open(spec.origin, encoding="utf-8") as source:
            if ">>> " in source.read():
                names.append(info.name)
    return names


MODULES = _modules_with_examples()


def test_some_modules_have_examples() -> None:
    assert "pcainterp_stream.synth" in MODULES


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name: str) -> None:
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS)
    assert result.failed == 0, name
