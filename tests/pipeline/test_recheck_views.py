"""Which frames of a check are one view: the check made again on frames apart in the stream,
and a standing camera whose first frame the check leaves out (bug hunt 15C F1, F2)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from pcainterp_stream.estimate import adapt
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.frontend.motion import Motion
from pcainterp_stream.pipeline import adaptation as adaptation_module
from pcainterp_stream.pipeline.adapt_frames import AdaptFrame, still_links
from pcainterp_stream.records import StereoCamera

SIZE = (48, 64)
CAMERA = StereoCamera(64, 48, 50.0, 50.0, 32.0, 24.0, 1.0)  # f*b 50: 10 px of disparity at 5 m


def _frame(index: int, grid: np.ndarray, step: float | None) -> AdaptFrame:
    """A frame of 40 measurements at 10 px, moved ``step`` m sideways since the one before
    (10 px of image motion per 1 m here; None: motion unknown)."""
    rng = np.random.default_rng(0)
    pixels = rng.uniform([2, 2], [61, 45], (40, 2)).astype(np.float32)
    disparities = np.full(40, 10.0, np.float32)
    moved = np.eye(4)
    if step is not None:
        moved[0, 3] = step
    motion = None if step is None else Motion(moved, 40, 40)
    reference = np.full(SIZE, 10.0, np.float32) + np.linspace(0, 1, SIZE[1], dtype=np.float32)
    return AdaptFrame(pixels, disparities, reference, grid, SIZE, 50.0, None, motion, CAMERA, index)


def test_the_check_made_again_tells_views_by_the_motion_since_the_view_before(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """F1: a camera creeping 0.15 px of view shift per frame after a standing start. The
    check made again keeps every other frame (0.30 px from the view before it), but its
    `_decide` chained only the kept frames' own motions (0.15 px each, the skipped frames'
    lost), so distinct views counted as one: "8 frames of 2 views", a 2-map basis adopted,
    or at a slower creep the check deferred again and again."""
    adaptation = adaptation_module.Adaptation("auto", True, 4, "cauchy", False)
    base = np.full((12, 16), 10.0, np.float32)
    adaptation.checked = adaptation.deferred = True
    adaptation._given, adaptation._camera = Basis.default(), (SIZE, 50.0)
    adaptation._last_map, adaptation._since = base, np.eye(4)
    decided: list[list[AdaptFrame]] = []

    def decide(basis: Basis, frames: list[AdaptFrame], settings: Any) -> None:
        decided.append(frames)

    monkeypatch.setattr(adaptation, "_decide", decide)
    frames = [_frame(k, base + 0.2 * (k + 1), 0.015) for k in range(8)]
    adaptation.update(frames)
    (views,) = decided
    assert [frame.index for frame in views] == [1, 3, 5, 7]  # every other: 0.30 px apart
    assert still_links(views) == [0, 1, 2, 3]  # before: [0, 0, 2, 2]
    # each carries the motion since the view kept before it (both skipped frames' steps)
    assert [frame.motion.transform[0, 3] for frame in views[1:] if frame.motion] == [
        pytest.approx(0.03)
    ] * 3


def test_the_check_made_again_does_not_chain_over_a_lost_motion(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """F1: a frame whose motion since the view before it is unknown (a skipped frame lost
    it) starts a view of its own by ego-motion: its own motion is not that."""
    adaptation = adaptation_module.Adaptation("auto", True, 2, "cauchy", False)
    base = np.full((12, 16), 10.0, np.float32)
    adaptation.checked = adaptation.deferred = True
    adaptation._given, adaptation._camera = Basis.default(), (SIZE, 50.0)
    adaptation._last_map, adaptation._since = base, np.eye(4)
    decided: list[list[AdaptFrame]] = []
    monkeypatch.setattr(adaptation, "_decide", lambda basis, frames, s: decided.append(frames))
    frames = [
        _frame(0, base + 1.0, 0.5),  # moved: a view
        _frame(1, base + 1.0, None),  # the same map, motion lost: a repeat by its map
        _frame(2, base + 2.0, 0.001),  # a new map, motion known only since frame 1
    ]
    adaptation.update(frames)
    (views,) = decided
    assert [frame.index for frame in views] == [0, 2]
    assert views[1].motion is None  # not frame 2's 1 mm, which would make it frame 0's view
    assert still_links(views) == [0, 1]


def test_a_standing_camera_stays_one_view_when_its_first_frame_is_left_out(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """F2: 4 frames of one pose with fresh noise (maps 0.15 px apart); the check leaves out
    frame 0 (typical_frames: partly blank). The ego-motion chains every frame to frame 0,
    and each fell back to its own index: "8 frames of 7 views", the log's own basis learned
    from copies and adopted on a flattering figure. Now they link to the first frame kept."""
    rng = np.random.default_rng(5)
    base = np.full((12, 16), 10.0, np.float32)
    frames = [
        _frame(k, (base + rng.normal(0.0, 0.15, base.shape)).astype(np.float32), 0.0001)
        for k in range(4)
    ]
    monkeypatch.setattr(adapt, "typical_frames", lambda frames, lines: frames[1:])
    seen: list[list[int]] = []
    view_labels = adapt.view_labels

    def spy(maps: Any, **kwargs: Any) -> Any:
        seen.append(list(kwargs["same_as"]))
        return view_labels(maps, **kwargs)

    monkeypatch.setattr(adapt, "view_labels", spy)
    adaptation = adaptation_module.Adaptation("check", False, 4, "cauchy", False)
    adaptation.warm_up(Basis.default(), frames, {})
    assert still_links(frames) == [0, 0, 0, 0]
    assert seen == [[0, 0, 0]]  # before: [0, 1, 2], the maps alone deciding
