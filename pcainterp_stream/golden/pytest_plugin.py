"""The ``log_golden`` pytest fixture, registered through the ``pytest11`` entry point.

Installing pcainterp-stream is enough to use it::

    def test_my_pipeline(tmp_path, log_golden):
        out = run_my_pipeline(tmp_path)       # writes a log
        log_golden.check(out)

The first run writes the golden file beside the test, in pytest-regressions' layout
(``test_module/test_name.golden.json``), and fails so that it is reviewed; later runs
check the log against it and fail with the list of differences. ``--force-regen`` (the
pytest-regressions flag) rewrites the golden files that differ and fails those tests (a
matching file of an older format that leaves out something of the log too, as its note
says); ``--update-golden`` rewrites every golden file the run checks and passes.

The golden file is named after the test (``test_name.golden.json``); with pytest-regressions'
``--with-test-class-names`` a test method's after its class too (``TestA_test_name``).
Parts of the log the golden file cannot guard in full (a payload that does not decode, a
golden file of an older format) are reported as a :class:`GoldenNoteWarning` in pytest's
warnings summary.

A golden file named with ``basename=`` or ``fullpath=`` may be shared by several checks (the
cases of a parametrized test that must all give the same log, two code paths that must
agree): the first check of the run that matches or writes it settles it, and the others
compare with it, never rewrite it, failing in one line naming both when their logs differ.

Under pytest-xdist "the run" is one worker: each worker keeps its own record of the files
checked, so neither that rule nor the refusal of two tests whose ids give one file name
holds across workers (two cases on two workers that give different logs both pass, and the
file holds whichever wrote last). A run that regenerates (``--update-golden``,
``--force-regen``) on several workers says so once at its end; regenerate without xdist
(``-p no:xdist`` or ``-n 0``).

The snapshot machinery (naming, the data directory beside the test, the first-run and
``--force-regen`` flow) is pytest-regressions' ``perform_regression_check``; this module
supplies only how a log is dumped (:func:`~.store.save_golden`) and compared
(:func:`~.store.check_log`).
"""

from __future__ import annotations

import re
import shutil
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from pcainterp_stream.errors import GoldenError, GoldenToleranceError

if TYPE_CHECKING:
    from pcainterp_stream.golden.comparison import Difference

__all__ = ["GoldenNoteWarning", "LogGolden", "log_golden"]

EXTENSION = ".golden.json"
MAX_LINES = 40
MAX_NOTES = 5


class GoldenNoteWarning(UserWarning):
    """A part of a checked log its golden file does not guard in full (shown, not failed)."""


@dataclass
class _Claim:
    """The first check of a golden file in a run, and the one that settled it."""

    node_id: str  # the test that first checked the file
    named: bool  # by basename= or fullpath=: other checks naming it too may share it
    settled: tuple[str, str, str] | None = None  # (node id, log name, "wrote"/"matched")


_CLAIMED = pytest.StashKey[dict[Path, _Claim]]()
"""The golden files the session's tests have checked: resolved path -> its claim."""


def pytest_addoption(parser: pytest.Parser) -> None:
    """Add ``--update-golden``."""
    group = parser.getgroup("log_golden", "golden-file tests of logs (pcainterp-stream)")
    group.addoption(
        "--update-golden",
        action="store_true",
        default=False,
        help="rewrite every log_golden golden file the run checks, and pass",
    )


XDIST_NOTE = (
    "log_golden: warning: golden files were rewritten (--update-golden/--force-regen) under "
    "pytest-xdist: each worker is a run of its own, so checks that share a golden file "
    "(basename=/fullpath=) were not compared across workers, nor two tests whose ids give "
    "one file name refused, and such a file holds whichever worker wrote it last; "
    "regenerate golden files without xdist (-p no:xdist, or -n 0)"
)
"""Said once at the end of a run that regenerates golden files on several xdist workers."""


def _on_xdist_workers(config: pytest.Config) -> bool:
    """Whether this is the controller of a pytest-xdist run on more than one worker."""
    if hasattr(config, "workerinput"):  # a worker: the controller says it, once
        return False
    try:
        dist = config.getoption("dist")
        workers = config.getoption("numprocesses")
    except ValueError:  # xdist not installed, or -p no:xdist
        return False
    return bool(dist != "no" and workers != 1)  # -n 0: dist "no"; --tx specs: workers None


