"""Densify a log's images as other sensors give them: a table of the error per image level.

Rewrites the stereo images of an MCAP log the way real sensors differ from a well-exposed
8-bit camera, one named variant each (same topics, stamps, camera infos and other messages;
MCAP out), runs ``pcainterp densify`` (no flags) and ``pcainterp evaluate`` on the original
and on each variant, and prints a markdown table: PCA-MAP's mean |disparity error| (px), its
ratio to nearest neighbour, the share of the stored std's +-2 sigma interval holding the
truth, the basis densify kept and the ``note:`` lines densify printed. The log needs a
truth evaluate scores against (LiDAR depth, a synthetic log's truth)::

    pcainterp synth street.mcap --frames 4 --scale 0.5 --seed 1
    python tools/image_levels.py street.mcap
    python tools/image_levels.py k07.mcap --variants original over_exposed --keep levels_k07

Variants (:data:`VARIANTS`): ``original`` (the log as recorded), ``offset16`` (mono16,
30000 + 300 counts of signal: a thermal camera or a large black level), ``dark`` (8-bit
levels 0..40), ``right_gain`` (the right image x0.7), ``right_gamma`` (the right image's
gamma 0.6), ``over_exposed`` (both images x3, clipped at 255, or brighter until 60 % of an
image is at 255). The
``at 255`` column is the left images' mean share at 255 as rewritten. The pair rewritten is
the one ``densify`` finds with no topic flags; a raw (unrectified) pair is rewritten as
recorded, before densify rectifies it (as a sensor's levels reach it).

The commands run as ``python -m pcainterp_stream.cli`` of this interpreter, in a scratch
folder (``--keep``: that folder, kept), so PYTHONPATH chooses the tree measured.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

Image = npt.NDArray[Any]
Rewrite = Callable[[Image, bool], tuple[Image, str | None]]
"""(image, is the left one) -> (new image, its encoding; None: the encoding of its dtype)."""


def _grey8(image: Image) -> npt.NDArray[np.float64]:
    """The image as 8-bit grey levels (float): colour to grey, 16 bit scaled by its max."""
    if image.ndim == 3:
        image = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    grey = image.astype(np.float64)
    if image.dtype != np.uint8:
        grey = grey * 255.0 / max(float(grey.max()), 1.0)
    return grey


def _eight(values: npt.NDArray[np.float64]) -> npt.NDArray[np.uint8]:
    return np.clip(np.round(values), 0, 255).astype(np.uint8)


def _offset16(image: Image, left: bool) -> tuple[Image, str | None]:
    return np.round(30000 + _grey8(image) * 300 / 255).astype(np.uint16), "mono16"


def _dark(image: Image, left: bool) -> tuple[Image, str | None]:
    return _eight(_grey8(image) * 40 / 255), "mono8"


def _right_gain(image: Image, left: bool) -> tuple[Image, str | None]:
    grey = _grey8(image)
    return _eight(grey if left else grey * 0.7), "mono8"


def _right_gamma(image: Image, left: bool) -> tuple[Image, str | None]:
    grey = _grey8(image)
    return _eight(grey if left else 255 * (grey / 255) ** 0.6), "mono8"


def _over_exposed(image: Image, left: bool) -> tuple[Image, str | None]:
    grey = _grey8(image)
    # x3, or more when that leaves less than 60 % of the image at 255 (a dark scene)
    gain = max(3.0, 255.0 / max(float(np.percentile(grey[::4, ::4], 40.0)), 1.0))
    return _eight(grey * gain), "mono8"


VARIANTS: dict[str, Rewrite | None] = {
    "original": None,
    "offset16": _offset16,
    "dark": _dark,
    "right_gain": _right_gain,
    "right_gamma": _right_gamma,
    "over_exposed": _over_exposed,
}
"""The variants by name, in the table's order; None: the log as recorded."""

IMAGE_SCHEMA = "sensor_msgs/msg/Image"


class BadInput(Exception):
    """A log this tool cannot rewrite (the message is the one line printed)."""


