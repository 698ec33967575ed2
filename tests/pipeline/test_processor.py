"""Tests of the pipelined frame processor on small synthetic stereo pairs."""

from __future__ import annotations

import dataclasses
import threading
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from pcainterp_stream.estimate import estimator
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.estimator import densify
from pcainterp_stream.estimate.prior import LocalPrior
from pcainterp_stream.estimate.variance import prior_std_map
from pcainterp_stream.frontend.features import features_to_measurements
from pcainterp_stream.frontend.motion import CarryConfig
from pcainterp_stream.frontend.stereo import SgbmConfig, StereoFrontEnd
from pcainterp_stream.pipeline import processor
from pcainterp_stream.pipeline.processor import (
    FrameProcessor,
    MeasurementSource,
    ProcessorConfig,
)
from pcainterp_stream.records import DensifiedFrame, SparseFeatures, StereoCamera, StereoFrame

HEIGHT, WIDTH = 94, 310  # a quarter of KITTI's 376 x 1241
CAMERA = StereoCamera(
    width=WIDTH, height=HEIGHT, fx=180.0, fy=180.0, cx=155.0, cy=47.0, baseline=0.54
)
SGBM = SgbmConfig(num_disparities=32)


def random_basis(seed: int, n_components: int = 8) -> Basis:
    """Return a random orthonormal basis on a (24, 78) grid for the quarter-size camera."""
    rng = np.random.default_rng(seed)
    grid = (24, 78)
    q = np.linalg.qr(rng.normal(size=(grid[0] * grid[1], n_components)))[0]
    return Basis(
        mean=rng.uniform(8, 20, grid).astype(np.float32),
        components=q.T.reshape(n_components, *grid).astype(np.float32),
        eigenvalues=np.sort(rng.uniform(1.0, 400.0, n_components))[::-1].copy(),
        total_variance=4000.0,
        image_size=(HEIGHT, WIDTH),
        focal_baseline=CAMERA.focal_baseline,
        n_train=50,
    )


def shifted_pair(seed: int, shift: int) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
    """Return a textured pair whose every left pixel has disparity ``shift`` px."""
    rng = np.random.default_rng(seed)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (HEIGHT, WIDTH + shift)), (0, 0), 1.2)
    texture = np.clip((texture - texture.mean()) * 3 + 128, 0, 255).astype(np.uint8)
    left = np.ascontiguousarray(texture[:, :WIDTH])  # left x sees right x - shift
    right = np.ascontiguousarray(texture[:, shift:])
    return left, right


def make_frame(index: int, shift: int, camera: StereoCamera = CAMERA) -> StereoFrame:
    left, right = shifted_pair(index, shift)
    return StereoFrame(
        index=index,
        stamp_ns=1_000_000_000 + index * 100_000_000,
        log_time_ns=1_000_000_000 + index * 100_000_000,
        frame_id="left",
        left=left,
        right=right,
        camera=camera,
    )


SHIFTS = [6, 9, 12, 15, 18, 21, 8]


@pytest.fixture(scope="module")
def basis() -> Basis:
    return random_basis(0)


@pytest.fixture(scope="module")
def frames() -> list[StereoFrame]:
    return [make_frame(index, shift) for index, shift in enumerate(SHIFTS)]


def run(basis: Basis, frames: list[StereoFrame], **options: Any) -> list[DensifiedFrame]:
    config = ProcessorConfig(sgbm=SGBM, **options)
    with FrameProcessor(basis, config) as engine:
        return list(engine.process(frames))


@pytest.mark.parametrize("batch_size", [1, 2, 3, 8])
@pytest.mark.parametrize(("lookahead", "workers"), [(0, 1), (1, 2), (4, 2), (9, 3)])
def test_results_come_in_stream_order_one_per_frame(
    basis: Basis, frames: list[StereoFrame], batch_size: int, lookahead: int, workers: int
) -> None:
    results = run(basis, frames, batch_size=batch_size, lookahead=lookahead, stereo_workers=workers)
    assert [result.frame.index for result in results] == list(range(len(frames)))
    for result, shift in zip(results, SHIFTS, strict=True):
        # the lookups measure this frame's own shift, so no frame got another's results
        assert result.pixels.shape[0] > 20
        assert np.median(result.disparities) == pytest.approx(shift, abs=0.5)
        assert result.disparity.shape == (HEIGHT, WIDTH)


