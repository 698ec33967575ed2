"""Frames of a broken view are left out of the fit check (bughunt13A F2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate.adapt import typical_frames


@dataclass(frozen=True)
class _Frame:
    pixels: npt.NDArray[np.float32]
    sgbm_map: npt.NDArray[np.float32] | None
    index: int


def _frame(index: int, points: int, matched: float) -> _Frame:
    sgbm = np.zeros((10, 100), np.float32)
    sgbm.flat[: int(matched * sgbm.size)] = 5.0
    return _Frame(np.zeros((points, 2), np.float32), sgbm, index)


def test_a_minority_of_frames_without_measurements_or_matches_is_left_out() -> None:
    # before: their SGBM pixels were scored as truth and chose the basis for the whole log
    frames = [_frame(i, 150, 0.75) for i in range(8)]
    frames[4] = _frame(4, 31, 0.26)  # a textureless wall
    frames[5] = _frame(5, 160, 0.2)  # few SGBM matches
    frames[6] = _frame(6, 0, 0.0)  # a pair not matched
    lines: list[str] = []
    kept = typical_frames(frames, lines)
    assert [f.index for f in kept] == [0, 1, 2, 3, 7]
    assert lines
    assert "3 of the check's 8 frames left out (frame(s) 4, 5, 6)" in lines[0]


def test_similar_frames_are_all_kept() -> None:
    frames = [_frame(i, 100 + 40 * (i % 3), 0.6 + 0.05 * (i % 4)) for i in range(8)]
    lines: list[str] = []
    assert typical_frames(frames, lines) == frames
    assert lines == []
