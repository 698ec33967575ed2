from __future__ import annotations

import dataclasses
import json
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from pcainterp_stream.errors import BasisError
from pcainterp_stream.estimate.basis import (
    FORMAT,
    Basis,
    bilinear_weights,
    grid_size_for,
    image_to_grid,
    resample_grid,
    sample_rows,
)


def make_basis(
    grid_size: tuple[int, int] = (6, 9),
    image_size: tuple[int, int] = (12, 18),
    n_components: int = 4,
    seed: int = 0,
) -> Basis:
    rng = np.random.default_rng(seed)
    s = grid_size[0] * grid_size[1]
    q = np.linalg.qr(rng.normal(size=(s, n_components)))[0]
    return Basis(
        mean=rng.uniform(5, 20, grid_size).astype(np.float32),
        components=q.T.reshape(n_components, *grid_size).astype(np.float32),
        eigenvalues=np.sort(rng.uniform(1, 50, n_components))[::-1].copy(),
        total_variance=500.0,
        image_size=image_size,
        focal_baseline=380.0,
        n_train=17,
        meta={"note": "test"},
    )


def test_grid_size_for_rounds() -> None:
    assert grid_size_for((376, 1241), 0.25) == (94, 310)
    assert grid_size_for((376, 1241), 1.0) == (376, 1241)
    with pytest.raises(ValueError, match="grid_scale"):
        grid_size_for((10, 10), 0.0)


@pytest.mark.parametrize(
    ("grid", "image"), [((6, 9), (12, 18)), ((5, 7), (23, 31)), ((8, 8), (8, 8))]
)
def test_bilinear_sampling_matches_cv2_resize(
    grid: tuple[int, int], image: tuple[int, int]
) -> None:
    rng = np.random.default_rng(1)
    grid_map = rng.normal(size=grid).astype(np.float32)
    ys, xs = np.mgrid[0 : image[0], 0 : image[1]]
    pixels = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
    indices, weights = bilinear_weights(image_to_grid(pixels, image, grid), grid)
    sampled = sample_rows(grid_map.reshape(-1, 1), indices, weights).reshape(image)
    resized = cv2.resize(grid_map, (image[1], image[0]), interpolation=cv2.INTER_LINEAR)
    np.testing.assert_allclose(sampled, resized, atol=1e-5)
    np.testing.assert_allclose(resample_grid(grid_map, image), resized, atol=0)


def test_save_load_round_trip(tmp_path: Path) -> None:
    basis = make_basis()
    path = tmp_path / "basis.npz"
    basis.save(path)
    loaded = Basis.load(path)
    np.testing.assert_array_equal(loaded.mean, basis.mean)
    np.testing.assert_array_equal(loaded.components, basis.components)
    np.testing.assert_array_equal(loaded.eigenvalues, basis.eigenvalues)
    assert loaded.total_variance == basis.total_variance
    assert loaded.image_size == basis.image_size
    assert loaded.focal_baseline == basis.focal_baseline
    assert loaded.n_train == basis.n_train
    assert loaded.meta == basis.meta
    assert not list(tmp_path.glob(".*tmp"))


def test_a_name_too_long_is_a_basis_error_not_an_oserror(tmp_path: Path) -> None:
    """Review 57d D4: ``target.is_symlink()`` ran outside the save's ``try``: a name too long
    for the file system raised OSError (a traceback), not the one-line BasisError."""
    path = tmp_path / ("n" * 300 + ".npz")
    with pytest.raises(BasisError, match=r"^cannot write basis .*: File name too long$"):
        make_basis().save(path)
    assert not list(tmp_path.iterdir())


def test_a_loaded_basis_and_what_it_caches_are_read_only(tmp_path: Path) -> None:
    """A loaded basis may be shared (Basis.default()): an in-place edit raises."""
    made = make_basis()
    made.save(tmp_path / "basis.npz")
    loaded = Basis.load(tmp_path / "basis.npz")
    covariance = loaded.prior_covariance(1)
    assert covariance is not None
    for array in (loaded.mean, loaded.components, loaded.eigenvalues, covariance):
        assert not array.flags.writeable
    with pytest.raises(ValueError, match="read-only"):
        loaded.eigenvalues[0] = 0.0
    # a basis built from the caller's arrays leaves them as they were; its caches are its own
    assert made.mean.flags.writeable
    assert not made.mean_flat.flags.writeable
    assert made.mean.flags.writeable  # the cached flat view did not lock the caller's array


