"""Bytes that are no log piped to ``densify -`` (bug hunt 16A F7).

The log reader named the temporary copy of standard input (the user never gave that path,
and it is gone when the command ends) and suggested a rosbag2 folder, which cannot be piped.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest

from pcainterp_stream import cli
from pcainterp_stream.errors import LogReadError
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.pipes import spool

EXPECTED = (
    "pcainterp: error: standard input is not a log (no MCAP, ROS 1 bag or SQLite magic "
    "bytes); pipe an MCAP file, a ROS 1 bag or a rosbag2 sqlite3 .db3 into `pcainterp "
    "densify -` (a rosbag2 folder cannot be piped: pass its path)"
)


class _Stdin:
    """What ``sys.stdin`` is in a process: text, with the bytes under ``.buffer``."""

    def __init__(self, data: bytes) -> None:
        self.buffer = io.BytesIO(data)


@pytest.mark.parametrize(
    "data",
    [bytes(range(256)) * 20, json.dumps({"format": "pcainterp-golden/3"}).encode(), b"x"],
    ids=["random", "json", "one byte"],
)
def test_densify_names_standard_input_and_advice_for_a_pipe(
    data: bytes,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
) -> None:
    monkeypatch.setattr("sys.stdin", _Stdin(data))
    monkeypatch.chdir(tmp_path)
    assert cli.main(["densify", "-", "-o", "out.mcap"]) == 2
    err = capsys.readouterr().err
    assert err.splitlines() == [EXPECTED]
    assert "pcainterp-stdin" not in err


def test_spool_rewords_only_the_refusal_of_bytes_that_are_no_log() -> None:
    with pytest.raises(LogReadError, match=r"^standard input is not a log"):
        with spool(io.BytesIO(b"not a log at all")) as path:
            open_log(path)
    with pytest.raises(LogReadError, match="something else"):  # another error: as it was
        with spool(io.BytesIO(b"\x89MCAP0\r\n and then")):
            raise LogReadError("something else")
