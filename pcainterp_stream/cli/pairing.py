"""The options that name a log's stereo pair and its calibration, shared by several commands.

``densify`` and ``learn`` take the topics, ``--baseline``, ``--stamp-tolerance-ms``,
``--rectify`` and ``--calibration``; ``evaluate`` takes the topics, ``--rectify``,
``--calibration`` and ``--stamp-tolerance-ms`` (default: the one the log records) to read the
input pair of a densified log as ``densify`` did. Without topic
options the pair is found in the log (:mod:`frontend.discovery`). Heavy modules load only when
a command runs.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from pcainterp_stream.cli.common import path_arg
from pcainterp_stream.errors import PcaInterpError

if TYPE_CHECKING:
    from pcainterp_stream.frontend.pairing import PairingConfig


def add_topic_options(parser: argparse.ArgumentParser) -> None:
    """Add the topic, rectification and calibration options of ``densify`` and ``learn``."""
    group = parser.add_argument_group(
        "topics and calibration (default: the stereo pair found in the log, printed)"
    )
    group.add_argument("--left-topic", default=None, metavar="TOPIC", help="left image topic")
    group.add_argument("--right-topic", default=None, metavar="TOPIC", help="right image topic")
    group.add_argument(
        "--left-info-topic",
        default=None,
        metavar="TOPIC",
        help="left CameraInfo (default: the left image's sibling camera_info)",
    )
    group.add_argument(
        "--right-info-topic",
        default=None,
        metavar="TOPIC",
        help="right CameraInfo (default: the right image's sibling camera_info)",
    )
    group.add_argument(
        "--rectify",
        choices=["auto", "always", "never"],
        default="auto",
        help="auto (default): remap raw images from their CameraInfo (D, R, P) as image_proc "
        "does, and use images named image_rect or with D = 0, R = I, K = P as they are; "
        "the decision is printed; always: remap from the calibration in any case; never: use "
        "the images as recorded and skip the check that the pair is rectified",
    )
    group.add_argument(
        "--calibration",
        type=path_arg,
        nargs="+",
        default=None,
        metavar="YAML",
        help="for logs without CameraInfo: LEFT.yaml RIGHT.yaml (camera_info_manager or "
        "EuRoC sensor.yaml) or one Kalibr camchain.yaml",
    )
    group.add_argument(
        "--baseline",
        type=float,
        default=None,
        metavar="M",
        help="stereo baseline (m); it overrides the right camera info's (for a log whose "
        "right camera info has none)",
    )
    group.add_argument(
        "--stamp-tolerance-ms",
        type=float,
        default=1.0,
        metavar="MS",
        help="left/right header stamps closer than this form a pair (default: %(default)s)",
    )
    group.add_argument(
        "--hold-s",
        type=float,
        default=3.0,
        metavar="S",
        help="how long (s of log time) an image waits for the other side's image of its "
        "stamp, a frame for its feature cloud, a cloud for its frame: streams recorded up to "
        "this far apart still pair (default: %(default)s)",
    )
    group.add_argument(
        "--hold-mib",
        type=float,
        default=512.0,
        metavar="MIB",
        help="the most memory (MiB) the images, frames and clouds waiting so take; beyond it "
        "the oldest is given up (default: %(default)s)",
    )


def add_input_pair_options(parser: argparse.ArgumentParser) -> None:
    """Add evaluate's options naming the input pair and its rectification (as densify's)."""
    group = parser.add_argument_group(
        "the input stereo pair, as densify read it (default: found in the log)"
    )
    for side in ("left", "right"):
        group.add_argument(
            f"--{side}-topic",
            default=None,
            metavar="TOPIC",
            help=f"the {side} image topic densify read (default: found by name)",
        )
        group.add_argument(
            f"--{side}-info-topic",
            default=None,
            metavar="TOPIC",
            help=f"the {side} camera info topic densify read (default: found by name)",
        )
    group.add_argument(
        "--rectify",
        choices=["auto", "always", "never"],
        default="auto",
        help=(
            "rectify raw input images as densify did (default: auto, what the log records "
            "densify decided, else decided again as densify would)"
        ),
    )
    group.add_argument(
        "--calibration",
        type=path_arg,
        nargs="+",
        default=None,
        metavar="YAML",
        help=(
            "the calibration files densify was given, for logs without CameraInfo (needed "
            "only for logs densified before the output recorded their calibration)"
        ),
    )
    group.add_argument(
        "--stamp-tolerance-ms",
        type=float,
        default=None,
        metavar="MS",
        help=(
            "a frame's right image, ground truth, --reference-topic message and pose are "
            "the ones stamped nearest it within this (default: the tolerance the log records "
            "densify paired with, 1 ms for logs that record none; for a --reference-topic, "
            "under half the frame interval)"
        ),
    )


def pairing_config(args: argparse.Namespace, features_topic: str | None = None) -> PairingConfig:
    """Return the pairing a parsed command line asks for (``discover`` without topic options).

    Raises:
        PcaInterpError: equal left and right topics, a bad tolerance or baseline, or a
            calibration file that cannot be used (:class:`~errors.CalibrationError`).
    """
    from pcainterp_stream.frontend.pairing import PairingConfig

    calibration, named = None, None
    if args.calibration is not None:
        from pcainterp_stream.io.calibration import load_calibration

        calibration, named = load_calibration(list(args.calibration))
    # one image topic named: the other side comes from the pair found in the log; no image
    # topic named (info topics alone): the pair is found, the info topics named kept
    one_side = (args.left_topic is None) != (args.right_topic is None)
    infos_named = args.left_info_topic is not None or args.right_info_topic is not None
    no_image_topic = args.left_topic is None and args.right_topic is None
    discover = no_image_topic or (one_side and not infos_named)
    if named is not None:
        # a camchain's rostopics: the pair unless both sides are named; when the log has not
        # both, the pair is found in it (the calibration stands for the infos)
        discover = args.left_topic is None or args.right_topic is None
    defaults = PairingConfig()
    left_topic = args.left_topic or defaults.left_topic
    right_topic = args.right_topic or defaults.right_topic
    if left_topic == right_topic:
        raise PcaInterpError(
            f"--left-topic and --right-topic are both {left_topic}; a stereo pair needs the "
            "images of two cameras (a topic whose images hold both views side by side is split "
            "into a left and a right half on two topics first): pass the right camera's topic "
            "as --right-topic"
        )
    tolerance_ms = stamp_tolerance_ms(args)
    if tolerance_ms is None:  # evaluate: the log's own, read later
        tolerance_ms = defaults.tolerance_ns / 1e6
    baseline = getattr(args, "baseline", None)  # evaluate has none
    hold_s = getattr(args, "hold_s", None)  # evaluate has neither
    hold_s = defaults.hold_ns / 1e9 if hold_s is None else hold_s
    hold_mib = getattr(args, "hold_mib", None)
    hold_mib = defaults.hold_bytes / 2**20 if hold_mib is None else hold_mib
    if not 0 <= hold_s < float("inf"):
        raise PcaInterpError(f"--hold-s must be a finite number >= 0 s, got {hold_s}")
    if not 1 <= hold_mib < float("inf"):
        raise PcaInterpError(f"--hold-mib must be a finite number >= 1 MiB, got {hold_mib}")
    if baseline is not None and not 0 < baseline < float("inf"):
        raise PcaInterpError(f"--baseline must be a finite number > 0 m, got {baseline}")
    return PairingConfig(
        left_topic=left_topic,
        right_topic=right_topic,
        left_info_topic=args.left_info_topic or defaults.left_info_topic,
        right_info_topic=args.right_info_topic or defaults.right_info_topic,
        features_topic=features_topic,
        tolerance_ns=round(tolerance_ms * 1e6),
        hold_ns=round(hold_s * 1e9),
        hold_bytes=round(hold_mib * 2**20),
        baseline=baseline,
        rectify=args.rectify,
        calibration=calibration,
        discover=discover,
        calibration_topics=named if discover else None,
        named_sides=tuple(
            side
            for side, topic in (("left", args.left_topic), ("right", args.right_topic))
            if topic
        ),
        named_infos=tuple(
            side
            for side, topic in (("left", args.left_info_topic), ("right", args.right_info_topic))
            if topic
        ),
        check_rows=args.rectify != "never",
    )


def stamp_tolerance_ms(args: argparse.Namespace) -> float | None:
    """Return ``--stamp-tolerance-ms`` as given (None: not given, evaluate's default).

    Raises:
        PcaInterpError: a negative or infinite tolerance.
    """
    tolerance_ms: float | None = getattr(args, "stamp_tolerance_ms", None)
    if tolerance_ms is not None and not 0 <= tolerance_ms < float("inf"):
        raise PcaInterpError(f"--stamp-tolerance-ms must be >= 0, got {tolerance_ms}")
    return tolerance_ms
