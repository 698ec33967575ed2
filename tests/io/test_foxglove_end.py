"""The end of a live Foxglove stream and its port: bug hunt 12A F1, F2, F5, F6."""

from __future__ import annotations

import socket
import sys
from pathlib import Path

import pytest

from pcainterp_stream import cli
from pcainterp_stream.cli.app import build_parser
from pcainterp_stream.errors import StreamError
from pcainterp_stream.io.foxglove import FoxgloveLive, ServeAddress


def _time_wait_port() -> int:
    """A loopback port whose server side of a connection is in TIME_WAIT, nothing listening.

    The server closes first (as densify's does when a run stops while it sends), so its
    side of the connection waits out TIME_WAIT (60 s on Linux) after the listener is gone.
    """
    with socket.socket() as listener:
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        port = int(listener.getsockname()[1])
        client = socket.create_connection(("127.0.0.1", port))
        accepted, _ = listener.accept()
        accepted.close()  # the server's side closes first: it goes to TIME_WAIT
        client.recv(1)  # the FIN
        client.close()
    return port


@pytest.mark.skipif(sys.platform == "win32", reason="Linux/macOS TIME_WAIT rule")
def test_a_port_in_time_wait_is_served_and_a_live_one_refused() -> None:
    """12A F6: the probe bound without SO_REUSEADDR: "Address already in use; stop the other
    server" for up to 60 s after a run stopped while sending, though none ran."""
    port = _time_wait_port()
    with FoxgloveLive(ServeAddress("127.0.0.1", port), rate=0) as live:
        assert live.port == port
    for reuse in (0, 1):  # a live listener, bound as plain sockets or as servers bind
        with socket.socket() as taken:
            taken.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, reuse)
            taken.bind(("127.0.0.1", 0))
            taken.listen()
            busy = int(taken.getsockname()[1])
            with pytest.raises(StreamError, match="Address already in use"):
                FoxgloveLive(ServeAddress("127.0.0.1", busy)).open()


@pytest.mark.parametrize(
    "argv",
    [
        ["--foxglove", "{log}"],
        ["--foxglove", "{log}", "-o", "{out}"],
        ["--foxglove", "{folder}"],  # an existing path that is no address (a ROS 2 bag folder)
    ],
)
def test_a_log_after_foxglove_is_one_line_with_the_fix(
    argv: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """12A F5: `densify --foxglove drive.mcap` took the log as HOST:PORT, then printed the
    whole usage and "the following arguments are required: INPUT"."""
    log, folder = tmp_path / "drive.mcap", tmp_path / "bag"
    log.write_bytes(b"")
    folder.mkdir()
    names = {"log": str(log), "out": str(tmp_path / "out.mcap"), "folder": str(folder)}
    code = cli.main(["densify", *(part.format(**names) for part in argv)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1, err
    assert "--foxglove took" in err
    assert "as its address" in err
    assert "put the log first" in err
    assert "--foxglove=HOST:PORT" in err


def test_an_address_after_foxglove_is_still_an_address() -> None:
    parser = build_parser()
    args = parser.parse_args(["densify", "drive.mcap", "--foxglove", "0.0.0.0:8766"])
    assert args.foxglove == "0.0.0.0:8766"
    args = parser.parse_args(["densify", "--foxglove", "8766", "drive.mcap"])
    assert args.foxglove == "8766"
    assert [str(p) for p in args.input] == ["drive.mcap"]
    args = parser.parse_args(["densify", "drive.mcap", "--foxglove"])
    assert args.foxglove == "127.0.0.1:8765"