def test_prior_variance_is_cached_and_correct() -> None:
    basis = make_basis()
    rows = basis.components.reshape(basis.n_components, -1).astype(np.float64)
    expected = (basis.eigenvalues[:, None] * rows**2).sum(axis=0).reshape(basis.grid_size)
    np.testing.assert_allclose(basis.prior_variance, expected, rtol=1e-5)
    assert basis.prior_variance is basis.prior_variance
    assert basis.pixel_major.flags.c_contiguous
    assert basis.pixel_major.shape == (54, 4)


def _write(path: Path, **overrides: object) -> Path:
    basis = make_basis()
    arrays: dict[str, object] = {
        "format": np.array(FORMAT),
        "mean": basis.mean,
        "components": basis.components,
        "eigenvalues": basis.eigenvalues,
        "total_variance": np.array(500.0),
        "image_size": np.array([12, 18], dtype=np.int64),
        "focal_baseline": np.array(380.0),
        "n_train": np.array(17, dtype=np.int64),
        "meta": np.array(json.dumps({})),
    }
    for key, value in overrides.items():
        if value is None:
            del arrays[key]
        else:
            arrays[key] = value
    np.savez(path, **arrays)  # type: ignore[arg-type]
    return path


def test_load_missing_file(tmp_path: Path) -> None:
    with pytest.raises(BasisError, match="does not exist"):
        Basis.load(tmp_path / "nope.npz")


def test_load_not_a_zip(tmp_path: Path) -> None:
    path = tmp_path / "basis.npz"
    path.write_bytes(b"this is not an npz archive at all")
    with pytest.raises(BasisError, match=r"basis\.npz is not a basis file \(\.npz\); pass"):
        Basis.load(path)


@pytest.mark.parametrize(
    ("head", "what"),
    [
        (b"\x89MCAP0\r\n" + bytes(64), ": it is an MCAP log; "),
        (b"#ROSBAG V2.0\n" + bytes(64), ": it is a ROS 1 bag; "),
        (b"", ": it is empty; "),
        (b"\x80\x04\x95" + bytes(64), "; "),  # a pickle: numpy's hint to load it unsafely leaked
    ],
)
def test_load_names_what_a_file_given_as_basis_is(tmp_path: Path, head: bytes, what: str) -> None:
    path = tmp_path / "drive.mcap"
    path.write_bytes(head)
    with pytest.raises(BasisError) as caught:
        Basis.load(path)
    expected = f"basis file {path} is not a basis file (.npz){what}pass the path of a basis .npz"
    assert str(caught.value).startswith(expected)
    assert "pickle" not in str(caught.value)


def test_load_a_folder_or_an_npy(tmp_path: Path) -> None:
    # a folder was reported as "does not exist"
    with pytest.raises(BasisError, match=r"basis file .* is a folder, not a basis file; pass"):
        Basis.load(tmp_path)
    np.save(tmp_path / "mean.npy", np.zeros(3))
    with pytest.raises(BasisError, match=r"mean\.npy is not a basis file \(\.npz\): it is a sin"):
        Basis.load(tmp_path / "mean.npy")


def test_load_truncated(tmp_path: Path) -> None:
    path = _write(tmp_path / "basis.npz")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(BasisError, match="truncated"):
        Basis.load(path)


def test_load_missing_key(tmp_path: Path) -> None:
    path = _write(tmp_path / "basis.npz", eigenvalues=None)
    with pytest.raises(BasisError, match="has no key 'eigenvalues'"):
        Basis.load(path)


def test_load_wrong_format(tmp_path: Path) -> None:
    path = _write(tmp_path / "basis.npz", format=np.array("pcainterp-basis/9"))
    with pytest.raises(BasisError, match="key 'format' is 'pcainterp-basis/9'"):
        Basis.load(path)


def test_load_wrong_dtype(tmp_path: Path) -> None:
    path = _write(tmp_path / "basis.npz", n_train=np.array(1.5))
    with pytest.raises(BasisError, match="key 'n_train' has dtype float64"):
        Basis.load(path)


