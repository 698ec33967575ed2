"""Copy an MCAP file message by message, so a test can edit, drop or move messages."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from types import TracebackType
from typing import IO, Any

from mcap.reader import make_reader
from mcap.writer import Writer


class McapCopy:
    """Copy ``source`` to ``target``: :meth:`messages` reads, :meth:`add` writes.

    Each input channel (and its schema) is registered in the output when its first message
    is read, with the same topic, encodings and metadata; nothing is written but what
    :meth:`add` is given, so a test may change, leave out or reorder messages.

    Examples:
        >>> def copy_all(source: Path, target: Path) -> None:
        ...     with McapCopy(source, target) as copy:
        ...         for topic, channel_id, message in copy.messages():
        ...             copy.add(channel_id, message.log_time, message.data)
    """

    def __init__(self, source: Path, target: Path) -> None:
        self.source, self.target = source, target
        self._schemas: dict[int, int] = {}
        self._channels: dict[int, int] = {}

    def __enter__(self) -> McapCopy:
        self._stream: IO[bytes] = self.source.open("rb")
        self._out: IO[bytes] = self.target.open("wb")
        self._writer = Writer(self._out)
        self._writer.start()
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, _: TracebackType | None
    ) -> None:
        if kind is None:
            self._writer.finish()
        self._out.close()
        self._stream.close()

    def messages(self, drop: tuple[str, ...] = ()) -> Iterator[tuple[str, int, Any]]:
        """Yield (topic, output channel id, message) in file order.

        ``drop``: topic prefixes left out, their channels too (a log without them).
        """
        for schema, channel, message in make_reader(self._stream).iter_messages(
            log_time_order=False
        ):
            if channel.topic.startswith(drop) and drop:
                continue
            if channel.id not in self._channels:
                if schema is not None and schema.id not in self._schemas:
                    self._schemas[schema.id] = self._writer.register_schema(
                        schema.name, schema.encoding, schema.data
                    )
                self._channels[channel.id] = self._writer.register_channel(
                    channel.topic,
                    channel.message_encoding,
                    self._schemas.get(schema.id, 0) if schema is not None else 0,
                    dict(channel.metadata),
                )
            yield channel.topic, self._channels[channel.id], message

    def add(
        self, channel_id: int, log_time: int, data: bytes, publish_time: int | None = None
    ) -> None:
        """Write one message (publish time: the log time unless given)."""
        self._writer.add_message(
            channel_id, log_time, data, log_time if publish_time is None else publish_time
        )