def test_submit_returns_finished_frames_and_finish_the_rest(
    basis: Basis, frames: list[StereoFrame]
) -> None:
    config = ProcessorConfig(sgbm=SGBM, batch_size=2, lookahead=1, stereo_workers=1, adapt="off")
    returned: list[list[int]] = []
    with FrameProcessor(basis, config) as engine:
        for frame in frames:
            returned.append([result.frame.index for result in engine.submit(frame)])
        rest = [result.frame.index for result in engine.finish()]
        assert engine.frames_done == len(frames)
    # batches are densified in a thread of their own: submit hands back those done so far,
    # in order, and never lets more than the look-ahead, a batch and the densify thread's
    # queue (warm-up + one batch) wait; finish returns the rest
    assert [index for batch in returned for index in batch] + rest == list(range(len(frames)))
    held = config.lookahead + config.batch_size + config.warmup_frames + config.batch_size
    done = 0
    for submitted, batch in enumerate(returned, start=1):
        done += len(batch)
        assert submitted - done <= held
    assert rest


def test_the_fit_check_holds_the_warm_up_frames_and_reports(
    basis: Basis, frames: list[StereoFrame]
) -> None:
    config = ProcessorConfig(
        sgbm=SGBM, batch_size=2, lookahead=1, stereo_workers=1, warmup_frames=3
    )
    returned: list[list[int]] = []
    with FrameProcessor(basis, config) as engine:
        for frame in frames:
            returned.append([result.frame.index for result in engine.submit(frame)])
        rest = [result.frame.index for result in engine.finish()]
        check = engine.adaptation.check
        lines = engine.adaptation.lines
    # nothing leaves before the three warm-up frames are measured and checked
    assert returned[:3] == [[], [], []]
    assert [i for batch in [*returned, rest] for i in batch] == list(range(len(frames)))
    assert check is not None
    assert check.frames == 3
    assert check.prior > 0
    assert check.linear > 0
    assert lines[0].startswith("prior: the basis ")
    assert "x linear" in lines[0]
    # a basis the user gave is never replaced
    assert not engine.adaptation.adapted


