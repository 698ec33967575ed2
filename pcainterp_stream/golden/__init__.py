"""Golden-file tests of logs: snapshot a log's content, check a later log against it.

A golden file records what a log must contain (channels and schemas, message counts, log
times and header stamps, every value, and robust statistics of every numeric array) with
the tolerances it is checked within, so that the last bits a renderer or a stereo matcher
changes between machines pass while a real change fails with a readable list of
differences. Any MCAP, ROS 1 bag or rosbag2 log works: messages are decoded generically.

Use :func:`save_golden` and :func:`check_log` from Python, ``pcainterp golden save`` and
``pcainterp golden check`` from a shell, or the ``log_golden`` pytest fixture (installed
with the package) in a test::

    def test_my_pipeline(tmp_path, log_golden):
        out = run_my_pipeline(tmp_path)      # writes a log
        log_golden.check(out)                # snapshot beside the test, --force-regen rewrites
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from pcainterp_stream.golden.comparison import (
        DEFAULT_TOLERANCE,
        Difference,
        compare,
        format_differences,
    )
    from pcainterp_stream.golden.decode import decode_compressed_depth, message_content
    from pcainterp_stream.golden.store import (
        FORMAT,
        CheckResult,
        arrays_path,
        check_log,
        describe_golden_file,
        is_golden_arrays,
        load_golden,
        save_golden,
    )
    from pcainterp_stream.golden.summary import LogSummary, array_statistics, summarize_log

# the public names load their modules on first use (PEP 562), so that the command line's
# parser (`cli/golden.py`) does not load OpenCV and the ROS type store
_MODULES = {
    "DEFAULT_TOLERANCE": "comparison",
    "Difference": "comparison",
    "compare": "comparison",
    "format_differences": "comparison",
    "decode_compressed_depth": "decode",
    "message_content": "decode",
    "FORMAT": "store",
    "CheckResult": "store",
    "arrays_path": "store",
    "check_log": "store",
    "describe_golden_file": "store",
    "is_golden_arrays": "store",
    "load_golden": "store",
    "save_golden": "store",
    "LogSummary": "summary",
    "array_statistics": "summary",
    "summarize_log": "summary",
}


def __getattr__(name: str) -> Any:
    module = _MODULES.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)


__all__ = [
    "DEFAULT_TOLERANCE",
    "FORMAT",
    "CheckResult",
    "Difference",
    "LogSummary",
    "array_statistics",
    "arrays_path",
    "check_log",
    "compare",
    "decode_compressed_depth",
    "describe_golden_file",
    "format_differences",
    "is_golden_arrays",
    "load_golden",
    "message_content",
    "save_golden",
    "summarize_log",
]
