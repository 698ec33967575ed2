"""What discovery says about a Kalibr camchain's topics (``--calibration camchain.yaml``).

:func:`camchain_order` is the line saying a camchain's cam1 is the left camera,
:func:`one_topic_both_sides` the error of a camchain's topics that make one topic both sides,
:func:`calibration_file` the camchain's file name those lines use.
"""

from __future__ import annotations

from pathlib import Path

from pcainterp_stream.frontend.pairing import PairingConfig

__all__ = ["calibration_file", "camchain_order", "one_topic_both_sides"]


def camchain_order(config: PairingConfig) -> str:
    """Return the line saying a Kalibr camchain's cam1 is the left camera ("" if it is not).

    :func:`io.calibration.load_calibration` names such a pair's cameras ``PATH:cam1``,
    ``PATH:cam0``.
    """
    calibration = config.calibration
    if calibration is None:
        return ""
    left = str(getattr(calibration.left, "name", ""))
    if not left.endswith(":cam1") or calibration.right.name != left[: -len("1")] + "0":
        return ""
    source = calibration_file(config)
    try:
        apart = f" {calibration.left.baseline(calibration.right):.3f} m"
    except (AttributeError, TypeError, ValueError):
        apart = ""
    return (
        f"{source}: cam1 is the left camera (cam0 lies{apart} to its right; Kalibr numbers "
        "cameras in --topics order)"
    )


def one_topic_both_sides(
    topic: str, named_left: bool, named_right: bool, config: PairingConfig
) -> str:
    """Return the error of a camchain's topics that make ``topic`` both sides of the pair.

    One side named as the camchain's other camera (``--left-topic /cam1/image_raw`` with
    ``/cam0/image_raw``, ``/cam1/image_raw``), or a camchain naming one rostopic twice.
    """
    assert config.calibration_topics is not None
    cal_left, cal_right = config.calibration_topics
    source = calibration_file(config)
    if named_left == named_right:  # none named: the camchain's two cameras share a rostopic
        return (
            f"the rostopics of {source} are both {topic}; a stereo pair needs the images of "
            "two cameras: pass --left-topic and --right-topic"
        )
    named, other = ("left", "right") if named_left else ("right", "left")
    return (
        f"--{named}-topic and --{other}-topic are both {topic} (--{named}-topic as given, "
        f"--{other}-topic the rostopic of {source}'s {other} camera); a stereo pair needs "
        f"the images of two cameras: pass the {other} camera's topic as --{other}-topic, or "
        f"no topic option to read the pair {source} names (left {cal_left}, right {cal_right})"
    )


def calibration_file(config: PairingConfig) -> str:
    """Return the name of the calibration file (a Kalibr camchain) ``config`` has."""
    if config.calibration is None:
        return "the calibration file"
    # the cameras are named PATH:cam0, PATH:cam1
    return Path(config.calibration.left.name.rpartition(":")[0]).name or "the calibration file"