def test_the_checks_held_out_pixels_are_made_beside_sgbm(
    basis: Basis, frames: list[StereoFrame], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The stereo workers hold out the check's pixels and interpolate there; the check on
    the densify thread scores with them and makes none itself, and its figures are the
    same as when it makes them."""
    from pcainterp_stream.estimate import adapt

    config = ProcessorConfig(sgbm=SGBM, batch_size=2, warmup_frames=3)
    with FrameProcessor(basis, config) as engine:
        list(engine.process(frames))
        by_workers = engine.adaptation.check
    made_on: list[str] = []
    original = adapt.HeldOut.of

    def recorded(*args: Any) -> adapt.HeldOut:
        made_on.append(threading.current_thread().name)
        return original(*args)

    monkeypatch.setattr(adapt.HeldOut, "of", recorded)
    with FrameProcessor(basis, config) as engine:
        list(engine.process(frames))
    assert len(made_on) == 3
    assert all(name.startswith("stereo") for name in made_on)
    # made by the check itself when the workers did not (frames measured elsewhere)
    monkeypatch.setattr(processor, "adapt_frame", _without_held_out(processor.adapt_frame))
    with FrameProcessor(basis, config) as engine:
        list(engine.process(frames))
        by_check = engine.adaptation.check
    assert by_check == by_workers
    assert by_check is not None
    assert by_check.frames == 3


def _without_held_out(function: Any) -> Any:
    def adapt_frame(item: Any) -> Any:
        import dataclasses

        return dataclasses.replace(function(item), held_out=None)

    return adapt_frame


def test_batch_equals_one_by_one(basis: Basis, frames: list[StereoFrame]) -> None:
    batched = run(basis, frames, batch_size=4, lookahead=4)
    single = run(basis, frames, batch_size=1, lookahead=0, stereo_workers=1)
    for one, other in zip(batched, single, strict=True):
        np.testing.assert_array_equal(one.pixels, other.pixels)
        np.testing.assert_allclose(one.disparity, other.disparity, rtol=1e-4, atol=1e-4)
        np.testing.assert_allclose(one.disparity_std, other.disparity_std, rtol=1e-4, atol=1e-4)
        np.testing.assert_allclose(one.depth, other.depth, rtol=1e-4, atol=1e-5)
        assert np.isfinite(one.disparity_std).all()


@pytest.mark.parametrize("temporal", [False, True])
def test_the_estimate_pool_changes_no_bit(
    basis: Basis, frames: list[StereoFrame], temporal: bool
) -> None:
    """Batches estimated several at once (or, with the temporal prior, in turn) come out
    in order and bit for bit as from one estimating thread."""
    options: dict[str, Any] = {"batch_size": 1, "lookahead": 4, "temporal": temporal}
    pooled = run(basis, frames * 2, estimate_workers=3, **options)
    alone = run(basis, frames * 2, estimate_workers=1, **options)
    assert [r.frame.index for r in pooled] == [f.index for f in frames * 2]
    for one, other in zip(pooled, alone, strict=True):
        np.testing.assert_array_equal(one.disparity, other.disparity)
        np.testing.assert_array_equal(one.disparity_std, other.disparity_std)
        np.testing.assert_array_equal(one.depth, other.depth)
        assert one.counts == other.counts


def test_results_match_the_estimator(basis: Basis, frames: list[StereoFrame]) -> None:
    result = run(basis, frames[:1])[0]
    # the processor's default estimate: the basis has no fitted prior, so the paper's prior
    # with sigma 2 px, plus the default robust loss
    expected = densify(
        basis, result.pixels, result.disparities, sigma=2.0, robust=ProcessorConfig().robust
    )
    np.testing.assert_allclose(result.disparity, expected.disparity, rtol=1e-4, atol=1e-4)
    assert result.counts["dropped"] == 0
    assert result.measurement_source == "stereo"


def test_features_project_a_known_point() -> None:
    camera = StereoCamera(
        width=320, height=100, fx=500.0, fy=400.0, cx=160.0, cy=50.0, baseline=0.5
    )
    points = np.array(
        [
            [1.0, 0.5, 10.0],  # u = 500 * 0.1 + 160 = 210, v = 400 * 0.05 + 50 = 70, d = 25
            [0.0, 0.0, -5.0],  # behind the camera
            [100.0, 0.0, 10.0],  # u = 5160: right of the image
            [0.0, 0.0, 0.0],  # at the optical centre
            [-3.2, -1.25, 10.0],  # u = 0, v = 0: the first pixel centre, kept
        ],
        dtype=np.float32,
    )
    features = SparseFeatures(stamp_ns=1, log_time_ns=1, frame_id="left", points=points)
    pixels, disparities, counts = features_to_measurements(features, camera)
    np.testing.assert_allclose(pixels, [[210.0, 70.0], [0.0, 0.0]], atol=1e-4)
    np.testing.assert_allclose(disparities, [25.0, 25.0], rtol=1e-6)
    # rejected: behind (z = -5 and z = 0) and right of the image
    assert counts == {
        "feature_cloud": 1,
        "features": 5,
        "features_rejected": 3,
        "features_behind": 2,
        "features_near": 0,
        "features_thinned": 0,
        "features_cell": 0,
    }
    assert pixels.dtype == np.float32
    assert disparities.dtype == np.float32


def test_no_features_is_empty_data() -> None:
    pixels, disparities, counts = features_to_measurements(None, CAMERA)
    assert pixels.shape == (0, 2)
    assert disparities.shape == (0,)
    assert counts == {
        "feature_cloud": 0,
        "features": 0,
        "features_rejected": 0,
        "features_behind": 0,
        "features_near": 0,
        "features_thinned": 0,
        "features_cell": 0,
    }


def test_features_source_densifies_the_projected_points(basis: Basis) -> None:
    frame = make_frame(0, 10)
    z = CAMERA.focal_baseline / 10.0  # disparity 10 px everywhere
    u = np.array([80.0, 150.0, 250.0])
    v = np.array([20.0, 47.0, 80.0])
    xy = np.stack([(u - CAMERA.cx) * z / CAMERA.fx, (v - CAMERA.cy) * z / CAMERA.fy], 1)
    points = np.asarray(np.column_stack([xy, np.full(3, z)]), dtype=np.float32)
    features = SparseFeatures(frame.stamp_ns, frame.log_time_ns, "left", points)
    config = ProcessorConfig(source=MeasurementSource.FEATURES)
    with FrameProcessor(basis, config) as engine:
        (result,) = [*engine.submit(frame, features), *engine.finish()]
    np.testing.assert_allclose(result.pixels, np.stack([u, v], 1), atol=1e-3)
    np.testing.assert_allclose(result.disparities, 10.0, rtol=1e-5)
    assert result.measurement_source == "features"
    assert result.counts["features"] == 3


def test_blank_frame_has_no_estimate(basis: Basis) -> None:
    """Not the prior's mean (a scene never seen, which the estimator's MAP gives): NaN."""
    blank = np.full((HEIGHT, WIDTH), 128, dtype=np.uint8)
    frame = make_frame(0, 10)._replace(left=blank, right=blank)
    (result, after) = run(basis, [frame, make_frame(1, 10)])
    assert result.pixels.shape == (0, 2)
    assert not result.estimated
    for image in (result.disparity, result.disparity_std, result.depth, result.depth_std):
        assert image.shape == (HEIGHT, WIDTH)
        assert np.isnan(image).all()
    assert after.estimated
    assert np.isfinite(after.disparity).all()
    # the estimator itself still answers no measurement with the prior
    prior = densify(basis, np.zeros((0, 2)), np.zeros(0))
    assert np.isfinite(prior.disparity).all()


def test_camera_change_splits_the_batch(basis: Basis, monkeypatch: pytest.MonkeyPatch) -> None:
    other = StereoCamera(
        width=WIDTH, height=HEIGHT, fx=180.0, fy=180.0, cx=155.0, cy=47.0, baseline=1.08
    )
    stream = [make_frame(i, 10, CAMERA if i < 3 else other) for i in range(5)]
    calls: list[tuple[int, float]] = []
    real = estimator.densify_batch

    def spy(basis: Basis, pixels: list[Any], disparities: list[Any], **options: Any) -> Any:
        calls.append((len(pixels), options["focal_baseline"]))
        return real(basis, pixels, disparities, **options)

    monkeypatch.setattr(processor, "densify_batch", spy)
    results = run(basis, stream, batch_size=8, lookahead=8)
    assert calls == [(3, CAMERA.focal_baseline), (2, other.focal_baseline)]
    # twice the baseline: the same disparity is twice the depth
    np.testing.assert_allclose(
        results[3].depth,
        2 * results[0].depth * (results[0].disparity / results[3].disparity),
        rtol=1e-3,
    )


def test_each_frames_camera_is_noted_once(basis: Basis, monkeypatch: pytest.MonkeyPatch) -> None:
    # the batch cut at a camera change asked the adaptation about the changed frame, then
    # asked again when densifying from it: the second answer (no change) lost the first's
    # basis, so a choice re-made for the new camera never reached the estimate
    from pcainterp_stream.pipeline.refit import Refitting

    other = StereoCamera(
        width=WIDTH, height=HEIGHT, fx=180.0, fy=180.0, cx=155.0, cy=47.0, baseline=1.08
    )
    stream = [make_frame(i, 10, CAMERA if i < 3 else other) for i in range(5)]
    asked: list[int] = []
    real = Refitting.new_camera

    def spy(self: Refitting, frame: StereoFrame) -> Any:
        asked.append(frame.index)
        return real(self, frame)

    monkeypatch.setattr(Refitting, "new_camera", spy)
    run(basis, stream, batch_size=8, lookahead=8)
    assert sorted(asked) == list(range(5))


def test_close_mid_stream_does_not_hang_and_restores_threads(
    basis: Basis, frames: list[StereoFrame]
) -> None:
    threads_before = cv2.getNumThreads()
    config = ProcessorConfig(sgbm=SGBM, batch_size=64, lookahead=64, opencv_threads=1)
    engine = FrameProcessor(basis, config)
    assert cv2.getNumThreads() == 1
    for frame in frames * 3:
        assert engine.submit(frame) == []
    started = time.perf_counter()
    engine.close()
    assert time.perf_counter() - started < 10.0
    assert cv2.getNumThreads() == threads_before
    assert not [t for t in threading.enumerate() if t.name.startswith("stereo")]


def test_thread_limits_hold_until_the_last_open_processor_closes(basis: Basis) -> None:
    """Jobs in the threads of one process share the limits: the first closing keeps them."""
    from threadpoolctl import threadpool_info

    def numpy_blas() -> set[int]:
        return {i["num_threads"] for i in threadpool_info() if "numpy" in i["filepath"]}

    cv_before, blas_before = cv2.getNumThreads(), numpy_blas()
    config = ProcessorConfig(sgbm=SGBM, opencv_threads=1, blas_threads=1)
    first = FrameProcessor(basis, config)
    second = FrameProcessor(basis, config)
    assert cv2.getNumThreads() == 1
    assert numpy_blas() == {1}
    first.close()
    assert cv2.getNumThreads() == 1
    assert numpy_blas() == {1}
    first.close()  # twice: still counted once
    assert numpy_blas() == {1}
    second.close()
    assert cv2.getNumThreads() == cv_before
    assert numpy_blas() == blas_before


def test_bad_config_raises() -> None:
    with pytest.raises(ValueError, match="batch_size must be >= 1, got 0"):
        ProcessorConfig(batch_size=0)
    with pytest.raises(ValueError, match="lookahead must be >= 0, got -1"):
        ProcessorConfig(lookahead=-1)
    with pytest.raises(ValueError, match="stereo_workers must be >= 1, got 0"):
        ProcessorConfig(stereo_workers=0)
    with pytest.raises(ValueError, match="estimate_workers must be >= 1, got 0"):
        ProcessorConfig(estimate_workers=0)
    with pytest.raises(ValueError, match="blas_threads must be >= 1 or None, got 0"):
        ProcessorConfig(blas_threads=0)


def _drive(frames: int) -> list[StereoFrame]:
    from pcainterp_stream.synth import SynthConfig, generate

    return [
        StereoFrame(
            index=frame.index,
            stamp_ns=frame.stamp_ns,
            log_time_ns=frame.stamp_ns,
            frame_id="left",
            left=frame.left,
            right=frame.right,
            camera=frame.camera,
        )
        for frame in generate(SynthConfig(seed=3, frames=frames, scale=0.5))
    ]


def test_carried_points_come_from_the_previous_frames(basis: Basis) -> None:
    frames = _drive(3)
    carried = run(basis, frames, batch_size=2, lookahead=2)
    assert carried[0].counts["carried"] == 0  # nothing before the first frame
    assert carried[1].counts["carried"] > 0
    assert carried[2].counts["carried"] >= carried[1].counts["carried"]
    assert all(result.counts["carry_reset"] == 0 for result in carried)
    alone = run(basis, frames, carry=CarryConfig(frames=0))
    assert all(result.counts["carried"] == 0 for result in alone)
    np.testing.assert_array_equal(carried[0].disparity, alone[0].disparity)
    assert not np.allclose(carried[2].disparity, alone[2].disparity)
    # the frame's own measurements are what the results report
    np.testing.assert_array_equal(carried[2].pixels, alone[2].pixels)


def test_unrelated_frames_carry_nothing(basis: Basis, frames: list[StereoFrame]) -> None:
    # the shifted random-texture pairs are different scenes: no motion links them
    results = run(basis, frames)
    assert sum(result.counts["carried"] for result in results) == 0


def test_dense_measurements_fill_every_pixel_and_keep_sgbm() -> None:
    from pcainterp_stream.frontend.stereo import compute_disparity
    from pcainterp_stream.synth import SynthConfig, generate

    frames = [
        StereoFrame(f.index, f.stamp_ns, f.stamp_ns, "left", f.left, f.right, f.camera)
        for f in generate(SynthConfig(seed=3, frames=3, scale=0.5))
    ]
    sgbm = SgbmConfig(num_disparities=64)
    sparse_config = ProcessorConfig(sgbm=sgbm, near=None)  # dense mode measures no near points
    with FrameProcessor(config=sparse_config) as sparse_processor:
        sparse = list(sparse_processor.process(frames))
    config = ProcessorConfig(measurements="dense", sgbm=sgbm)
    with FrameProcessor(config=config) as dense_processor:
        dense = list(dense_processor.process(frames))
    assert [r.frame.index for r in dense] == [0, 1, 2]
    for result, field, frame in zip(dense, sparse, frames, strict=True):
        assert result.measurement_source == "dense"
        assert np.isfinite(result.disparity).all()
        assert np.isfinite(result.disparity_std).all()
        # the same sparse points shaped the field; SGBM's pixels are kept to ~3 %
        np.testing.assert_array_equal(result.pixels, field.pixels)
        matched = compute_disparity(frame.left, frame.right, sgbm)
        valid = np.isfinite(matched)
        gap = np.abs(field.disparity - matched)[valid]
        moved = np.abs(result.disparity - matched)[valid]
        assert np.median(moved) <= 0.03 * np.median(gap) + 1e-3
        assert result.disparity_std[valid].mean() < field.disparity_std[valid].mean()
    with pytest.raises(ValueError, match="sparse"):
        ProcessorConfig(measurements="both")
    with pytest.raises(ValueError, match="feature stream"):
        ProcessorConfig(measurements="dense", source=MeasurementSource.FEATURES)


def test_dense_matcher_only_removes_more_speckles() -> None:
    # dense mode's matcher takes out larger isolated regions than the default matcher
    # (measured better on every source, docs/dense.md); it must change no other value
    from pcainterp_stream.frontend.matchers import DENSE_SGBM
    from pcainterp_stream.frontend.stereo import compute_disparity
    from pcainterp_stream.synth import SynthConfig, generate

    assert DENSE_SGBM.speckle_window_size > SgbmConfig().speckle_window_size
    default_window = dataclasses.replace(
        DENSE_SGBM, speckle_window_size=SgbmConfig().speckle_window_size
    )
    removed = 0
    for frame in generate(SynthConfig(seed=3, frames=2, scale=0.5)):
        dense = compute_disparity(frame.left, frame.right, DENSE_SGBM)
        other = compute_disparity(frame.left, frame.right, default_window)
        assert not (np.isfinite(dense) & np.isnan(other)).any()
        both = np.isfinite(dense)
        np.testing.assert_array_equal(dense[both], other[both])
        removed += int((np.isnan(dense) & np.isfinite(other)).sum())
    assert removed > 100


def test_dense_holes_found_in_the_stereo_workers_change_nothing(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # dense mode finds the SGBM map's holes beside SGBM, in the stereo workers; fused on
    # the densify thread from scratch instead, every output is the same to the bit
    from pcainterp_stream.pipeline import processor as processor_module
    from pcainterp_stream.synth import SynthConfig, generate

    frames = [
        StereoFrame(f.index, f.stamp_ns, f.stamp_ns, "left", f.left, f.right, f.camera)
        for f in generate(SynthConfig(seed=4, frames=3, scale=0.5))
    ]
    config = ProcessorConfig(measurements="dense", sgbm=SgbmConfig(num_disparities=64))
    find_holes = processor_module.find_holes
    found: list[int] = []

    def counted(
        disparity_map: np.ndarray, weak: np.ndarray | None = None, **options: bool
    ) -> object:
        found.append(1)
        return find_holes(disparity_map, weak, **options)

    monkeypatch.setattr(processor_module, "find_holes", counted)
    with FrameProcessor(config=config) as dense_processor:
        ahead = list(dense_processor.process(frames))
    assert len(found) == len(frames)
    monkeypatch.setattr(processor_module, "find_holes", lambda disparity_map, weak, **options: None)
    with FrameProcessor(config=config) as dense_processor:
        alone = list(dense_processor.process(frames))
    for one, other in zip(ahead, alone, strict=True):
        for name in ("disparity", "disparity_std", "depth", "depth_std"):
            np.testing.assert_array_equal(getattr(one, name), getattr(other, name))


def test_an_interrupted_processor_does_not_wait_for_its_threads(basis: Basis) -> None:
    # A Ctrl-C that lands while the densify thread is busy (e.g. importing scipy on a loaded
    # machine) must not wait for that task: the command has seconds to clean up.
    release = threading.Event()
    closed = threading.Event()
    started = threading.Event()
    engine = FrameProcessor(basis, ProcessorConfig(sgbm=SGBM))

    def busy() -> None:
        started.set()
        release.wait()

    engine._lane.submit(busy)  # the densify thread is busy until released
    assert started.wait(60)

    def interrupt() -> None:
        try:
            with engine:
                raise KeyboardInterrupt
        except KeyboardInterrupt:
            closed.set()

    thread = threading.Thread(target=interrupt, daemon=True)
    thread.start()
    try:
        assert closed.wait(60), "closing waited for the busy densify thread"
        assert not release.is_set()
    finally:
        release.set()
        thread.join(60)


def test_a_processor_closed_normally_finishes_its_running_task(basis: Basis) -> None:
    done: list[int] = []
    engine = FrameProcessor(basis, ProcessorConfig(sgbm=SGBM))
    started = threading.Event()

    def task() -> None:
        started.set()
        time.sleep(0.2)
        done.append(1)

    engine._lane.submit(task)
    assert started.wait(60)
    with engine:
        pass
    assert done == [1]


def test_the_warm_up_batch_is_estimated_in_batch_size_parts(
    basis: Basis, frames: list[StereoFrame], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The check's large first batch goes to the estimate pool in parts of ``batch_size``
    frames, several at once; the results do not depend on how many threads solve them."""
    sizes: list[int] = []
    original = FrameProcessor._estimate

    def recorded(self: FrameProcessor, job: Any) -> Any:
        sizes.append(len(job.group))
        return original(self, job)

    monkeypatch.setattr(FrameProcessor, "_estimate", recorded)
    options: dict[str, Any] = {"sgbm": SGBM, "batch_size": 2, "warmup_frames": 5}
    checks = []
    results = []
    for workers in (1, 2, 3):
        sizes.clear()
        with FrameProcessor(basis, ProcessorConfig(estimate_workers=workers, **options)) as engine:
            results.append(list(engine.process(frames * 2)))
            checks.append(engine.adaptation.check)
        assert max(sizes) <= 2
        assert sum(sizes) == len(frames) * 2
    assert checks[0] is not None
    assert checks[0].frames == 5
    assert checks[1] == checks[0]
    assert checks[2] == checks[0]
    for one, other in zip(results[0], results[2], strict=True):
        np.testing.assert_array_equal(one.disparity, other.disparity)
        np.testing.assert_array_equal(one.disparity_std, other.disparity_std)


