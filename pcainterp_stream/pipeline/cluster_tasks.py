"""Dask tasks that return the errors they meet instead of raising them.

Dask logs every exception a task raises as a multi-line "Compute Failed" block on the
worker's stderr, before the caller could say the same in one line. A task run by
:func:`run_task` returns a :class:`TaskFailure` instead, and :func:`task_result` raises it
here, as one line.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pcainterp_stream.errors import ClusterTaskError, PcaInterpError

__all__ = ["TaskFailure", "run_task", "task_result"]


@dataclass(frozen=True)
class TaskFailure:
    """An error a task met, returned as its result instead of raised (see the module's notes).

    Attributes:
        message: the error's message, its first line.
        kind: the exception's class name.
        error: the error itself when it is one of this package's (the input's fault, its
            message written for the user), else None (unexpected: a bug).
    """

    message: str
    kind: str
    error: PcaInterpError | None

    @classmethod
    def of(cls, error: Exception) -> TaskFailure:
        """Return the failure of ``error``."""
        text = str(error).splitlines()[0] if str(error) else type(error).__name__
        expected = error if isinstance(error, PcaInterpError) else None
        return cls(text, type(error).__name__, expected)

    def raise_error(self, what: str) -> None:
        """Raise the error here: this package's as it was, anything else as one line.

        Args:
            what: the task, for the message of an unexpected error ("a learning task").

        Raises:
            PcaInterpError: the task's own error.
            ClusterTaskError: any other.
        """
        if self.error is not None:
            raise self.error
        raise ClusterTaskError(
            f"{what} failed on the cluster with an unexpected {self.kind}: {self.message}"
        )


def run_task(function: Callable[..., Any], *args: Any) -> Any:
    """Run ``function(*args)`` as a task: its result, or the :class:`TaskFailure` it met.

    An argument that is itself a failure (the summary of a chunk that failed, merged) is
    passed on as the result, unrun.
    """
    for arg in args:
        if isinstance(arg, TaskFailure):
            return arg
    try:
        return function(*args)
    except Exception as err:  # returned, not raised: see TaskFailure
        return TaskFailure.of(err)


def task_result(future: Any, what: str) -> Any:
    """Return a task's result (:func:`run_task`), raising the error it met here.

    Raises:
        PcaInterpError: the task's own error.
        ClusterTaskError: anything else, a worker that died under the task included.
    """
    try:
        result = future.result()
    except Exception as err:  # Dask's own: a worker died (KilledWorker), a lost scheduler
        result = TaskFailure.of(err)
    if isinstance(result, TaskFailure):
        result.raise_error(what)
    return result
