"""The writing thread of a threaded log writer (``open_writer(..., threaded=True)``)."""

from __future__ import annotations

import sys
import threading
import time as clock
from types import FrameType
from typing import Any

from pcainterp_stream.errors import LogWriteError
from pcainterp_stream.io.logwriter import WRITE_QUEUE_ITEMS
from pcainterp_stream.io.write_thread import WriteThread


def _submit_interrupted_at_line(writer: WriteThread, line: int) -> bool:
    """Submit an item with ``KeyboardInterrupt`` raised at the ``line``-th traced line.

    Return whether the interrupt fired (False once ``line`` is past the submit's end).
    """
    seen = 0

    def trace(frame: FrameType, event: str, arg: object) -> Any:
        nonlocal seen
        if event == "line":
            seen += 1
            if seen == line:
                raise KeyboardInterrupt
        return trace

    sys.settrace(trace)
    try:
        writer.submit(lambda: None)
    except KeyboardInterrupt:
        return True
    finally:
        sys.settrace(None)
    return False


def test_writer_thread_still_takes_work_after_an_interrupt_at_any_line() -> None:
    # Ctrl-C raises KeyboardInterrupt between any two lines of the caller's Python code.
    # One raised inside the hand-off to the writer thread (a condition's notify, in the
    # standard queue) could leave the writer asleep with work queued: the command's
    # clean-up then waited for it forever. Every line, in a thread of its own so that a
    # hang fails the test instead of stopping it.
    failures: list[int] = []

    def drive() -> None:
        line = 1
        while True:
            writer = WriteThread(LogWriteError, queue_items=WRITE_QUEUE_ITEMS)
            clock.sleep(0.02)  # the writer is waiting for work
            fired = _submit_interrupted_at_line(writer, line)
            clock.sleep(0.02)  # whatever was handed over ran; the writer waits again
            done = threading.Thread(target=writer.call, args=(lambda: None,), daemon=True)
            done.start()
            done.join(10.0)
            if done.is_alive():
                failures.append(line)
            else:
                writer.stop()
            if not fired:
                return
            line += 1

    driver = threading.Thread(target=drive, daemon=True)
    driver.start()
    driver.join(120.0)
    assert not driver.is_alive()
    assert failures == []