_WORKERS_CHECKED = pytest.StashKey[bool]()
"""On the xdist controller: whether a worker checked a golden file (``log_golden`` ran)."""


def pytest_sessionfinish(session: pytest.Session) -> None:
    """On an xdist worker, tell the controller whether a ``log_golden`` check ran."""
    output = getattr(session.config, "workeroutput", None)
    if output is not None:
        output["log_golden_checked"] = bool(session.config.stash.get(_CLAIMED, {}))


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node: Any, error: Any) -> None:
    """On the xdist controller, note a worker that checked a golden file (review 17d R4)."""
    if getattr(node, "workeroutput", {}).get("log_golden_checked"):
        node.config.stash[_WORKERS_CHECKED] = True


@pytest.hookimpl(trylast=True)
def pytest_terminal_summary(terminalreporter: Any, config: pytest.Config) -> None:
    """Warn that the run's shared-file rules held only within each xdist worker (17B F3).

    A line, not a warning: a project with ``filterwarnings = error`` (this one) would turn a
    warning into a failed start.
    """
    regenerating = config.getoption("update_golden") or config.getoption("force_regen", False)
    checked = config.stash.get(_WORKERS_CHECKED, False)  # not a run of other tests alone
    if regenerating and checked and _on_xdist_workers(config):
        terminalreporter.write_line(XDIST_NOTE, yellow=True)


