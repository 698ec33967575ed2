"""Connect to Dask: a running scheduler, checked and watched, or a local cluster of our own.

A scheduler's address is checked before any work (:func:`check_address`), the connection
is announced before Dask's connect timeout could pass in silence, and an address that
cannot be reached, stays silent after taking the connection (the dashboard's port) or
answers as something else (an HTTP server) is one
:class:`~pcainterp_stream.errors.SchedulerError` within the connect timeout, not a wait
without end or Dask's traceback (:func:`_probe`). A scheduler without workers would queue
the tasks forever: the command says so at once, waits a bounded time for a worker
(:data:`DEFAULT_WORKER_WAIT`) and gives up in one line naming the address and
``dask worker ADDRESS``; while tasks are pending, :func:`completed` notices when the last
worker is gone and does the same. A scheduler that is lost while the job runs (it stopped,
its node or the network to it failed) is one :class:`SchedulerError` at once (Dask's client
has cancelled the job's tasks, and the tasks submitted since never run), not a wait for
ever, and Dask's client logs nothing meanwhile (:func:`_client_log_dropped`).

A running scheduler's workers may be other machines, with other files: a task there
checks the paths it needs first (:class:`WorkerPaths`, :func:`checked`) and names a missing
one as the worker's view, not as the user's mistake.

A local cluster's worker processes leave SIGINT and SIGTERM to the command, and are killed
at once when its block ends with an exception (:func:`connect`, :func:`stop_local_workers`);
a worker that dies while it runs is one note, not Dask's log line (:class:`_WorkerDeaths`).
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import signal
import sys
import threading
import time
import weakref
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pcainterp_stream.errors import (
    BasisError,
    ClusterTaskError,
    LogReadError,
    LogWriteError,
    PcaInterpError,
    SchedulerError,
)

__all__ = [
    "DEFAULT_WORKER_WAIT",
    "QUIET_TRACKER",
    "WorkerPaths",
    "WorkerWatch",
    "check_address",
    "checked",
    "completed",
    "connect",
    "running_scheduler",
    "stop_local_workers",
]

QUIET_TRACKER = "ignore:resource_tracker:UserWarning"
"""The warnings filter that keeps the resource tracker's leaked-semaphore warning quiet."""

DEFAULT_WORKER_WAIT = 60.0
"""Seconds a job waits for a worker when the scheduler has none (at the start or later)."""

WATCH_INTERVAL = 1.0
"""Seconds between two looks at the scheduler's workers while tasks are pending."""

WORKER_START_S = 90.0
"""How long a local cluster's worker processes may take to start before the job gives up."""

EXAMPLE = "tcp://HOST:PORT, e.g. tcp://10.0.0.5:8786"

_WATCHES: weakref.WeakKeyDictionary[Any, WorkerWatch] = weakref.WeakKeyDictionary()


def check_address(address: str) -> str:
    """Return a scheduler address as Dask reads it (surrounding blanks dropped), or refuse it.

    Accepted: what a ``dask.distributed.Client`` connects to, ``tcp://HOST:PORT`` or
    ``HOST:PORT`` (tcp), ``[::1]:PORT`` for IPv6, and the schemes ``tls``, ``ws``, ``wss``
    and ``ucx``. Nothing is resolved or contacted.

    Raises:
        SchedulerError: no port, an unknown scheme (``http://``), ``inproc://`` (this
            process only), an empty host or a port outside 1-65535.
    """
    from distributed.comm.addressing import parse_address, parse_host_port
    from distributed.comm.registry import backends

    text = address.strip()
    try:
        scheme, location = parse_address(text, strict=False)
        if scheme == "inproc":
            raise ValueError("inproc:// reaches a scheduler inside this process only")
        if scheme not in backends:
            known = ", ".join(f"{name}://" for name in sorted(backends) if name != "inproc")
            raise ValueError(f"{scheme}:// is not one of Dask's schemes, {known}")
        host, port = parse_host_port(location)
        if not host:
            raise ValueError("no host")
        if not 0 < int(port) < 65536:
            raise ValueError(f"port {port} is not in 1-65535")
    except ValueError as err:
        raise SchedulerError(
            f"{address!r} is not a Dask scheduler address ({err}); give {EXAMPLE}"
        ) from None
    return text