def test_an_edge_aware_prior_gets_each_frames_sgbm_map(frames: list[StereoFrame]) -> None:
    """A basis whose local prior has a cell weight densifies along each frame's SGBM map
    (the default); ``edge_aware=False`` gives the stationary kernel, bit for bit."""
    local = {"variance": 20.0, "length_scale": 40.0, "kernel": "laplace"}
    stationary = dataclasses.replace(
        random_basis(0), meta={"prior": {"local": local, "sigma": 0.5}}
    )
    edge_aware = dataclasses.replace(
        stationary, meta={"prior": {"local": {**local, "cell_weight": 0.3}, "sigma": 0.5}}
    )
    options: dict[str, Any] = {"adapt": "off", "carry": CarryConfig(frames=0)}
    aware = run(edge_aware, frames[:3], **options)
    off = run(edge_aware, frames[:3], edge_aware=False, **options)
    plain = run(stationary, frames[:3], **options)
    for one, other in zip(off, plain, strict=True):
        np.testing.assert_array_equal(one.disparity, other.disparity)
        np.testing.assert_array_equal(one.disparity_std, other.disparity_std)
    assert not np.array_equal(aware[0].disparity, off[0].disparity)
    front_end = StereoFrontEnd(ProcessorConfig().gftt, SGBM)
    measured = front_end.measure(frames[0].left, frames[0].right)
    expected = densify(
        edge_aware,
        aware[0].pixels,
        aware[0].disparities,
        sigma=0.5,
        local_prior=LocalPrior(20.0, 40.0, cell_weight=0.3),
        robust=ProcessorConfig().robust,
        edge_map=measured.disparity_map,
    )
    np.testing.assert_allclose(aware[0].disparity, expected.disparity, rtol=1e-4, atol=1e-4)


