"""The built-in basis (package data, ``Basis.default()``) and basis fingerprints.

The shipped file is replaced when the built-in basis is re-made, so these tests check only
what any built-in basis must be: present, valid, for the KITTI grey camera, consistent with
its sidecar JSON, quick to load and used wherever no basis is given.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pcainterp_stream import densify
from pcainterp_stream.errors import BasisError
from pcainterp_stream.estimate import basis as basis_module
from pcainterp_stream.estimate.basis import (
    Basis,
    builtin_kind,
    default_basis_path,
    default_basis_recipe,
    indoor_basis_path,
    is_default,
)
from pcainterp_stream.synth import SynthConfig


def test_built_in_basis_is_for_the_kitti_grey_camera() -> None:
    basis = Basis.default()
    camera = SynthConfig().camera
    assert basis.image_size == (376, 1241) == camera.image_size
    assert basis.focal_baseline == pytest.approx(camera.focal_baseline, rel=0.01)  # ~386 px*m
    assert basis.n_components >= 1
    assert basis.n_train > basis.n_components
    assert 0 < basis.explained_variance_ratio <= 1


def test_built_in_basis_is_loaded_once() -> None:
    first = Basis.default()
    assert Basis.default() is first
    assert is_default(first)
    assert not is_default(Basis.load(default_basis_path()))  # an equal copy is not it


def test_built_in_basis_cannot_be_edited_in_place() -> None:
    basis = Basis.default()
    derived = (
        basis.mean,
        basis.components,
        basis.eigenvalues,
        basis.pixel_major,
        basis.component_rows,
        basis.mean_flat,
        basis.prior_variance,
        basis.variance_grid(1).component_rows,
        basis.variance_grid(4).prior_variance,
        basis.variance_grid(4).squared_rows,
    )
    for array in derived:
        assert not array.flags.writeable
    mean = basis.mean
    with pytest.raises(ValueError, match="read-only"):
        mean *= 0.5  # a notebook's scaled prior must not change every later Basis.default()
    scaled = dataclasses.replace(basis, mean=basis.mean * 0.5)  # the way to edit: a copy
    assert scaled.mean.flags.writeable
    assert float(np.abs(Basis.default().mean - basis.mean).max()) == 0.0


def test_built_in_basis_loads_quickly_and_keeps_slow_parts_lazy() -> None:
    started = time.perf_counter()
    basis = Basis.load(default_basis_path())
    elapsed = time.perf_counter() - started
    # < 1 s on an idle core; the bound leaves room for a busy shared machine
    assert elapsed < 3.0, f"loading the built-in basis took {elapsed:.2f} s"
    assert "_prior_covariances" not in vars(basis)
    assert "_variance_grids" not in vars(basis)


def test_built_in_basis_matches_its_sidecar() -> None:
    sidecar = default_basis_recipe()
    assert sidecar, "pcainterp_stream/data/default_basis.json is missing or not an object"
    digest = hashlib.sha256(default_basis_path().read_bytes()).hexdigest()
    assert sidecar["sha256"] == digest
    assert isinstance(sidecar.get("recipe"), dict)


def test_built_in_indoor_basis_is_small_loaded_once_and_matches_its_sidecar() -> None:
    indoor = Basis.indoor()
    assert Basis.indoor() is indoor
    assert builtin_kind(indoor) == "indoor"
    assert builtin_kind(Basis.default()) == "street"
    assert builtin_kind(Basis.load(indoor_basis_path())) is None  # an equal copy is not it
    assert indoor.image_size == (480, 752)
    assert indoor.n_components <= 100
    assert indoor_basis_path().stat().st_size < 8 << 20  # it ships in the wheel
    sidecar = default_basis_recipe(indoor=True)
    assert sidecar["sha256"] == hashlib.sha256(indoor_basis_path().read_bytes()).hexdigest()
    assert sidecar["command"] == "python tools/make_default_basis.py --indoor"
    assert indoor.meta["source"]["indoor_walks"] == sidecar["recipe"]["walks"]


def test_a_missing_basis_file_names_no_command_line_names(tmp_path: Path) -> None:
    # the names are --basis's: the command line lists them (tests/test_cli.py), the
    # library, which takes Basis.default() and Basis.indoor(), does not
    with pytest.raises(
        BasisError, match=r"builtin-indor does not exist; pass the path of a "
    ) as err:
        Basis.load(tmp_path / "builtin-indor")
    assert "builtin-street" not in str(err.value)


def test_missing_built_in_basis_says_how_to_go_on(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    missing = tmp_path / "data" / "default_basis.npz"
    monkeypatch.setattr(basis_module, "default_basis_path", lambda: missing)
    with pytest.raises(BasisError, match=r"built-in basis .* is missing .*pass --basis"):
        Basis.default()
    assert default_basis_recipe() == {}


def test_densify_without_a_basis_uses_the_built_in_one() -> None:
    rng = np.random.default_rng(0)
    pixels = rng.uniform([0, 0], [1240, 375], size=(50, 2))
    disparities = rng.uniform(5, 40, size=50)
    implicit = densify(None, pixels, disparities)
    explicit = densify(Basis.default(), pixels, disparities)
    np.testing.assert_array_equal(implicit.disparity, explicit.disparity)
    assert implicit.disparity.shape == (376, 1241)


def test_fingerprint_tells_bases_apart_and_survives_a_round_trip(tmp_path: Path) -> None:
    basis = Basis.default()
    path = tmp_path / "copy.npz"
    dataclasses.replace(basis, meta={"note": "another meta"}).save(path)
    assert Basis.load(path).fingerprint == basis.fingerprint  # meta is not content
    eigenvalues = basis.eigenvalues.copy()
    eigenvalues[-1] *= 0.5
    other = dataclasses.replace(basis, eigenvalues=eigenvalues)
    assert other.fingerprint != basis.fingerprint
    assert len(basis.fingerprint) == 16


TOOL = Path(__file__).resolve().parents[2] / "tools" / "make_default_basis.py"


def _make_small(out: Path) -> dict[str, object]:
    import json
    import subprocess
    import sys

    subprocess.run(
        [sys.executable, str(TOOL), "--small", "--out", str(out)],
        check=True,
        capture_output=True,
        text=True,
        timeout=600,
    )
    sidecar: dict[str, object] = json.loads((out / "default_basis.json").read_text())
    return sidecar


@pytest.mark.slow
def test_make_default_basis_regenerates_a_small_basis_bit_for_bit(tmp_path: Path) -> None:
    """tools/make_default_basis.py --small, twice: the same arrays and metadata each time."""
    if not TOOL.is_file():
        pytest.skip(f"{TOOL} not found (an installed package without the repository's tools)")
    first = _make_small(tmp_path / "a")
    second = _make_small(tmp_path / "b")
    assert first["content_sha256"] == second["content_sha256"]
    path = tmp_path / "a" / "default_basis.npz"
    assert first["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    basis = Basis.load(path)
    recipe = first["recipe"]
    assert isinstance(recipe, dict)
    assert basis.meta["recipe"] == recipe
    assert basis.n_train == recipe["drives"] * len(range(0, recipe["frames"], recipe["step"]))
    assert basis.meta["prior"]["local"]["length_scale"] == recipe["local_kernel"][1]


@pytest.mark.slow
def test_make_default_basis_learns_from_indoor_walks_and_info_lists_them(tmp_path: Path) -> None:
    """--indoor-seeds adds the walks' maps; the recipe, the source and `info` say so."""
    import subprocess
    import sys

    from pcainterp_stream.pipeline.jobs import describe_basis

    if not TOOL.is_file():
        pytest.skip(f"{TOOL} not found (an installed package without the repository's tools)")
    out = tmp_path / "indoor"
    subprocess.run(
        [sys.executable, str(TOOL), "--small", "--indoor-seeds", "1", "--out", str(out)],
        check=True,
        capture_output=True,
        text=True,
        timeout=600,
    )
    basis = Basis.load(out / "default_basis.npz")
    recipe = basis.meta["recipe"]
    walk = len(range(0, recipe["indoor_frames"], recipe["indoor_step"]))
    street = recipe["drives"] * len(range(0, recipe["frames"], recipe["step"]))
    assert recipe["indoor_seeds"] == 1
    assert basis.n_train == street + walk
    assert basis.meta["source"]["indoor_walks"] == 1
    assert "--indoor-seeds 1" in basis.meta["command"]
    text = describe_basis(out / "default_basis.npz")
    assert "indoor walks     1 synthetic rooms, corridors and halls" in text
    # the street-only recipe says nothing of rooms
    assert "indoor walks" not in describe_basis()


