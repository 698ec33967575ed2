"""The input pair ``evaluate`` matches again: the one ``densify`` recorded it read, if it did.

``evaluate`` runs SGBM on a densified log's input pair (its reference without ground truth,
the ``sgbm`` rows, the points sweep), so it must read the images as ``densify`` did: the same
topics, the same calibration and the same ``--rectify``. ``densify`` records them in the log
(:class:`~pcainterp_stream.io.densify_record.FrontEnd`); :func:`follow_densify` puts them into
evaluate's pairing where the command line left them open, and says which it used. A log
without the record (another format, an older densify) is read as before: the pair found in
the log, ``--rectify auto`` decided again. The matcher is not taken from the record: densify
matches at half resolution for speed, evaluate's reference stays full resolution.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.frontend.stereo import SgbmConfig
from pcainterp_stream.io.densify_record import FrontEnd, options_json
from pcainterp_stream.io.outputs import front_end_record

__all__ = ["describe_pair", "follow_densify", "matcher_notes"]


def follow_densify(
    path: Path,
    pairing: PairingConfig | None,
    present: dict[str, Any],
    prefix: str | None = None,
) -> tuple[PairingConfig | None, str, FrontEnd | None]:
    """Return the pairing to read a densified log's input pair with, and where it came from.

    What the caller left open is taken from the record: the image topics when ``pairing``
    names none (None, ``discover`` without a named side, or only info topics named, which
    are kept), the calibration files' values when it has no calibration, ``--rectify`` when
    it is ``auto`` (evaluate's ``auto`` means "as densify did"), ``--baseline`` when it has
    none. What the caller set stays. Image topics named other than the recorded ones take
    nothing from the record: ``--rectify auto`` is decided again for them, as for a log
    without the record, and the note says so. Info topics named other than the ones
    densify read (any, when it read calibration files) are used and take only the image
    topics from the record: its ``--rectify``, calibration and baseline were decided for
    its calibration, so ``--rectify auto`` is decided again and the note says so. Without a
    record, only info topics named leave the images to discovery.

    Args:
        path: the densified log (its record: ``io.outputs.front_end_record``).
        pairing: the pairing asked for (None: the library default, nothing named).
        present: the log's topics, to check the recorded ones are still there.
        prefix: the prefix of the outputs evaluated: the record of that prefix is taken (a
            log densified again under another ``--output-prefix`` has one per prefix; None:
            the last record).

    Returns:
        The pairing (``pairing`` itself without a usable record), a note on its source and
        the record (None without one).
    """
    again = (
        "--rectify as given"
        if pairing is not None and pairing.rectify != "auto"
        else "--rectify auto decided again as densify decides"
    )
    open_topics = _topics_open(pairing)
    if open_topics and pairing is not None and _infos_named(pairing):
        # only info topics named: the images are found in the log, the infos named kept
        pairing = dataclasses.replace(pairing, discover=True)
    try:
        front_end, which = front_end_record(path, prefix)
    except ValueError as err:
        return pairing, f"the log's record cannot be read ({err}): {again}", None
    if front_end is None:
        return pairing, f"{which or 'the log records none'}: {again}", None
    pairing, source, front_end = _follow(pairing, front_end, present, open_topics, again)
    return pairing, f"{source}; {which}" if which else source, front_end


def _follow(
    pairing: PairingConfig | None,
    front_end: FrontEnd,
    present: dict[str, Any],
    open_topics: bool,
    again: str,
) -> tuple[PairingConfig | None, str, FrontEnd]:
    """Return :func:`follow_densify`'s pairing and note for a log's record ``front_end``."""
    if front_end.left_topic not in present or front_end.right_topic not in present:
        return (
            pairing,
            (
                f"the recorded {front_end.left_topic} and {front_end.right_topic} are not in the "
                f"log: {again}"
            ),
            front_end,
        )
    if not open_topics and pairing is not None and not _names_recorded(pairing, front_end):
        # other images than densify read: its --rectify, calibration and baseline were
        # decided for its pair, not for these
        return (
            pairing,
            (
                f"other topics than densify read ({front_end.left_topic}, "
                f"{front_end.right_topic}), so not its --rectify, calibration or baseline: "
                f"{again}"
            ),
            front_end,
        )
    given = pairing or PairingConfig()
    defaults = PairingConfig()
    given = dataclasses.replace(
        given,
        left_topic=front_end.left_topic,
        right_topic=front_end.right_topic,
        # info topics named on the command line are kept, else the ones densify read: both
        # are named, so discovery reads them and not each image's own
        left_info_topic=(
            given.left_info_topic
            if "left" in given.named_infos or given.left_info_topic != defaults.left_info_topic
            else front_end.left_info_topic
        ),
        right_info_topic=(
            given.right_info_topic
            if "right" in given.named_infos or given.right_info_topic != defaults.right_info_topic
            else front_end.right_info_topic
        ),
        named_infos=("left", "right"),
        discover=False,
    )
    others = _other_infos(pairing, front_end)
    if others:
        # other camera infos than densify's calibration: its --rectify, calibration files and
        # baseline were decided for that calibration, not for these, which are used
        read = (
            f"calibration files {', '.join(front_end.calibration_files)}"
            if front_end.calibration == "files"
            else f"{front_end.left_info_topic}, {front_end.right_info_topic}"
        )
        return (
            given,
            (
                f"{'topics as densify recorded them; ' if open_topics else ''}"
                f"{', '.join(others)} named, not densify's {read}, so not its --rectify, "
                f"calibration or baseline: {again}"
            ),
            front_end,
        )
    config = dataclasses.replace(
        given,
        rectify=front_end.rectify if given.rectify == "auto" else given.rectify,
        calibration=(
            given.calibration if given.calibration is not None else front_end.calibration_values
        ),
        baseline=given.baseline if given.baseline is not None else front_end.baseline,
    )
    taken = [
        *(["topics"] if open_topics else []),
        *(["--rectify"] if given.rectify == "auto" else []),
        *(
            ["calibration files"]
            if given.calibration is None and front_end.calibration == "files"
            else []
        ),
    ]
    source = (
        f"{', '.join(taken)} as densify recorded them; its images: {front_end.images}"
        if taken
        else f"as given; densify recorded --rectify {front_end.rectify}, images {front_end.images}"
    )
    if given.rectify not in ("auto", front_end.rectify):
        source += f"; --rectify {given.rectify} given, densify used {front_end.rectify}"
    return config, source, front_end


def _topics_open(pairing: PairingConfig | None) -> bool:
    """Whether ``pairing`` leaves the image topics open (no image topic named).

    None, ``discover`` without a named side, or the default image topics without
    ``discover`` and without a named side (only info topics named: ``cli.pairing`` then
    leaves ``discover`` unset).
    """
    if pairing is None:
        return True
    if pairing.named_sides:
        return False
    defaults = PairingConfig()
    return pairing.discover or (pairing.left_topic, pairing.right_topic) == (
        defaults.left_topic,
        defaults.right_topic,
    )


def _infos_named(pairing: PairingConfig) -> bool:
    """Whether ``pairing`` names an info topic (given, or other than the default one)."""
    defaults = PairingConfig()
    return bool(pairing.named_infos) or (pairing.left_info_topic, pairing.right_info_topic) != (
        defaults.left_info_topic,
        defaults.right_info_topic,
    )


def _other_infos(pairing: PairingConfig | None, front_end: FrontEnd) -> list[str]:
    """Return the info topics ``pairing`` names that densify did not read ([]: none).

    A named topic (given, or not the default) other than the recorded one, or any when
    densify read calibration files. None when ``pairing`` gives calibration files itself:
    no info topic is read then.
    """
    if pairing is None or pairing.calibration is not None:
        return []
    defaults = PairingConfig()
    files = front_end.calibration == "files"
    named = [
        ("left", pairing.left_info_topic, defaults.left_info_topic, front_end.left_info_topic),
        ("right", pairing.right_info_topic, defaults.right_info_topic, front_end.right_info_topic),
    ]
    return [
        topic
        for side, topic, default, recorded in named
        if (side in pairing.named_infos or topic != default) and (files or topic != recorded)
    ]


def _names_recorded(pairing: PairingConfig, front_end: FrontEnd) -> bool:
    """Whether the image topics ``pairing`` names are the ones densify recorded it read.

    With ``discover``, only the named sides are compared (the other one is found): the
    recorded pair has them.
    """
    recorded = {"left": front_end.left_topic, "right": front_end.right_topic}
    named = {"left": pairing.left_topic, "right": pairing.right_topic}
    sides = pairing.named_sides if pairing.discover else ("left", "right")
    return all(named[side] == recorded[side] for side in sides)


def describe_pair(config: PairingConfig, source: str) -> str:
    """Return the report's line on the input pair: topics, calibration, ``--rectify``, source."""
    calibration = "calibration files" if config.calibration is not None else "camera infos"
    return (
        f"{config.left_topic}, {config.right_topic}, {calibration}, --rectify "
        f"{config.rectify} ({source})"
    )


def matcher_notes(front_end: FrontEnd | None, sgbm: SgbmConfig) -> list[str]:
    """Say which of densify's SGBM settings evaluate's matcher does not share (a note or none).

    The resolution is left out: densify matches at half resolution for speed by default,
    evaluate's reference is full resolution by design.
    """
    if front_end is None or front_end.source != "stereo":
        return []
    ours = json.loads(options_json(sgbm))  # as the record holds them
    other = {
        name: value
        for name, value in front_end.sgbm.items()
        if name != "downscale" and name in ours and ours[name] != value
    }
    if not other:
        return []
    settings = ", ".join(f"{name} {value}" for name, value in sorted(other.items()))
    return [
        f"densify matched with {settings}; evaluate's SGBM (reference, stereo rows, sweep) "
        "keeps its own settings, at full resolution"
    ]
