"""The image clock's placed stamps stay between the stamps of their own (review 59a F1)."""

from __future__ import annotations

import itertools

from pcainterp_stream.frontend.image_clock import ImageClock

MS = 1_000_000
SECOND = 1_000_000_000
LOG_START = 1_317_046_453 * SECOND


def _placed(stamps: list[int], period_ns: int = 100 * MS) -> list[int]:
    """Feed one topic's stamps (logged ``period_ns`` apart); return where each is placed."""
    clock = ImageClock()
    return [clock.stamp(stamp, LOG_START + i * period_ns) for i, stamp in enumerate(stamps)]


def _slow(repeats: int, step_ns: int, frames: int = 12) -> list[int]:
    """A header clock at 1000 s whose stamp advances ``step_ns`` every ``repeats`` frames."""
    return [1000 * SECOND + (i // repeats) * step_ns for i in range(frames)]


def _strictly_between_own(stamps: list[int], placed: list[int]) -> None:
    assert all(b > a for a, b in itertools.pairwise(placed)), placed
    for index, stamp in enumerate(stamps):
        if index and stamp in (0, stamps[index - 1]):
            later = [s for s in stamps[index:] if s not in (0, stamp)]
            if later:
                assert placed[index] < later[0], (index, placed)


def test_a_clock_at_half_real_time_stays_between_its_own_stamps() -> None:
    # review 59a F1: 1000.0, 1000.1, 1000.1, 1000.2, 1000.2 ... (every repeat on the next
    # frame's own stamp); now 1000.05 before the rate is known, then 1000.15, 1000.25 ...
    stamps = _slow(2, 100 * MS)
    placed = _placed(stamps)
    _strictly_between_own(stamps, placed)
    assert placed[:6] == [1000 * SECOND + ms * MS for ms in (0, 50, 100, 150, 200, 250)]


def test_a_clock_at_a_third_of_real_time_never_goes_back() -> None:
    # review 59a F1: 1000.0, 1000.1, 1000.2, 1000.1 (back), 1000.2, 1000.3, 1000.2 ...
    stamps = _slow(3, 100 * MS)
    placed = _placed(stamps)
    _strictly_between_own(stamps, placed)
    assert placed[3] == 1000 * SECOND + 100 * MS
    assert abs(placed[4] - (1000 * SECOND + 133_333_333)) <= 1


def test_the_coarse_clock_of_12c_and_the_all_zero_camera() -> None:
    coarse = _slow(2, 200 * MS)  # 12C F2: a device clock at rate 1 ticking every 200 ms
    placed = _placed(coarse)
    _strictly_between_own(coarse, placed)
    assert placed[2:6] == [1000 * SECOND + ms * MS for ms in (200, 300, 400, 500)]
    zeros = _placed([0] * 5)  # no clock: log time (bug hunt 7A F6)
    assert zeros == [LOG_START + i * 100 * MS for i in range(5)]


def test_missed_stuck_and_restarted_stamps_stay_monotonic() -> None:
    missed = [1000 * SECOND + i * 100 * MS for i in range(6)]
    missed[4] = 0  # missed once, with the rate known: on the clock exactly
    assert _placed(missed)[4] == 1000 * SECOND + 400 * MS
    stuck = [SECOND, 2 * SECOND] + [3 * SECOND] * 5  # a clock that jumps: log-time rate
    assert _placed(stuck)[2:] == [3 * SECOND + i * 100 * MS for i in range(5)]
    first_run = [SECOND] * 6  # no rate ever known: within one frame of the stamp
    placed = _placed(first_run)
    assert all(b > a for a, b in itertools.pairwise(placed))
    assert placed[-1] < SECOND + 100 * MS
    restart = [5 * SECOND, 5 * SECOND + 100 * MS, SECOND, SECOND]  # the clock restarted
    assert _placed(restart)[3] == SECOND + 50 * MS


def test_a_clock_stuck_for_longer_than_a_second_goes_on_at_log_time() -> None:
    # bug hunt 16B F8: every image stamped 1317046453.0 s; the whole log was squeezed into
    # one frame interval (1 ns apart after some thousand images); past a second of log time
    # the images are placed at the stamp plus the log time since it
    stuck = [LOG_START] * 40  # 4 s at 10 Hz
    placed = _placed(stuck)
    assert all(b > a for a, b in itertools.pairwise(placed)), placed
    assert placed[1] == LOG_START + 50 * MS  # within the first second: within one frame
    assert placed[11:] == [LOG_START + i * 100 * MS for i in range(11, 40)]
    long_run = _placed([LOG_START] * 20_000, period_ns=33 * MS)  # 11 min at 30 Hz
    assert min(b - a for a, b in itertools.pairwise(long_run[31:])) == 33 * MS


def test_a_coarse_clock_of_whole_seconds_stays_short_of_its_next_stamp() -> None:
    seconds = [1000 * SECOND + (i // 15) * SECOND for i in range(45)]  # 15 Hz, 1 s ticks
    placed = _placed(seconds, period_ns=66_666_667)
    _strictly_between_own(seconds, placed)
