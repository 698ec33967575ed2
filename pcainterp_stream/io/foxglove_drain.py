"""What the Foxglove server still has to send each client at the end of a stream.

The foxglove-sdk exposes no per-client queue (nor a count of what it sent), and its stop
closes the connections without sending what is still queued. A client keeps up with what
it was sent once its connection's send queue in the kernel is empty: a client that reads
slower than the stream first fills its own receive buffer, then the server's send buffer
(the kernel's ``tx_queue``: bytes written and not yet acknowledged), and only then does the
SDK's outbox for it grow. So an empty ``tx_queue``, twice in a row a short while apart,
means nothing is queued for that client anywhere on this machine. The kernel's connection
table is read from ``/proc/net/tcp`` and ``/proc/net/tcp6`` (Linux); elsewhere
:func:`queued_bytes` returns None and the end waits a fixed second, as before.
"""

from __future__ import annotations

import ipaddress
from collections import deque
from collections.abc import Collection
from pathlib import Path

_TABLES = (Path("/proc/net/tcp"), Path("/proc/net/tcp6"))
_ESTABLISHED = "01"
_FRAME_OVERHEAD = 13 + 10
"""Bytes a message takes on the wire besides its payload: the protocol's opcode, channel id
and log time (13), and at most 10 of WebSocket framing."""


IPAddress = ipaddress.IPv4Address | ipaddress.IPv6Address


def _ip(given: str | bytes) -> IPAddress:
    """An address as compared here: an IPv4-mapped IPv6 one as IPv4, a scope id dropped."""
    address = ipaddress.ip_address(given.split("%")[0] if isinstance(given, str) else given)
    if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
        return address.ipv4_mapped
    return address


def _address(text: str) -> tuple[IPAddress, int]:
    """``0100007F:1F90`` (``/proc/net/tcp``'s form: 32-bit words in host order) -> address."""
    hex_host, hex_port = text.split(":")
    raw = bytes.fromhex(hex_host)
    host = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
    return _ip(host), int(hex_port, 16)


def _bound_to(local: IPAddress, hosts: frozenset[IPAddress]) -> bool:
    """Whether a connection to ``local`` is one a server bound to ``hosts`` accepted.

    ``0.0.0.0`` takes every IPv4 address, ``::`` every address (IPv4 ones mapped); no hosts:
    any (the port alone).
    """
    return not hosts or any(
        local == host or (host.is_unspecified and (host.version == 6 or local.version == 4))
        for host in hosts
    )


def queued_bytes(port: int, hosts: Collection[str] = ()) -> dict[str, int] | None:
    """Client address (as the SDK names it, ``HOST:PORT``) -> bytes queued to it, on ``port``.

    ``hosts``: the addresses the server bound (:func:`_bound_to`): another server's clients
    on the same port number at another address (``[::1]:P`` beside ``127.0.0.1:P``) are not
    its own. Only connections with something queued are listed. None where the kernel's
    table cannot be read (not Linux).
    """
    bound = frozenset(map(_ip, hosts))
    found: dict[str, int] = {}
    readable = False
    for table in _TABLES:
        try:
            lines = table.read_text().splitlines()[1:]
        except OSError:
            continue
        readable = True
        for line in lines:
            fields = line.split()
            if len(fields) < 5 or fields[3] != _ESTABLISHED:
                continue
            local, remote = _address(fields[1]), _address(fields[2])
            queued = int(fields[4].split(":")[0], 16)
            if local[1] == port and queued > 0 and _bound_to(local[0], bound):
                shown = f"[{remote[0]}]" if remote[0].version == 6 else str(remote[0])
                found[f"{shown}:{remote[1]}"] = queued
    return found if readable else None


class SentSizes:
    """The wire sizes of the latest messages sent, to tell how many a queue of bytes holds."""

    def __init__(self, keep: int) -> None:
        self._sizes: deque[int] = deque(maxlen=keep)

    def add(self, payload: int) -> None:
        """Note a message of ``payload`` bytes."""
        self._sizes.append(payload + _FRAME_OVERHEAD)

    def messages_in(self, queued: int) -> int:
        """How many of the latest messages ``queued`` bytes reach into (at least 1)."""
        count, total = 0, 0
        for size in reversed(self._sizes):
            if total >= queued:
                break
            count, total = count + 1, total + size
        return max(count, 1)
