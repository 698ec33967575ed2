"""``densify --out-dir`` on Dask: many logs densified in parallel, one output per log.

Each log is :func:`pcainterp_stream.pipeline.densify.densify` in a task of its own; a
failing log is reported and does not stop the others, and each log's outcome is handed to
the caller as soon as its task is done (:func:`densify_many`'s ``on_outcome``), not when
the last one is. A task writes its output into a hidden staging folder in DIR
(``.NAME.partial-PID@HOST~SCOPE-XXXX``, this process's id and machine), and this process,
not the worker, moves it onto the target once the task is done: nothing is committed after
a Ctrl-C. A run that was killed cannot remove its staging folders: the next run into DIR
removes every one of a process of this machine that no longer exists, whichever log it
was for (:func:`remove_dead_staging`). A task run again because its worker died removes
what its own earlier attempt left in its staging folder first, and says so as such.
"""

from __future__ import annotations

import contextlib
import errno
import glob
import os
import re
import shutil
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pcainterp_stream.errors import ClusterTaskError, PcaInterpError, SchedulerError
from pcainterp_stream.interrupt import (
    Interrupted,
    raise_if_signalled,
    signalled,
    signals_deferred,
    track_partial,
    untrack_partial,
)
from pcainterp_stream.io.output_paths import (
    partial_prefix,
    process_alive,
    remove_stale_partials,
)
from pcainterp_stream.pipeline.cluster_tasks import run_task, task_result
from pcainterp_stream.pipeline.densify import densify
from pcainterp_stream.pipeline.scheduler import (
    WorkerPaths,
    checked,
    completed,
    running_scheduler,
    stop_local_workers,
)

__all__ = [
    "DensifyOutcome",
    "densify_many",
    "output_path",
    "remove_dead_staging",
]


@dataclass(frozen=True)
class DensifyOutcome:
    """What happened to one log of ``densify --out-dir``.

    Attributes:
        input: the input log.
        output: the output log.
        frames: frames densified (0 on failure).
        seconds: wall time of the task (s).
        error: one-line error of a failed log, or None.
        unexpected: the error is not one of this package's (a bug, or a worker that died):
            its message alone does not say what to fix.
        warnings: the run's warnings (:meth:`~pcainterp_stream.pipeline.densify.
            DensifySummary.warning_lines`), one line each.
        adapted: why the log was densified with a basis of its own (:meth:`~pcainterp_stream.
            pipeline.densify.DensifySummary.adapted_line`), None when it was not.
        bases: the bases saved beside ``output`` when it adapted (``OUTPUT.basis.npz``, the
            one its channels name, then ``OUTPUT.final.basis.npz`` when relearned).
    """

    input: Path
    output: Path
    frames: int
    seconds: float
    error: str | None
    unexpected: bool = False
    warnings: tuple[str, ...] = ()
    adapted: str | None = None
    bases: tuple[Path, ...] = ()


def output_path(input_path: Path, out_dir: Path) -> Path:
    """Return the output of one input of ``densify --out-dir``: ``DIR/<stem>_dense.mcap``.

    The stem is that of the path as given (a symbolic link's own name, not its target's);
    a folder's (a rosbag2 log) is its whole name, dots included (``drive_v1.2``). ``.`` and
    ``..`` are taken lexically, links not followed (``morning/notes/..`` is ``morning``).
    """
    named = Path(os.path.abspath(input_path))
    stem = named.name if input_path.is_dir() else named.stem
    return out_dir / f"{stem}_dense.mcap"


def _same_log(first: Path, path: Path) -> bool:
    """Whether two inputs are one file or folder (``b1.mcap`` and ``sub/../b1.mcap``)."""
    try:
        return os.path.samefile(first, path)
    except OSError:  # not there (to be reported when read): compared as written
        return os.path.abspath(first) == os.path.abspath(path)


def _check_distinct(inputs: list[Path], outputs: list[Path]) -> None:
    """Refuse two inputs that would write one output, naming the first such pair.

    Raises:
        PcaInterpError: naming both inputs, the output and the fix.
    """
    first_of: dict[Path, Path] = {}
    for path, out in zip(inputs, outputs, strict=True):
        first = first_of.setdefault(out, path)
        if first is path:
            continue
        if first == path:
            raise PcaInterpError(f"{path} is given twice; give each log once")
        if _same_log(first, path):
            raise PcaInterpError(f"{first} and {path} are one log given twice; give each once")
        raise PcaInterpError(
            f"{first} and {path} share the name stem {out.name.removesuffix('_dense.mcap')!r}, "
            f"so both would write {out}; densify them into different --out-dir folders, or "
            "give one of them under another name (a symbolic link)"
        )