def pair_topics(log: Path) -> tuple[str, str]:
    """The stereo pair densify takes from ``log`` (left, right image topics).

    Found as ``densify`` with no topic flags finds it (the pair discovered in the log: the
    default ``/stereo/*/image_rect``, a raw pair such as ``/camera/*/image_raw``, EuRoC's
    ``/cam0`` and ``/cam1``).
    """
    from pcainterp_stream.errors import PcaInterpError
    from pcainterp_stream.frontend.discovery import resolve_pairing
    from pcainterp_stream.frontend.pairing import PairingConfig
    from pcainterp_stream.io import logreader

    try:
        with logreader.open_log(log) as reader:
            pairing = resolve_pairing(reader, PairingConfig(discover=True))
    except (PcaInterpError, OSError, ValueError) as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise BadInput(first if str(log) in first else f"{log}: {first}") from None
    return pairing.left_topic, pairing.right_topic


def rewrite(log: Path, out: Path, variant: Rewrite) -> float:
    """Write ``log`` to ``out`` with the pair's images rewritten by ``variant``.

    Every other message, each channel's topic and metadata, and each message's times and
    stamps are copied as they are. Returns the left images' mean share at 255 as rewritten.
    """
    from mcap.exceptions import McapError
    from mcap.reader import make_reader
    from mcap.writer import Writer

    from pcainterp_stream.io import rosmsg

    left_topic, right_topic = pair_topics(log)
    shares: list[float] = []
    with log.open("rb") as source, out.open("wb") as target:
        try:
            reader = make_reader(source)
            profile = reader.get_header().profile
        except (McapError, ValueError) as err:
            raise BadInput(f"{log}: not an MCAP file ({err}); convert it first") from None
        writer = Writer(target)
        writer.start(profile=profile, library="tools/image_levels.py")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(
                    schema.name, schema.encoding, schema.data
                )
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic,
                    channel.message_encoding,
                    schemas[schema.id] if schema is not None else 0,
                    dict(channel.metadata),
                )
            data = message.data
            if channel.topic in (left_topic, right_topic):
                name = schema.name if schema is not None else "?"
                if name != IMAGE_SCHEMA or channel.message_encoding != "cdr":
                    raise BadInput(
                        f"{log}: {channel.topic} is {name} ({channel.message_encoding}); "
                        f"the tool rewrites {IMAGE_SCHEMA} (cdr) images only"
                    )
                decoded = rosmsg.deserialize(data, IMAGE_SCHEMA)
                left = channel.topic == left_topic
                image, encoding = variant(rosmsg.image_array(decoded), left)
                if left:
                    shares.append(float(np.count_nonzero(image == 255)) / image.size)
                rebuilt = rosmsg.image_message(
                    np.ascontiguousarray(image),
                    rosmsg.stamp_ns(decoded),
                    decoded.header.frame_id,
                    encoding=encoding,
                )
                data = rosmsg.serialize(rebuilt)
            writer.add_message(
                channels[channel.id],
                log_time=message.log_time,
                publish_time=message.publish_time,
                data=data,
                sequence=message.sequence,
            )
        writer.finish()  # type: ignore[no-untyped-call]
    if not shares:
        raise BadInput(f"{log}: no image on {left_topic}; nothing to rewrite")
    return float(np.mean(shares))


@dataclass
class Row:
    """One variant's figures (None: not measured; ``failed``: why)."""

    variant: str
    at_255: float | None = None
    pca_map: float | None = None
    to_nearest: float | None = None
    sigma2: float | None = None
    basis: str = "-"
    notes: tuple[str, ...] = ()
    failed: str = ""


def _cli(args: list[str], folder: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "pcainterp_stream.cli", *args],
        cwd=folder,  # never a repository folder: -m puts the cwd first on sys.path
        capture_output=True,
        text=True,
        check=False,
    )


def _last_line(done: subprocess.CompletedProcess[str], folder: Path) -> str:
    lines = [line for line in (done.stderr + done.stdout).splitlines() if line.strip()]
    last = lines[-1] if lines else f"exit status {done.returncode}"
    return last.replace(f"{folder}/", "")  # the scratch folder: named once, by --keep


