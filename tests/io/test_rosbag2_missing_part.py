"""A split rosbag2 bag with one part missing (bug hunt 16B F13).

Before: "cannot read rosbag2 log ... (AnyReaderError: Some database files are missing: [...]);
check metadata.yaml and the storage": the part present (which reads when passed directly)
was not offered. It is still refused: an output that silently lacks a stretch of the
recording is worse than one line that names the missing part and the way round it.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Writer

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log

LEFT = "/stereo/left/image_rect"


def _split_missing(tmp_path: Path) -> Path:
    bag = tmp_path / "drive 1"  # a space: the suggested path is quoted for a shell
    rng = np.random.default_rng(0)
    with Writer(bag, version=8) as writer:
        connection = writer.add_connection(LEFT, rosmsg.IMAGE, typestore=rosmsg.TYPESTORE)
        for i in range(3):
            image = rng.integers(0, 256, (8, 8), dtype=np.uint8)
            stamp = 1_000_000_000 + i
            writer.write(
                connection, stamp, rosmsg.serialize(rosmsg.image_message(image, stamp, "l"))
            )
    db = next(bag.glob("*.db3"))
    db.rename(bag / "drive_0.db3")
    meta = bag / "metadata.yaml"
    text = meta.read_text().replace(db.name, "drive_0.db3")
    text = text.replace("  - drive_0.db3\n", "  - drive_0.db3\n  - drive_1.db3\n", 1)
    meta.write_text(text)
    return bag


def test_a_missing_part_is_named_and_the_parts_present_offered(tmp_path: Path) -> None:
    bag = _split_missing(tmp_path)
    with pytest.raises(LogReadError) as caught:
        open_log(bag)
    assert str(caught.value) == (
        f"cannot read rosbag2 folder {bag}: metadata.yaml lists 2 storage files and drive_1.db3 "
        "is missing (an interrupted copy?); copy the missing part in, or pass the parts present "
        f"instead of the folder to read them alone: '{bag / 'drive_0.db3'}'"
    )
    with open_log(bag / "drive_0.db3") as reader:  # what it offers reads
        assert len(list(reader.messages())) == 3
    assert not re.search(r"Some database files", str(caught.value))
