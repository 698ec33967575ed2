"""Write a golden file and its arrays file together: both replaced, or neither.

A golden pair is ``NAME.golden.json`` and the ``NAME.golden.npz`` it names. Each is
written to a temporary beside its target; the renames that commit them run together
(a signal waits until they are done) and, when a later one fails (a file that cannot be
replaced, a folder removed meanwhile), the files already renamed get their old contents
back: a failed save never leaves the new arrays beside the old JSON (bug hunt 16C F9).
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from pcainterp_stream.errors import GoldenError, LogWriteError
from pcainterp_stream.interrupt import raise_if_signalled, signals_deferred
from pcainterp_stream.io.output_paths import check_output_file, make_partial_file, write_advice

__all__ = ["replacing_together", "staged_at", "write_error"]


def staged_at(target: Path) -> Path:
    """Return the file to write ``target`` beside and rename onto (a link's own file).

    Raises:
        GoldenError: a device, a pipe, a file that cannot be replaced, or a folder above
            it that is a file or not writable.
    """
    try:
        return check_output_file(target, creates_folders=True)
    except LogWriteError as err:
        raise GoldenError(str(err)) from None


def write_error(target: Path, err: OSError) -> GoldenError:
    """The error naming ``target``, the cause and the fix."""
    return GoldenError(f"cannot write {target}: {err.strerror or err}; {write_advice(err)}")


@contextmanager
def replacing_together(*targets: Path) -> Iterator[list[Path]]:
    """Yield a temporary path beside each of ``targets``; rename them onto them on success.

    All the renames happen, or none: they run in order under
    :func:`~pcainterp_stream.interrupt.signals_deferred`, and when one fails those before
    it are undone (the old file put back, or the new one removed where there was none).

    Raises:
        GoldenError: a file cannot be written (a full disk, a read-only folder, a file
            where a folder should be, a target that cannot be replaced); nothing is left
            beside the targets and each holds what it held before.
    """
    staged = [staged_at(target) for target in targets]
    temporaries: list[Path] = []
    try:
        for target in staged:
            try:
                target.parent.mkdir(parents=True, exist_ok=True)
                # owner-named (a killed save's is removed by the next), shortened to fit
                handle, temporary = make_partial_file(target)  # a golden file's mode
            except OSError as err:
                raise write_error(target, err) from err
            os.close(handle)
            temporaries.append(temporary)
        yield temporaries  # the caller names the target whose writing failed
        raise_if_signalled()  # never committed after a signal
        with signals_deferred():
            _commit(staged, temporaries)
    finally:
        for temporary in temporaries:
            temporary.unlink(missing_ok=True)


def _commit(targets: list[Path], temporaries: list[Path]) -> None:
    """Rename each temporary onto its target; undo the earlier renames if one fails."""
    kept: list[tuple[Path, Path | None]] = []  # (target renamed onto, its old file kept)
    try:
        for index, (target, temporary) in enumerate(zip(targets, temporaries, strict=True)):
            last = index == len(targets) - 1
            old = None if last or not os.path.lexists(target) else _keep_old(target)
            kept.append((target, old))
            try:
                os.replace(temporary, target)
            except OSError as err:
                kept.pop()
                if old is not None:
                    old.unlink(missing_ok=True)
                _undo(kept)
                raise write_error(target, err) from err
    finally:
        for _, old in kept:
            if old is not None:
                old.unlink(missing_ok=True)


def _keep_old(target: Path) -> Path:
    """Keep ``target``'s current file beside it until the renames are done (a hard link).

    Raises:
        GoldenError: no room or no permission for the copy (nothing was renamed yet).
    """
    try:
        handle, old = make_partial_file(target)
        os.close(handle)
    except OSError as err:
        raise write_error(target, err) from err
    try:
        old.unlink()
        try:
            os.link(target, old)
        except OSError:  # a file system without hard links: a copy
            shutil.copyfile(target, old)
    except OSError as err:
        old.unlink(missing_ok=True)
        raise write_error(target, err) from err
    return old


def _undo(done: list[tuple[Path, Path | None]]) -> None:
    """Put back the old files of the targets renamed onto (remove the new where none was)."""
    for target, old in reversed(done):
        with contextlib.suppress(OSError):
            if old is None:
                target.unlink()
            else:
                os.replace(old, target)
