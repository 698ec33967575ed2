"""The image clock's placed stamps stay between the stamps of their own (review 59a F1)."""

from __future__ import annotations

import itertools

from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

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
    missed[4] = 0  # missed once, with the rate known: on the clock, half a ms short of its tick
    assert _placed(missed)[4] == 1000 * SECOND + 400 * MS - MS // 2
    stuck = [SECOND, 2 * SECOND] + [3 * SECOND] * 5  # a clock that jumps: log-time rate
    assert _placed(stuck)[2:] == [3 * SECOND + i * 100 * MS for i in range(5)]
    first_run = [SECOND] * 6  # no rate ever known: within one frame of the stamp
    placed = _placed(first_run)
    assert all(b > a for a, b in itertools.pairwise(placed))
    assert placed[-1] < SECOND + 100 * MS
    restart = [5 * SECOND, 5 * SECOND + 100 * MS, SECOND, SECOND]  # the clock restarted
    assert _placed(restart)[3] == SECOND + 50 * MS


def test_a_clock_stuck_for_a_whole_log_stays_within_one_frame_of_its_stamp() -> None:
    # bug hunt 16B F8 (every image stamped 1317046453.0 s) is evaluate's to catch: no rate is
    # ever measured, so the repeats stay within one frame interval, in order (review 16b R2:
    # placing them at log-time rate past a second passed the stamps of a clock paused at start)
    placed = _placed([LOG_START] * 40)  # 4 s at 10 Hz
    assert all(b > a for a, b in itertools.pairwise(placed)), placed
    assert placed[1] == LOG_START + 50 * MS
    assert placed[-1] < LOG_START + 100 * MS


def test_a_simulator_paused_at_start_or_amid_a_run_never_goes_back() -> None:
    # review 16b R2: paused 2.5 s at start, then 10 Hz; the 1 s stuck rule placed the
    # repeats at 1.1-2.4 s, then the clock's own 0.1 s went back
    at_start = [1000 * SECOND] * 25 + [1000 * SECOND + i * 100 * MS for i in range(1, 16)]
    placed = _placed(at_start)
    _strictly_between_own(at_start, placed)
    assert placed[25:] == at_start[25:]  # the frames after the pause keep their stamps
    # review 16b R1: paused 1.5 s after 6 frames; at rate 1 the repeats were placed at
    # 0.6-2.0 s, past the own stamps 0.6-1.5 s of the frames after the pause
    amid = [1000 * SECOND + i * 100 * MS for i in range(6)]
    amid += [amid[-1]] * 15 + [1000 * SECOND + i * 100 * MS for i in range(6, 16)]
    placed = _placed(amid)
    _strictly_between_own(amid, placed)
    assert placed[21:] == amid[21:]
    assert all(amid[5] < p < amid[21] for p in placed[6:21]), placed


