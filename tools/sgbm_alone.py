"""SGBM alone as a program: the reference a ``densify`` job is timed against.

Reads a log, pairs its stereo images and computes full-resolution SGBM on every pair, in
two worker threads of one OpenCV thread each (the job's stereo workers), nothing written.
It imports only what that needs (numpy, OpenCV, the log reader, the pairer, the matcher),
so its start-up is that of a lean SGBM program, not of the whole pipeline's modules.

Example::

    /usr/bin/time -v python tools/sgbm_alone.py kitti_odometry.mcap
"""

from __future__ import annotations

import argparse
import sys
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import cv2

from pcainterp_stream.allocator import keep_freed_memory
from pcainterp_stream.errors import PcaInterpError
from pcainterp_stream.frontend.discovery import resolve_pairing
from pcainterp_stream.frontend.pairing import PairingConfig, StereoPairer
from pcainterp_stream.frontend.stereo import SgbmConfig, compute_disparity
from pcainterp_stream.io import logreader

WORKERS = 2
"""Matching threads (the job's stereo workers), one OpenCV thread each."""


def sgbm_alone(
    log: Path,
    config: SgbmConfig,
    *,
    workers: int = WORKERS,
    left_topic: str | None = None,
    right_topic: str | None = None,
) -> int:
    """Read, pair and stereo-match every pair of a log; return the number of pairs.

    The pair is the one densify takes: found in the log as densify finds it (compressed
    images, raw ``image_raw`` ones, a camera's own names), or the topics named; raw images
    are rectified as densify rectifies them. Up to ``2 * workers`` pairs are queued for the
    workers at once.
    """
    named = tuple(side for side, topic in (("left", left_topic), ("right", right_topic)) if topic)
    defaults = PairingConfig()
    wanted = PairingConfig(
        left_topic=left_topic or defaults.left_topic,
        right_topic=right_topic or defaults.right_topic,
        discover=len(named) < 2,
        named_sides=named,
    )
    pairs = 0
    with logreader.open_log(log) as reader, ThreadPoolExecutor(max_workers=workers) as pool:
        pairing = resolve_pairing(reader, wanted)
        pairer = StereoPairer(pairing)
        pending: deque[Future[Any]] = deque()
        for raw in reader.messages(pairing.topics):
            for frame in pairer.push_raw(raw, reader.decode):
                pending.append(pool.submit(compute_disparity, frame.left, frame.right, config))
                pairs += 1
                if len(pending) > 2 * workers:
                    pending.popleft().result()
        for frame in pairer.flush():
            pending.append(pool.submit(compute_disparity, frame.left, frame.right, config))
            pairs += 1
        for future in pending:
            future.result()
    return pairs


def main(argv: list[str] | None = None) -> int:
    """Run SGBM alone on the log named on the command line; return the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("log", type=Path, help="a stereo log (MCAP or ROS bag)")
    parser.add_argument("--workers", type=int, default=WORKERS, help="matching threads")
    parser.add_argument("--left-topic", help="the left image topic (default: found as densify)")
    parser.add_argument("--right-topic", help="the right image topic (default: found)")
    args = parser.parse_args(argv)
    if not args.log.exists():
        print(f"error: {args.log} does not exist", file=sys.stderr)
        return 2
    keep_freed_memory()
    cv2.setNumThreads(1)
    try:
        pairs = sgbm_alone(
            args.log,
            SgbmConfig(),
            workers=args.workers,
            left_topic=args.left_topic,
            right_topic=args.right_topic,
        )
    except PcaInterpError as err:  # no pair found, or two equally good ones
        print(f"error: {args.log}: {err}", file=sys.stderr)
        return 2
    if pairs == 0:  # a reference time of nothing: never divided by
        print(f"error: {args.log}: 0 stereo pairs matched; nothing to time", file=sys.stderr)
        return 1
    print(f"{pairs} pairs matched")
    return 0


if __name__ == "__main__":
    sys.exit(main())
