"""Bug hunt 16F F1: densify's fit check on an over-exposed log.

The check scores each basis against SGBM's map at held-out pixels. Where the images are
clipped at 255 SGBM's values are streaks, and on the hunter's over-exposed room (93 % at
255) the check chose the street basis (PCA-MAP 5.58 px, 1.55x nearest neighbour, +-2 sigma
53 %). On a pair whose over-exposure note fires (more than half of an image at 255) the
clipped pixels are now left out of the check; any other pair's check is the same as before.
"""

from __future__ import annotations

import threading
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from pcainterp_stream.estimate import adapt
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.frontend import levels
from pcainterp_stream.frontend.stereo import SgbmConfig, StereoFrontEnd
from pcainterp_stream.pipeline.held_out import clipped_pixels
from pcainterp_stream.pipeline.measured import Measured, sgbm_maps
from pcainterp_stream.pipeline.processor import FrameProcessor, ProcessorConfig
from pcainterp_stream.pipeline.refit import adapt_frame, score
from pcainterp_stream.records import StereoCamera, StereoFrame

HEIGHT, WIDTH = 94, 310
CAMERA = StereoCamera(
    width=WIDTH, height=HEIGHT, fx=180.0, fy=180.0, cx=155.0, cy=47.0, baseline=0.54
)
SGBM = SgbmConfig(num_disparities=32)
SHIFTS = [6, 9, 12, 15]


def _basis() -> Basis:
    rng = np.random.default_rng(0)
    grid, n = (24, 78), 8
    q = np.linalg.qr(rng.normal(size=(grid[0] * grid[1], n)))[0]
    return Basis(
        mean=rng.uniform(8, 20, grid).astype(np.float32),
        components=q.T.reshape(n, *grid).astype(np.float32),
        eigenvalues=np.sort(rng.uniform(1.0, 400.0, n))[::-1].copy(),
        total_variance=4000.0,
        image_size=(HEIGHT, WIDTH),
        focal_baseline=CAMERA.focal_baseline,
        n_train=50,
    )


def _pair(seed: int, shift: int, gain: float, offset: float) -> tuple[Any, Any]:
    """A textured pair (every left pixel at disparity ``shift``), levels * gain + offset."""
    rng = np.random.default_rng(seed)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (HEIGHT, WIDTH + shift)), (0, 0), 1.2)
    texture = (texture - texture.mean()) * 3 * gain + 128 + offset
    texture = np.clip(texture, 0, 255).astype(np.uint8)
    return np.ascontiguousarray(texture[:, :WIDTH]), np.ascontiguousarray(texture[:, shift:])


def _frames(gain: float, offset: float) -> list[StereoFrame]:
    frames = []
    for index, shift in enumerate(SHIFTS):
        left, right = _pair(index, shift, gain, offset)
        stamp = 1_000_000_000 + index * 100_000_000
        frames.append(StereoFrame(index, stamp, stamp, "left", left, right, CAMERA))
    return frames


def _held_out(
    frames: list[StereoFrame], monkeypatch: pytest.MonkeyPatch
) -> tuple[list[adapt.HeldOut], adapt.FitCheck | None]:
    made: list[adapt.HeldOut] = []
    lock = threading.Lock()
    original = adapt.HeldOut.of

    def recorded(*args: Any, **kwargs: Any) -> adapt.HeldOut:
        held = original(*args, **kwargs)
        with lock:
            made.append(held)
        return held

    monkeypatch.setattr(adapt.HeldOut, "of", recorded)
    config = ProcessorConfig(sgbm=SGBM, batch_size=2, warmup_frames=len(frames))
    with FrameProcessor(_basis(), config) as engine:
        list(engine.process(frames))
        check = engine.adaptation.check
    return made, check


def _share_at_255(image: npt.NDArray[np.uint8]) -> float:
    return float(np.count_nonzero(image == 255)) / image.size


