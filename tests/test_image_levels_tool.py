"""tools/image_levels.py: a log's images rewritten as other sensors give them, and the table.

The figures docs/raw_logs.md ("Image levels") quotes come from this tool; a variant that
left the images as they were, changed another message, or a table without its rows would
quote figures of nothing.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from pcainterp_stream.io import rosmsg

ROOT = Path(__file__).resolve().parents[1]
TOOL = ROOT / "tools" / "image_levels.py"
LEFT, RIGHT = "/stereo/left/image_rect", "/stereo/right/image_rect"


@pytest.fixture(scope="module")
def tool() -> Any:
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import image_levels
    finally:
        sys.path.remove(str(ROOT / "tools"))
    return image_levels


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from pcainterp_stream.pipeline.jobs import synth

    path = tmp_path_factory.mktemp("levels") / "street.mcap"
    synth(path, frames=2, seed=1, scale=0.25, fmt=None)
    return path


def _messages(path: Path) -> list[tuple[str, int, int, bytes, str]]:
    with path.open("rb") as stream:
        return [
            (
                channel.topic,
                message.log_time,
                message.publish_time,
                bytes(message.data),
                schema.name,
            )
            for schema, channel, message in make_reader(stream).iter_messages(log_time_order=False)
        ]


@pytest.mark.parametrize(
    "variant", ["offset16", "dark", "right_gain", "right_gamma", "over_exposed"]
)
def test_a_variant_rewrites_the_pairs_images_only(
    tool: Any, log: Path, tmp_path: Path, variant: str
) -> None:
    out = tmp_path / f"{variant}.mcap"
    share = tool.rewrite(log, out, tool.VARIANTS[variant])
    before, after = _messages(log), _messages(out)
    assert [m[:3] for m in after] == [m[:3] for m in before]  # topics, times, order
    changed = {LEFT: 0, RIGHT: 0}
    for old, new in zip(before, after, strict=True):
        if old[0] not in changed:
            assert new[3:] == old[3:], old[0]  # camera infos, truth: byte for byte
            continue
        was = rosmsg.deserialize(old[3], old[4])
        now = rosmsg.deserialize(new[3], new[4])
        assert rosmsg.stamp_ns(now) == rosmsg.stamp_ns(was)
        assert now.header.frame_id == was.header.frame_id
        image, original = rosmsg.image_array(now), rosmsg.image_array(was)
        assert image.shape[:2] == original.shape[:2]
        if not np.array_equal(image, original):
            changed[old[0]] += 1
        if variant == "offset16":
            assert now.encoding == "mono16"
            assert 30000 <= int(image.min()) <= int(image.max()) <= 30300
        if variant == "dark":
            assert int(image.max()) <= 40
    frames = sum(1 for m in before if m[0] == LEFT)
    assert changed[RIGHT] == frames
    assert changed[LEFT] == (0 if variant.startswith("right_") else frames)
    assert (share > 0.5) == (variant == "over_exposed"), share


def test_a_raw_logs_pair_is_found_as_densify_finds_it(tool: Any, tmp_path: Path) -> None:
    # review 17a R2: the tool took /stereo/*/image_rect only and called a raw log imageless
    from pcainterp_stream.pipeline.jobs import synth_raw

    log = tmp_path / "raw.mcap"
    synth_raw(log, frames=2, seed=1, scale=0.25, fmt=None, model="plumb_bob")
    raw_left, raw_right = "/camera/left/image_raw", "/camera/right/image_raw"
    assert tool.pair_topics(log) == (raw_left, raw_right)
    out = tmp_path / "over.mcap"
    assert tool.rewrite(log, out, tool.VARIANTS["over_exposed"]) > 0.5
    before, after = _messages(log), _messages(out)
    assert [m[:3] for m in after] == [m[:3] for m in before]
    for old, new in zip(before, after, strict=True):
        assert (new[3] != old[3]) == (old[0] in (raw_left, raw_right)), old[0]


def _run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, str(TOOL), *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )


def test_the_table_has_a_row_per_variant_with_densifys_notes(log: Path, tmp_path: Path) -> None:
    done = _run(str(log), "--variants", "original", "dark", "over_exposed", cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    rows = [line for line in done.stdout.splitlines() if line.startswith("| ")]
    assert rows[0].startswith("| variant | at 255 | PCA-MAP px | /NN | +-2 sigma |")
    assert [row.split(" | ")[0] for row in rows[2:]] == ["| original", "| dark", "| over_exposed"]
    for row in rows[2:]:
        cells = row.split(" | ")
        assert float(cells[2]) > 0, row  # PCA-MAP px
        assert float(cells[3]) > 0, row  # /NN
        assert cells[4].endswith(" %"), row
    assert rows[2].endswith("| - |")  # the original: no note
    assert "dark images (grey levels" in rows[3]
    assert "over-exposed images:" in rows[4]
    assert list(tmp_path.iterdir()) == []  # scratch only, removed


def test_bad_input_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "text.mcap").write_text("not a log\n")
    for name in ("missing.mcap", "text.mcap"):
        done = _run(name, "--variants", "dark", cwd=tmp_path)
        assert done.returncode == 2
        assert done.stdout == ""
        assert done.stderr.startswith(f"error: {tmp_path / name if name == 'text.mcap' else name}")
        assert len(done.stderr.splitlines()) == 1
        assert "Traceback" not in done.stderr
