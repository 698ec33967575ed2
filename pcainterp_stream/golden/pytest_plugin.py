"""The ``log_golden`` pytest fixture, registered through the ``pytest11`` entry point.

Installing pcainterp-stream is enough to use it::

    def test_my_pipeline(tmp_path, log_golden):
        out = run_my_pipeline(tmp_path)       # writes a log
        log_golden.check(out)

The first run writes the golden file beside the test, in pytest-regressions' layout
(``test_module/test_name.golden.json``), and fails so that it is reviewed; later runs
check the log against it and fail with the list of differences. ``--force-regen`` (the
pytest-regressions flag) rewrites the golden files that differ and fails those tests;
``--update-golden`` rewrites every golden file the run checks and passes.

The snapshot machinery (naming, the data directory beside the test, the first-run and
``--force-regen`` flow) is pytest-regressions' ``perform_regression_check``; this module
supplies only how a log is dumped (:func:`~.store.save_golden`) and compared
(:func:`~.store.check_log`).
"""

from __future__ import annotations

import re
import shutil
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import pytest

from pcainterp_stream.errors import GoldenError, GoldenToleranceError

__all__ = ["LogGolden", "log_golden"]

EXTENSION = ".golden.json"
MAX_LINES = 40

_CLAIMED = pytest.StashKey[dict[Path, str]]()
"""The golden files the session's tests have checked: resolved path -> the test's node id."""


def pytest_addoption(parser: pytest.Parser) -> None:
    """Add ``--update-golden``."""
    group = parser.getgroup("log_golden", "golden-file tests of logs (pcainterp-stream)")
    group.addoption(
        "--update-golden",
        action="store_true",
        default=False,
        help="rewrite every log_golden golden file the run checks, and pass",
    )


