"""The log_golden fixture on a tiny fabricated log: first run, pass, fail, regenerate."""

from __future__ import annotations

import json
from pathlib import Path

import numpy.fft  # noqa: F401 - see _run
import pytest

pytest_plugins = ["pytester"]

TEST = """
import json
from pathlib import Path

import numpy as np

from pcainterp_stream.records import StereoCamera, SynthFrame
from pcainterp_stream.synth.log import write_synthetic_log

SCALE = {scale}
CAMERA = StereoCamera(width=40, height=30, fx=30.0, fy=30.0, cx=19.5, cy=14.5, baseline=0.5)


def write_log(path, scale=SCALE):
    rng = np.random.default_rng(0)
    frames = []
    for i in range(2):
        depth = rng.uniform(3.0, 60.0, size=CAMERA.image_size).astype(np.float32) * scale
        depth[:5] = np.nan
        grey = rng.integers(0, 256, size=CAMERA.image_size, dtype=np.uint8)
        frames.append(SynthFrame(i, 10**9 + i * 10**8, grey, grey, depth, np.eye(4), CAMERA))
    write_synthetic_log(frames, path)
    return path


def test_log(tmp_path, log_golden):
    log_golden.check(write_log(tmp_path / "a.mcap"), arrays={arrays})
"""


def _write(pytester: pytest.Pytester, *, scale: float, arrays: bool = False) -> None:
    pytester.makepyfile(test_tiny=TEST.format(scale=scale, arrays=arrays))


def _run(pytester: pytest.Pytester, *args: str) -> pytest.RunResult:
    # in this process (a fresh one each is ~10x slower): a run drops the modules first
    # imported inside it, and numpy.fft's compiled module (which the comparison's imports
    # reach) cannot load twice per process, so it is imported above, before any run
    # pytest-benchmark, where installed, warns in a run inside an xdist worker (an error here)
    return pytester.runpytest("-q", "-p", "no:cacheprovider", "-p", "no:benchmark", *args)


@pytest.mark.parametrize("arrays", [False, True])
def test_first_run_pass_fail_and_force_regen(pytester: pytest.Pytester, arrays: bool) -> None:
    _write(pytester, scale=1.0, arrays=arrays)
    golden = pytester.path / "test_tiny" / "test_log.golden.json"
    _run(pytester).assert_outcomes(failed=1)
    assert golden.is_file()
    assert golden.with_suffix(".npz").is_file() == arrays
    _run(pytester).assert_outcomes(passed=1)

    _write(pytester, scale=1.0 + 1e-7, arrays=arrays)  # last bits: within tolerance
    _run(pytester).assert_outcomes(passed=1)

    _write(pytester, scale=1.05, arrays=arrays)
    failed = _run(pytester)
    failed.assert_outcomes(failed=1)
    failed.stdout.fnmatch_lines(
        [
            "*a.mcap differs from the golden file*",
            "*/ground_truth/depth #0 (stamp 1.000000000 s): image mean * (moved *, tolerance *)",
        ]
    )
    if arrays:
        failed.stdout.fnmatch_lines(["*image elements * beyond atol*"])
    before = golden.read_text()
    _run(pytester, "--force-regen").assert_outcomes(failed=1)  # rewritten, for review
    assert golden.read_text() != before
    _run(pytester).assert_outcomes(passed=1)

    _write(pytester, scale=1.0, arrays=arrays)
    _run(pytester, "--update-golden").assert_outcomes(passed=1)
    _run(pytester).assert_outcomes(passed=1)


def test_old_format_is_a_failure_that_force_regen_fixes(pytester: pytest.Pytester) -> None:
    _write(pytester, scale=1.0)
    golden = pytester.path / "test_tiny" / "test_log.golden.json"
    golden.parent.mkdir()
    golden.write_text('{"format": "pcainterp-golden/1", "channels": []}')
    result = _run(pytester)
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*old format pcainterp-golden/1*"])
    _run(pytester, "--force-regen").assert_outcomes(failed=1)
    _run(pytester).assert_outcomes(passed=1)


def test_fixture_is_registered_by_the_entry_point(pytester: pytest.Pytester) -> None:
    result = _run(pytester, "--fixtures")
    result.stdout.fnmatch_lines(["*log_golden*", "*Check a log against a golden file beside*"])
    assert Path(__file__).exists()


