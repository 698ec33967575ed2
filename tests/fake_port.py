"""A loopback port that stands in for a viewer at the other end of a connection."""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Iterator


@contextlib.contextmanager
def loopback_port(mode: str) -> Iterator[int]:
    """Yield a loopback port that accepts connections, then closes them or never answers.

    ``mode``: "close" (an `ssh -R` with no viewer behind it, a viewer closed) or "hold" (a
    suspended or frozen viewer: the connections stay open, nothing is read or written).
    """
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(16)
    listener.settimeout(0.1)
    held: list[socket.socket] = []
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            try:
                connection, _ = listener.accept()
            except OSError:
                continue
            if mode == "close":
                connection.close()
            else:
                held.append(connection)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield int(listener.getsockname()[1])
    finally:
        stop.set()
        thread.join(2)
        for connection in held:
            connection.close()
        listener.close()
