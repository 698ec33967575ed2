"""The edge-aware local prior (cells.py) against brute-force graph search and Gaussian algebra."""

from __future__ import annotations

import heapq

import numpy as np
import pytest

from pcainterp_stream import Basis, densify, densify_batch
from pcainterp_stream.estimate.cells import (
    Partition,
    Seeding,
    cell_grid_size,
    cell_map,
    geodesic_labels,
    partition_all,
    to_cell_grid,
)
from pcainterp_stream.estimate.fitting import fit_cell_weight, fit_frame
from pcainterp_stream.estimate.prior import Kernel, LocalPrior, same_cell_pairs


def _basis(height: int = 12, width: int = 16, n_components: int = 6) -> Basis:
    """A full-resolution (grid = image) random orthonormal basis of smooth fields."""
    rng = np.random.default_rng(0)
    ys, xs = np.mgrid[0:height, 0:width] / max(height, width)
    fields = [
        np.cos(np.pi * (a * xs + b * ys) + c)
        for a, b, c in rng.uniform(0.0, 3.0, size=(n_components, 3))
    ]
    q, _ = np.linalg.qr(np.stack([f.ravel() for f in fields], axis=1))
    eigenvalues = np.sort(rng.uniform(5.0, 200.0, n_components))[::-1]
    return Basis(
        mean=(20.0 + 10.0 * ys).astype(np.float32),
        components=q.T.reshape(n_components, height, width).astype(np.float32),
        eigenvalues=eigenvalues,
        total_variance=float(eigenvalues.sum()) * 1.5,
        image_size=(height, width),
        focal_baseline=100.0,
        n_train=50,
    )


