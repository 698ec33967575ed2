"""The project's exceptions.

Every error a user can cause by what they pass in (a file, a topic, an option) is a
subclass of :class:`PcaInterpError` whose message is one sentence naming the thing and the
fix. The command line prints that sentence and exits non-zero; it never shows a traceback
for these. Library errors are wrapped at the I/O boundary (``raise LogReadError(...) from
err``) so callers only ever need to catch this family.
"""

from __future__ import annotations


class PcaInterpError(Exception):
    """Root of every error this package raises on bad input."""


class BasisError(PcaInterpError):
    """A basis file is missing, malformed, or does not fit the data it is used with."""


class LogReadError(PcaInterpError):
    """An input log cannot be opened or read (missing, not a log, damaged)."""


class TopicNotFoundError(LogReadError):
    """A requested topic is not in the log."""


class CalibrationError(PcaInterpError):
    """Camera calibration is missing or unusable (no baseline, bad projection matrix)."""


class LogWriteError(PcaInterpError):
    """An output log cannot be written (bad path, the input itself, disk error)."""


class DatasetImportError(PcaInterpError):
    """A dataset folder (KITTI) is missing files or has malformed ones."""


class StreamError(PcaInterpError):
    """A live stream cannot be served (a bad address, a port in use, a bad rate)."""


class GoldenError(PcaInterpError):
    """A golden file is missing, malformed, or of a format version this package does not read."""


class GoldenToleranceError(GoldenError):
    """A golden file's tolerances (or those given to write one) are not valid.

    An unknown key, a value that is not a finite number >= 0, or a per-channel override of
    a channel the golden file does not record. A rewrite (``--update``, ``--force-regen``)
    does not replace such a file: its tolerances were edited by hand and must be fixed.
    """


class SchedulerError(PcaInterpError):
    """A Dask scheduler cannot be used: a malformed or unreachable address, no workers."""


class ClusterTaskError(PcaInterpError):
    """A task on a Dask cluster failed with an unexpected error (a bug or a dead worker).

    The errors of the family above reach the caller as they are; anything else a task
    raises (or a worker process that died under it) arrives as this, in one line.
    """
