"""A running Dask scheduler: its address checked, an unreachable one and one without workers."""

from __future__ import annotations

import contextlib
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from pcainterp_stream.errors import PcaInterpError, SchedulerError
from pcainterp_stream.io.output_paths import partial_prefix
from pcainterp_stream.pipeline import densify_fleet, distributed, jobs, scheduler

pytest.importorskip("dask.distributed")


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("scheduler") / "a.mcap"
    jobs.synth(path, frames=2, seed=3, scale=0.25, fmt="mcap")
    return path


@pytest.fixture
def empty_scheduler() -> Iterator[Any]:
    """A scheduler with no worker, in this process (a few tenths of a second to start)."""
    from dask.distributed import LocalCluster

    with LocalCluster(  # type: ignore[no-untyped-call]
        n_workers=0, processes=False, protocol="tcp", host="127.0.0.1", dashboard_address=":0"
    ) as cluster:
        yield cluster


@pytest.fixture
def closed_port() -> Iterator[str]:
    """The address of a port nothing listens on; Dask's connect timeout cut to 0.5 s."""
    import dask

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with dask.config.set({"distributed.comm.timeouts.connect": "0.5s"}):
        yield f"tcp://127.0.0.1:{port}"


@pytest.mark.parametrize(
    "address", ["tcp://10.0.0.5:8786", "10.0.0.5:8786", "tcp://[::1]:8786", "tls://h:1", " h:1 "]
)
def test_check_address_takes_what_dask_connects_to(address: str) -> None:
    assert scheduler.check_address(address) == address.strip()


@pytest.mark.parametrize(
    ("address", "why"),
    [
        ("tcp//bad", "missing port number"),
        ("", "missing port number"),
        ("localhost", "missing port number"),
        ("http://127.0.0.1:8786", "http:// is not one of Dask's schemes"),
        ("foo:bar:baz", "invalid address"),
        ("inproc://x", "inside this process only"),
        ("tcp://h:0", "port 0 is not in 1-65535"),
        ("tcp://:8786", "no host"),
    ],
)
def test_check_address_refuses_a_malformed_one_naming_it_and_the_form(
    address: str, why: str
) -> None:
    with pytest.raises(SchedulerError, match=why) as info:
        scheduler.check_address(address)
    assert str(info.value).startswith(f"{address!r} is not a Dask scheduler address")
    assert str(info.value).endswith("give tcp://HOST:PORT, e.g. tcp://10.0.0.5:8786")


