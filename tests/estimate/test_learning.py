from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
import scipy.linalg
from scipy import ndimage

from pcainterp_stream.estimate.learning import learn_basis, preprocess_disparity


def planted(
    seed: int, n_maps: int, grid_size: tuple[int, int], rank: int
) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    s = grid_size[0] * grid_size[1]
    subspace = np.linalg.qr(rng.normal(size=(s, rank)))[0]
    scales = np.linspace(12, 3, rank)
    mean = rng.uniform(5, 40, s)
    maps = mean + (rng.normal(size=(n_maps, rank)) * scales) @ subspace.T
    maps += 1e-3 * rng.normal(size=maps.shape)
    return maps.astype(np.float32), subspace


@pytest.mark.parametrize("method", ["exact", "streaming"])
def test_recovers_planted_subspace(method: str) -> None:
    grid = (10, 14)
    maps, subspace = planted(0, 240, grid, rank=6)
    seen: list[int] = []
    basis = learn_basis(
        (m.reshape(grid) for m in maps),
        n_components=6,
        method=method,
        preprocessed=True,
        image_size=(40, 56),
        batch_size=50,
        oversampling=4,
        progress=seen.append,
    )
    assert basis.meta["learning"]["method"] == method
    assert seen[-1] == 240
    rows = basis.components.reshape(6, -1).astype(np.float64)
    np.testing.assert_allclose(rows @ rows.T, np.eye(6), atol=1e-5)
    angles = scipy.linalg.subspace_angles(rows.T, subspace)
    assert np.degrees(angles.max()) < 0.1
    np.testing.assert_allclose(basis.mean.reshape(-1), maps.mean(axis=0), atol=1e-4)
    total = maps.astype(np.float64).var(axis=0, ddof=1).sum()
    np.testing.assert_allclose(basis.total_variance, total, rtol=1e-6)
    centred = maps - maps.mean(axis=0)
    expected = np.linalg.svd(centred.astype(np.float64), compute_uv=False)[:6] ** 2 / 239
    np.testing.assert_allclose(basis.eigenvalues, expected, rtol=1e-4)
    assert basis.n_train == 240
    assert basis.image_size == (40, 56)


def test_streaming_matches_exact_beyond_planted_rank() -> None:
    grid = (9, 11)
    rng = np.random.default_rng(1)
    maps = rng.normal(size=(150, 99)).astype(np.float32) * np.linspace(5, 0.1, 99).astype(
        np.float32
    )
    kwargs = {"n_components": 5, "preprocessed": True, "image_size": grid}
    exact = learn_basis((m.reshape(grid) for m in maps), method="exact", **kwargs)  # type: ignore[arg-type]
    stream = learn_basis(
        (m.reshape(grid) for m in maps),
        method="streaming",
        oversampling=60,
        batch_size=30,
        **kwargs,  # type: ignore[arg-type]
    )
    np.testing.assert_allclose(stream.eigenvalues, exact.eigenvalues, rtol=2e-2)


def test_auto_switches_to_streaming_over_budget() -> None:
    grid = (10, 14)
    maps, _ = planted(2, 60, grid, rank=3)
    small = learn_basis(
        (m.reshape(grid) for m in maps), n_components=3, preprocessed=True, image_size=grid
    )
    assert small.meta["learning"]["method"] == "exact"
    big = learn_basis(
        (m.reshape(grid) for m in maps),
        n_components=3,
        preprocessed=True,
        image_size=grid,
        exact_max_bytes=20 * 140 * 4,
    )
    assert big.meta["learning"]["method"] == "streaming"
    angles = scipy.linalg.subspace_angles(
        small.components.reshape(3, -1).T.astype(np.float64),
        big.components.reshape(3, -1).T.astype(np.float64),
    )
    assert np.degrees(angles.max()) < 0.1


def test_variance_threshold_picks_smallest_l() -> None:
    grid = (10, 14)
    maps, _ = planted(3, 100, grid, rank=6)
    full = learn_basis(
        (m.reshape(grid) for m in maps), n_components=20, preprocessed=True, image_size=grid
    )
    ratio = np.cumsum(full.eigenvalues) / full.total_variance
    target = float(ratio[2]) - 1e-6
    chosen = learn_basis(
        (m.reshape(grid) for m in maps),
        n_components=20,
        variance=target,
        preprocessed=True,
        image_size=grid,
    )
    assert chosen.n_components == 3
    assert chosen.explained_variance_ratio >= target