TWICE = """
from test_tiny import write_log


def test_twice(tmp_path, log_golden):
    log_golden.check(write_log(tmp_path / "a.mcap"){first})
    log_golden.check(write_log(tmp_path / "b.mcap"){second})
"""


def test_a_second_check_needs_its_own_basename(pytester: pytest.Pytester) -> None:
    _write(pytester, scale=1.0)
    pytester.makepyfile(test_twice=TWICE.format(first="", second=""))
    _run(pytester, "test_twice.py").assert_outcomes(failed=1)  # the first file is written
    result = _run(pytester, "test_twice.py")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(
        [
            "*log_golden.check('b.mcap'): this test already checked a log against "
            "test_twice.golden.json; pass basename=*"
        ]
    )
    result.stdout.no_fnmatch_line("*Traceback*")
    pytester.makepyfile(test_twice=TWICE.format(first="", second=', basename="raw"'))
    _run(pytester, "test_twice.py").assert_outcomes(failed=1)  # raw.golden.json written
    _run(pytester, "test_twice.py").assert_outcomes(passed=1)
    assert (pytester.path / "test_twice" / "raw.golden.json").is_file()


TOLERANCE = """
from test_tiny import write_log


def test_tol(tmp_path, log_golden):
    log_golden.check(write_log(tmp_path / "a.mcap"), tolerance={tolerance})
"""


def test_a_bad_tolerance_fails_in_one_line_and_an_edited_file_is_not_replaced(
    pytester: pytest.Pytester,
) -> None:
    _write(pytester, scale=1.0)
    golden = pytester.path / "test_tol" / "test_tol.golden.json"
    pytester.makepyfile(test_tol=TOLERANCE.format(tolerance='{"flaot": {"rel": 0.5}}'))
    result = _run(pytester, "test_tol.py")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(
        [
            'log_golden.check(tolerance=...) for test_tol.golden.json: tolerance[[]"flaot"[]] '
            'is not a tolerance (did you mean "float"?); the keys of tolerance are note, *'
        ]
    )
    result.stdout.no_fnmatch_line("*Traceback*")
    assert not golden.exists()  # not written with the misspelt key
    pytester.makepyfile(test_tol=TOLERANCE.format(tolerance='{"float": {"rel": 0.01}}'))
    _run(pytester, "test_tol.py").assert_outcomes(failed=1)  # written
    _run(pytester, "test_tol.py").assert_outcomes(passed=1)
    document = json.loads(golden.read_text())
    document["tolerance"]["channels"] = {"/ground_truth/dpeth": {"float": {"rel": "0.5"}}}
    golden.write_text(json.dumps(document))
    before = golden.read_text()
    for flags in ([], ["--update-golden"], ["--force-regen"]):
        result = _run(pytester, "test_tol.py", *flags)
        result.assert_outcomes(failed=1)
        result.stdout.fnmatch_lines(
            [
                f'{golden}: tolerance[[]"channels"[]][[]"/ground_truth/dpeth"[]] names no '
                'channel of the golden file (did you mean "/ground_truth/depth"?); *'
            ]
        )
        result.stdout.no_fnmatch_line("*Traceback*")
        assert golden.read_text() == before  # fixed by hand, never replaced


COLLIDE = """
import pytest

from test_tiny import write_log


@pytest.mark.parametrize("scale", [1.0, 2.0], ids={ids})
def test_scale(tmp_path, log_golden, scale):
    log_golden.check(write_log(tmp_path / "a.mcap"){basename})
"""