def test_an_over_exposed_pairs_check_leaves_out_its_clipped_pixels(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    frames = _frames(gain=1.0, offset=150.0)
    assert all(_share_at_255(frame.left) > levels.SATURATED_SHARE for frame in frames)
    made, check = _held_out(frames, monkeypatch)
    assert len(made) == len(frames)
    assert check is not None
    assert check.frames > 0  # SGBM matched the unclipped texture
    # the held-out pixels are made in the stereo workers, frames in any order
    for held in made:
        assert held.flat.size > 0
        at_255 = [int(np.count_nonzero(frame.left.ravel()[held.flat] == 255)) for frame in frames]
        # one of the frames is this one: its left image has none of them at 255
        assert min(at_255) == 0, at_255


def test_a_pair_under_the_notes_share_is_checked_as_before(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A normal pair (a fisheye's white border: 39 % at 255) keeps its clipped pixels."""
    frames = _frames(gain=1.0, offset=110.0)  # 37-38 % at 255
    shares = [_share_at_255(frame.left) for frame in frames]
    assert all(0.2 < share < levels.SATURATED_SHARE for share in shares), shares
    for frame in frames:
        sgbm = np.full(frame.left.shape, 5.0, np.float32)
        assert clipped_pixels(frame.left, frame.right, sgbm) is None
    made, _ = _held_out(frames, monkeypatch)
    assert any(
        np.count_nonzero(frame.left.ravel()[held.flat] == 255) for held in made for frame in frames
    )


def test_clipped_pixels_are_at_255_in_either_view() -> None:
    left = np.full((40, 60), 100, np.uint8)
    right = np.full((40, 60), 100, np.uint8)
    left[:, :35] = 255  # 58 % of the left image: the note's trigger
    right[:, 50:] = 255  # left column x sees right column x - 5: left 55.. clipped
    disparity = np.full((40, 60), 5.0, np.float32)
    disparity[0, :] = np.nan  # no match: the same column
    clipped = levels.clipped_pixels(left, right, disparity)
    assert clipped_pixels(left, right, disparity) is not None
    assert clipped is not None
    expected = np.zeros((40, 60), bool)
    expected[:, :35] = True
    expected[1:, 55:] = True
    expected[0, 50:] = True
    np.testing.assert_array_equal(clipped, expected)
    # 16-bit images: judged after their 8-bit conversion, as the note is
    wide = clipped_pixels(left.astype(np.uint16) * 257, right.astype(np.uint16) * 257, disparity)
    assert wide is not None
    np.testing.assert_array_equal(wide, expected)


def _measured_later(frames: list[StereoFrame]) -> list[Measured]:
    """The frames as the stereo workers hand them after the warm-up: maps, no held-out pixels."""
    front_end = StereoFrontEnd(ProcessorConfig().gftt, SGBM)
    items = []
    for frame in frames:
        measurements = front_end.measure(frame.left, frame.right)
        sgbm_map, grid = sgbm_maps(measurements.disparity_map, frame.camera)
        items.append(
            Measured(
                frame,
                measurements.pixels,
                measurements.disparities,
                dict(measurements.counts),
                sgbm_map=sgbm_map,
                grid_map=grid,
            )
        )
    return items


def _none_at_255(made: list[adapt.HeldOut], frames: list[StereoFrame]) -> None:
    assert len(made) == len(frames)
    for held, frame in zip(made, frames, strict=True):
        assert held.flat.size > 0
        assert np.count_nonzero(frame.left.ravel()[held.flat] == 255) == 0


def test_a_check_made_after_the_warm_up_leaves_out_the_clipped_pixels_too(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """fix-LVL17's left-over: a check made again (a camera change, a stop) and the watch of a
    log's own basis hold pixels out of frames measured after the warm-up, with no held-out
    pixels from the stereo workers; they kept the clipped pixels. Before: 13000+ of each
    frame's held-out pixels at 255."""
    frames = _frames(gain=1.0, offset=150.0)
    items = _measured_later(frames)
    adapt_frames = [adapt_frame(item) for item in items]
    assert all(frame.held_out is None and frame.clipped is not None for frame in adapt_frames)
    made: list[adapt.HeldOut] = []
    original = adapt.HeldOut.of

    def recorded(*args: Any, **kwargs: Any) -> adapt.HeldOut:
        made.append(original(*args, **kwargs))
        return made[-1]

    monkeypatch.setattr(adapt.HeldOut, "of", recorded)
    basis = _basis()
    config = ProcessorConfig(sgbm=SGBM, warmup_frames=len(frames), adapt="check")
    with FrameProcessor(basis, config) as engine:
        options = engine.settings.densify_options()
        # the check (adaptation.py, frames without the workers' held-out pixels)
        engine.adaptation.warm_up(basis, adapt_frames, options)
        assert engine.adaptation.check is not None
        assert engine.adaptation.check.frames > 0
        _none_at_255(made, frames)
        # the watch of a log's own basis (refit.score)
        made.clear()
        for frame in adapt_frames:
            assert score(basis, frame, options, "none").pixels > 0
        _none_at_255(made, frames)
    # a pair under the note's share has no mask: checked as before
    normal = [adapt_frame(item) for item in _measured_later(_frames(gain=1.0, offset=110.0))]
    assert all(frame.clipped is None for frame in normal)