def parse_evaluate(text: str, row: Row) -> None:
    """Fill ``row`` from evaluate's report: the pca_map row and the stored std's coverage."""
    table = re.search(r"^pca_map\s+([\d.]+)\s+([\d.]+)", text, re.M)
    if table:
        row.pca_map, row.to_nearest = float(table[1]), float(table[2])
    coverage = re.search(r"^uncertainty stored .*?\+-2 sigma ([\d.]+) %", text, re.M)
    if coverage:
        row.sigma2 = float(coverage[1])
    basis = re.search(r"^basis of the re-densified rows: (\S+)", text, re.M)
    if basis:
        row.basis = basis[1]


def measure(log: Path, name: str, folder: Path) -> Row:
    """Rewrite ``log`` as variant ``name`` in ``folder``, densify and evaluate it."""
    row = Row(name)
    variant = VARIANTS[name]
    source = log
    if variant is not None:
        source = folder / f"{name}.mcap"
        row.at_255 = rewrite(log, source, variant)
    dense = folder / f"{name}_dense.mcap"
    done = _cli(["densify", str(source), "-o", str(dense)], folder)
    (folder / f"{name}.densify.txt").write_text(done.stdout + done.stderr)
    row.notes = tuple(
        line for line in (done.stdout + done.stderr).splitlines() if line.startswith("note:")
    )
    if done.returncode != 0:
        row.failed = f"densify failed: {_last_line(done, folder)}"
        return row
    done = _cli(["evaluate", str(dense), "-o", str(folder / f"rep_{name}")], folder)
    (folder / f"{name}.evaluate.txt").write_text(done.stdout + done.stderr)
    if done.returncode != 0:
        row.failed = f"evaluate failed: {_last_line(done, folder)}"
        return row
    parse_evaluate(done.stdout, row)
    return row


def _figure(value: float | None, form: str) -> str:
    return "-" if value is None else format(value, form)


def table(rows: list[Row]) -> str:
    """The markdown table of the rows."""
    lines = [
        "| variant | at 255 | PCA-MAP px | /NN | +-2 sigma | basis | densify's notes |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for row in rows:
        notes = "; ".join(note.removeprefix("note: ") for note in row.notes) or "-"
        if row.failed:
            notes = f"{row.failed}; {notes}" if row.notes else row.failed
        lines.append(
            f"| {row.variant} | "
            f"{'-' if row.at_255 is None else f'{100 * row.at_255:.0f} %'} | "
            f"{_figure(row.pca_map, '.3f')} | {_figure(row.to_nearest, '.2f')} | "
            f"{'-' if row.sigma2 is None else f'{row.sigma2:.1f} %'} | {row.basis} | "
            f"{notes.replace('|', '/')} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the command line; return the exit status."""
    parser = argparse.ArgumentParser(
        prog="image_levels.py", description=(__doc__ or "").split("\n\n")[0]
    )
    parser.add_argument("log", type=Path, help="an MCAP stereo log with a truth to score on")
    parser.add_argument(
        "--variants",
        nargs="+",
        choices=list(VARIANTS),
        default=list(VARIANTS),
        metavar="NAME",
        help=f"the variants to measure, in this order (default: all: {', '.join(VARIANTS)})",
    )
    parser.add_argument(
        "--keep", type=Path, help="write the logs, outputs and reports here and keep them"
    )
    args = parser.parse_args(argv)
    if not args.log.is_file():
        print(f"error: {args.log}: no such file (an MCAP stereo log)", file=sys.stderr)
        return 2
    log = args.log.resolve()
    try:
        if args.keep is not None:
            args.keep.mkdir(parents=True, exist_ok=True)
            rows = [measure(log, name, args.keep.resolve()) for name in args.variants]
        else:
            with tempfile.TemporaryDirectory(prefix="image_levels_") as scratch:
                rows = [measure(log, name, Path(scratch)) for name in args.variants]
    except BadInput as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"{args.log.name}: densify (no flags), evaluate; PCA-MAP's mean |disparity error|")
    print()
    print(table(rows))
    # a variant that fails is a figure of the table; the log itself failing is not
    return 1 if any(row.failed for row in rows if row.variant == "original") else 0


if __name__ == "__main__":
    sys.exit(main())
