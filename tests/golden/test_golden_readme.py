"""The README's golden-file example, extracted from the README so that it cannot drift."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

pytest_plugins = ["pytester"]


def readme_example() -> str:
    """Return the first python block of the README's "Golden-file tests" section."""
    text = (ROOT / "README.md").read_text()
    section = text.split("\n## Golden-file tests\n", 1)[1].split("\n## ", 1)[0]
    match = re.search(r"```python\n(.*?)```", section, re.DOTALL)
    assert match, "the README's Golden-file tests section has no python example"
    return match.group(1)


def test_readme_example_passes_then_fails_naming_the_depth(pytester: pytest.Pytester) -> None:
    # each run in a fresh process, as a user runs it: an in-process run drops the modules
    # first imported inside it, and numpy's compiled modules cannot load twice per process
    example = readme_example()
    assert len(example.strip().splitlines()) <= 12
    pytester.makepyfile(test_densify_golden=example)

    first = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider")
    first.assert_outcomes(failed=1)
    first.stdout.fnmatch_lines(["*File not found in data directory, created*"])
    golden = pytester.path / "test_densify_golden" / "test_densified_drive_is_unchanged.golden.json"
    assert golden.is_file()

    pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider").assert_outcomes(passed=1)

    densify = '"-o", str(dense)]'
    assert densify in example
    changed = example.replace(densify, '"-o", str(dense), "--corners", "15"]')
    pytester.makepyfile(test_densify_golden=changed)
    third = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider")
    third.assert_outcomes(failed=1)
    third.stdout.fnmatch_lines(
        ["*drive_dense.mcap differs from the golden file*", "*/pcainterp/depth #0 (stamp *"]
    )