def _points(basis: Basis, k: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """k measurements on distinct whole pixels, disparities 10-40 px."""
    rng = np.random.default_rng(seed)
    height, width = basis.image_size
    flat = rng.choice(height * width, size=k, replace=False)
    pixels = np.stack([flat % width, flat // width], axis=1).astype(np.float64)
    return pixels, rng.uniform(10.0, 40.0, k)


def _distances(field: np.ndarray, seed: tuple[int, int], cap: float = 20.0) -> np.ndarray:
    """Geodesic distance of every node from one seed node (row, col), by plain Dijkstra."""
    rows, cols = field.shape
    distance = np.full((rows, cols), np.inf)
    distance[seed] = 0.0
    queue = [(0.0, seed)]
    while queue:
        here, (r, c) = heapq.heappop(queue)
        if here > distance[r, c]:
            continue
        for nr, nc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
            if 0 <= nr < rows and 0 <= nc < cols:
                step = abs(float(field[r, c]) - float(field[nr, nc]))
                cost = 1.0 + (min(step, cap) if np.isfinite(step) else 0.0)
                if here + cost < distance[nr, nc]:
                    distance[nr, nc] = here + cost
                    heapq.heappush(queue, (here + cost, (nr, nc)))
    return distance


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_node_takes_a_geodesically_nearest_seed(seed: int) -> None:
    rng = np.random.default_rng(seed)
    field = rng.choice([10.0, 12.0, 40.0, np.nan], size=(9, 13), p=[0.4, 0.3, 0.2, 0.1])
    field = field.astype(np.float32)
    seeds = rng.choice(9 * 13, size=7, replace=False)
    labels = geodesic_labels(field, seeds, sweeps=9 * 13)  # enough rounds to converge
    assert set(np.unique(labels).tolist()) <= set(seeds.tolist())
    distances = {int(s): _distances(field, (int(s) // 13, int(s) % 13)) for s in seeds}
    nearest = np.min(np.stack(list(distances.values())), axis=0)
    taken = np.choose(
        np.searchsorted(np.sort(seeds), labels), [distances[int(s)] for s in np.sort(seeds)]
    )
    np.testing.assert_allclose(taken, nearest)
    for s in seeds:
        assert labels.flat[s] == s  # a seed is its own cell


@pytest.mark.parametrize("sweeps", [1, 2])
def test_without_edges_the_cells_are_city_block_nearest(sweeps: int) -> None:
    rng = np.random.default_rng(sweeps)
    seeds = rng.choice(10 * 16, size=9, replace=False)
    labels = geodesic_labels(np.full((10, 16), 5.0, np.float32), seeds, sweeps=sweeps)
    rows, cols = np.divmod(np.arange(10 * 16), 16)
    city = np.abs(rows[:, None] - seeds // 16) + np.abs(cols[:, None] - seeds % 16)
    which = [seeds.tolist().index(label) for label in labels.ravel()]
    taken = city[np.arange(10 * 16), which]
    np.testing.assert_array_equal(taken, city.min(axis=1))


def test_a_depth_edge_keeps_a_cell_on_its_own_surface() -> None:
    field = np.full((6, 20), 10.0, np.float32)
    field[:, 10:] = 50.0  # a depth edge between columns 9 and 10
    seeds = np.array([3 * 20 + 2, 3 * 20 + 11])  # far on the left, near on the right
    labels = geodesic_labels(field, seeds)
    assert (labels[:, :10] == seeds[0]).all()  # column 9 is nearer the right one in the plane
    assert (labels[:, 10:] == seeds[1]).all()


def test_measurements_join_the_cell_of_their_node() -> None:
    # a 4 x 4 image on a 2 x 2 cell grid (a 4 x 4 basis grid): 2 px per node
    partition = Partition.along(np.ones((4, 4)), [[0.0, 0.0], [3.0, 3.0]], (4, 4), (4, 4))
    assert partition is not None
    assert partition.labels[0, 0] == 0
    assert partition.labels[1, 1] == 3
    # the seeds, a second one on the first's node, and one (carried) on a seedless node
    cells = partition.cells(np.array([[0.0, 0.0], [3.0, 3.0], [1.0, 0.4], [3.0, 0.0]]))
    assert cells.point_cells[:3].tolist() == [0, 3, 0]
    assert cells.point_cells[3] == partition.labels[0, 1]
    assert cells.counts.tolist() == np.bincount(cells.point_cells, minlength=4).tolist()
    assert cells.counts[0] >= 2
    assert cells.counts[3] >= 1
    assert cells.counts[1] == cells.counts[2] == 0  # not seeds: no cells of their own
    assert cells.first.tolist() == [0, -1, -1, 1]
    for cell in (0, 1, 2, 3):
        entry, members = cells.members(np.array([cell, cell]))
        expected = np.flatnonzero(cells.point_cells == cell).tolist()
        assert members.tolist() == expected + expected  # in their order, per entry
        assert entry.tolist() == [0] * len(expected) + [1] * len(expected)
        entry, members = cells.members(np.array([cell]), after=1)
        assert members.tolist() == expected[1:]


def test_no_seed_no_partition() -> None:
    assert Partition.along(np.zeros((3, 4)), np.zeros((0, 2)), (3, 4), (3, 4)) is None
    with pytest.raises(ValueError, match="shape"):
        Partition.along(np.zeros(5), np.ones((1, 2)), (3, 4), (3, 4))


def test_cell_grid_map_is_nearest_and_unknown_is_nan() -> None:
    disparity = np.arange(16, dtype=np.float32).reshape(4, 4)
    disparity[0, 0] = -1.0  # SGBM's invalid
    small = to_cell_grid(disparity, (2, 2))
    assert small.shape == (2, 2)
    assert np.isnan(small).sum() <= 1
    assert set(small[np.isfinite(small)].tolist()) <= set(disparity.ravel().tolist())
    assert cell_grid_size((94, 310)) == (47, 155)
    assert cell_map(disparity, (8, 8)).shape == (4, 4)


def _edge_map(height: int, width: int) -> np.ndarray:
    edge = np.full((height, width), 15.0, np.float32)
    edge[:, width // 2 :] = 45.0
    return edge


def _brute_force_cells(
    basis: Basis,
    pixels: np.ndarray,
    disparities: np.ndarray,
    sigma: float,
    local: LocalPrior,
    partition: Partition | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Dense GP posterior with C(x, x') = v k(x - x') [w + (1 - w) 1{same cell}]."""
    height, width = basis.image_size
    b = basis.pixel_major.astype(np.float64)
    prior = b @ np.diag(basis.eigenvalues) @ b.T
    if partition is None:
        partition = Partition.along(
            _edge_map(height, width), pixels, basis.image_size, basis.grid_size
        )
    assert partition is not None
    cells = partition.cells(pixels)
    labels = cells.at(
        np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64), (height, width)
    ).ravel()
    ys, xs = np.mgrid[0:height, 0:width]
    grid = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
    kernel = (
        local.variance * local.axis(grid[:, 0], grid[:, 0]) * local.axis(grid[:, 1], grid[:, 1])
    )
    same = labels[:, None] == labels[None, :]
    prior += kernel * np.where(same, 1.0, local.cell_weight)
    index = pixels[:, 1].astype(int) * width + pixels[:, 0].astype(int)
    # the measurements' cells are their nodes' labels, as the pixels' are
    np.testing.assert_array_equal(labels[index], cells.point_cells)
    system = prior[np.ix_(index, index)] + np.diag(np.full(len(index), sigma**2))
    gain = np.linalg.solve(system, prior[index]).T
    mean = basis.mean_flat.astype(np.float64)
    estimate = mean + gain @ (disparities - mean[index])
    variance = np.diag(prior) - np.einsum("sk,ks->s", gain, prior[index])
    return estimate.reshape(height, width), np.sqrt(np.maximum(variance, 0)).reshape(height, width)


def _assert_batch_is_dense_posterior(
    basis: Basis,
    pixels: np.ndarray,
    disparities: np.ndarray,
    local: LocalPrior,
    partition: Partition,
) -> None:
    """``densify_batch`` with ``partition`` gives the dense posterior's mean and std."""
    result = densify_batch(
        basis,
        [pixels],
        [disparities],
        sigma=1.5,
        local_prior=local,
        variance_stride=1,
        partitions=[partition],
    )[0]
    expected = _brute_force_cells(basis, pixels, disparities, 1.5, local, partition)
    np.testing.assert_allclose(result.disparity, expected[0], atol=2e-3)
    assert result.disparity_std is not None
    np.testing.assert_allclose(result.disparity_std, expected[1], atol=2e-3)


@pytest.mark.parametrize("kernel", [Kernel.LAPLACE, Kernel.GAUSSIAN])
@pytest.mark.parametrize("length_scale", [3.0, 20.0])  # full-size and grid local part
@pytest.mark.parametrize("weight", [0.0, 0.4])
@pytest.mark.parametrize("uncertainty", ["exact-coarse", "exact"])
def test_edge_aware_prior_equals_dense_gaussian_posterior(
    kernel: Kernel, length_scale: float, weight: float, uncertainty: str
) -> None:
    basis = _basis()
    pixels, disparities = _points(basis, 9, seed=3)
    local = LocalPrior(4.0, length_scale, kernel, cell_weight=weight)
    result = densify(
        basis,
        pixels,
        disparities,
        sigma=1.5,
        local_prior=local,
        variance_stride=1,
        uncertainty=uncertainty,
        edge_map=_edge_map(*basis.image_size),
    )
    expected = _brute_force_cells(basis, pixels, disparities, 1.5, local)
    np.testing.assert_allclose(result.disparity, expected[0], atol=2e-3)
    assert result.disparity_std is not None
    np.testing.assert_allclose(result.disparity_std, expected[1], atol=2e-3)


def test_stationary_kernel_without_a_map_or_a_cell_weight() -> None:
    basis = _basis()
    pixels, disparities = _points(basis, 9, seed=4)
    edge = _edge_map(*basis.image_size)
    plain = densify(basis, pixels, disparities, sigma=1.5, local_prior=LocalPrior(4.0, 20.0))
    for local, edge_map in (
        (LocalPrior(4.0, 20.0), edge),  # w = 1: the map is not used
        (LocalPrior(4.0, 20.0, cell_weight=0.3), None),  # no map: one cell
    ):
        other = densify(basis, pixels, disparities, sigma=1.5, local_prior=local, edge_map=edge_map)
        np.testing.assert_array_equal(other.disparity, plain.disparity)
        assert other.disparity_std is not None
        assert plain.disparity_std is not None
        np.testing.assert_array_equal(other.disparity_std, plain.disparity_std)


def test_edge_aware_batch_equals_one_by_one() -> None:
    basis = _basis()
    local = LocalPrior(4.0, 20.0, cell_weight=0.2)
    frames = [_points(basis, 8, seed=s) for s in (5, 6)]
    edge = _edge_map(*basis.image_size)
    batch = densify_batch(
        basis,
        [p for p, _ in frames],
        [d for _, d in frames],
        sigma=1.0,
        local_prior=local,
        partitions=[Partition.along(edge, frames[0][0], basis.image_size, basis.grid_size), None],
    )
    for (pixels, disparities), result, edge_map in zip(frames, batch, [edge, None], strict=True):
        single = densify(
            basis, pixels, disparities, sigma=1.0, local_prior=local, edge_map=edge_map
        )
        np.testing.assert_allclose(result.disparity, single.disparity, atol=1e-5)
    with pytest.raises(ValueError, match="partitions"):
        densify_batch(basis, [frames[0][0]], [frames[0][1]], partitions=[None, None])


@pytest.mark.parametrize("weight", [0.0, 0.5, 1.0])
def test_edge_aware_covariance_is_positive_semidefinite(weight: float) -> None:
    rng = np.random.default_rng(7)
    positions = rng.uniform(0, 50, size=(40, 2))
    point_cells = rng.integers(0, 12, 40)
    matrix = LocalPrior(3.0, 10.0, cell_weight=weight).matrix(positions, point_cells)
    np.testing.assert_allclose(matrix, matrix.T)
    assert np.linalg.eigvalsh(matrix).min() > -1e-6
    np.testing.assert_allclose(np.diag(matrix), 3.0, rtol=1e-6)


def test_cell_weight_validates_and_round_trips() -> None:
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="cell_weight"):
            LocalPrior(1.0, 2.0, cell_weight=bad)
    local = LocalPrior(1.0, 2.0, cell_weight=0.25)
    assert LocalPrior.from_meta(local.to_meta()) == local
    assert "cell_weight" not in LocalPrior(1.0, 2.0).to_meta()  # old bases' meta unchanged


def test_fit_cell_weight_prefers_the_cells_the_data_came_from() -> None:
    basis = _basis()
    rng = np.random.default_rng(8)
    height, width = basis.image_size
    edge = _edge_map(height, width)
    frames, cells = [], []
    for _ in range(6):
        pixels, _ = _points(basis, 12, seed=int(rng.integers(1 << 30)))
        # each side of the edge at its own level: independent surfaces
        disparities = np.where(pixels[:, 0] < width // 2, 15.0, 45.0) + rng.normal(0, 0.3, 12)
        found = Partition.along(edge, pixels, basis.image_size, basis.grid_size)
        assert found is not None
        frames.append(fit_frame(basis, pixels, disparities))
        cells.append(found.cells(pixels).point_cells)
    local = LocalPrior(100.0, 30.0)
    best, scores = fit_cell_weight(basis, frames, cells, local=local, sigma=0.5)
    assert set(scores) == {0.0, 0.1, 0.25, 0.4, 0.5, 0.6, 0.75, 0.9, 1.0}
    assert best == max(scores, key=lambda w: scores[w])
    assert scores[best] > scores[1.0]
    with pytest.raises(ValueError, match="point_cells"):
        fit_cell_weight(basis, frames, cells[:-1], local=local, sigma=0.5)


def test_a_cell_without_measurements_gets_the_stationary_part_alone() -> None:
    """A partition seeded by a point that is not measured: its cell's pixels are
    correlated with every measurement by w only, as the dense posterior says."""
    basis = _basis()
    pixels, disparities = _points(basis, 8, seed=9)
    local = LocalPrior(4.0, 20.0, cell_weight=0.3)
    edge = _edge_map(*basis.image_size)
    seeds = np.vstack([pixels, [[15.0, 11.0], [0.0, 11.0]]])
    partition = Partition.along(edge, seeds, basis.image_size, basis.grid_size)
    assert partition is not None
    _assert_batch_is_dense_posterior(basis, pixels, disparities, local, partition)


@pytest.mark.parametrize("kernel", [Kernel.LAPLACE, Kernel.GAUSSIAN])
@pytest.mark.parametrize("length_scale", [0.02, 3.0, 20.0])  # 0.02: columns in blocks
def test_cells_holding_several_measurements_on_uneven_nodes(
    kernel: Kernel, length_scale: float
) -> None:
    """Measurements that are not seeds (carried ones) join a seed's cell, so cells hold
    several; an image whose cell grid's nodes span 2 or 3 pixels (13 x 19 px on 6 x 10
    nodes). Mean and std still equal the dense posterior's."""
    basis = _basis(13, 19)
    pixels, disparities = _points(basis, 16, seed=11)
    partition = Partition.along(_edge_map(13, 19), pixels[:5], basis.image_size, basis.grid_size)
    assert partition is not None
    assert partition.cells(pixels).counts.max() >= 3  # a cell holds three or more
    local = LocalPrior(4.0, length_scale, kernel, cell_weight=0.3)
    _assert_batch_is_dense_posterior(basis, pixels, disparities, local, partition)


def test_seedings_searched_together_are_each_frames_own_partition() -> None:
    """A batch's label search in one stack (:func:`partition_all`) gives every frame the
    labels it gets alone, on grids of two shapes mixed, partitions and None passing
    through; densify_batch given the seedings gives the same maps as given partitions."""
    rng = np.random.default_rng(5)
    frames = []
    for shape, size in [((24, 40), (6, 10)), ((24, 40), (6, 10)), ((16, 16), (4, 4))] * 2:
        edge = rng.choice([8.0, 8.5, 30.0, np.nan], size=shape, p=[0.4, 0.3, 0.2, 0.1])
        pixels = rng.uniform(0.0, 1.0, (int(rng.integers(1, 9)), 2)) * (shape[1], shape[0])
        frames.append((edge, pixels, shape, size))
    alone = [Partition.along(e, p, shape, size) for e, p, shape, size in frames]
    seedings: list[Seeding | Partition | None] = [
        Seeding.along(e, p, shape, size) for e, p, shape, size in frames
    ]
    seedings[3] = alone[3]
    together = partition_all([*seedings, None])
    assert together[-1] is None
    for one, other in zip(alone, together, strict=False):
        assert one is not None
        assert other is not None
        np.testing.assert_array_equal(one.labels, other.labels)
        assert one.image_size == other.image_size
    basis = _basis(12, 16)
    local = LocalPrior(4.0, 6.0, Kernel.LAPLACE, cell_weight=0.3)
    points = [_points(basis, 9, seed) for seed in (1, 2)]
    edge = _edge_map(12, 16)
    arguments = ([p for p, _ in points], [d for _, d in points])
    given = [Seeding.along(edge, p, basis.image_size, basis.grid_size) for p, _ in points]
    searched = partition_all(given)
    from_seedings = densify_batch(basis, *arguments, local_prior=local, partitions=given)
    from_partitions = densify_batch(basis, *arguments, local_prior=local, partitions=searched)
    for one, other in zip(from_seedings, from_partitions, strict=True):
        np.testing.assert_array_equal(one.disparity, other.disparity)
        np.testing.assert_array_equal(one.disparity_std, other.disparity_std)


def test_the_cells_list_the_same_cell_pairs_of_c_pp() -> None:
    """Cells.members of every measurement's own cell are the (i, j) pairs C_pp keeps at v k
    (prior.same_cell_pairs), (i, i) included."""
    rng = np.random.default_rng(8)
    pixels = rng.uniform(0.0, 1.0, (40, 2)) * (40, 24)
    partition = Partition.along(rng.uniform(5.0, 30.0, (24, 40)), pixels[:12], (24, 40), (6, 10))
    assert partition is not None
    cells = partition.cells(pixels)
    listed = set(zip(*(a.tolist() for a in cells.members(cells.point_cells)), strict=True))
    paired = set(zip(*(a.tolist() for a in same_cell_pairs(cells.point_cells)), strict=True))
    assert listed == paired
    assert len(listed) > 40  # cells holding several