class LogGolden:
    """Check logs against golden files stored beside the test (the ``log_golden`` fixture).

    Attributes:
        max_lines: how many differences a failure lists before their count.
    """

    def __init__(self, request: pytest.FixtureRequest, datadir: Any, original_datadir: Path):
        self._request = request
        self._datadir = datadir
        self._original_datadir = Path(original_datadir)
        self._checked: dict[Path, bool] = {}  # golden files this test checked -> named
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
                Checks that name one file (``basename=`` or ``fullpath=``) share it: the
                first of the run to match or write it settles it, the others must match it
                (under pytest-xdist: of the worker's run only, see the module's note).
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
                did (parametrized ids that differ only in punctuation map to one file name)
                and not both named it; the log differs from a shared golden file another
                check of the run settled; or the golden file's tolerances, or
                ``tolerance``, are not valid.
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

        from pcainterp_stream.golden.comparison import count_differences, format_differences
        from pcainterp_stream.golden.store import (
            FORMAT,
            FORMAT_VERSION,
            OLDEST_FORMAT_VERSION,
            checked_tolerance,
            compare_documents,
            format_version,
            load_golden,
            save_golden,
            topic_selection,
        )

        log = Path(log)
        selected = topic_selection(topics)
        node = self._request.node
        named = basename is not None or fullpath is not None
        paths_basename = self._test_stem() if basename is None else basename
        source = (
            Path(fullpath)
            if fullpath is not None
            else self._original_datadir / f"{paths_basename}{EXTENSION}"
        )
        key = source.resolve()
        claim = self._claim(log, key, source, named=named, paths_basename=paths_basename)

        notes: list[str] = []
        older: list[str] = []  # the older format of a golden file the notes say to rewrite

        def dump(path: Path, version: int = FORMAT_VERSION) -> None:
            kept = tolerance
            if path.exists() and not path.name.endswith(".obtained" + EXTENSION):
                try:
                    kept = load_golden(path).get("tolerance", tolerance)
                except GoldenToleranceError:
                    raise
                except GoldenError:  # an unreadable or old file is simply replaced
                    kept = tolerance
            try:
                summary = save_golden(
                    log,
                    path,
                    topics=selected,
                    arrays=arrays,
                    tolerance=kept,
                    format_version=version,
                )
            except GoldenToleranceError as err:  # an override of a channel the log lacks
                raise _naming(err, path, source) from None
            notes[:] = summary.notes
            if path == source:
                claim.settled = (node.nodeid, log.name, "wrote")

        def differences(obtained: Path, expected: Path) -> list[Difference]:
            try:
                golden = load_golden(expected)
                _refuse_other_selection(golden, source, selected, arrays)
                name = golden.get("arrays_file")
                if name and not (expected.parent / name).exists():
                    # the lazy data directory copied the JSON only
                    shutil.copy2(source.parent / name, expected.parent / name)
                if format_version(golden) < FORMAT_VERSION:  # summarised as it was written
                    dump(obtained, OLDEST_FORMAT_VERSION)
                    if notes:  # only what the older format leaves out is noted
                        older[:] = [str(golden["format"])]
                        notes.append(
                            f"{source.name} has the older format {golden['format']}, which "
                            "leaves these out; rewrite it with --force-regen or --update-golden"
                        )
                return compare_documents(golden, expected, load_golden(obtained), obtained)
            except GoldenToleranceError as err:
                raise _naming(err, expected, source) from None
            except GoldenError as err:  # an old format: --force-regen rewrites it
                raise AssertionError(
                    f"{err}\n(rerun with --force-regen or --update-golden)"
                ) from err

        def compare(obtained: Path, expected: Path) -> None:
            __tracebackhide__ = True
            found = differences(obtained, expected)
            if found:
                raise AssertionError(
                    f"{log.name} differs from the golden file {source} in "
                    f"{count_differences(found)}:\n"
                    + format_differences(found, self.max_lines)
                    + "\n(rerun with --force-regen or --update-golden to accept the log)"
                )
            if older and self._request.config.getoption("force_regen"):
                # a matching file pytest-regressions would keep: the note names --force-regen
                dump(source)
                pytest.fail(
                    f"rewrote the golden file {source} in format {FORMAT} "
                    f"(--force-regen: it had the older format {older[0]}, which leaves out "
                    "what the notes say); rerun without --force-regen",
                    pytrace=False,
                )
            claim.settled = claim.settled or (node.nodeid, log.name, "matched")

        if tolerance is not None:  # before the work, named as the test wrote it
            checked_tolerance(tolerance, f"log_golden.check(tolerance=...) for {source.name}")
        settled = claim.settled
        if settled is not None and (settled[0] != node.nodeid or key in self._checked):
            # shared, and settled by another check of the run: compared, never rewritten
            self._checked[key] = named
            stem = f"{source.name.removesuffix(EXTENSION)}.shared{len(self._checked)}"
            obtained = self._datadir / f"{stem}.obtained{EXTENSION}"
            dump(obtained)
            found = differences(obtained, source)
            if found:  # the notes go into the failure: a warning raised first would hide it
                self._fail_shared(log, source, settled, found, _noted(log, source, notes))
            _warn(log, source, notes)
            return
        self._checked[key] = named
        try:
            if self._request.config.getoption("update_golden"):
                dump(source)
            else:
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
        except (Exception, pytest.fail.Exception) as err:  # under `filterwarnings = error` a
            # warning raised here would replace the failure (review 58c C6)
            _add_notes(err, _noted(log, source, notes))
            raise
        _warn(log, source, notes)

    def _test_stem(self) -> str:
        """Return the golden file name of this test, as pytest-regressions names it."""
        node = self._request.node
        stem = _file_stem(node.name)
        cls = getattr(node, "cls", None)
        if cls is not None and self._request.config.getoption("with_test_class_names", False):
            stem = f"{_file_stem(cls.__name__)}_{stem}"
        return stem

    def _claim(
        self, log: Path, key: Path, source: Path, *, named: bool, paths_basename: str
    ) -> _Claim:
        """Return the run's claim on a golden file; fail when this check may not share it."""
        __tracebackhide__ = True
        node = self._request.node
        if key in self._checked and not (named and self._checked[key]):
            pytest.fail(
                f"log_golden.check({log.name!r}): this test already checked a log against "
                f"{source.name}; pass basename='...' (a name per call) or fullpath=... so "
                "that each log has its own golden file",
                pytrace=False,
            )
        claims = self._request.config.stash.setdefault(_CLAIMED, {})
        claim = claims.setdefault(key, _Claim(node.nodeid, named))
        if claim.node_id != node.nodeid and not (named and claim.named):
            # --update-golden would write the file twice, last one wins
            owner_name = claim.node_id.rpartition("::")[2]
            fix = "pass another basename='...' or fullpath=..."
            owner_class = claim.node_id.rpartition("::")[0]
            node_class = node.nodeid.rpartition("::")[0]
            if not named and owner_name == node.name and owner_class != node_class:
                fix = (
                    f"the tests {claim.node_id} and {node.nodeid} have the same name in "
                    "different classes; run with --with-test-class-names (the class name "
                    "then prefixes the file name) or pass basename='...'"
                )
            elif not named and paths_basename == _file_stem(owner_name) == _file_stem(node.name):
                fix = (
                    f"the test names {owner_name} and {node.name} differ only in characters "
                    "the file name replaces with '_'; give the parameters ids that differ in "
                    "letters or digits (pytest.param(..., id='...')) or pass basename='...'"
                )
            else:
                fix += " (checks share a golden file only when each names it so)"
            pytest.fail(
                f"log_golden.check({log.name!r}): the golden file {source.name} is already "
                f"that of {claim.node_id} in this run; {fix}, so that each test has its own "
                "golden file",
                pytrace=False,
            )
        return claim

    def _fail_shared(
        self,
        log: Path,
        source: Path,
        settled: tuple[str, str, str],
        found: list[Difference],
        noted: str | None = None,
    ) -> None:
        """Fail in one line: the log differs from a shared file another check settled."""
        __tracebackhide__ = True
        node_id, log_name, how = settled
        who = (
            f"this test's check of {log_name!r}"
            if node_id == self._request.node.nodeid
            else f"{node_id} (log {log_name})"
        )
        count = len(found)
        pytest.fail(
            f"log_golden.check({log.name!r}): {log.name} differs from the shared golden file "
            f"{source.name}, which {who} {how} in this run, in {count} "
            f"place{'s' if count > 1 else ''} beyond tolerance (first: {found[0]}); checks "
            "that share a golden file must give the same log: fix the one that is wrong, or "
            "give each its own basename='...' or fullpath=..." + (f"\n{noted}" if noted else ""),
            pytrace=False,
        )