def test_load_wrong_ndim(tmp_path: Path) -> None:
    path = _write(tmp_path / "basis.npz", mean=np.zeros(54, dtype=np.float32))
    with pytest.raises(BasisError, match=r"key 'mean' has shape \(54,\), expected 2"):
        Basis.load(path)


def test_load_wrong_component_shape(tmp_path: Path) -> None:
    path = _write(tmp_path / "basis.npz", components=np.zeros((4, 6, 8), dtype=np.float32))
    with pytest.raises(BasisError, match="key 'components' has shape"):
        Basis.load(path)


def test_load_refuses_a_basis_without_components(tmp_path: Path) -> None:
    empty = np.zeros((0, 6, 9), dtype=np.float32)
    path = _write(tmp_path / "basis.npz", components=empty, eigenvalues=np.zeros(0))
    with pytest.raises(BasisError, match="key 'components' holds no component; learn"):
        Basis.load(path)


def test_load_wrong_eigenvalue_count(tmp_path: Path) -> None:
    path = _write(tmp_path / "basis.npz", eigenvalues=np.ones(3))
    with pytest.raises(BasisError, match="key 'eigenvalues' has shape"):
        Basis.load(path)


def test_load_unsorted_eigenvalues(tmp_path: Path) -> None:
    path = _write(tmp_path / "basis.npz", eigenvalues=np.array([1.0, 2.0, 3.0, 4.0]))
    with pytest.raises(BasisError, match="non-negative and descending"):
        Basis.load(path)


def test_load_non_finite(tmp_path: Path) -> None:
    mean = make_basis().mean.copy()
    mean[0, 0] = np.nan
    path = _write(tmp_path / "basis.npz", mean=mean)
    with pytest.raises(BasisError, match="key 'mean' has non-finite values"):
        Basis.load(path)


def test_load_not_orthonormal(tmp_path: Path) -> None:
    components = make_basis().components * 2
    path = _write(tmp_path / "basis.npz", components=components)
    with pytest.raises(BasisError, match="not orthonormal"):
        Basis.load(path)


def test_load_image_size_shape(tmp_path: Path) -> None:
    path = _write(tmp_path / "basis.npz", image_size=np.array([12, 18, 3]))
    with pytest.raises(BasisError, match=r"key 'image_size' has shape \(3,\), expected \(2,\)"):
        Basis.load(path)


def test_load_negative_focal_baseline(tmp_path: Path) -> None:
    path = _write(tmp_path / "basis.npz", focal_baseline=np.array(-1.0))
    with pytest.raises(BasisError, match="key 'focal_baseline' must be finite and >= 0"):
        Basis.load(path)


def test_a_bad_field_is_named_as_an_argument_of_basis() -> None:
    good = make_basis()
    with pytest.raises(
        ValueError, match=r"^Basis argument `focal_baseline` must be finite and >= 0 \(px\*m"
    ):
        dataclasses.replace(good, focal_baseline=-1.0)
    with pytest.raises(ValueError, match=r"^Basis argument `n_train` must be >= 0, got -3$"):
        dataclasses.replace(good, n_train=-3)
    with pytest.raises(ValueError, match=r"^Basis argument `components` is not orthonormal"):
        dataclasses.replace(good, components=good.components * 2)


def test_load_bad_meta(tmp_path: Path) -> None:
    path = _write(tmp_path / "basis.npz", meta=np.array("{not json"))
    with pytest.raises(BasisError, match="key 'meta' is not valid JSON"):
        Basis.load(path)


def test_load_meta_not_object(tmp_path: Path) -> None:
    path = _write(tmp_path / "basis.npz", meta=np.array("[1, 2]"))
    with pytest.raises(BasisError, match="key 'meta' is not a JSON object"):
        Basis.load(path)


def test_load_pickled_object_refused(tmp_path: Path) -> None:
    path = _write(tmp_path / "basis.npz", meta=np.array([{"a": 1}], dtype=object))
    with pytest.raises(BasisError, match="not a readable"):
        Basis.load(path)


def test_zip_without_npy(tmp_path: Path) -> None:
    path = tmp_path / "basis.npz"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("readme.txt", "hello")
    with pytest.raises(BasisError, match="has no key 'format'"):
        Basis.load(path)
