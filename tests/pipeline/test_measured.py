"""A basis switched to mid-log: what a frame is estimated with never depends on thread timing.

The stereo workers measure frames ahead of the densify thread, so when the densify thread
switches the basis (a standing start checked again once the camera moves), some frames were
measured before the switch and are estimated after it; which ones depends on timing. Their
edge-aware cells were made on the old basis's grid: densify's output changed from run to
run (6 runs, 5 different files; frames after the switch up to 1.5 px apart).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from pcainterp_stream import synth as synth_module
from pcainterp_stream.estimate.basis import Basis, builtin_basis
from pcainterp_stream.estimate.cells import Seeding, cell_grid_size
from pcainterp_stream.pipeline import processor as processor_module
from pcainterp_stream.pipeline.measured import Measured, cells_on_grid
from pcainterp_stream.pipeline.processor import FrameProcessor, ProcessorConfig
from pcainterp_stream.records import StereoCamera, StereoFrame
from pcainterp_stream.synth import SynthConfig, generate

STAND = 9
"""Frames standing at a facade: the warm-up (8) keeps the indoor basis and defers."""
FRAMES = STAND + 14
"""The 8 moving frames after the standing ones are checked again and the street basis is
used from frame 17 on (batches of 4 from frame 8: the switch's batch is frames 16-19); frames
20-22 are measured before or after the switch as the threads run."""
AFTER_SWITCH_BATCH = 20
WAIT_S = 60.0
"""Longest wait of a thread held back (a test that fails goes on instead of hanging)."""


@pytest.fixture(scope="module")
def standing_then_driving() -> list[StereoFrame]:
    """The synthetic street (seed 7, half size): 9 pairs at a facade, then the drive."""
    first_pose = synth_module.camera_pose
    facade = SynthConfig(seed=7, frames=1, scale=0.5, speed=0.01)

    def pose(world: Any, config: SynthConfig, index: int) -> npt.NDArray[np.float64]:
        if index < STAND:
            return first_pose(world, facade, 0)
        return first_pose(world, config, index - STAND + 1)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(synth_module, "camera_pose", pose)
        return [
            StereoFrame(f.index, f.stamp_ns, f.stamp_ns, "left", f.left, f.right, f.camera)
            for f in generate(SynthConfig(seed=7, frames=FRAMES, scale=0.5))
        ]


def _run(
    frames: list[StereoFrame], hold: Callable[[FrameProcessor], None]
) -> tuple[npt.NDArray[np.float32], list[tuple[tuple[int, int], list[tuple[int, ...]]]]]:
    """Densify ``frames`` with the threads held back by ``hold``.

    Returns every frame's disparity and, per estimate, the cell grid of its basis and of
    each frame's cells.
    """
    grids: list[tuple[tuple[int, int], list[tuple[int, ...]]]] = []
    densify_batch = processor_module.densify_batch

    def recorded(basis: Basis, *args: Any, **kwargs: Any) -> Any:
        seedings = kwargs.get("partitions") or []
        shapes = [seeding.field.shape for seeding in seedings if seeding is not None]
        grids.append((cell_grid_size(basis.grid_size), shapes))
        return densify_batch(basis, *args, **kwargs)

    with pytest.MonkeyPatch.context() as patch, FrameProcessor(None, ProcessorConfig()) as engine:
        patch.setattr(processor_module, "densify_batch", recorded)
        hold(engine)
        results = list(engine.process(frames))
        assert "prior: the camera moved: checked again on 8 frames of other views" in (
            engine.adaptation.lines
        )
        assert engine.basis is Basis.default()  # switched to the street basis mid-log
    return np.stack([result.disparity for result in results]), grids


def _hold(engine: FrameProcessor, measure_after: int, switch_waits: bool) -> None:
    """Hold the stereo workers, or the densify thread, back at the basis switches.

    Frames from ``measure_after`` on are measured only once the basis has switched: to the
    street basis (the switch mid-log), or with ``switch_waits`` to the indoor one (the
    warm-up's), and the switch to the street basis then waits until every frame submitted
    is measured (the frames after the switch's batch were submitted before it was handed
    over).
    """
    use, measure = engine._use, engine._measure
    switched, measured, lock = threading.Event(), [0], threading.Condition()

    def use_then_tell(basis: Basis) -> None:
        street = basis is Basis.default()  # the warm-up chose the indoor basis
        if street and switch_waits:
            with lock:
                lock.wait_for(lambda: measured[0] >= engine._submitted, WAIT_S)
        use(basis)
        if street != switch_waits:
            switched.set()

    def measure_after_switch(frame: StereoFrame, *args: Any) -> Measured:
        if frame.index >= measure_after:
            switched.wait(WAIT_S)
        item = measure(frame, *args)
        with lock:
            measured[0] += 1
            lock.notify_all()
        return item

    engine._use = use_then_tell  # type: ignore[method-assign]
    engine._measure = measure_after_switch  # type: ignore[method-assign]


def _switch_first(engine: FrameProcessor) -> None:
    """Frames 20-22 measured after the switch to the street basis."""
    _hold(engine, measure_after=AFTER_SWITCH_BATCH, switch_waits=False)


def _measure_first(engine: FrameProcessor) -> None:
    """Frames 8-22 measured after the warm-up's switch to the indoor basis, and before the
    switch to the street one."""
    _hold(engine, measure_after=8, switch_waits=True)


def test_a_switch_mid_log_gives_the_same_output_however_the_threads_run(
    standing_then_driving: list[StereoFrame],
) -> None:
    """Frames 20-22 measured after the switch, then before it (for the indoor basis the
    warm-up chose): the same output."""
    late, late_grids = _run(standing_then_driving, _switch_first)
    early, early_grids = _run(standing_then_driving, _measure_first)
    np.testing.assert_array_equal(late, early)
    # every frame's cells on the grid of the basis it is estimated with (the switch's batch
    # measured before it in both runs); the street basis's cells are used
    assert late_grids == early_grids
    street = cell_grid_size(builtin_basis("street").grid_size)
    assert any(grid == street and shapes for grid, shapes in late_grids)
    for grid, shapes in late_grids:
        assert all(shape == grid for shape in shapes)


def _frame(disparity_map: npt.NDArray[np.float32], **maps: Any) -> Measured:
    camera = StereoCamera(width=80, height=40, fx=50.0, fy=50.0, cx=40.0, cy=20.0, baseline=0.5)
    image = np.zeros((40, 80), np.uint8)
    frame = StereoFrame(0, 0, 0, "left", image, image, camera)
    pixels = np.array([[10.0, 10.0], [60.0, 30.0]], np.float32)
    seeding = Seeding.along(disparity_map, pixels, (40, 80), (20, 40))
    return Measured(frame, pixels, np.ones(2, np.float32), {}, partition=seeding, **maps)


def test_cells_are_made_again_for_a_basis_of_another_grid() -> None:
    raw = np.random.default_rng(3).uniform(1.0, 9.0, (40, 80)).astype(np.float32)
    raw[:, :7] = 0.0  # SGBM's invalid
    nan_for_invalid = np.where(raw > 0, raw, np.nan).astype(np.float32)
    item = _frame(raw, raw_map=raw)
    assert cells_on_grid(item, (20, 40)) is item.partition  # its own grid: as made
    again = cells_on_grid(item, (32, 64))
    expected = Seeding.along(raw, item.pixels, (40, 80), (32, 64))
    assert again is not None
    assert expected is not None
    assert again.field.shape == cell_grid_size((32, 64))
    np.testing.assert_array_equal(again.field, expected.field)
    np.testing.assert_array_equal(again.nodes, expected.nodes)
    # from the fit check's map (NaN where SGBM's was invalid): the same cells
    from_check = cells_on_grid(_frame(raw, sgbm_map=nan_for_invalid), (32, 64))
    assert from_check is not None
    np.testing.assert_array_equal(from_check.field, expected.field)
    np.testing.assert_array_equal(from_check.nodes, expected.nodes)