@contextlib.contextmanager
def connect(
    scheduler: str | None = None,
    workers: int | None = None,
    *,
    worker_wait: float = DEFAULT_WORKER_WAIT,
    say: Callable[[str], object] | None = None,
) -> Iterator[Any]:
    """Yield a ``dask.distributed.Client``: to ``scheduler``, or to a new local cluster.

    A running scheduler is checked (:func:`check_address`), the connection announced
    (``say``), and its workers watched while tasks wait (:func:`completed`): with none the
    job waits ``worker_wait`` seconds for one, then fails.

    A local cluster's worker processes leave SIGINT and SIGTERM to the command
    (:func:`_start_workers`): a Ctrl-C at the terminal reaches its whole process group, and
    a worker left to the default handling prints a ``KeyboardInterrupt`` traceback and goes
    on with its task. When the block ends with an exception (an interruption, a failed
    task) they are killed at once (:func:`stop_local_workers`), and Dask's logging is
    silenced until the cluster is closed: Dask would otherwise report the tasks it cancels
    and the workers it finds still running.

    Args:
        scheduler: address of a running scheduler (``tcp://host:8786``), or None.
        workers: worker processes of a new ``LocalCluster`` (one thread each) when no
            scheduler is given; default 2.
        worker_wait: seconds to wait for a worker when the scheduler has none.
        say: called with each note on the connection and the workers (one line each).

    Yields:
        The connected client (closed, with its local cluster, on exit).

    Raises:
        SchedulerError: a malformed or unreachable address, or no worker within
            ``worker_wait`` seconds.
    """
    if scheduler is not None:
        with _scheduler_client(scheduler, worker_wait, say or _quiet) as client:
            yield client
        return
    from dask.distributed import Client, LocalCluster

    # multiprocessing's resource tracker (a process of its own, started with this
    # interpreter's -W options) warns of the semaphores of workers a Ctrl-C ended: it
    # removes them all the same, so the warning is noise under the one-line message
    if QUIET_TRACKER not in sys.warnoptions:
        sys.warnoptions.append(QUIET_TRACKER)
    # the cluster is made without workers (the scheduler alone, a few tenths of a second)
    # and they are added once it is bound here, so an interruption while they start
    # still finds and stops them; closing restores the logging last
    with contextlib.ExitStack() as after_close, contextlib.ExitStack() as stack:
        stack.enter_context(_worker_deaths_noted(say or _quiet))
        cluster = stack.enter_context(
            LocalCluster(  # type: ignore[no-untyped-call]
                n_workers=0,
                threads_per_worker=1,
                processes=True,
                # any free port for its HTTP server: ":8787" may be taken by another cluster
                dashboard_address=":0",
            )
        )
        client = stack.enter_context(Client(cluster))  # type: ignore[no-untyped-call]
        children = set(multiprocessing.active_children())
        try:
            _start_workers(cluster, client, workers or 2)
            yield client
        except BaseException:
            after_close.enter_context(_logging_silenced())
            stop_local_workers(client)
            # the worker processes still starting (Dask lists them once all have started):
            # killed too, else closing the cluster waits for them to start and then stop
            for process in set(multiprocessing.active_children()) - children:
                process.kill()
            raise


def _quiet(line: str) -> None:
    """Say nothing (a caller that passed no ``say``)."""