def test_without_the_depth_std_the_rest_is_the_same(
    basis: Basis, frames: list[StereoFrame]
) -> None:
    with_std = run(basis, frames)
    without = run(basis, frames, depth_std=False)
    for one, other in zip(with_std, without, strict=True):
        np.testing.assert_array_equal(one.disparity, other.disparity)
        np.testing.assert_array_equal(one.disparity_std, other.disparity_std)
        np.testing.assert_array_equal(one.depth, other.depth)
        assert np.isfinite(one.depth_std).any()
        assert np.isnan(other.depth_std).all()  # unknown, as with uncertainty "none"


def test_densify_drops_the_depth_std_only_when_nothing_takes_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from pcainterp_stream.io.outputs import OutputTopics
    from pcainterp_stream.pipeline import densify as pipeline
    from pcainterp_stream.pipeline.jobs import synth

    log = tmp_path / "drive.mcap"
    synth(log, frames=2, seed=3, scale=0.25, fmt=None)
    seen: list[bool] = []
    real = pipeline.FrameProcessor

    def recording(basis: Basis, config: ProcessorConfig) -> FrameProcessor:
        seen.append(config.depth_std)
        return real(basis, config)

    monkeypatch.setattr(pipeline, "FrameProcessor", recording)
    taken: list[DensifiedFrame] = []
    pipeline.densify(log, tmp_path / "compact.mcap")  # compact: the disparity's std only
    pipeline.densify(log, tmp_path / "full.mcap", topics=OutputTopics())
    pipeline.densify(log, tmp_path / "callback.mcap", on_frame=taken.append)
    assert seen == [False, True, True]
    assert taken
    assert all(np.isfinite(frame.depth_std).any() for frame in taken)