_SHORTENED = re.compile(r"~[0-9a-f]{8}")
"""The end of an output name shortened to fit a staging folder's name (``NAME~HASH``)."""


def remove_dead_staging(out_dir: Path) -> int:
    """Remove the staging folders in ``out_dir`` of ``densify --out-dir`` runs that were killed.

    Every log's, not only those densified now: a folder named ``.NAME.partial-OWNER-XXXX``
    with NAME an output's (``<stem>_dense.mcap``, or shortened to ``...~HASH``), removed by
    :func:`~pcainterp_stream.io.output_paths.remove_stale_partials` when OWNER is a process
    of this machine, boot and PID namespace that no longer exists (a run still going, or
    one of another machine sharing the folder, is never touched), one line each.

    Returns:
        The number of partial outputs removed.
    """
    try:
        entries = list(os.scandir(out_dir))
    except OSError:
        return 0
    names: set[str] = set()
    for entry in entries:
        head, dot, _ = entry.name.rpartition(".partial-")
        name = head[1:]
        if not dot or not head.startswith(".") or not entry.is_dir(follow_symlinks=False):
            continue
        if name.endswith("_dense.mcap") or _SHORTENED.fullmatch(name[-9:]):
            names.add(name)
    return sum(remove_stale_partials(out_dir / name, where=out_dir) for name in sorted(names))


def _remove_dead_attempt(log: Path, output: Path) -> None:
    """Remove what an earlier attempt of this task left in its staging folder; say so.

    The staging folder is this run's, made for this task alone: a partial output in it is
    an earlier attempt's, which Dask runs again because its worker died. The writer would
    remove it as a partial "left by an earlier run that was killed"; it is this run's own.
    Only partials of a process of this machine (boot, PID namespace) that no longer exists
    are removed, as the writer would (where that is unknown, it is left to the writer).
    """
    here = f"partial-{os.getpid()}@"
    _, _, owner = partial_prefix(output).partition(here)  # HOST~SCOPE-
    if not owner or owner.endswith("~unknown-"):
        return
    pattern = re.compile(r"\..+\.partial-(\d+)@" + re.escape(owner) + r"[^-]+")
    size = removed = 0
    with contextlib.suppress(OSError):
        for entry in os.scandir(output.parent):
            match = pattern.fullmatch(entry.name)
            if match is None or int(match[1]) == os.getpid() or process_alive(int(match[1])):
                continue
            with contextlib.suppress(OSError):
                if entry.is_dir(follow_symlinks=False):
                    shutil.rmtree(entry.path)
                else:
                    size += entry.stat(follow_symlinks=False).st_size
                    os.unlink(entry.path)
                removed += 1
    if removed:
        with contextlib.suppress(OSError, ValueError):
            print(
                f"note: {log.name}: removed the partial output of this run's own earlier "
                f"attempt, whose Dask worker died ({size / 1e6:.1f} MB); densifying it again",
                file=sys.stderr,
            )


def _densify_one(input_path: Path, output: Path, basis: Path | None, kwargs: dict[str, Any]) -> Any:
    _remove_dead_attempt(input_path, output)
    return densify(input_path, output, basis, **kwargs)