def test_ids_that_differ_only_in_punctuation_need_their_own_golden_files(
    pytester: pytest.Pytester,
) -> None:
    _write(pytester, scale=1.0)
    pytester.makepyfile(test_collide=COLLIDE.format(ids='["a/b", "a.b"]', basename=""))
    runs = [([], 0), (["--update-golden"], 1), ([], 1), (["--force-regen"], 1)]
    for flags, passed in runs:  # the first run writes test_scale[a/b]'s file
        result = _run(pytester, "test_collide.py", *flags)
        result.assert_outcomes(passed=passed, failed=2 - passed)
        result.stdout.fnmatch_lines(
            [
                "log_golden.check('a.mcap'): the golden file test_scale_a_b_.golden.json is "
                "already that of test_collide.py::test_scale[[]a/b[]] in this run; the test "
                "names test_scale[[]a/b[]] and test_scale[[]a.b[]] differ only in characters the "
                "file name replaces with '_'; give the parameters ids that differ in letters or "
                "digits (pytest.param(..., id='...')) or pass basename='...', so that each test "
                "has its own golden file"
            ]
        )
        result.stdout.no_fnmatch_line("*Traceback*")
    assert [p.name for p in (pytester.path / "test_collide").iterdir()] == [
        "test_scale_a_b_.golden.json"
    ]
    # a name given by one test only is not shared with a test named after it
    pytester.makepyfile(
        test_collide=COLLIDE.format(ids='["one", "two"]', basename="")
        + "\n\ndef test_other(tmp_path, log_golden):\n"
        "    log_golden.check(write_log(tmp_path / 'a.mcap'), basename='test_scale_one_')\n"
    )
    result = _run(pytester, "test_collide.py", "--update-golden")
    result.assert_outcomes(passed=2, failed=1)
    result.stdout.fnmatch_lines(
        [
            "*test_scale_one_.golden.json is already that of test_collide.py::test_scale[[]one[]] "
            "in this run; pass another basename='...' or fullpath=... (checks share a golden "
            "file only when each names it so), so that each test has its own golden file"
        ]
    )
    pytester.makepyfile(test_collide=COLLIDE.format(ids='["ab", "a_b"]', basename=""))
    _run(pytester, "test_collide.py", "--update-golden").assert_outcomes(passed=2)
    _run(pytester, "test_collide.py").assert_outcomes(passed=2)


SHARED = """
import pytest

from test_tiny import write_log

NAME = {name}


@pytest.mark.parametrize("scale", {scales}, ids=["one", "two"])
def test_path(tmp_path, log_golden, scale):
    log_golden.check(write_log(tmp_path / "a.mcap", scale), **NAME)
"""


@pytest.mark.parametrize("how", ["fullpath", "basename"])
def test_a_golden_file_named_by_several_tests_is_shared_and_written_once(
    pytester: pytest.Pytester, how: str
) -> None:
    _write(pytester, scale=1.0)
    golden = pytester.path / "shared" / "path.golden.json"
    name = {"fullpath": f"{{'fullpath': {str(golden)!r}}}", "basename": "{'basename': 'path'}"}
    if how == "basename":
        golden = pytester.path / "test_shared" / "path.golden.json"

    def run(*flags: str, scales: str = "[1.0, 1.0]") -> pytest.RunResult:
        pytester.makepyfile(test_shared=SHARED.format(name=name[how], scales=scales))
        return _run(pytester, "test_shared.py", *flags)

    # the same log: the first run writes the file once (one "created" failure), then all pass
    run().assert_outcomes(passed=1, failed=1)
    for flags in ([], ["--update-golden"], ["--force-regen"]):
        run(*flags).assert_outcomes(passed=2)
    written = golden.read_text()
    # logs that differ: whatever the flags, the second never rewrites the file the first
    # matched or wrote, and fails in one line naming both
    message = (
        "log_golden.check('a.mcap'): a.mcap differs from the shared golden file "
        "path.golden.json, which test_shared.py::test_path[[]one[]] (log a.mcap) {how} in this "
        "run, in * places beyond tolerance (first: /ground_truth/depth #0 *); checks that "
        "share a golden file must give the same log: fix the one that is wrong, or give each "
        "its own basename='...' or fullpath=..."
    )
    for flags in ([], ["--update-golden"], ["--force-regen"]):
        result = run(*flags, scales="[1.0, 1.05]")
        result.assert_outcomes(passed=1, failed=1)
        how_settled = "wrote" if flags == ["--update-golden"] else "matched"
        result.stdout.fnmatch_lines([message.format(how=how_settled)])
        result.stdout.no_fnmatch_line("*Traceback*")
        assert golden.read_text() == written
    result = run("--force-regen", scales="[1.05, 1.0]")  # the first rewrites it, for review
    result.assert_outcomes(failed=2)
    result.stdout.fnmatch_lines([message.format(how="wrote")])
    assert golden.read_text() != written
    run(scales="[1.05, 1.0]").assert_outcomes(passed=1, failed=1)