def _refuse_other_selection(
    golden: Mapping[str, Any], source: Path, selected: list[str] | None, arrays: bool
) -> None:
    """Fail naming the fix when the call asks for other channels or arrays than the file has.

    Raises:
        AssertionError: ``topics=`` leaves out channels the file records, or ``arrays=True``
            and the file was saved without arrays (no element-wise check would run).
    """
    __tracebackhide__ = True
    rerun = "rerun with --force-regen or --update-golden"
    if selected is not None:
        left_out = [topic for topic in golden["channels"] if topic not in selected]
        if left_out:
            shown = ", ".join(left_out[:6]) + (
                f" and {len(left_out) - 6} more" * (len(left_out) > 6)
            )
            raise AssertionError(
                f"the golden file {source} records channels that topics={selected!r} leaves "
                f"out ({shown}): pass them in topics=, or {rerun} to record only those topics"
            )
    if arrays and not golden.get("arrays_file"):
        raise AssertionError(
            f"the golden file {source} was saved without arrays, so arrays=True would check "
            f"no element; {rerun} to add them"
        )


def _noted(log: Path, source: Path, notes: list[str]) -> str | None:
    """Return the notes of a check in one line (at most :data:`MAX_NOTES`), None without."""
    if not notes:
        return None
    shown = notes[:MAX_NOTES]
    if len(notes) > MAX_NOTES:
        shown.append(f"... and {len(notes) - MAX_NOTES} more notes")
    return f"log_golden.check({log.name!r}) against {source.name}: " + "; ".join(shown)


def _warn(log: Path, source: Path, notes: list[str]) -> None:
    """Show the notes of a check that passed in pytest's warnings summary."""
    noted = _noted(log, source, notes)
    if noted is not None:
        warnings.warn(GoldenNoteWarning(noted), stacklevel=4)


def _add_notes(err: BaseException, noted: str | None) -> None:
    """Add a failed check's notes to its failure's message (not a warning: review 58c C6)."""
    if noted is None:
        return
    text = f"notes ({GoldenNoteWarning.__name__}, not failures themselves): {noted}"
    if isinstance(err, pytest.fail.Exception):
        err.msg = f"{err.msg}\n{text}" if err.msg else text
    elif isinstance(err, AssertionError) and len(err.args) == 1:
        err.args = (f"{err.args[0]}\n{text}",)
    else:
        err.add_note(text)


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
