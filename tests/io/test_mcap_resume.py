"""An MCAP with an intact summary and one damaged record between chunks reads on.

Before (bug hunt 16B F1): a damaged chunk length, or damaged message-index records after a
chunk, ended the walk ("record claims N bytes but M remain"): the chunks after it were
lost, though the summary's chunk index lists every one with its offset and length.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log

LEFT = "/stereo/left/image_rect"


def _mcap(path: Path, n: int = 6, *, summary: bool = True) -> list[bytes]:
    """One image per chunk; return the serialized messages."""
    rng = np.random.default_rng(2)
    datas: list[bytes] = []
    with path.open("wb") as f:
        writer = Writer(f, chunk_size=1, compression=CompressionType.ZSTD)
        writer.start("ros2", "test")
        schema = writer.register_schema(
            rosmsg.IMAGE, "ros2msg", rosmsg.schema_text(rosmsg.IMAGE).encode()
        )
        channel = writer.register_channel(LEFT, "cdr", schema)
        for i in range(n):
            stamp = 1_000_000_000 + i * 100_000_000
            image = rng.integers(0, 256, (8, 8), dtype=np.uint8)
            data = rosmsg.serialize(rosmsg.image_message(image, stamp, "left"))
            datas.append(data)
            writer.add_message(channel, stamp, data, stamp)
        writer.finish()
    if not summary:  # cut after the data: no footer, no summary
        with path.open("rb") as f:
            indexes = make_reader(f).get_summary().chunk_indexes  # type: ignore[union-attr]
        end = max(c.chunk_start_offset + c.chunk_length for c in indexes)
        path.write_bytes(path.read_bytes()[:end])
    return datas


def _chunks(path: Path) -> list[tuple[int, int]]:
    """(start, length) of each chunk, from the summary."""
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return sorted((c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes)


def _read(path: Path) -> tuple[list[bytes], list[str]]:
    with open_log(path) as reader:
        return [r.data for r in reader.messages()], list(reader.damage)


def test_a_chunk_whose_length_is_damaged_is_read_with_the_index_length(tmp_path: Path) -> None:
    """Before: 2 of 6 messages, the walk ended at chunk 2."""
    path = tmp_path / "c_len.mcap"
    datas = _mcap(path)
    start, _ = _chunks(path)[2]
    data = bytearray(path.read_bytes())
    data[start + 1 : start + 9] = (10**12).to_bytes(8, "little")
    path.write_bytes(bytes(data))
    got, damage = _read(path)
    assert got == datas
    assert damage == [
        f"c_len.mcap: chunk record of {10**12} bytes where the summary's chunk index lists a "
        f"chunk of {_chunks(path)[2][1] - 9} (corrupt); read with the index's length at byte "
        f"{start} of {len(data)}"
    ]


def test_damaged_message_index_records_are_passed_over_to_the_next_chunk(
    tmp_path: Path,
) -> None:
    """Before: 3 of 6 messages; the message index (which the reader does not need) ended it."""
    path = tmp_path / "c_msgidx.mcap"
    datas = _mcap(path)
    chunks = _chunks(path)
    start, length = chunks[2]
    after, _ = chunks[3]
    data = bytearray(path.read_bytes())
    at = start + length  # the message index records after chunk 2
    data[at:after] = bytes(b ^ 0xA5 for b in data[at:after])
    path.write_bytes(bytes(data))
    got, damage = _read(path)
    assert got == datas
    assert len(damage) == 1
    assert damage[0].endswith(
        f"(corrupt; the walk resumed at byte {after}, the next chunk the summary's chunk index "
        f"lists) at byte {at} of {len(data)}"
    )


def test_without_a_summary_damaged_framing_still_ends_the_walk(tmp_path: Path) -> None:
    """No chunk index to resume at: the messages before the damage, as before."""
    path = tmp_path / "nosummary.mcap"
    datas = _mcap(path, summary=True)
    start, _ = _chunks(path)[2]
    _mcap(path, summary=False)
    data = bytearray(path.read_bytes())
    data[start + 1 : start + 9] = (10**12).to_bytes(8, "little")
    path.write_bytes(bytes(data))
    got, damage = _read(path)
    assert got == datas[:2]
    assert any("claims 1000000000000 bytes" in line for line in damage)