ONE_TEST = """
from pathlib import Path

from test_tiny import write_log


def test_paths(tmp_path, log_golden):
    golden = Path(__file__).parent / "agree.golden.json"
    log_golden.check(write_log(tmp_path / "a.mcap"), fullpath=golden)
    log_golden.check(write_log(tmp_path / "b.mcap", {scale}), fullpath=golden)
"""


def test_two_checks_of_one_test_may_share_a_named_golden_file(pytester: pytest.Pytester) -> None:
    _write(pytester, scale=1.0)
    pytester.makepyfile(test_agree=ONE_TEST.format(scale=1.0))
    _run(pytester, "test_agree.py").assert_outcomes(failed=1)  # created
    _run(pytester, "test_agree.py").assert_outcomes(passed=1)
    _run(pytester, "test_agree.py", "--update-golden").assert_outcomes(passed=1)
    pytester.makepyfile(test_agree=ONE_TEST.format(scale=1.05))
    result = _run(pytester, "test_agree.py", "--update-golden")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(
        [
            "log_golden.check('b.mcap'): b.mcap differs from the shared golden file "
            "agree.golden.json, which this test's check of 'a.mcap' wrote in this run, in *"
        ]
    )


TEST_OPTIONS = """
import os

from pcainterp_stream.golden import save_golden

{body}


def test_options(tmp_path, log_golden):
    topics = os.environ.get("T")
    log_golden.check(
        write_log(tmp_path / "a.mcap"),
        topics=topics.split(",") if topics else None,
        arrays=bool(os.environ.get("A")),
    )
"""


def _write_options(pytester: pytest.Pytester) -> None:
    body = TEST.format(scale=1.0, arrays=False).replace("def test_log(", "def _unused(")
    pytester.makepyfile(test_opts=TEST_OPTIONS.format(body=body))