@contextlib.contextmanager
def _scheduler_client(
    address: str, worker_wait: float, say: Callable[[str], object]
) -> Iterator[Any]:
    """Yield a client of the scheduler at ``address`` that has (or got) a worker."""
    import dask
    from dask.distributed import Client
    from dask.utils import parse_timedelta

    address = check_address(address)
    timeout = parse_timedelta(dask.config.get("distributed.comm.timeouts.connect"), "s")
    say(f"connecting to the Dask scheduler at {address} (waiting up to {timeout:g} s)")
    _probe(address, timeout)
    try:
        client = Client(address)  # type: ignore[no-untyped-call]
    except (OSError, ValueError, TypeError, ImportError) as err:  # TimeoutError is an OSError
        raise _unreachable(address, timeout, err) from None
    # Dask's client logs a lost scheduler (its reconnection, its traceback, "Failed to
    # reconnect ... closing client", also when it is closed while reconnecting): the
    # watch says it in one line instead, until the client is closed
    with _client_log_dropped(), client:
        watch = WorkerWatch(client, address, worker_wait, say)
        watch.wait_for_first()
        _WATCHES[client] = watch
        try:
            yield client
        except Exception as err:
            # Dask's own errors (a closed client's ClosedClientError) and a task's unexpected
            # one (its future cancelled) are the lost scheduler's; a task's own error stays
            unexpected = isinstance(err, ClusterTaskError) or not isinstance(err, PcaInterpError)
            if unexpected and _lost(client):
                raise watch.lost() from None
            raise
        finally:
            _WATCHES.pop(client, None)


def _lost(client: Any) -> bool:
    """Whether ``client`` lost its scheduler: it reconnects (its tasks cancelled) or closed."""
    return getattr(client, "status", "running") not in ("running", "newly-created")


def _cancel_reason(future: Any) -> str | None:
    """Dask's reason for cancelling ``future`` (``"scheduler-restart"``, ...), None if unknown.

    A cancelled future's ``exception()`` is None: the reason is on its state's
    ``FutureCancelledError`` (Dask 2024.2 and later).
    """
    error = getattr(getattr(future, "_state", None), "exception", None)
    reason = getattr(error, "reason", None)
    return reason if isinstance(reason, str) else None


class _DroppedRecords(logging.Filter):
    """Drops every record of the logger it filters."""

    def filter(self, record: logging.LogRecord) -> bool:
        return False


@contextlib.contextmanager
def _client_log_dropped() -> Iterator[None]:
    """While a running scheduler's client is open: ``distributed.client`` logs nothing."""
    logger = logging.getLogger("distributed.client")
    dropped = _DroppedRecords()
    logger.addFilter(dropped)
    try:
        yield
    finally:
        logger.removeFilter(dropped)


NOT_A_SCHEDULER = (
    "give the address of a running scheduler (it listens on port 8786 unless told "
    "otherwise; 8787 is its dashboard's)"
)


def _unreachable(address: str, timeout: float, err: BaseException) -> SchedulerError:
    """Return the error of a scheduler address that did not take the connection."""
    text = str(err).splitlines()[0] if str(err) else type(err).__name__
    reason = f"no answer within {timeout:g} s" if "Timed out" in text else text
    _host, _sep, port = address.rpartition(":")
    return SchedulerError(
        f"cannot reach the Dask scheduler at {address} ({reason}); start one there "
        f"(dask scheduler --port {port}) or give the address of a running one"
    )


def _probe(address: str, timeout: float) -> None:
    """Connect to ``address`` and finish Dask's handshake within about ``timeout`` seconds.

    Dask's connect timeout bounds the TCP connection only; its handshake then waits without
    a bound for a reply that an HTTP server (the dashboard's port) or a silent listener
    never sends, and reads an HTTP answer as a frame length (a MemoryError). The whole
    connection is bounded here, by the timeout and a second more (Dask's own timeout of the
    TCP part ends first, so an address that takes no connection is told apart from one
    that takes it and stays silent), and anything but a Dask reply is one line.

    Raises:
        SchedulerError: the address did not connect, stayed silent or is no Dask scheduler.
    """
    import asyncio

    from distributed.comm.core import CommClosedError, FatalCommClosedError
    from distributed.comm.core import connect as comm_connect
    from distributed.security import Security

    async def handshake() -> None:
        args = Security().get_connection_args("client")  # type: ignore[no-untyped-call]
        comm = await comm_connect(address, timeout=timeout, **args)  # type: ignore[no-untyped-call]
        await comm.close()

    async def bounded() -> None:
        await asyncio.wait_for(handshake(), timeout + min(1.0, timeout))

    try:
        asyncio.run(bounded())
    except TimeoutError:  # ours: the TCP connection was made (Dask's own timeout is OSError)
        raise SchedulerError(
            f"{address} accepted the connection but did not answer as a Dask scheduler "
            f"within {timeout:g} s (is it the dashboard's port?); {NOT_A_SCHEDULER}"
        ) from None
    except FatalCommClosedError as err:  # before any connection (a TLS setting)
        raise _unreachable(address, timeout, err) from None
    except CommClosedError:
        raise SchedulerError(
            f"{address} accepted the connection and closed it without answering as a Dask "
            f"scheduler; {NOT_A_SCHEDULER}"
        ) from None
    except OSError as err:
        raise _unreachable(address, timeout, err) from None
    except Exception:  # an HTTP reply read as a frame: a MemoryError, a ValueError...
        raise SchedulerError(
            f"{address} answered, but not as a Dask scheduler (an HTTP server? the "
            f"dashboard's port?); {NOT_A_SCHEDULER}"
        ) from None