def test_a_prior_std_fill_weighs_by_the_basiss_prior(
    basis: Basis, frames: list[StereoFrame]
) -> None:
    local = {"kernel": "laplace", "length_scale": 16.0, "variance": 9.0}
    hybrid = dataclasses.replace(basis, meta={"prior": {"local": local}})
    std = prior_std_map(hybrid)
    assert std.shape == basis.grid_size
    assert std.dtype == np.float32
    np.testing.assert_allclose(std**2, basis.prior_variance + 9.0, rtol=1e-5)
    np.testing.assert_allclose(prior_std_map(basis) ** 2, basis.prior_variance, rtol=1e-5)
    gftt = dataclasses.replace(ProcessorConfig().gftt, fill_spacing=24.0)
    placed = dataclasses.replace(gftt, fill_placement="prior_std")
    config = ProcessorConfig(sgbm=SGBM, gftt=placed)
    with FrameProcessor(basis, config) as engine:
        assert engine.front_end.prior_std is not None
        results = list(engine.process(frames[:2]))
    lattice = run(basis, frames[:2], gftt=gftt)
    for result, reference in zip(results, lattice, strict=True):
        assert result.counts["kept"] == reference.counts["kept"]
        assert np.isfinite(result.disparity).all()


def _coarse_pair(shift: int) -> StereoFrame:
    """A plane at ``shift`` px with texture coarse enough to match at quarter resolution."""
    rng = np.random.default_rng(5)
    texture = cv2.GaussianBlur(rng.random((HEIGHT, WIDTH + shift)).astype(np.float32), (0, 0), 2.5)
    texture = (texture - texture.min()) / (texture.max() - texture.min()) * 255
    scene = texture.astype(np.uint8)
    left, right = np.ascontiguousarray(scene[:, :WIDTH]), np.ascontiguousarray(scene[:, shift:])
    return StereoFrame(0, 1_000_000_000, 1_000_000_000, "left", left, right, CAMERA)