def densify_many(
    inputs: list[Path],
    out_dir: Path,
    basis: Path | None,
    client: Any,
    on_outcome: Callable[[DensifyOutcome], object] | None = None,
    **kwargs: Any,
) -> list[DensifyOutcome]:
    """Densify many logs in parallel on a Dask cluster, one output per log.

    Each task writes into a staging folder of its own in ``out_dir``; its output (and the
    adapted basis saved beside it) is moved onto the target here, as soon as the task is
    done. On an interruption the local workers are killed, every staging folder removed,
    and :class:`pcainterp_stream.interrupt.Interrupted` names the outputs committed before it.

    Args:
        inputs: input logs (paths readable by the workers), distinct stems.
        out_dir: output folder (created); outputs are :func:`output_path`. The staging
            folders runs that were killed left in it are removed first
            (:func:`remove_dead_staging`).
        basis: the basis file (readable by the workers); None: the built-in basis.
        client: a connected ``dask.distributed.Client``.
        on_outcome: called with each log's outcome as soon as it is known (its output
            committed, or its error met), in the order the tasks finish.
        **kwargs: keyword options of :func:`pcainterp_stream.pipeline.densify.densify`
            (``pairing``, ``processor``, ``topics``).

    Returns:
        One outcome per input, in input order; failures carry their error.

    Raises:
        PcaInterpError: two inputs would write the same output.
        Interrupted: a signal (or ``KeyboardInterrupt``) stopped the run.
    """
    from dask.distributed import as_completed

    outputs = [output_path(path, out_dir) for path in inputs]
    _check_distinct(inputs, outputs)
    created = not out_dir.exists()
    out_dir.mkdir(parents=True, exist_ok=True)
    remove_dead_staging(out_dir)  # every log's, not only these (never a live run's)
    staging: dict[int, Path] = {}  # input index -> its staging folder, until committed
    outcomes: dict[int, DensifyOutcome] = {}
    kept: list[Path] = []
    remote = running_scheduler(client)  # its workers may not see these paths: they check
    try:
        tasks: dict[Any, int] = {}
        for index, (path, out) in enumerate(zip(inputs, outputs, strict=True)):
            if out.is_dir():  # refused before its work, not when committing it
                message = (
                    f"output {out} is a folder but densify writes a file there; remove the "
                    "folder or densify into another one"
                )
                outcomes[index] = DensifyOutcome(path, out, 0, 0.0, message)
                if on_outcome is not None:
                    on_outcome(outcomes[index])
                continue
            remove_stale_partials(out, where=out_dir)  # a killed -o run's partial file of it
            folder = Path(tempfile.mkdtemp(prefix=partial_prefix(out, out_dir), dir=out_dir))
            track_partial(folder)
            staging[index] = folder
            paths = WorkerPaths((path,), basis, out_dir, folder) if remote else None
            future = client.submit(
                run_task,
                checked,
                paths,
                *(_densify_one, path, folder / out.name, basis, kwargs),
                pure=False,
            )
            tasks[future] = index
        for future in completed(as_completed(list(tasks)), client):  # type: ignore[no-untyped-call]
            index = tasks.pop(future)
            path, out = inputs[index], outputs[index]
            try:
                summary = task_result(future, "densifying")
            except PcaInterpError as err:  # reported per log; the other logs go on
                outcomes[index] = DensifyOutcome(
                    path, out, 0, 0.0, str(err), isinstance(err, ClusterTaskError)
                )
            else:
                try:
                    _commit(staging[index], out)
                except OSError as err:  # a folder of the output's name, no permission
                    message = (
                        f"cannot write {out}: {err.strerror or err}; nothing was written there"
                    )
                    outcomes[index] = DensifyOutcome(path, out, 0, 0.0, message)
                else:
                    kept.append(out)
                    outcomes[index] = DensifyOutcome(
                        path,
                        out,
                        summary.frames,
                        summary.seconds,
                        None,
                        warnings=tuple(summary.warning_lines()),
                        adapted=summary.adapted_line(),
                        bases=tuple(  # committed beside the output with it
                            out.parent / written.name for written, _ in summary.bases_saved
                        ),
                    )
            _remove(staging.pop(index))
            future.release()  # done with: not run again when the worker holding it dies
            if on_outcome is not None:
                on_outcome(outcomes[index])
    except BaseException as err:
        stop_local_workers(client)  # before the clean-up: a live worker could still write
        for folder in staging.values():
            _remove(folder)
        if created and not kept:  # the folder this run made, empty again
            with contextlib.suppress(OSError):
                out_dir.rmdir()
        if isinstance(err, KeyboardInterrupt) or signalled():
            raise Interrupted(out_dir, kept, len(inputs)) from err
        if isinstance(err, SchedulerError) and kept:
            raise SchedulerError(
                f"{err}; kept {len(kept)} of {len(inputs)} outputs, finished before: "
                + ", ".join(map(str, kept))
            ) from err
        raise
    return [outcomes[index] for index in range(len(inputs))]


def _commit(folder: Path, output: Path) -> None:
    """Move a finished output, and the bases densify saved beside it, onto the target.

    The renames happen together or not at all: a signal during them takes effect after.
    """
    raise_if_signalled()  # nothing is committed after a signal
    stem = glob.escape(output.stem)  # OUTPUT.basis.npz, OUTPUT.final.basis-2.npz...
    sides = {*folder.glob(f"{stem}.basis*.npz"), *folder.glob(f"{stem}.final.basis*.npz")}
    names = [side.name for side in sorted(sides)] + [output.name]
    names = [name for name in names if (folder / name).exists()]
    for name in names:  # checked before any rename: none of them or all
        if (output.parent / name).is_dir():
            raise IsADirectoryError(errno.EISDIR, "a folder of that name is in the way")
    with signals_deferred():
        for name in names:  # the output last: it names the basis beside it
            os.replace(folder / name, output.parent / name)


def _remove(folder: Path) -> None:
    """Remove a staging folder and forget it."""
    shutil.rmtree(folder, ignore_errors=True)
    untrack_partial(folder)