@dataclass
class WorkerWatch:
    """Notices a scheduler without workers; mutable: when the count was last seen at 0.

    Attributes:
        client: the connected client.
        address: the scheduler's address, for the messages.
        wait: seconds to wait for a worker before giving up.
        say: called with each note (one line).
        empty_since: ``time.monotonic()`` when no worker was seen first, None while some are.
        unanswered_since: ``time.monotonic()`` of the first look the scheduler did not
            answer, None while it answers.
        next_look: ``time.monotonic()`` of the next look at the workers.
    """

    client: Any
    address: str
    wait: float
    say: Callable[[str], object]
    empty_since: float | None = field(default=None)
    unanswered_since: float | None = field(default=None)
    next_look: float = field(default=0.0)

    def _hint(self) -> str:
        return f"dask worker {self.address}"

    def lost(self, why: str = "it stopped, or the network to it failed") -> SchedulerError:
        """Return the error of a scheduler lost while the job runs."""
        return SchedulerError(
            f"lost the connection to the Dask scheduler at {self.address} ({why}); the tasks "
            "it held are lost with it: run again once it is back"
        )

    def cancelled(self, future: Any) -> SchedulerError:
        """Return the error of a task of the job cancelled without a lost connection.

        The client still connected, the scheduler cancelled the task itself: Dask's reason
        ``scheduler-restart`` is a ``client.restart()`` (another client's, on a shared
        scheduler); another reason is named as Dask gives it.
        """
        reason = _cancel_reason(future)
        if _lost(self.client) or reason in (None, "scheduler-connection-lost"):
            return self.lost()
        if reason == "scheduler-restart":
            return SchedulerError(
                f"the Dask scheduler at {self.address} was restarted (by another client?) "
                "and cancelled this job's tasks; run again"
            )
        return SchedulerError(
            f"the Dask scheduler at {self.address} cancelled this job's tasks (reason: "
            f"{reason}); run again"
        )

    def check_connected(self) -> None:
        """Raise :meth:`lost` when the client lost its scheduler (a cheap look, no message).

        Dask's client, on losing the scheduler, cancels every task of the job at once and
        tries to reconnect for its connect timeout, then closes: the job is lost either way.

        Raises:
            SchedulerError: the client reconnects or is closed.
        """
        if _lost(self.client):
            raise self.lost()

    def workers(self) -> int | None:
        """Return how many workers the scheduler has, None when it cannot be asked."""
        try:
            return len(self.client.scheduler_info()["workers"])
        except Exception:  # a lost scheduler: the pending tasks' own errors say so
            return None

    def wait_for_first(self) -> None:
        """Return once the scheduler has a worker; say so and wait if it has none.

        Raises:
            SchedulerError: none joined within ``wait`` seconds.
        """
        self.check_connected()
        if self.workers() != 0:
            return
        self.say(
            f"the Dask scheduler at {self.address} has no workers; waiting up to "
            f"{self.wait:g} s for one (start some: {self._hint()})"
        )
        try:
            self.client.wait_for_workers(1, timeout=self.wait)
        except (TimeoutError, OSError):  # Dask's TimeoutError (an OSError)
            self.check_connected()
            raise SchedulerError(
                f"the Dask scheduler at {self.address} has no workers and none joined within "
                f"{self.wait:g} s; start some ({self._hint()}) and run again"
            ) from None

    def check(self) -> None:
        """Look at the workers (at most every :data:`WATCH_INTERVAL` s) while tasks wait.

        Says when the last worker is gone and when one is back. A lost scheduler fails at
        once (:meth:`check_connected`, every call), or after ``wait`` seconds of looks it
        did not answer.

        Raises:
            SchedulerError: the scheduler was lost, or had no worker for ``wait`` seconds.
        """
        self.check_connected()
        now = time.monotonic()
        if now < self.next_look:
            return
        self.next_look = now + WATCH_INTERVAL
        count = self.workers()
        self.check_connected()  # lost during the look: its count is not the scheduler's
        if count is None:
            if self.unanswered_since is None:
                self.unanswered_since = now
            elif now - self.unanswered_since >= self.wait:
                raise self.lost(f"no answer for {self.wait:g} s")
            return
        self.unanswered_since = None
        if count:
            if self.empty_since is not None:
                self.say(f"the Dask scheduler at {self.address} has a worker again; going on")
                self.empty_since = None
            return
        if self.empty_since is None:
            self.empty_since = now
            self.say(
                f"the Dask scheduler at {self.address} has no workers left; waiting up to "
                f"{self.wait:g} s for one (start some: {self._hint()})"
            )
        elif now - self.empty_since >= self.wait:
            raise SchedulerError(
                f"the Dask scheduler at {self.address} has had no workers for {self.wait:g} s "
                f"with tasks still to run; start some ({self._hint()}) and run again"
            )