@pytest.mark.slow
def test_make_default_basis_indoor_regenerates_bit_for_bit(tmp_path: Path) -> None:
    """--indoor --small, twice: the same arrays and metadata; a basis for the 752x480 camera."""
    import subprocess
    import sys

    if not TOOL.is_file():
        pytest.skip(f"{TOOL} not found (an installed package without the repository's tools)")
    sidecars = []
    for name in ("a", "b"):
        out = tmp_path / name
        subprocess.run(
            [sys.executable, str(TOOL), "--indoor", "--small", "--out", str(out)],
            check=True,
            capture_output=True,
            text=True,
            timeout=600,
        )
        sidecars.append(json.loads((out / "indoor_basis.json").read_text()))
    assert sidecars[0]["content_sha256"] == sidecars[1]["content_sha256"]
    basis = Basis.load(tmp_path / "a" / "indoor_basis.npz")
    recipe = sidecars[0]["recipe"]
    assert basis.image_size == (480, 752)
    assert basis.n_train == recipe["walks"] * len(range(0, recipe["frames"], recipe["step"]))
    assert basis.meta["source"]["cameras"] == ["752x480", "640x480", "1280x720", "fisheye-752x480"]
    assert "prior" in basis.meta


def test_a_preloaded_built_in_basis_is_read_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A load started ahead (``preload_builtin``) is waited for by the first caller, never
    repeated, and hands every caller the same object; a missing file is left to that
    caller to report."""
    import shutil
    import threading

    copy = tmp_path / "data" / "default_basis.npz"
    copy.parent.mkdir()
    shutil.copy(default_basis_path(), copy)
    monkeypatch.setattr(basis_module, "default_basis_path", lambda: copy)
    loads: list[str] = []
    original = Basis.load
    started = threading.Event()

    def slow_load(path: Any) -> Basis:
        loads.append(threading.current_thread().name)
        started.set()
        time.sleep(0.2)  # the caller below arrives while this load is under way
        return original(path)

    monkeypatch.setattr(Basis, "load", staticmethod(slow_load))
    basis_module.preload_builtin("street")
    assert started.wait(10)
    first = Basis.default()
    assert loads == ["basis-load"]
    assert Basis.default() is first
    # nothing to load: the preload says nothing, the caller raises
    monkeypatch.setattr(basis_module, "default_basis_path", lambda: tmp_path / "gone.npz")
    basis_module.preload_builtin("street")
    with pytest.raises(BasisError, match="is missing"):
        Basis.default()