def test_near_reach_measures_a_plane_beyond_sgbms_range(basis: Basis) -> None:
    from pcainterp_stream.frontend.near import NearConfig

    frame = _coarse_pair(48)  # beyond the 32 px range of SGBM
    near = NearConfig(match_range=32.0, num_disparities=16, margin=4.0, trigger_share=0.0)
    options: dict[str, Any] = {"adapt": "off", "carry": CarryConfig(frames=0)}
    (plain,) = run(basis, [frame], near=None, **options)
    (reached,) = run(basis, [frame], near=near, **options)
    assert "near_added" not in plain.counts
    assert reached.counts["near_matched"] == 1
    assert reached.counts["near_added"] > 5
    added = reached.pixels[-reached.counts["near_added"] :]
    assert added.shape[0] == reached.counts["near_added"]
    values = reached.disparities[-added.shape[0] :]
    assert np.median(np.abs(values - 48.0)) < 3.0
    # beside carried points (own points first, then the carried ones with their age noise)
    drive = run(basis, _drive(3), near=near, adapt="off")
    assert drive[2].counts["carried"] > 0
    assert drive[2].counts["near_added"] > 0
    # the basis's fit check judges it on SGBM's own lookups only: its reference, SGBM's map,
    # has no value beyond the range (and on real pairs an aliased one)
    checked: list[int] = []
    original = adapt_frame = processor.adapt_frame

    def recorded(item: Any) -> Any:
        frame = adapt_frame(item)
        checked.append(frame.pixels.shape[0])
        return frame

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(processor, "adapt_frame", recorded)
        (fitted,) = run(basis, [frame], near=near, carry=CarryConfig(frames=0), warmup_frames=1)
    assert processor.adapt_frame is original
    assert fitted.counts["near_added"] > 5
    assert checked == [fitted.pixels.shape[0] - fitted.counts["near_added"]]
    # on by default, its range set from SGBM's
    assert ProcessorConfig().near is not None
    with FrameProcessor(basis, ProcessorConfig(sgbm=SGBM, adapt="off")) as engine:
        assert engine.near is not None
        assert engine.near.match_range == 32