def completed(futures: Any, client: Any) -> Iterator[Any]:
    """Yield the futures of a ``dask.distributed.as_completed`` as they finish.

    With a client of :func:`connect`'s running scheduler, its workers are watched while
    none is ready (:meth:`WorkerWatch.check`); futures added during the iteration are
    waited for too. A lost scheduler ends the iteration at once: Dask's client cancels
    the job's futures then (a cancelled future is not yielded), and one submitted since
    would never finish. A scheduler restarted by another client cancels them too, the
    connection kept: that is said as such (:meth:`WorkerWatch.cancelled`).

    Raises:
        SchedulerError: the scheduler was lost, restarted, or had no workers for the
            watch's ``wait`` seconds.
    """
    watch = _WATCHES.get(client)
    if watch is None:
        yield from futures
        return
    condition = futures.thread_condition  # notified as each future finishes
    while True:
        watch.check_connected()
        if futures.has_ready():
            future = next(futures)
            if getattr(future, "status", None) == "cancelled":  # a lost or restarted scheduler
                raise watch.cancelled(future)
            yield future
            continue
        if futures.is_empty():
            return
        watch.check()
        with condition:
            condition.wait(timeout=0.1)


def running_scheduler(client: Any) -> bool:
    """Whether ``client`` is :func:`connect`'s client of a running scheduler (not local).

    A running scheduler's workers may be other machines; a local cluster's share these files.
    """
    return client in _WATCHES


@dataclass(frozen=True)
class WorkerPaths:
    """The paths a task needs, checked on the worker that runs it (:meth:`check`).

    The command resolved and checked them here; a worker of a running scheduler sees its
    own filesystem. Without this check the task's first error would be densify's own, for
    one machine: a log the user can see "does not exist", or "create it first" for the
    staging folder the command itself made.

    Attributes:
        logs: the input logs.
        basis: the basis file (``--basis``), None for none.
        out_dir: the output folder (``--out-dir``), None for none.
        staging: the staging folder made in ``out_dir`` for the task's output.
    """

    logs: tuple[Path, ...] = ()
    basis: Path | None = None
    out_dir: Path | None = None
    staging: Path | None = None

    def check(self) -> None:
        """Refuse, in one line naming the worker, a path this worker does not see.

        Raises:
            LogReadError: a log does not exist here.
            BasisError: the basis file does not exist here.
            LogWriteError: ``out_dir`` or the staging folder does not exist here.
        """
        names = ["the logs"] + ["--basis"] * (self.basis is not None)
        names += ["--out-dir"] * (self.out_dir is not None)
        shared = ", ".join(names[:-1]) + " and " + names[-1] if len(names) > 1 else names[0]
        hint = f"the workers need {shared} at the same paths (a shared filesystem)"
        where = f"the Dask worker ({_worker_address()})"
        for log in self.logs:
            if not log.exists():
                raise LogReadError(f"{log} does not exist on {where}: {hint}")
        if self.basis is not None and not self.basis.exists():
            raise BasisError(f"--basis {self.basis} does not exist on {where}: {hint}")
        if self.out_dir is not None and not self.out_dir.is_dir():
            raise LogWriteError(f"--out-dir {self.out_dir} does not exist on {where}: {hint}")
        if self.staging is not None and not self.staging.is_dir():
            raise LogWriteError(
                f"--out-dir {self.staging.parent} on {where} is not the folder this command wrote "
                f"to (the staging folder {self.staging.name} it made there is missing): {hint}"
            )