def test_a_coarse_clock_of_whole_seconds_stays_short_of_its_next_stamp() -> None:
    # review 16b R5: a second of 1 s ticks at 15 Hz whose last image is logged 80 ms late
    # (log latency): at rate 1 it fell 1.013 s after its stamp, past the next own stamp 1001.0
    seconds = [1000 * SECOND + (i // 15) * SECOND for i in range(60)]
    log_times = [LOG_START + i * 66_666_667 + (80 * MS if i % 15 == 14 else 0) for i in range(60)]
    clock = ImageClock()
    placed = [clock.stamp(s, t) for s, t in zip(seconds, log_times, strict=True)]
    _strictly_between_own(seconds, placed)
    assert placed[15::15] == seconds[15::15]  # each second's first image at its own stamp


def _sequence(draw: st.DrawFn) -> tuple[list[int], list[int]]:
    """A header clock that never goes back, with repeats, zeros and any log-time steps.

    ``again`` is the last own stamp once more, after zeros too (bug hunt 17G F3: an own stamp
    equal to the last own one after an unstamped image was given out again, going back).
    """
    count = draw(st.integers(2, 60))
    stamps, log_times = [1000 * SECOND], [LOG_START]
    for _ in range(count):
        log_times.append(log_times[-1] + draw(st.integers(1, 3 * SECOND)))
        kind = draw(st.sampled_from(["advance", "repeat", "repeat", "zero", "again"]))
        last = next((s for s in reversed(stamps) if s), stamps[0])
        if kind == "advance":
            stamps.append(last + draw(st.integers(1, 3 * SECOND)))
        elif kind == "again":
            stamps.append(last)
        else:
            stamps.append(0 if kind == "zero" else stamps[-1])
    return stamps, log_times


@settings(max_examples=examples(300), deadline=None)
@given(st.data())
def test_the_stamps_given_out_never_repeat_or_go_back(data: st.DataObject) -> None:
    # review 16b R2: for any clock that does not go back itself, whatever its repeats,
    # pauses, ticks and log times, every stamp given out (own or placed) is after the last
    stamps, log_times = data.draw(st.composite(_sequence)())
    clock = ImageClock()
    given = [clock.stamp(s, t) for s, t in zip(stamps, log_times, strict=True)]
    assert all(b > a for a, b in itertools.pairwise(given)), (stamps, log_times, given)


def _sequence_with_restarts(draw: st.DrawFn) -> tuple[list[int], list[int]]:
    """As :func:`_sequence`, with restarts, log-time steps of 0 and a clock starting at 0."""
    count = draw(st.integers(2, 60))
    first = draw(st.sampled_from([0, 1000 * SECOND]))
    stamps, log_times = [first], [LOG_START]
    for _ in range(count):
        log_times.append(log_times[-1] + draw(st.integers(0, 3 * SECOND)))
        kind = draw(st.sampled_from(["advance", "repeat", "repeat", "zero", "restart", "again"]))
        last = next((s for s in reversed(stamps) if s), 0)
        if kind == "advance" or (kind in ("restart", "again") and last <= 1):
            stamps.append(max(last, 100 * SECOND) + draw(st.integers(1, 3 * SECOND)))
        elif kind == "restart":  # the clock goes back (a restarted driver or simulator)
            stamps.append(draw(st.integers(1, last - 1)))
        elif kind == "again":  # the last own stamp once more, after zeros too (17G F3)
            stamps.append(last)
        else:
            stamps.append(0 if kind == "zero" else stamps[-1])
    return stamps, log_times


def _segments(stamps: list[int], log_times: list[int]) -> list[list[int]]:
    """The indices between the clock's documented exceptions to "never repeats or goes back".

    A new segment starts at a restart (an own stamp below the last own one) and at the first
    own stamp after images placed at their log times (no own stamp before: those are on the
    log's clock, checked apart); an image whose stamp and log time are its last own stamp's
    again is that message logged twice (it keeps its stamp) and is left out of the order.
    """
    segments: list[list[int]] = [[]]
    own: tuple[int, int] | None = None
    previous: int | None = None
    for i, (stamp, log_time) in enumerate(zip(stamps, log_times, strict=True)):
        is_own = stamp not in (0, previous)
        previous = stamp
        if is_own and (own is None or stamp < own[0]):
            segments.append([])
        if not is_own and (own is None or (stamp == own[0] and log_time <= own[1])):
            continue
        if is_own:
            own = (stamp, log_time)
        segments[-1].append(i)
    return segments


@settings(max_examples=examples(300), deadline=None)
@given(st.data())
def test_the_stamps_given_out_keep_order_between_restarts(data: st.DataObject) -> None:
    # review 16e R4: restarts, log-time steps of 0 and a clock that starts at 0 (stamped 0,
    # placed at its log time): between the documented exceptions, still strictly in order
    stamps, log_times = data.draw(st.composite(_sequence_with_restarts)())
    clock = ImageClock()
    given = [clock.stamp(s, t) for s, t in zip(stamps, log_times, strict=True)]
    before = next((i for i, s in enumerate(stamps) if s), len(stamps))
    assert given[:before] == log_times[:before]  # no own stamp yet: at their log times
    for segment in _segments(stamps, log_times):
        if segment:  # a restart or the first stamp of its own: kept, measured again
            assert given[segment[0]] == stamps[segment[0]], (stamps, log_times, given)
        order = [given[i] for i in segment]
        assert all(b > a for a, b in itertools.pairwise(order)), (stamps, log_times, given)


def test_the_second_of_two_missed_stamps_is_squeezed() -> None:
    # review 16e R1: 800 and 900 ms missed at 10 Hz are placed at 799.5 and 799.75 ms; the
    # second's time is unknown (evaluate takes only truth of its exact stamp), the first's not
    for missed in (700 * MS, 0):
        clock = ImageClock()
        flags = []
        for i, stamp in enumerate(
            [*(k * 100 * MS for k in range(1, 8)), missed, missed, 1000 * MS]
        ):
            clock.stamp(stamp or 0, LOG_START + i * 100 * MS)
            flags.append(clock.squeezed)
        assert flags == [False] * 8 + [True, False], flags


def test_the_last_own_stamp_again_after_an_unstamped_image_is_placed_after() -> None:
    # bug hunt 17G F3: 1.1 s, 0, 1.1 s gave out 1.1, 1.1995, 1.1 (back and repeated); the
    # second 1.1 s is placed 1 ns after the stamp placed before it
    assert _placed([1000 * MS, 1100 * MS, 0, 1100 * MS]) == [
        1000 * MS,
        1100 * MS,
        1_199_500_000,
        1_199_500_001,
    ]
    given = _placed([1000 * MS, 1100 * MS, 1100 * MS, 0, 1100 * MS, 0, 1200 * MS])
    assert all(b > a for a, b in itertools.pairwise(given)), given
    assert given[-1] == 1200 * MS  # the clock's next tick is its own stamp again
