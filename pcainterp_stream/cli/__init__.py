"""The ``pcainterp`` command line: parse, build typed configs, call a job, print.

:mod:`~pcainterp_stream.cli.app` builds the parser and dispatches; each command is a module
of its own (``synth``, ``import_kitti``, ``learn``, ``densify`` with ``densify_one``,
``evaluate``, ``info``, ``demo``, ``golden``) declaring its options beside the function that
runs them, and the option groups several commands share are in ``common`` (stereo front end,
Dask) and ``pairing`` (topics, rectification, calibration). This is the only layer that
speaks of flags: the jobs in :mod:`pcainterp_stream.pipeline` take typed configs.
"""

from pcainterp_stream.cli.app import COMMANDS, build_parser, console, main, run

__all__ = ["COMMANDS", "build_parser", "console", "main", "run"]