def test_a_camera_change_submitted_while_the_maps_are_decided_keeps_them(basis: Basis) -> None:
    # review 57d D6: the densify thread's _measured_for read _changes, the reader's submit then
    # counted a camera change and asked for maps, and _measured_for's stale "no maps" overwrote
    # it: the new camera's first frames lost the maps its re-check is made on. Driven here in
    # that order: the change is submitted (another thread) between that read and the write.
    config = ProcessorConfig(sgbm=SGBM, lookahead=8)
    other = dataclasses.replace(CAMERA, baseline=CAMERA.baseline * 2)
    with FrameProcessor(basis, config) as engine:
        engine.submit(make_frame(0, 6))
        submitted = threading.Thread(target=engine.submit, args=(make_frame(1, 6, other),))

        class Deciding:  # the basis whose grid _measured_for reads after deciding, before writing
            @property
            def grid_size(self) -> tuple[int, int]:
                submitted.start()
                submitted.join(timeout=0.5)  # with the fix, submit waits for _measured_for
                return basis.grid_size

        engine.adaptation.wants_maps = lambda: False  # type: ignore[method-assign]
        engine.basis = Deciding()  # type: ignore[assignment]
        engine._measured_for()
        engine.basis = basis
        submitted.join()
        assert engine._changes == 1
        assert engine._measuring == (basis.grid_size, True)  # the new camera's maps are kept
