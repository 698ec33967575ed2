"""The stamp of an image whose header stamp does not place it: on the image clock, or log time.

An image whose header stamp is 0 (not set) or its previous image's (a coarse device clock, a
simulator whose ``/clock`` ticks slower than the camera, a stamp missed once) tells nothing of
when it was taken. densify stamps the outputs of such a frame (``StereoPairer.full_result``)
and ``evaluate`` finds its input images (``evaluate.log_frames``) by the same rule, one
:class:`ImageClock` per image topic fed its images in log order, copies left out:

- once an image of the topic had a stamp of its own (the log has a header clock), an unplaced
  image stays on that clock: the last placed stamp plus the log time since that image (a
  coarse clock's 1000.0, 1000.0, 1000.2 s at 10 Hz give 1000.0, 1000.1, 1000.2 s);
- before that (a camera that stamps nothing, all 0; or the images before a clock's first
  stamp) the log time is the only clock there is: the image's log time.

No image is held back: the rule looks only at the images before. A clock that starts at 0
(a simulator's first frame stamped 0.0 s, then 0.1, 0.2 ...) therefore still places that
first frame at its log time: telling it from a camera that never stamps needs the next image.
"""

from __future__ import annotations

from typing import NamedTuple


class Restamp(NamedTuple):
    """Where an unplaced image is placed: ``stamp_ns``, on the image clock or by log time."""

    stamp_ns: int
    by_log_time: bool


class ImageClock:
    """One image topic's images in log order: where each image whose stamp does not place it is.

    See the module docstring for the rule.
    """

    def __init__(self) -> None:
        self._previous: int | None = None  # the header stamp of the topic's previous image
        self._placed: tuple[int, int] | None = None  # (stamp, log time) of the last placed one

    def place(self, stamp_ns: int, log_time_ns: int) -> Restamp | None:
        """Take the topic's next image; return where it is placed, None: at its own stamp."""
        previous, self._previous = self._previous, stamp_ns
        if stamp_ns not in (0, previous):
            self._placed = (stamp_ns, log_time_ns)
            return None
        if self._placed is None:
            return Restamp(log_time_ns, by_log_time=True)
        placed_ns, placed_log_ns = self._placed
        return Restamp(placed_ns + max(0, log_time_ns - placed_log_ns), by_log_time=False)

    def stamp(self, stamp_ns: int, log_time_ns: int) -> int:
        """Take the topic's next image; return the stamp it is placed at (its own or not)."""
        restamp = self.place(stamp_ns, log_time_ns)
        return stamp_ns if restamp is None else restamp.stamp_ns