def test_arrays_asked_of_a_file_saved_without_them_fails_naming_the_fix(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Bug hunt 10A F4: arrays=True against a file without arrays passed, checking none."""
    _write_options(pytester)
    _run(pytester).assert_outcomes(failed=1)  # first run: written without arrays
    monkeypatch.setenv("A", "1")
    result = _run(pytester)
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*was saved without arrays*--force-regen or --update-golden*"])
    _run(pytester, "--force-regen").assert_outcomes(failed=1)
    _run(pytester).assert_outcomes(passed=1)
    assert (pytester.path / "test_opts" / "test_options.golden.npz").is_file()


def test_topics_added_to_a_check_name_the_channels_left_out(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Bug hunt 10A F5: "channel missing from the log" for channels in the log."""
    _write_options(pytester)
    _run(pytester).assert_outcomes(failed=1)
    monkeypatch.setenv("T", "/ground_truth/depth")
    result = _run(pytester)
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*records channels that topics=* leaves out (*): pass them*"])
    assert "missing from the log" not in result.stdout.str()


CLASSES = """
from test_tiny import write_log


class TestA:
    def test_same(self, tmp_path, log_golden):
        log_golden.check(write_log(tmp_path / "a.mcap"))


class TestB:
    def test_same(self, tmp_path, log_golden):
        log_golden.check(write_log(tmp_path / "a.mcap", scale=2.0))
"""


def test_the_same_test_name_in_two_classes(pytester: pytest.Pytester) -> None:
    """Bug hunt 10A F2: --with-test-class-names was ignored and the message was wrong."""
    _write(pytester, scale=1.0)
    pytester.makepyfile(test_cls=CLASSES)
    result = _run(pytester, "test_cls.py")
    result.assert_outcomes(failed=2)
    result.stdout.fnmatch_lines(["*have the same name in different classes*"])
    assert "differ only in characters" not in result.stdout.str()
    _run(pytester, "test_cls.py", "--with-test-class-names").assert_outcomes(failed=2)
    _run(pytester, "test_cls.py", "--with-test-class-names").assert_outcomes(passed=2)
    folder = pytester.path / "test_cls"
    assert {p.name for p in folder.iterdir()} == {
        "test_same.golden.json",  # the first run's, TestA's
        "TestA_test_same.golden.json",
        "TestB_test_same.golden.json",
    }


def test_a_payload_that_does_not_decode_is_a_warning(pytester: pytest.Pytester) -> None:
    """Bug hunt 10A F11: the fixture dropped the notes; they reach the warnings summary."""
    pytester.makepyfile(
        test_video="""
from mcap_ros2.writer import Writer

from pcainterp_stream.io import rosmsg


def test_video(tmp_path, log_golden):
    path = tmp_path / "v.mcap"
    with path.open("wb") as stream:
        writer = Writer(stream)
        schema = writer.register_msgdef(
            rosmsg.COMPRESSED_IMAGE, rosmsg.schema_text(rosmsg.COMPRESSED_IMAGE)
        )
        message = {"header": {"stamp": {"sec": 1, "nanosec": 0}, "frame_id": "c"},
                   "format": "h264", "data": bytes(range(200))}
        writer.write_message("/video", schema, message, log_time=10**9, publish_time=10**9)
        writer.finish()
    log_golden.check(path)
"""
    )
    _run(pytester).assert_outcomes(failed=1)
    result = _run(pytester, "-W", "default")
    result.assert_outcomes(passed=1, warnings=1)
    result.stdout.fnmatch_lines(["*GoldenNoteWarning*'h264' does not decode; its raw data bytes*"])



VIDEO_STAMP = """
import os

from mcap_ros2.writer import Writer

from pcainterp_stream.io import rosmsg


def write(path):
    with path.open("wb") as stream:
        writer = Writer(stream)
        schema = writer.register_msgdef(
            rosmsg.COMPRESSED_IMAGE, rosmsg.schema_text(rosmsg.COMPRESSED_IMAGE)
        )
        message = {"header": {"stamp": {"sec": 1, "nanosec": 0}, "frame_id": "c"},
                   "format": "h264", "data": bytes(range(200))}
        stamp = int(os.environ.get("STAMP", "1")) * 10**9
        writer.write_message("/video", schema, message, log_time=stamp, publish_time=stamp)
        writer.finish()
    return path


def test_video(tmp_path, log_golden):
    log_golden.check(write(tmp_path / "v.mcap"))


def test_shared_a(tmp_path, log_golden):
    log_golden.check(write(tmp_path / "v.mcap"), basename="shared")


def test_shared_b(tmp_path, log_golden, monkeypatch):
    monkeypatch.setenv("STAMP", "2")
    log_golden.check(write(tmp_path / "v.mcap"), basename="shared")
"""


def test_a_failing_check_reports_its_differences_and_notes_under_filterwarnings_error(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Review 58c C6: under ``filterwarnings = error`` the note's warning replaced the failure
    (raised in ``finally``; on a shared file before the differences were reported at all)."""
    pytester.makepyfile(test_h264=VIDEO_STAMP)
    alone = ("-k", "test_video")
    _run(pytester, "-W", "default", *alone).assert_outcomes(failed=1)  # written
    _run(pytester, "-W", "default", *alone).assert_outcomes(passed=1, warnings=1)
    monkeypatch.setenv("STAMP", "5")  # the log differs from its golden file now
    result = _run(pytester, *alone)  # warnings are errors, as in this repo
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*v.mcap differs from the golden file*"])
    result.stdout.fnmatch_lines(["*notes (GoldenNoteWarning*'h264' does not decode*"])
    result.stdout.no_fnmatch_line("*During handling of the above exception*")
    # a shared file: the second check differs from what the first settled in this run
    monkeypatch.delenv("STAMP")
    _run(pytester, "-W", "default", "-k", "shared_a").assert_outcomes(failed=1)  # written
    result = _run(pytester, "-k", "shared")
    result.assert_outcomes(failed=2)  # a: its note raised as the error; b: the differences
    result.stdout.fnmatch_lines(["*differs from the shared golden file shared.golden.json*"])
    result.stdout.fnmatch_lines(["*shared.golden.json: /video #0: *'h264' does not decode*"])


POSES = """
from pathlib import Path

from mcap_ros2.writer import Writer

from pcainterp_stream.golden import save_golden

GOLDEN = Path(__file__).parent / "poses.golden.json"


def write(path, scale):
    with path.open("wb") as stream:
        writer = Writer(stream)
        name = "geometry_msgs/msg/PoseArray"
        from pcainterp_stream.io import rosmsg
        schema = writer.register_msgdef(name, rosmsg.schema_text(name))
        poses = [{"position": {"x": i * scale, "y": 0.0, "z": 0.0},
                  "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}} for i in range(100)]
        message = {"header": {"stamp": {"sec": 1, "nanosec": 0}, "frame_id": "map"},
                   "poses": poses}
        writer.write_message("/path", schema, message, log_time=10**9, publish_time=10**9)
        writer.finish()
    return path


def test_poses(tmp_path, log_golden):
    if not GOLDEN.exists():
        save_golden(write(tmp_path / "a.mcap", 1.0), GOLDEN, format_version=2)
    log_golden.check(write(tmp_path / "b.mcap", 1.0), fullpath=GOLDEN)
"""


def test_a_format_2_file_still_passes_and_warns_what_it_leaves_out(
    pytester: pytest.Pytester,
) -> None:
    """A format-2 golden file is compared with the log summarised as format 2 recorded it."""
    pytester.makepyfile(test_poses=POSES)
    result = _run(pytester, "-W", "default")
    result.assert_outcomes(passed=1, warnings=1)
    result.stdout.fnmatch_lines(["*format 2 records these 100 items by their count only*"])
    assert '"pcainterp-golden/2"' in (pytester.path / "poses.golden.json").read_text()


def test_force_regen_rewrites_a_matching_format_2_file_its_note_names(
    pytester: pytest.Pytester,
) -> None:
    # review 58a R6: the note says "rewrite it with --force-regen or --update-golden", but
    # --force-regen left a matching format-2 file as it was (pytest-regressions rewrites
    # only files whose check fails): still format 2, the same warning on every run
    pytester.makepyfile(test_poses=POSES)
    golden = pytester.path / "poses.golden.json"
    _run(pytester, "-W", "default").assert_outcomes(passed=1, warnings=1)
    result = _run(pytester, "-W", "default", "--force-regen")
    result.assert_outcomes(failed=1)  # rewritten, for review, as files that differ
    result.stdout.fnmatch_lines(
        ["*rewrote the golden file *poses.golden.json in format pcainterp-golden/3*"]
    )
    assert '"pcainterp-golden/3"' in golden.read_text()
    result = _run(pytester, "-W", "default")
    result.assert_outcomes(passed=1)
    result.stdout.no_fnmatch_line("*GoldenNoteWarning*")
    # --update-golden rewrites it too (and passes, as it does for files that differ)
    golden.unlink()
    _run(pytester, "-W", "default").assert_outcomes(passed=1, warnings=1)  # format 2 again
    assert '"pcainterp-golden/2"' in golden.read_text()
    _run(pytester, "-W", "default", "--update-golden").assert_outcomes(passed=1)
    assert '"pcainterp-golden/3"' in golden.read_text()


def test_regenerating_on_xdist_workers_is_warned_once(pytester: pytest.Pytester) -> None:
    # before (bug hunt 17B F3): `-n 2 --update-golden` with two cases sharing a golden file
    # but giving different logs passed both, silently: the rules hold within one worker
    pytester.makepyfile(test_plain="def test_a():\n    pass\n\ndef test_b():\n    pass\n")
    # review 17d R4: the plugin loads in every run; a run with no log_golden check (other
    # regression tests alone) was warned too
    result = _run(pytester, "-n", "2", "--update-golden")
    result.assert_outcomes(passed=2)
    assert "log_golden: warning" not in result.stdout.str()
    pytester.makepyfile(test_poses=POSES)
    result = _run(pytester, "-n", "2", "--update-golden")
    result.assert_outcomes(passed=3)
    assert result.stdout.str().count("log_golden: warning: golden files were rewritten") == 1
    assert "regenerate golden files without xdist (-p no:xdist, or -n 0)" in result.stdout.str()
    for args in (["-n", "2"], ["-n", "1", "--update-golden"], ["-p", "no:xdist", "--force-regen"]):
        quiet = _run(pytester, *args)
        quiet.assert_outcomes(passed=3)
        assert "log_golden: warning" not in quiet.stdout.str(), args
