"""``densify --out-dir`` (pipeline/densify_fleet.py): names, progress, staging (bug hunt 12B).

A Dask cluster of one worker in threads of this process: it starts in about a second and
sees what this process patches.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import pytest

from pcainterp_stream.errors import PcaInterpError
from pcainterp_stream.io import output_paths
from pcainterp_stream.io.reader_base import MCAP_MAGIC
from pcainterp_stream.pipeline import densify_fleet, distributed, jobs

pytest.importorskip("dask.distributed")


@pytest.fixture(scope="module")
def client() -> Iterator[Any]:
    from dask.distributed import Client, LocalCluster

    cluster = LocalCluster(  # type: ignore[no-untyped-call]
        n_workers=1,
        threads_per_worker=2,
        processes=False,
        protocol="tcp",
        host="127.0.0.1",
        dashboard_address=":0",
    )
    with cluster, Client(cluster) as connected:  # type: ignore[no-untyped-call]
        yield connected


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("fleet") / "L7.mcap"
    jobs.synth(path, frames=4, seed=7, scale=0.25, fmt="mcap")
    return path


def _dead_pid() -> int:
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


def _partial_of(target: Path, pid: int, suffix: str, where: Path | None = None) -> Path:
    """A partial of ``target`` named as process ``pid`` of this machine names it."""
    prefix = output_paths.partial_prefix(target, where)
    prefix = prefix.replace(f"-{os.getpid()}@", f"-{pid}@")
    return (where or target.parent) / (prefix + suffix)


def test_outputs_are_named_after_the_links_given_not_their_target(
    log: Path, client: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    """F1: m1.mcap and m2.mcap, links onto one file (a data lake's, git-annex's blobs), were
    refused as "sharing a file name stem" (both the target's) or named L7_dense.mcap."""
    from pcainterp_stream import cli

    many = tmp_path / "many"
    many.mkdir()
    (many / "m1.mcap").symlink_to(log)
    (many / "m2.mcap").symlink_to(os.path.relpath(log, many))
    monkeypatch.setattr(distributed, "connect", lambda *args, **kwargs: nullcontext(client))
    monkeypatch.chdir(tmp_path)
    code = cli.main(["densify", "many/m1.mcap", "many/m2.mcap", "--out-dir", "k3"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert sorted(p.name for p in (tmp_path / "k3").iterdir()) == [
        "m1_dense.mcap",
        "m2_dense.mcap",
    ]
    for name in ("m1", "m2"):
        assert (
            f"densified 4 frames of {many / name}.mcap -> {tmp_path / 'k3' / name}_dense.mcap"
        ) in out
    assert "L7" not in out


def test_a_rosbag2_folder_s_whole_name_is_its_stem(tmp_path: Path) -> None:
    """F3: drive_v1.2_morning (a folder) wrote drive_v1_dense.mcap; a file keeps its stem."""
    folder = tmp_path / "drive_v1.2_morning"
    folder.mkdir()
    out = tmp_path / "out"
    assert densify_fleet.output_path(folder, out) == out / "drive_v1.2_morning_dense.mcap"
    assert densify_fleet.output_path(tmp_path / "run_1.5x.mcap", out) == out / "run_1.5x_dense.mcap"
    assert densify_fleet.output_path(tmp_path / "2024.05.01", out) == out / "2024.05_dense.mcap"


def test_two_inputs_of_one_stem_are_named_with_the_output_they_would_share(
    tmp_path: Path,
) -> None:
    """F4: the error named neither the inputs nor the stem (refused before any work)."""
    first, second, out = (
        tmp_path / "a" / "drive.mcap",
        tmp_path / "b" / "drive.mcap",
        tmp_path / "o",
    )
    with pytest.raises(PcaInterpError) as raised:
        densify_fleet.densify_many([tmp_path / "x.mcap", first, second], out, None, None)
    assert str(raised.value) == (
        f"{first} and {second} share the name stem 'drive', so both would write "
        f"{out / 'drive_dense.mcap'}; densify them into different --out-dir folders, or give "
        "one of them under another name (a symbolic link)"
    )
    with pytest.raises(PcaInterpError, match=r"x\.mcap is given twice; give each log once$"):
        densify_fleet.densify_many([tmp_path / "x.mcap", tmp_path / "x.mcap"], out, None, None)
    assert not out.exists()


def test_a_folder_given_as_dot_dot_is_named_after_itself(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Review 59b F5: `densify .. --out-dir D` from inside a rosbag2 folder wrote the hidden
    D/.._dense.mcap. `.` and `..` are taken lexically, links not followed."""
    notes = tmp_path / "morning" / "notes"
    notes.mkdir(parents=True)
    out = tmp_path / "D"
    expected = out / "morning_dense.mcap"
    assert densify_fleet.output_path(notes / "..", out) == expected
    assert densify_fleet.output_path(tmp_path / "morning" / ".", out) == expected
    assert densify_fleet.output_path(Path(f"{tmp_path}/morning/"), out) == expected
    monkeypatch.chdir(notes)
    assert densify_fleet.output_path(Path(".."), out) == expected
    assert densify_fleet.output_path(Path("../notes/.."), out) == expected
    monkeypatch.chdir(notes.parent)
    assert densify_fleet.output_path(Path("."), out) == expected
    (tmp_path / "latest").symlink_to(notes.parent)  # a link's own name, as for a log
    assert densify_fleet.output_path(tmp_path / "latest" / "notes" / "..", out) == (
        out / "latest_dense.mcap"
    )


def test_one_log_given_twice_through_dot_dot_or_a_link_is_said_so(tmp_path: Path) -> None:
    """Review 59b F6: `b1.mcap sub/../b1.mcap` got the "share the name stem" advice."""
    log = tmp_path / "b1.mcap"
    log.write_bytes(b"")
    (tmp_path / "sub").mkdir()
    (tmp_path / "alias").symlink_to(tmp_path)
    out = tmp_path / "o"
    for again in (tmp_path / "sub" / ".." / "b1.mcap", tmp_path / "alias" / "b1.mcap"):
        with pytest.raises(PcaInterpError) as raised:
            densify_fleet.densify_many([log, again], out, None, None)
        assert str(raised.value) == f"{log} and {again} are one log given twice; give each once"
    assert not out.exists()


_REPORTED = threading.Event()
"""Set when an outcome was handed over (a module's: Dask pickles a task's function)."""
_DENSIFY_ONE = densify_fleet._densify_one


def _waiting_densify_one(
    path: Path, output: Path, basis: Path | None, kwargs: dict[str, Any]
) -> Any:
    """densify_fleet's task, but late.mcap's waits until an outcome was handed over."""
    if path.name == "late.mcap":
        assert _REPORTED.wait(60), "no outcome was handed over before this task ended"
    return _DENSIFY_ONE(path, output, basis, kwargs)


def test_each_log_s_outcome_is_handed_over_as_its_task_is_done(
    log: Path, client: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """F2: every line came after the last log was done. Here the second log's task waits
    until the first log's outcome was handed over (in vain before: it waits 60 s)."""
    reported = _REPORTED
    reported.clear()
    monkeypatch.setattr(densify_fleet, "_densify_one", _waiting_densify_one)
    late = tmp_path / "late.mcap"
    late.symlink_to(log)
    seen: list[tuple[str, bool]] = []

    def on_outcome(outcome: densify_fleet.DensifyOutcome) -> None:
        seen.append((outcome.input.name, outcome.output.is_file()))
        reported.set()

    outcomes = densify_fleet.densify_many(
        [late, log], tmp_path / "out", None, client, on_outcome=on_outcome
    )
    assert [o.error for o in outcomes] == [None, None]
    assert seen == [("L7.mcap", True), ("late.mcap", True)]  # each committed before its turn


def test_cli_prints_each_log_when_done_with_a_count_and_names_the_failed_at_the_end(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    """F2: the lines come as each log is done, "(k of N logs done)"; the closing summary
    names each failed log and why."""
    from pcainterp_stream import cli

    printed: list[tuple[str, str]] = []

    def densify_many(inputs: list[Path], out_dir: Path, *args: Any, **kwargs: Any) -> Any:
        outcomes = [
            distributed.DensifyOutcome(inputs[1], out_dir / "b_dense.mcap", 3, 1.0, None),
            distributed.DensifyOutcome(inputs[0], out_dir / "a_dense.mcap", 0, 0.0, "a.mcap: bad"),
        ]
        for outcome in outcomes:
            kwargs["on_outcome"](outcome)
            printed.append(capsys.readouterr())  # what the command printed by then
        return outcomes[::-1]

    monkeypatch.setattr(distributed, "connect", lambda *args, **kwargs: nullcontext(None))
    monkeypatch.setattr(distributed, "densify_many", densify_many)
    a, b, out_dir = tmp_path / "a.mcap", tmp_path / "b.mcap", tmp_path / "out"
    # MCAP's magic bytes: densify --out-dir checks each input is a log before the cluster
    a.write_bytes(MCAP_MAGIC)
    b.write_bytes(MCAP_MAGIC)
    code = cli.main(["densify", str(a), str(b), "--out-dir", str(out_dir), "--workers", "1"])
    assert code == 1
    assert printed[0] == (
        f"densified 3 frames of {b} -> {out_dir / 'b_dense.mcap'} (1 of 2 logs done)\n",
        "",
    )
    assert printed[1] == ("", "pcainterp: error: a.mcap: bad (2 of 2 logs done)\n")
    end = capsys.readouterr().out.splitlines()
    assert end[0].startswith("1 of 2 logs densified, 3 frames in ")
    assert end[0].endswith(" s; 1 failed:")
    assert end[1:] == ["failed: a.mcap: bad"]


def test_a_task_run_again_says_the_partial_it_removes_is_this_run_s_own(
    log: Path, tmp_path: Path, capsys: Any
) -> None:
    """F5: after a worker died, its task's new attempt removed the partial output the dead
    attempt left in the staging folder "left by an earlier run that was killed"."""
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    target = out_dir / "L7_dense.mcap"
    staging = _partial_of(target, os.getpid(), "abc12345", out_dir)  # this run's
    staging.mkdir()
    output = staging / target.name
    dead = _partial_of(output, _dead_pid(), "def67890")  # the dead worker's writer's
    dead.write_bytes(bytes(1_500_000))
    densify_fleet._densify_one(log, output, None, {})
    err = capsys.readouterr().err
    assert "earlier run" not in err
    assert err.splitlines() == [
        "note: L7.mcap: removed the partial output of this run's own earlier attempt, whose "
        "Dask worker died (1.5 MB); densifying it again"
    ]
    assert sorted(p.name for p in staging.iterdir()) == [target.name]


def test_the_next_run_removes_every_dead_run_s_staging_folder(
    log: Path, client: Any, tmp_path: Path, capsys: Any
) -> None:
    """F6: a killed run's staging folders of other logs stayed until each of those logs was
    densified into DIR again (docs/cluster.md: the next run into DIR removes them)."""
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    other = out_dir / "h1_dense.mcap"
    dead = _partial_of(other, _dead_pid(), "abc12345")
    dead.mkdir()
    (dead / other.name).write_bytes(bytes(2_000_000))
    live = _partial_of(out_dir / "h2_dense.mcap", os.getppid(), "def67890")  # a run going on
    live.mkdir()
    not_ours = _partial_of(out_dir / "notes.txt", _dead_pid(), "ghi13579")  # not a staging one
    not_ours.mkdir()
    [outcome] = densify_fleet.densify_many([log], out_dir, None, client)
    assert outcome.error is None
    assert not dead.exists()
    assert live.is_dir()
    assert not_ours.is_dir()
    assert capsys.readouterr().err.splitlines() == [
        f"note: removed {other}'s partial output left by an earlier run that was killed (2.0 MB)"
    ]


def test_a_committed_log_s_task_is_released_not_run_again_when_its_worker_dies(
    log: Path, client: Any, tmp_path: Path
) -> None:
    """A worker killed mid-job made Dask re-run the tasks whose results it held, logs
    already committed ("lose already computed task(s)"): each task is released once done."""
    other = tmp_path / "other.mcap"
    other.symlink_to(log)
    held: list[int] = []

    def on_outcome(_: densify_fleet.DensifyOutcome) -> None:
        deadline = time.monotonic() + 5  # the client forgets a released task on its loop
        while len(client.futures) >= 2 - len(held) and time.monotonic() < deadline:
            time.sleep(0.01)
        held.append(len(client.futures))

    densify_fleet.densify_many([log, other], tmp_path / "out", None, client, on_outcome=on_outcome)
    assert held == [1, 0]  # was [2, 2]: the client kept every finished task until the end
