"""The ``pcainterp`` command line: parse, build typed configs, call a job, print.

:mod:`~pcainterp_stream.cli.app` builds the parser and dispatches; each command is a module
of its own (``synth``, ``import_kitti``, ``learn``, ``densify`` with ``densify_one``,
``evaluate``, ``info``, ``demo``, ``golden``) declaring its options beside the function that
runs them, and the option groups several commands share are in ``common`` (stereo front end,
Dask) and ``pairing`` (topics, rectification, calibration). This is the only layer that
speaks of flags: the jobs in :mod:`pcainterp_stream.pipeline` take typed configs.

This package's own import is light: :func:`console` imports the rest, so that a Ctrl-C
during those imports (~0.4 s) is answered like one during the command.
"""

from __future__ import annotations

import importlib
import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from pcainterp_stream.cli.app import COMMANDS, build_parser, main, run

EXIT_INTERRUPTED = 130
"""The exit status of a command a signal stopped (128 + SIGINT), as a shell reports it."""

__all__ = ["COMMANDS", "build_parser", "console", "main", "run"]


def console() -> int:
    """Run the ``pcainterp`` program (its console script and ``python -m``).

    Returns:
        The exit status (the program usually ends before returning, see
        :func:`pcainterp_stream.cli.app.console`).
    """
    try:
        app = importlib.import_module("pcainterp_stream.cli.app")
    except KeyboardInterrupt:
        # nothing has been read or written yet
        print("pcainterp: interrupted while starting; nothing was read or written", file=sys.stderr)
        # a Ctrl-C inside code run by exec() makes `python -m` re-raise SIGINT at exit although
        # it was handled (CPython bpo-41602); any exec() of a string clears that flag
        exec("")
        return EXIT_INTERRUPTED
    code: int = app.console()
    return code


def __getattr__(name: str) -> Any:
    """Import :mod:`pcainterp_stream.cli.app` on first use of one of its names (PEP 562)."""
    if name not in ("COMMANDS", "build_parser", "main", "run"):
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module("pcainterp_stream.cli.app"), name)
    globals()[name] = value
    return value