def test_learn_from_raw_maps_applies_preprocessing() -> None:
    rng = np.random.default_rng(4)

    def raw_maps() -> Iterator[np.ndarray]:
        for _ in range(12):
            d = rng.uniform(1, 60, (32, 48)).astype(np.float32)
            d[rng.random(d.shape) < 0.2] = np.nan
            yield d

    basis = learn_basis(raw_maps(), n_components=4, grid_scale=0.25, focal_baseline=380.0)
    assert basis.grid_size == (8, 12)
    assert basis.image_size == (32, 48)
    assert basis.meta["preprocessing"]["box_size"] == 5
    assert basis.focal_baseline == 380.0


def test_preprocess_fills_nearest_then_blurs_then_area() -> None:
    rng = np.random.default_rng(5)
    d = rng.uniform(1, 60, (24, 36)).astype(np.float32)
    d[5:12, 7:20] = np.nan
    d[0, 0] = -1.0
    valid = np.isfinite(d) & (d >= 0)
    _, (iy, ix) = ndimage.distance_transform_edt(~valid, return_indices=True)
    filled = preprocess_disparity(d, (24, 36), box_size=1)
    # ties may pick another valid pixel at the same distance: compare distances
    yy, xx = np.mgrid[0:24, 0:36]
    best = np.hypot(iy - yy, ix - xx)
    ok = np.zeros(d.shape, dtype=bool)
    vy, vx = np.nonzero(valid)
    for y, x in zip(*np.nonzero(~valid), strict=True):
        candidates = np.hypot(vy - y, vx - x) <= best[y, x] + 1e-9
        ok[y, x] = np.any(np.isclose(d[vy[candidates], vx[candidates]], filled[y, x]))
    assert ok[~valid].all()
    np.testing.assert_array_equal(filled[valid], d[valid])
    grid = preprocess_disparity(d, (6, 9))
    import cv2

    expected = cv2.resize(cv2.blur(filled, (5, 5)), (9, 6), interpolation=cv2.INTER_AREA)
    np.testing.assert_allclose(grid, expected, rtol=1e-6)


def test_preprocess_rejects_empty_map() -> None:
    with pytest.raises(ValueError, match="no valid pixel"):
        preprocess_disparity(np.full((4, 4), np.nan), (2, 2))


def test_learn_rejects_too_few_maps() -> None:
    with pytest.raises(ValueError, match="`maps` is empty"):
        learn_basis([])
    with pytest.raises(ValueError, match="at least two"):
        learn_basis([np.ones((4, 4))], grid_scale=1.0, method="exact")


@pytest.mark.parametrize("focal_baseline", [-1.0, float("nan"), float("inf")])
def test_learn_names_a_bad_focal_baseline_as_its_argument(focal_baseline: float) -> None:
    maps = np.random.default_rng(0).uniform(1, 50, (3, 8, 8))
    with pytest.raises(
        ValueError,
        match=rf"^Expected `focal_baseline` finite and >= 0 \(px\*m; 0 when unknown\), "
        rf"got {focal_baseline}$",
    ):
        learn_basis(maps, grid_scale=1.0, method="exact", focal_baseline=focal_baseline)


def test_learn_refuses_maps_that_do_not_vary() -> None:
    same = np.random.default_rng(0).uniform(1, 50, (8, 8)).astype(np.float32)
    with pytest.raises(ValueError, match="the maps do not vary"):
        learn_basis([same, same, same], grid_scale=1.0, method="exact")


@pytest.mark.parametrize("dtype", [np.int16, np.uint16])
def test_fixed_point_maps_are_refused(dtype: type) -> None:
    """OpenCV's StereoSGBM.compute() gives int16 16 x px, KITTI's PNGs uint16 256 x px."""
    fixed = np.full((8, 10), 20 * 16, dtype)
    with pytest.raises(TypeError, match=r"`disparity` as float disparities in px, got u?int16"):
        preprocess_disparity(fixed, (4, 5))
    with pytest.raises(TypeError, match=r"`maps\[0\]`"):
        learn_basis([fixed, fixed], n_components=1)
    floats = np.full((8, 10), 20.0)
    with pytest.raises(TypeError, match=r"`maps\[1\]`"):
        learn_basis([floats, fixed], n_components=1)


def test_zero_is_valid_by_default_and_invalid_above_min_disparity() -> None:
    """0 is a match for SGBM with minDisparity 0 (learn's maps); KITTI's holes need NaN."""
    values = np.full((8, 10), 20.0, np.float32)
    values[:, :5] = 0.0
    assert float(preprocess_disparity(values, (8, 10), box_size=1).min()) == 0.0
    filled = preprocess_disparity(values, (8, 10), box_size=1, min_disparity=1 / 256)
    np.testing.assert_array_equal(filled, 20.0)