@pytest.mark.parametrize("command", ["densify", "learn"])
def test_cli_refuses_a_malformed_scheduler_before_reading_any_input(
    command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from pcainterp_stream import cli

    missing = tmp_path / "missing.mcap"  # read first, the error would name it
    where = ["--out-dir", str(tmp_path / "d")] if command == "densify" else ["-o", "b.npz"]
    assert cli.main([command, str(missing), *where, "--scheduler", "tcp//bad"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "pcainterp: error: --scheduler 'tcp//bad' is not a Dask scheduler address (missing "
        "port number in address 'tcp//bad'); give tcp://HOST:PORT, e.g. tcp://10.0.0.5:8786"
    ]


@pytest.mark.parametrize("command", ["densify", "learn"])
def test_cli_says_it_connects_and_an_unreachable_scheduler_is_one_line(
    command: str,
    log: Path,
    closed_port: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from pcainterp_stream import cli

    out = tmp_path / "d"
    where = ["--out-dir", str(out)] if command == "densify" else ["-o", str(tmp_path / "b.npz")]
    started = time.monotonic()
    assert cli.main([command, str(log), *where, "--scheduler", closed_port]) == 2
    assert time.monotonic() - started < 10
    err = capsys.readouterr().err.splitlines()
    port = closed_port.rsplit(":", 1)[1]
    assert err == [
        f"connecting to the Dask scheduler at {closed_port} (waiting up to 0.5 s)",
        f"pcainterp: error: cannot reach the Dask scheduler at {closed_port} (no answer within "
        f"0.5 s); start one there (dask scheduler --port {port}) or give the address of a "
        "running one",
    ]
    assert not out.exists()
    assert not (tmp_path / "b.npz").exists()


@pytest.mark.parametrize("command", ["densify", "learn"])
def test_cli_says_a_scheduler_has_no_workers_and_gives_up_after_the_wait(
    command: str,
    log: Path,
    empty_scheduler: Any,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from pcainterp_stream import cli

    address = empty_scheduler.scheduler_address
    out = tmp_path / "d"
    where = ["--out-dir", str(out)] if command == "densify" else ["-o", str(tmp_path / "b.npz")]
    args = [command, str(log), *where, "--scheduler", address, "--worker-wait", "0.5"]
    assert cli.main(args) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[-2:] == [
        f"the Dask scheduler at {address} has no workers; waiting up to 0.5 s for one "
        f"(start some: dask worker {address})",
        f"pcainterp: error: the Dask scheduler at {address} has no workers and none joined "
        f"within 0.5 s; start some (dask worker {address}) and run again",
    ]
    assert not out.exists()
    assert not (tmp_path / "b.npz").exists()


def test_cli_refuses_a_worker_wait_without_a_scheduler_or_not_positive(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from pcainterp_stream import cli

    args = ["densify", str(tmp_path / "a.mcap"), "--out-dir", str(tmp_path / "d")]
    assert cli.main([*args, "--workers", "1", "--worker-wait", "5"]) == 2
    assert cli.main([*args, "--scheduler", "h:1", "--worker-wait", "0"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "pcainterp: error: --worker-wait is the wait for a --scheduler's workers; add --scheduler",
        "pcainterp: error: --worker-wait must be > 0 seconds, got 0",
    ]


@pytest.mark.parametrize("job", ["densify", "learn"])
def test_a_job_says_when_the_workers_are_gone_and_gives_up_after_the_wait(
    job: str, log: Path, empty_scheduler: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The last worker leaves the scheduler before the job's tasks ran: the tasks would
    stay queued forever; the watch says so at once and fails after the wait."""
    from pcainterp_stream.frontend.pairing import PairingConfig

    monkeypatch.setattr(scheduler, "WATCH_INTERVAL", 0.05)
    address = empty_scheduler.scheduler_address
    empty_scheduler.scale(1)
    notes: list[str] = []
    import dask

    with (
        dask.config.set({"distributed.comm.timeouts.connect": "30s"}),  # whatever the user's
        scheduler.connect(address, worker_wait=0.5, say=notes.append) as client,
    ):
        client.wait_for_workers(1)
        client.retire_workers()
        deadline = time.monotonic() + 30
        while client.scheduler_info()["workers"]:
            assert time.monotonic() < deadline, "the retired worker did not leave"
            time.sleep(0.05)
        options = jobs.LearnOptions(n_components=2, fit_prior=False)
        run = (
            (lambda: distributed.densify_many([log], tmp_path / "d", None, client))
            if job == "densify"
            else (
                lambda: distributed.learn_distributed(
                    [log], tmp_path / "b.npz", options, PairingConfig(), client
                )
            )
        )
        started = time.monotonic()
        with pytest.raises(SchedulerError) as info:
            run()
        assert time.monotonic() - started < 5
    assert str(info.value) == (
        f"the Dask scheduler at {address} has had no workers for 0.5 s with tasks still to "
        f"run; start some (dask worker {address}) and run again"
    )
    assert notes == [
        f"connecting to the Dask scheduler at {address} (waiting up to 30 s)",
        f"the Dask scheduler at {address} has no workers left; waiting up to 0.5 s for one "
        f"(start some: dask worker {address})",
    ]
    assert not (tmp_path / "d").exists()  # nor a staging folder in it
    assert not (tmp_path / "b.npz").exists()


class _Futures:
    """An ``as_completed`` whose one future finishes after ``ready_after`` looks."""

    def __init__(self, ready_after: int) -> None:
        import threading

        self.looks = 0
        self.ready_after = ready_after
        self.thread_condition = threading.Condition()
        self.done = False

    def has_ready(self) -> bool:
        self.looks += 1
        return not self.done and self.looks > self.ready_after

    def is_empty(self) -> bool:
        return self.done

    def __next__(self) -> str:
        self.done = True
        return "future"


class _Client:
    """A client whose scheduler's workers come and go: one count per look."""

    def __init__(self, counts: list[int]) -> None:
        self.counts = counts

    def scheduler_info(self) -> dict[str, Any]:
        count = self.counts.pop(0) if len(self.counts) > 1 else self.counts[0]
        return {"workers": dict.fromkeys(range(count))}


def test_the_watch_says_when_workers_are_gone_and_back(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(scheduler, "WATCH_INTERVAL", 0.0)
    client = _Client([2, 0, 0, 1])
    notes: list[str] = []
    watch = scheduler.WorkerWatch(client, "tcp://h:1", 30.0, notes.append)
    monkeypatch.setitem(scheduler._WATCHES, client, watch)
    assert list(scheduler.completed(_Futures(ready_after=6), client)) == ["future"]
    assert notes == [
        "the Dask scheduler at tcp://h:1 has no workers left; waiting up to 30 s for one "
        "(start some: dask worker tcp://h:1)",
        "the Dask scheduler at tcp://h:1 has a worker again; going on",
    ]


# ------------------------------------------------- paths the workers do not see (5B, L1)

SHARED = "at the same paths (a shared filesystem)"


def _thread_cluster() -> Any:
    """A scheduler on a TCP port with one worker in a thread of this process."""
    from dask.distributed import LocalCluster

    return LocalCluster(  # type: ignore[no-untyped-call]
        n_workers=1,
        threads_per_worker=1,
        processes=False,
        protocol="tcp",
        host="127.0.0.1",
        dashboard_address=":0",
    )


@pytest.fixture
def one_worker() -> Iterator[Any]:
    """A scheduler with one worker in a thread of this process (it sees these files)."""
    with _thread_cluster() as cluster:
        yield cluster


def _worker(client: Any) -> str:
    [address] = client.scheduler_info()["workers"]
    return str(address)


def test_a_log_the_worker_does_not_see_is_its_view_on_a_running_scheduler(
    one_worker: Any, tmp_path: Path
) -> None:
    """Not "does not exist; pass an MCAP file": the user's machine may have it."""
    from dask.distributed import Client

    missing = tmp_path / "priv" / "a.mcap"
    with scheduler.connect(one_worker.scheduler_address) as client:
        [outcome] = distributed.densify_many([missing], tmp_path / "d", None, client)
        worker = _worker(client)
    assert outcome.error == (
        f"{missing} does not exist on the Dask worker ({worker}): the workers need the logs "
        f"and --out-dir {SHARED}"
    )
    assert not outcome.unexpected
    assert list((tmp_path / "d").iterdir()) == []  # no staging folder left
    with Client(one_worker) as local:  # a local cluster shares this machine's files
        assert not scheduler.running_scheduler(local)
        [outcome] = distributed.densify_many([missing], tmp_path / "d", None, local)
    assert outcome.error is not None
    assert outcome.error.startswith(f"{missing} does not exist; pass an MCAP file")


def test_cli_names_an_out_dir_the_worker_does_not_share_not_its_staging_folder(
    one_worker: Any,
    log: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The worker's --out-dir is another folder: the staging folder made here is not in it."""
    from types import SimpleNamespace

    from pcainterp_stream import cli

    def elsewhere(prefix: str, dir: Path) -> str:  # made on "another machine": not here
        return str(Path(dir) / f"{prefix}gone")

    monkeypatch.setattr(densify_fleet, "tempfile", SimpleNamespace(mkdtemp=elsewhere))
    out = tmp_path / "out"
    address = one_worker.scheduler_address
    assert cli.main(["densify", str(log), "--out-dir", str(out), "--scheduler", address]) == 1
    [worker] = one_worker.scheduler_info["workers"]
    err = capsys.readouterr().err.splitlines()
    staging = partial_prefix(out / "a_dense.mcap") + "gone"  # .a_dense.mcap.partial-PID@HOST-
    assert err[-1] == (
        f"pcainterp: error: {log}: --out-dir {out} on the Dask worker ({worker}) is not the "
        f"folder this command wrote to (the staging folder {staging} it made "
        f"there is missing): the workers need the logs and --out-dir {SHARED} (1 of 1 logs done)"
    )
    assert "create it first" not in "\n".join(err)


@pytest.mark.parametrize("missing", ["basis", "out_dir"])
def test_a_basis_or_out_dir_the_worker_does_not_see(
    one_worker: Any, log: Path, tmp_path: Path, missing: str
) -> None:
    basis = tmp_path / "b.npz"
    paths = scheduler.WorkerPaths((log,), basis, tmp_path / "out", tmp_path / "out" / ".s")
    if missing == "out_dir":
        basis.write_bytes(b"")
    with scheduler.connect(one_worker.scheduler_address) as client:
        future = client.submit(distributed.run_task, scheduler.checked, paths, len, ())
        with pytest.raises(PcaInterpError) as info:
            distributed.task_result(future, "densifying")
        worker = _worker(client)
    what = f"--basis {basis}" if missing == "basis" else f"--out-dir {tmp_path / 'out'}"
    assert str(info.value) == (
        f"{what} does not exist on the Dask worker ({worker}): the workers need the logs, "
        f"--basis and --out-dir {SHARED}"
    )


def test_learning_tasks_name_a_log_the_worker_does_not_see(one_worker: Any, tmp_path: Path) -> None:
    from pcainterp_stream.frontend.pairing import PairingConfig

    missing = tmp_path / "priv" / "a.mcap"
    options, pairing = jobs.LearnOptions(n_components=2, fit_prior=False), PairingConfig()
    with scheduler.connect(one_worker.scheduler_address) as client:
        worker = _worker(client)
        message = (
            f"{missing} does not exist on the Dask worker ({worker}): the workers need the "
            f"logs {SHARED}"
        )
        chunks = distributed._reduce(client, [(missing, 0, None)], options, pairing, 3)
        with pytest.raises(PcaInterpError) as info:
            distributed.task_result(chunks, "a learning task")
        assert str(info.value) == message
        with pytest.raises(PcaInterpError) as info:
            distributed.measure_on_cluster(client, [(missing, 0)], options, pairing)
        assert str(info.value) == message


@pytest.fixture
def odd_server(request: pytest.FixtureRequest) -> Iterator[str]:
    """A TCP server that accepts and says nothing ("silent") or answers as HTTP ("http")."""
    import threading

    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(8)
    held: list[socket.socket] = []

    def serve() -> None:
        while True:
            try:
                conn, _ = listener.accept()
            except OSError:
                return
            held.append(conn)
            if request.param == "http":
                conn.recv(100)
                conn.sendall(b"HTTP/1.1 400 Bad Request\r\ncontent-length: 0\r\n\r\n")
                conn.close()

    threading.Thread(target=serve, daemon=True).start()
    try:
        yield f"127.0.0.1:{listener.getsockname()[1]}"
    finally:
        listener.close()
        for conn in held:
            conn.close()


@pytest.mark.parametrize(
    ("odd_server", "says"),
    [
        ("silent", "accepted the connection but did not answer as a Dask scheduler within 1 s"),
        ("http", "answered, but not as a Dask scheduler (an HTTP server?"),
    ],
    indirect=["odd_server"],
)
def test_cli_an_address_that_is_no_dask_scheduler_is_one_line_within_the_timeout(
    odd_server: str, says: str, log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import dask

    from pcainterp_stream import cli

    started = time.monotonic()
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        code = cli.main(
            ["learn", str(log), "-o", str(tmp_path / "b.npz"), "--scheduler", odd_server]
        )
    assert code == 2
    assert time.monotonic() - started < 5  # was: for ever (silent), a MemoryError (http)
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2, err
    assert err[1].startswith(f"pcainterp: error: {odd_server} {says}")
    assert "8786" in err[1]
    assert not (tmp_path / "b.npz").exists()


def test_a_local_worker_that_dies_is_one_note_not_dask_s_log_line(
    capfd: pytest.CaptureFixture[str],
) -> None:
    # the nanny's own records, as it logs them when its worker process dies (a test that
    # killed a real worker depended on Dask restarting it in time, and hung or failed
    # under load)
    import logging

    nanny = logging.getLogger("distributed.nanny")
    handler = logging.StreamHandler()  # Dask's own handler writes to stderr so
    nanny.addHandler(handler)
    notes: list[str] = []
    try:
        with scheduler._worker_deaths_noted(notes.append):
            nanny.warning("Restarting worker")
            nanny.error("Failed to restart worker after its process exited")
        nanny.warning("outside the job: Dask's own line")
    finally:
        nanny.removeHandler(handler)
    assert notes == ["note: a Dask worker died; its tasks are run again"]
    err = capfd.readouterr().err
    assert "Restarting worker" not in err
    assert "Failed to restart" not in err
    assert "outside the job" in err  # the filter is gone with the job


# ------------------------------------------------- a scheduler lost mid-job (bug hunt 7B F10)

_RELEASE = __import__("threading").Event()


def _held(value: int) -> int:
    """A task that runs until the test releases it (a worker thread of this process)."""
    _RELEASE.wait(30)
    return value


@pytest.fixture
def doomed() -> Iterator[Any]:
    """:func:`one_worker`'s cluster, whose scheduler the test closes: its worker, closing
    after it, retries the scheduler for Dask's connect timeout, here cut to 0.2 s."""
    import dask

    cluster = _thread_cluster()
    try:
        yield cluster
    finally:
        _RELEASE.set()
        with dask.config.set({"distributed.comm.timeouts.connect": "0.2s"}):
            cluster.close()  # type: ignore[no-untyped-call]


@pytest.mark.parametrize("when", ["running", "submitted after"])
def test_a_scheduler_lost_mid_job_is_one_line_at_once_not_a_wait_for_ever(
    when: str, doomed: Any, capfd: pytest.CaptureFixture[str]
) -> None:
    """The scheduler closed while completed() waits: Dask's client cancels the job's
    futures and reconnects for its connect timeout; one submitted meanwhile never finishes.
    Was: the cancelled future yielded as a result ("unexpected FutureCancelledError"), or a
    wait for ever ("no workers left" first), and Dask's ERROR lines on stderr."""
    import threading

    import dask
    from dask.distributed import as_completed

    address = doomed.scheduler_address
    notes: list[str] = []
    raised: list[BaseException] = []
    _RELEASE.clear()
    with (
        dask.config.set({"distributed.comm.timeouts.connect": "30s"}),
        scheduler.connect(address, worker_wait=30, say=notes.append) as client,
    ):
        futures = [client.submit(_held, 1, pure=False)]
        if when == "submitted after":
            doomed.sync(doomed.scheduler.close)
            while client.status == "running":
                time.sleep(0.01)
            futures = [client.submit(_held, 2, pure=False)]  # pending for ever

        def iterate() -> None:
            try:
                list(scheduler.completed(as_completed(futures), client))
            except BaseException as err:  # handed to the test
                raised.append(err)

        started = time.monotonic()
        thread = threading.Thread(target=iterate, daemon=True)
        thread.start()
        if when == "running":
            time.sleep(0.3)
            doomed.sync(doomed.scheduler.close)
        thread.join(10)
        assert not thread.is_alive(), "completed() still waits"
        assert time.monotonic() - started < 5  # the wait (30 s) and Dask's (30 s) not spent
    [error] = raised
    assert isinstance(error, SchedulerError)
    assert str(error) == (
        f"lost the connection to the Dask scheduler at {address} (it stopped, or the network "
        "to it failed); the tasks it held are lost with it: run again once it is back"
    )
    assert notes == [f"connecting to the Dask scheduler at {address} (waiting up to 30 s)"]
    assert "distributed.client" not in capfd.readouterr().err  # also once the client closed


def test_a_scheduler_restarted_by_another_client_is_not_a_lost_connection(doomed: Any) -> None:
    """Review 55c R55c-1: another client's ``client.restart()`` on a shared scheduler cancels
    this job's futures (Dask's reason "scheduler-restart"), the connection kept; it was
    said as "lost the connection to the Dask scheduler"."""
    import threading

    from dask.distributed import Client, as_completed

    address = doomed.scheduler_address
    _RELEASE.clear()
    with scheduler.connect(address, worker_wait=30, say=lambda _: None) as client:
        futures = [client.submit(_held, 1, pure=False)]

        def restart() -> None:
            time.sleep(0.3)
            with contextlib.suppress(Exception), Client(address) as other:  # type: ignore[no-untyped-call]
                other.restart(timeout=5, wait_for_workers=False)

        thread = threading.Thread(target=restart, daemon=True)
        thread.start()
        with pytest.raises(SchedulerError) as caught:
            list(scheduler.completed(as_completed(futures), client))
        assert client.status == "running"
        thread.join(10)
    assert str(caught.value) == (
        f"the Dask scheduler at {address} was restarted (by another client?) and cancelled "
        "this job's tasks; run again"
    )


def test_a_cancel_reason_other_than_a_restart_is_named() -> None:
    """The reason Dask gives is named; none, or a lost connection, is the lost scheduler."""
    from distributed.client import FutureCancelledError

    class Future:
        def __init__(self, reason: str | None) -> None:
            error = None if reason is None else FutureCancelledError("k", reason)
            self._state = type("State", (), {"exception": error})()

    class Client:
        status = "running"

    watch = scheduler.WorkerWatch(Client(), "tcp://h:1", 1.0, lambda _: None)
    assert str(watch.cancelled(Future("by-hand"))) == (
        "the Dask scheduler at tcp://h:1 cancelled this job's tasks (reason: by-hand); run again"
    )
    assert str(watch.cancelled(Future(None))).startswith("lost the connection")
    assert str(watch.cancelled(Future("scheduler-connection-lost"))).startswith("lost the")
    Client.status = "connecting"
    assert str(watch.cancelled(Future("scheduler-restart"))).startswith("lost the connection")


_NO_MAIN_GUARD = """
from pcainterp_stream.pipeline import scheduler
scheduler.WORKER_START_S = 8.0
with scheduler.connect(workers=1):
    pass
"""


def test_local_workers_that_cannot_start_are_one_error_not_a_wait_for_ever(
    tmp_path: Path,
) -> None:
    # a user's script without a main guard: every worker process imports it again and dies
    # starting a cluster of its own; the job waited for them for ever
    import subprocess
    import sys

    script = tmp_path / "no_guard.py"
    script.write_text(_NO_MAIN_GUARD)
    done = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode != 0
    assert "the 1 local Dask worker process did not start within 8 s" in done.stderr
    assert 'if __name__ == "__main__":' in done.stderr