def _worker_address() -> str:
    """Return the address of the Dask worker running this task ("?" outside of one)."""
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except (ImportError, ValueError):
        return "?"


def checked(paths: WorkerPaths | None, function: Callable[..., Any], *args: Any) -> Any:
    """Run ``function(*args)`` once ``paths`` are checked on this worker (a task).

    ``paths`` None: no check (a local cluster's workers share this machine's files).
    """
    if paths is not None:
        paths.check()
    return function(*args)


def _start_workers(cluster: Any, client: Any, count: int) -> None:
    """Start ``count`` worker processes that never receive SIGINT or SIGTERM.

    A process starts with the signal mask of the thread that started it. Dask starts its
    worker processes from threads of its event loop's thread: SIGINT and SIGTERM are
    blocked in that thread first, so they stay pending, never delivered, in every worker
    from its first instruction on; the command stops its workers itself, and a worker
    ends anyway as soon as the process that started it does. The multiprocessing resource
    tracker is started before: starting it unblocks both signals in the thread that
    starts it.
    """
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    blocked = threading.Event()

    def block() -> None:
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
        blocked.set()

    cluster.loop.add_callback(block)
    blocked.wait()
    cluster.scale(count)
    try:
        client.wait_for_workers(count, timeout=WORKER_START_S)
    except TimeoutError:  # Dask's WorkerStartTimeoutError: the processes die as they start
        raise SchedulerError(
            f"the {count} local Dask worker process{'' if count == 1 else 'es'} did not start "
            f"within {WORKER_START_S:g} s: a worker process fails as it starts (from a script "
            "of your own, call the library under `if __name__ == \"__main__\":`: each worker "
            "process imports the script again)"
        ) from None


class _WorkerDeaths(logging.Filter):
    """Turns the nannies' "Restarting worker" warning into one note; drops their other lines."""

    def __init__(self, say: Callable[[str], object]) -> None:
        super().__init__()
        self.say = say

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno >= logging.WARNING and "Restarting worker" in record.getMessage():
            self.say("note: a Dask worker died; its tasks are run again")
        return False


@contextlib.contextmanager
def _worker_deaths_noted(say: Callable[[str], object]) -> Iterator[None]:
    """While a local cluster runs: a worker that dies is one note, not Dask's log line."""
    logger = logging.getLogger("distributed.nanny")
    deaths = _WorkerDeaths(say)
    logger.addFilter(deaths)
    try:
        yield
    finally:
        logger.removeFilter(deaths)


@contextlib.contextmanager
def _logging_silenced() -> Iterator[None]:
    """Silence every logger of this process for the block (Dask's closing a stopped cluster)."""
    previous = logging.root.manager.disable
    logging.disable(logging.CRITICAL)
    try:
        yield
    finally:
        logging.disable(previous)


def stop_local_workers(client: Any) -> None:
    """Kill the worker processes of the client's local cluster at once (a no-op for others).

    Their nannies (in this process) are told first that the end is intended, so none
    restarts its worker. A killed worker commits nothing, logs nothing and needs no time
    to end a task that was still running.
    """
    cluster = getattr(client, "cluster", None)
    for nanny in list(getattr(cluster, "workers", {}).values()):
        pid = getattr(nanny, "pid", None)
        if pid is None:
            continue  # a worker in a thread of this process, or already gone
        with contextlib.suppress(Exception):
            nanny.close_gracefully("pcainterp stopped the cluster")
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)
