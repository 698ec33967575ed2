"""A synthetic drive densified as it is and with some frames' stereo images black."""

from __future__ import annotations

from pathlib import Path

from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import decode_image, open_log
from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.pipeline import jobs

LEFT, RIGHT = "/stereo/left/image_rect", "/stereo/right/image_rect"


def blanked(source: Path, target: Path, frames: set[int]) -> Path:
    """Copy a log with the stereo images of ``frames`` (counted from 0) all black."""
    seen: dict[str, int] = {}
    with open_log(source) as reader, open_writer(target, "mcap") as writer:
        for raw in reader.messages():
            message = reader.decode(raw)
            if raw.topic in (LEFT, RIGHT):
                index = seen[raw.topic] = seen.get(raw.topic, -1) + 1
                if index in frames:
                    black = decode_image(message) * 0
                    message = rosmsg.image_message(
                        black,
                        rosmsg.stamp_ns(message),
                        message.header.frame_id,
                        encoding=message.encoding,
                    )
            writer.add_message(raw.topic, message, raw.log_time_ns)
    return target


def dense_and_blanked(folder: Path) -> dict[str, Path]:
    """A 6-frame drive (``log``) densified (``dense``), and with frames 1 and 2 black
    (``blank_dense``): those have no measurement."""
    log = folder / "drive.mcap"
    jobs.synth(log, frames=6, seed=31, scale=0.25, fmt="mcap")
    dense, blank_dense = folder / "dense.mcap", folder / "blank_dense.mcap"
    jobs.densify(log, dense)
    jobs.densify(blanked(log, folder / "blank.mcap", {1, 2}), blank_dense)
    return {"folder": folder, "log": log, "dense": dense, "blank_dense": blank_dense}