class LogGolden:
    """Check logs against golden files stored beside the test (the ``log_golden`` fixture).

    Attributes:
        max_lines: how many differences a failure lists before their count.
    """

    def __init__(self, request: pytest.FixtureRequest, datadir: Any, original_datadir: Path):
        self._request = request
        self._datadir = datadir
        self._original_datadir = Path(original_datadir)
        self._checked: set[Path] = set()  # the golden files this test has checked
        self.max_lines = MAX_LINES

    def check(
        self,
        log: str | Path,
        *,
        basename: str | None = None,
        fullpath: str | Path | None = None,
        topics: Iterable[str] | str | None = None,
        arrays: bool = False,
        tolerance: Mapping[str, Any] | None = None,
    ) -> None:
        """Check a log against its golden file; write the file on the first run.

        Args:
            log: the log to check (MCAP, ROS 1 ``.bag``, rosbag2).
            basename: golden file name without extension (default: the test's name); a
                test that checks more than one log passes one per call, e.g.
                ``check(dense, basename="dense")`` and ``check(raw, basename="raw")``.
            fullpath: an explicit golden file path instead (e.g. in a shared data folder).
            topics: record and check only these channels.
            arrays: also store and check every array element-wise.
            tolerance: tolerances written into a new golden file (an existing file keeps
                its own).

        Raises:
            AssertionError: (a test failure) the log differs; the message lists the
                differences, each with channel, message index, stamp, what moved and by
                how much against its tolerance.
            pytest.fail: (a test failure) this test already checked a log against the same
                golden file (two calls without ``basename=``), or another test of the run
                did (parametrized ids that differ only in punctuation map to one file name);
                or the golden file's tolerances, or ``tolerance``, are not valid.
        """
        __tracebackhide__ = True
        try:
            self._check(
                log,
                basename=basename,
                fullpath=fullpath,
                topics=topics,
                arrays=arrays,
                tolerance=tolerance,
            )
        except GoldenToleranceError as err:  # an edited file is fixed, not replaced
            message = str(err)
        else:
            return
        pytest.fail(message, pytrace=False)  # outside the except: one line, no chained error

    def _check(
        self,
        log: str | Path,
        *,
        basename: str | None,
        fullpath: str | Path | None,
        topics: Iterable[str] | str | None,
        arrays: bool,
        tolerance: Mapping[str, Any] | None,
    ) -> None:
        __tracebackhide__ = True
        from pytest_regressions.common import perform_regression_check

        from pcainterp_stream.golden.comparison import format_differences
        from pcainterp_stream.golden.store import (
            checked_tolerance,
            compare_documents,
            load_golden,
            save_golden,
            topic_selection,
        )

        log = Path(log)
        selected = topic_selection(topics)

        def dump(path: Path) -> None:
            kept = tolerance
            if path.exists() and not path.name.endswith(".obtained" + EXTENSION):
                try:
                    kept = load_golden(path).get("tolerance", tolerance)
                except GoldenToleranceError:
                    raise
                except GoldenError:  # an unreadable or old file is simply replaced
                    kept = tolerance
            try:
                save_golden(log, path, topics=selected, arrays=arrays, tolerance=kept)
            except GoldenToleranceError as err:  # an override of a channel the log lacks
                raise _naming(err, path, source) from None

        def compare(obtained: Path, expected: Path) -> None:
            __tracebackhide__ = True
            try:
                golden = load_golden(expected)
                name = golden.get("arrays_file")
                if name and not (expected.parent / name).exists():
                    # the lazy data directory copied the JSON only
                    shutil.copy2(source.parent / name, expected.parent / name)
                differences = compare_documents(golden, expected, load_golden(obtained), obtained)
            except GoldenToleranceError as err:
                raise _naming(err, expected, source) from None
            except GoldenError as err:  # an old format: --force-regen rewrites it
                raise AssertionError(
                    f"{err}\n(rerun with --force-regen or --update-golden)"
                ) from err
            if differences:
                count = len(differences)
                raise AssertionError(
                    f"{log.name} differs from the golden file {source} in {count} "
                    f"place{'s' if count > 1 else ''} beyond tolerance:\n"
                    + format_differences(differences, self.max_lines)
                    + "\n(rerun with --force-regen or --update-golden to accept the log)"
                )

        node = self._request.node
        paths_basename = basename
        if fullpath is None and basename is None:
            paths_basename = _file_stem(node.name)
        source = (
            Path(fullpath)
            if fullpath is not None
            else self._original_datadir / f"{paths_basename}{EXTENSION}"
        )
        if source.resolve() in self._checked:
            pytest.fail(
                f"log_golden.check({log.name!r}): this test already checked a log against "
                f"{source.name}; pass basename='...' (a name per call) or fullpath=... so "
                "that each log has its own golden file",
                pytrace=False,
            )
        self._checked.add(source.resolve())
        claimed = self._request.config.stash.setdefault(_CLAIMED, {})
        owner = claimed.setdefault(source.resolve(), node.nodeid)
        if owner != node.nodeid:  # --update-golden would write the file twice, last one wins
            owner_name = owner.rpartition("::")[2]
            fix = "pass another basename='...' or fullpath=..."
            if paths_basename == _file_stem(owner_name) == _file_stem(node.name):
                fix = (
                    f"the test names {owner_name} and {node.name} differ only in characters "
                    "the file name replaces with '_'; give the parameters ids that differ in "
                    "letters or digits (pytest.param(..., id='...')) or pass basename='...'"
                )
            pytest.fail(
                f"log_golden.check({log.name!r}): the golden file {source.name} is already "
                f"that of {owner} in this run; {fix}, so that each test has its own golden file",
                pytrace=False,
            )
        if tolerance is not None:  # before the work, named as the test wrote it
            checked_tolerance(tolerance, f"log_golden.check(tolerance=...) for {source.name}")
        if self._request.config.getoption("update_golden"):
            dump(source)
            return
        perform_regression_check(
            datadir=self._datadir,
            original_datadir=self._original_datadir,
            request=self._request,
            check_fn=compare,
            dump_fn=dump,
            extension=EXTENSION,
            basename=paths_basename if fullpath is None else None,
            fullpath=None if fullpath is None else Path(fullpath),
        )


def _naming(err: Exception, copy: Path, source: Path) -> GoldenToleranceError:
    """Return the error naming the golden file beside the test, not the run's copy of it."""
    message = str(err)
    if message.startswith(f"{copy}: "):
        message = f"{source}{message.removeprefix(str(copy))}"
    return GoldenToleranceError(message)


def _file_stem(test_name: str) -> str:
    """Return the golden file name of a test without extension (pytest-regressions' naming)."""
    return re.sub(r"[\W]", "_", test_name)


@pytest.fixture
def log_golden(
    request: pytest.FixtureRequest, lazy_datadir: Any, original_datadir: Path
) -> LogGolden:
    """Check a log against a golden file beside the test: ``log_golden.check(path)``."""
    return LogGolden(request, lazy_datadir, original_datadir)
