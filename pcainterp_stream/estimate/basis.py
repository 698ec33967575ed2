"""The PCA basis of disparity maps: the ``pcainterp-basis/1`` file and the grid it lives on.

A basis is learned for one image size and one f*b, on a grid that may be coarser than the
image. Grid and image are related by pixel-centre-aligned scaling (docs/estimator.md, "Grid"),

    g = (p + 0.5) * (grid_size / image_size) - 0.5,

OpenCV's ``INTER_LINEAR`` convention, so that bilinear sampling of the grid at image
positions and ``cv2.resize(grid, image, INTER_LINEAR)`` are the same function. Everything a
frame needs that depends only on the basis (the pixel-major component matrix, the prior
variance sum_i lambda_i u_i(x)^2, coarser variance grids) is computed once per
:class:`Basis` and cached on it.
"""

from __future__ import annotations

import contextlib
import contextvars
import hashlib
import importlib.resources
import json
import os
import stat
import tempfile
import threading
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
from threadpoolctl import threadpool_limits

from pcainterp_stream.errors import BasisError
from pcainterp_stream.estimate.prior_meta import check_fitted_prior
from pcainterp_stream.interrupt import raise_if_signalled

FORMAT = "pcainterp-basis/1"
"""The format string stored under the ``format`` key of a basis file."""

ORTHONORMALITY_TOLERANCE = 1e-3
"""Largest allowed |B^T B - I| entry when loading a basis (float32 storage rounding)."""

DEFAULT_BASIS_FILE = "default_basis.npz"
"""The built-in basis, package data in ``pcainterp_stream/data/`` (:meth:`Basis.default`)."""

DEFAULT_BASIS_SIDECAR = "default_basis.json"
"""Beside it: its sha256 and the recipe that made it (``tools/make_default_basis.py``)."""

INDOOR_BASIS_FILE = "indoor_basis.npz"
"""The built-in indoor basis, package data beside the street one (:meth:`Basis.indoor`)."""

INDOOR_BASIS_SIDECAR = "indoor_basis.json"
"""Beside it: its sha256 and the recipe that made it (``make_default_basis.py --indoor``)."""

BUILT_IN = "built-in"
"""How a densified log and a report name the built-in (street) basis."""

BUILT_IN_INDOOR = "built-in-indoor"
"""How they name the built-in indoor basis."""

IN_MEMORY = "in-memory"
"""How they name a basis passed as an object that is not the built-in one (no file)."""

_KEYS = (
    "format",
    "mean",
    "components",
    "eigenvalues",
    "total_variance",
    "image_size",
    "focal_baseline",
    "n_train",
    "meta",
)


def grid_size_for(image_size: tuple[int, int], grid_scale: float) -> tuple[int, int]:
    """Return the basis grid size for an image size and a scale factor.

    Args:
        image_size: (height, width) of the images (px).
        grid_scale: grid pixels per image pixel, in (0, 1].

    Returns:
        (grid_height, grid_width), each ``max(1, round(size * grid_scale))``.
    """
    if not 0.0 < grid_scale <= 1.0:
        raise ValueError(f"grid_scale must be in (0, 1], got {grid_scale}")
    return (
        max(1, round(image_size[0] * grid_scale)),
        max(1, round(image_size[1] * grid_scale)),
    )


def image_to_grid(
    pixels: npt.NDArray[np.floating[Any]],
    image_size: tuple[int, int],
    grid_size: tuple[int, int],
) -> npt.NDArray[np.float64]:
    """Map image positions to grid positions, pixel-centre aligned (cv2 INTER_LINEAR).

    Args:
        pixels: (k, 2) float, (x, y) in image px.
        image_size: (height, width) of the image (px).
        grid_size: (height, width) of the grid (grid px).

    Returns:
        (k, 2) float64, (x, y) in grid px: g = (p + 0.5) * (grid / image) - 0.5.
    """
    scale = np.array([grid_size[1] / image_size[1], grid_size[0] / image_size[0]], dtype=np.float64)
    return (np.asarray(pixels, dtype=np.float64) + 0.5) * scale - 0.5


def bilinear_weights(
    grid_positions: npt.NDArray[np.float64], grid_size: tuple[int, int]
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.float64]]:
    """Return flat indices and weights of the four grid pixels around each position.

    Positions outside the grid are clamped to its border, as ``cv2.resize`` does.

    Args:
        grid_positions: (k, 2) float64, (x, y) in grid px.
        grid_size: (height, width) of the grid.

    Returns:
        indices: (k, 4) intp, flat (row-major) grid indices.
        weights: (k, 4) float64, bilinear weights summing to 1 per row.
    """
    gh, gw = grid_size
    x = np.clip(grid_positions[:, 0], 0.0, gw - 1)
    y = np.clip(grid_positions[:, 1], 0.0, gh - 1)
    x0 = np.minimum(np.floor(x).astype(np.intp), max(gw - 2, 0))
    y0 = np.minimum(np.floor(y).astype(np.intp), max(gh - 2, 0))
    x1 = np.minimum(x0 + 1, gw - 1)
    y1 = np.minimum(y0 + 1, gh - 1)
    fx = x - x0
    fy = y - y0
    indices = np.stack([y0 * gw + x0, y0 * gw + x1, y1 * gw + x0, y1 * gw + x1], axis=1)
    weights = np.stack([(1 - fy) * (1 - fx), (1 - fy) * fx, fy * (1 - fx), fy * fx], axis=1)
    return indices, weights


def sample_rows(
    pixel_major: npt.NDArray[np.float32],
    indices: npt.NDArray[np.intp],
    weights: npt.NDArray[np.float64],
) -> npt.NDArray[np.float32]:
    """Bilinearly interpolate rows of a pixel-major matrix.

    Args:
        pixel_major: (s, c) float32, one row per grid pixel (row-major grid order).
        indices: (k, 4) intp from :func:`bilinear_weights`.
        weights: (k, 4) float64 from :func:`bilinear_weights`.

    Returns:
        (k, c) float32, the interpolated rows.
    """
    w = weights.astype(np.float32)
    out = pixel_major[indices[:, 0]] * w[:, 0:1]
    for corner in range(1, 4):
        out += pixel_major[indices[:, corner]] * w[:, corner : corner + 1]
    return out


def resample_grid(
    grid_map: npt.NDArray[np.floating[Any]], image_size: tuple[int, int]
) -> npt.NDArray[np.float32]:
    """Resample a grid map to an image size, bilinear and pixel-centre aligned.

    Args:
        grid_map: (gh, gw) float, values on the grid.
        image_size: (height, width) of the output (px).

    Returns:
        (height, width) float32.
    """
    grid32 = np.ascontiguousarray(grid_map, dtype=np.float32)
    if grid32.shape == tuple(image_size):
        return grid32
    resized = cv2.resize(
        grid32, (int(image_size[1]), int(image_size[0])), interpolation=cv2.INTER_LINEAR
    )
    return np.asarray(resized, dtype=np.float32)


_FILE_KINDS = {
    b"\x89MCAP": "an MCAP log",
    b"#ROSBAG": "a ROS 1 bag",
    b"SQLite format 3": "a SQLite (rosbag2) database",
    b"\x93NUMPY": "a single numpy array (.npy)",
}
"""First bytes of files given as a basis by mistake, and what to call them."""


def check_basis_file(path: Path) -> None:
    """Refuse a path that cannot be a basis file, before reading it.

    Args:
        path: the path given as a basis.

    Raises:
        BasisError: the path does not exist, is a folder, or does not start as a zip
            archive (an ``.npz``) does; the message says what it is when it can.
    """
    fix = "pass the path of a basis .npz (pcainterp learn writes one)"
    if path.is_dir():
        raise BasisError(f"basis file {path} is a folder, not a basis file; {fix}")
    if not path.is_file():
        raise BasisError(f"basis file {path} does not exist; {fix}")
    try:
        with path.open("rb") as stream:
            head = stream.read(16)
    except OSError as err:
        raise BasisError(f"cannot read basis file {path}: {err.strerror or err}") from err
    if not head.startswith(b"PK"):  # every zip archive (an .npz is one) starts so
        kind = next((name for magic, name in _FILE_KINDS.items() if head.startswith(magic)), "")
        what = ": it is empty" if not head else f": it is {kind}" if kind else ""
        raise BasisError(f"basis file {path} is not a basis file (.npz){what}; {fix}")


def _read_only(array: npt.NDArray[Any]) -> npt.NDArray[Any]:
    """Return ``array`` marked read-only (a view's flag leaves its base writable).

    A basis is shared - :meth:`Basis.default` is one object per process - so what it holds
    and what it caches is read-only: an in-place edit raises instead of changing every later
    frame. Edit a copy (``dataclasses.replace(basis, mean=basis.mean * 0.5)``).
    """
    array.flags.writeable = False
    return array


PRIOR_COVARIANCE_MAX_BYTES = 512 << 20
"""Largest :meth:`Basis.prior_covariance` kept (the KITTI-size basis's takes 218 MB)."""


@dataclass(frozen=True, eq=False)
class VarianceGrid:
    """The basis sampled on a (possibly coarser) grid where the posterior std is evaluated.

    Attributes:
        size: (height, width) of this grid.
        component_rows: (l, s_v) float32, u_i at the grid's pixel centres, C-contiguous.
        prior_variance: (s_v,) float32, sum_i lambda_i u_i(x)^2 at those centres (px^2).
    """

    size: tuple[int, int]
    component_rows: npt.NDArray[np.float32]
    prior_variance: npt.NDArray[np.float32]

    @cached_property
    def squared_rows(self) -> npt.NDArray[np.float32]:
        """(l, s_v) float32, u_i(x)^2, for the paper's diagonal variance (eq. 15/16)."""
        return _read_only(self.component_rows * self.component_rows)


@dataclass(frozen=True, eq=False)
class Basis:
    """A learned PCA basis of disparity maps (the ``pcainterp-basis/1`` file).

    A basis read by :meth:`load` (so the built-in ones, shared by the whole process) holds
    read-only arrays, and every basis's cached arrays are read-only: to try a change, edit
    a copy, ``dataclasses.replace(basis, mean=basis.mean * 0.5)``.

    Attributes:
        mean: (gh, gw) float32, mean disparity on the grid (px).
        components: (l, gh, gw) float32, orthonormal over grid pixels.
        eigenvalues: (l,) float64, variances (px^2 summed over the grid), descending.
        total_variance: trace of the training covariance over all components.
        image_size: (height, width) of the images the basis is for (px).
        focal_baseline: f*b (px*m) of the training camera; 0 when unknown.
        n_train: number of training maps.
        meta: preprocessing, SGBM and learning parameters, software version.
    """

    mean: npt.NDArray[np.float32]
    components: npt.NDArray[np.float32]
    eigenvalues: npt.NDArray[np.float64]
    total_variance: float
    image_size: tuple[int, int]
    focal_baseline: float
    n_train: int
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _check_arrays(self, _NAMING.get())

    @property
    def n_components(self) -> int:
        """Return l, the number of components."""
        return int(self.components.shape[0])

    @property
    def grid_size(self) -> tuple[int, int]:
        """Return (gh, gw), the size of the basis grid."""
        return (int(self.mean.shape[0]), int(self.mean.shape[1]))

    @property
    def explained_variance_ratio(self) -> float:
        """Return sum(eigenvalues) / total_variance, the share of variance the basis keeps."""
        if self.total_variance <= 0:
            return 1.0
        return float(self.eigenvalues.sum() / self.total_variance)

    @cached_property
    def pixel_major(self) -> npt.NDArray[np.float32]:
        """(s, l) float32 C-contiguous: B with one row per grid pixel, for gathers and B @ Y."""
        s = self.grid_size[0] * self.grid_size[1]
        return _read_only(np.ascontiguousarray(self.components.reshape(self.n_components, s).T))

    @cached_property
    def component_rows(self) -> npt.NDArray[np.float32]:
        """(l, s) float32 C-contiguous view of the components: B^T."""
        s = self.grid_size[0] * self.grid_size[1]
        return _read_only(np.ascontiguousarray(self.components.reshape(self.n_components, s)))

    @cached_property
    def mean_flat(self) -> npt.NDArray[np.float32]:
        """(s,) float32, the mean map flattened in row-major grid order."""
        return _read_only(np.ascontiguousarray(self.mean.reshape(-1)))

    @cached_property
    def prior_variance(self) -> npt.NDArray[np.float32]:
        """(gh, gw) float32, prior variance sum_i lambda_i u_i(x)^2 on the grid (px^2)."""
        return _read_only(self.variance_grid(1).prior_variance.reshape(self.grid_size))

    @cached_property
    def _variance_grids(self) -> dict[int, VarianceGrid]:
        return {}

    def variance_grid(self, stride: int) -> VarianceGrid:
        """Return the basis sampled on a grid ``stride`` times coarser than the basis grid.

        The coarse grid is pixel-centre aligned with the basis grid; components are sampled
        there bilinearly, so the posterior variance computed on it is exact at those points.
        Cached per stride.

        Args:
            stride: coarsening factor >= 1 (1: the basis grid itself).

        Returns:
            The :class:`VarianceGrid`.
        """
        if stride < 1:
            raise ValueError(f"variance stride must be >= 1, got {stride}")
        cached = self._variance_grids.get(stride)
        if cached is not None:
            return cached
        gh, gw = self.grid_size
        if stride == 1:
            size = (gh, gw)
            rows = self.component_rows
        else:
            size = (max(1, -(-gh // stride)), max(1, -(-gw // stride)))
            ys, xs = np.mgrid[0 : size[0], 0 : size[1]]
            coarse = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
            fine = image_to_grid(coarse, size, (gh, gw))
            indices, weights = bilinear_weights(fine, (gh, gw))
            rows = np.ascontiguousarray(sample_rows(self.pixel_major, indices, weights).T)
        prior = np.einsum(
            "i,is,is->s", self.eigenvalues, rows.astype(np.float64), rows.astype(np.float64)
        ).astype(np.float32)
        grid = VarianceGrid(
            size=size, component_rows=_read_only(rows), prior_variance=_read_only(prior)
        )
        self._variance_grids[stride] = grid
        return grid

    @cached_property
    def _prior_covariances(self) -> dict[int, npt.NDArray[np.float32] | None]:
        return {}

    def prior_covariance(self, stride: int) -> npt.NDArray[np.float32] | None:
        """Return U Lambda U_v^T, the prior covariance of basis grid and variance grid.

        (s, s_v) float32: row j is the covariance of grid pixel j with every point of
        :meth:`variance_grid` (stride). A measurement's row B~_j is a bilinear mix of grid
        rows, so B~ Lambda U_v^T is the same mix of rows of this matrix: 4 k s_v products
        instead of the k l s_v of a GEMM. Computed once per stride (l s s_v products,
        about a second for the KITTI-size basis); None when it would exceed
        :data:`PRIOR_COVARIANCE_MAX_BYTES`.
        """
        if stride in self._prior_covariances:
            return self._prior_covariances[stride]
        grid = self.variance_grid(stride)
        covariance = None
        if self.pixel_major.shape[0] * grid.prior_variance.shape[0] * 4 <= (
            PRIOR_COVARIANCE_MAX_BYTES
        ):
            scaled = grid.component_rows * self.eigenvalues.astype(np.float32)[:, None]
            covariance = _read_only(self.pixel_major @ scaled)
        self._prior_covariances[stride] = covariance
        return covariance

    def save(
        self,
        path: str | os.PathLike[str],
        *,
        partial_file: Callable[[Path], tuple[int, Path]] | None = None,
    ) -> None:
        """Write the basis as a ``pcainterp-basis/1`` .npz file, atomically.

        The file is written beside the target and renamed over it, so a crash never leaves
        a half-written basis.

        Args:
            path: destination file (conventionally ``.npz``); a symbolic link is written
                through.
            partial_file: makes the temporary beside the target and returns its open
                descriptor and path (``io.output_paths.make_partial_file``: owner-named,
                within the name limit, a killed save's removed); default ``mkstemp``.

        Raises:
            BasisError: ``path`` is a device, pipe or folder, or cannot be written.
        """
        target = Path(path)
        try:  # a name too long for its file system fails here (ENAMETOOLONG)
            if target.is_symlink():  # written through the link: the file it points to replaced
                target = Path(os.path.realpath(target))
        except OSError as err:
            raise BasisError(f"cannot write basis {target}: {err.strerror or err}") from err
        with contextlib.suppress(OSError):  # absent: a new file
            if not stat.S_ISREG(os.stat(target).st_mode):  # a rename would replace a device
                raise BasisError(
                    f"cannot write basis {path}: it is not a regular file; give a file path"
                )
        arrays: dict[str, npt.NDArray[Any]] = {
            "format": np.array(FORMAT),
            "mean": np.ascontiguousarray(self.mean, dtype=np.float32),
            "components": np.ascontiguousarray(self.components, dtype=np.float32),
            "eigenvalues": np.ascontiguousarray(self.eigenvalues, dtype=np.float64),
            "total_variance": np.array(self.total_variance, dtype=np.float64),
            "image_size": np.array(self.image_size, dtype=np.int64),
            "focal_baseline": np.array(self.focal_baseline, dtype=np.float64),
            "n_train": np.array(self.n_train, dtype=np.int64),
            "meta": np.array(json.dumps(self.meta, sort_keys=True)),
        }
        try:
            if partial_file is not None:
                handle, temp = partial_file(target)
            else:
                handle, name = tempfile.mkstemp(
                    prefix=f".{target.name}.", suffix=".tmp", dir=target.parent
                )
                temp = Path(name)
                umask = os.umask(0)  # mkstemp's 0600: give it a normally created file's mode
                os.umask(umask)
                os.fchmod(handle, 0o666 & ~umask)
        except OSError as err:
            raise BasisError(f"cannot write basis {target}: {err.strerror or err}") from err
        temp_name = str(temp)
        try:
            with os.fdopen(handle, "wb") as stream:
                np.savez(stream, **arrays)  # type: ignore[arg-type]
            raise_if_signalled()  # never committed after a signal
            os.replace(temp_name, target)
        except OSError as err:
            Path(temp_name).unlink(missing_ok=True)
            raise BasisError(f"cannot write basis {target}: {err.strerror or err}") from err
        except BaseException:
            Path(temp_name).unlink(missing_ok=True)
            raise

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Basis:
        """Read and validate a ``pcainterp-basis/1`` file.

        Args:
            path: the .npz file.

        Returns:
            The validated :class:`Basis`.

        Raises:
            BasisError: the file is missing, not an .npz, truncated, or a key is missing or
                has the wrong dtype, shape or non-finite values; the message names the file,
                the key and the problem.
        """
        path = Path(path)
        check_basis_file(path)
        try:
            # open the file ourselves: np.load leaks its handle when the archive is damaged
            with path.open("rb") as stream, np.load(stream, allow_pickle=False) as archive:
                missing = [key for key in _KEYS if key not in archive.files]
                if missing:
                    raise BasisError(
                        f"basis file {path} has no key {missing[0]!r}; "
                        "it is not a complete pcainterp-basis/1 file, re-run `pcainterp learn`"
                    )
                data = {key: archive[key] for key in _KEYS}
        except BasisError:
            raise
        except (zipfile.BadZipFile, EOFError, OSError, ValueError) as err:
            # a zip archive cut short or damaged (check_basis_file saw its first bytes)
            raise BasisError(
                f"basis file {path} is not a readable .npz archive ({err}); "
                "it is truncated or not a basis, re-run `pcainterp learn`"
            ) from err
        return _from_arrays(data, path)

    @classmethod
    def default(cls) -> Basis:
        """Return the built-in basis, learned from the synthetic world only.

        It is package data (``pcainterp_stream/data/default_basis.npz``), for the KITTI grey
        camera (1241 x 376 px, f*b ~ 386 px*m); ``densify`` maps it onto any other camera
        (docs/estimator.md, "Camera mapping"). Loaded and validated once per
        process and cached; what is slow to derive (the prior covariance, variance grids)
        stays lazy, as for any basis.

        Returns:
            The built-in :class:`Basis` (the same object on every call; its arrays are
            read-only).

        Raises:
            BasisError: the file is missing from this installation or damaged.
        """
        return _load_default(str(default_basis_path()))

    @classmethod
    def indoor(cls) -> Basis:
        """Return the built-in indoor basis, learned from synthetic rooms, corridors and halls.

        Package data (``pcainterp_stream/data/indoor_basis.npz``) for a 752 x 480 camera
        with f*b ~ 48 px*m (a VI-sensor), learned from walks seen at hand-held, drone and
        ground-robot heights by several cameras (68-102 degrees across), each view stretched
        onto that image as ``densify`` maps a log onto a basis. ``densify`` checks it
        against the street basis on the first frames of a log and uses the one that fits.

        Returns:
            The built-in indoor :class:`Basis` (the same object on every call).

        Raises:
            BasisError: the file is missing from this installation or damaged.
        """
        return _load_default(str(indoor_basis_path()))

    @cached_property
    def fingerprint(self) -> str:
        """Return a short content hash (16 hex digits) that tells bases apart.

        sha256 over every array and the camera, not the ``meta`` text: the same basis saved
        twice has the same fingerprint. A densified log records it, so that ``evaluate``
        can check it re-densifies with the basis the log was made with.
        """
        digest = hashlib.sha256()
        for array in (self.mean, self.components, self.eigenvalues):
            digest.update(np.ascontiguousarray(array).data.cast("B"))  # no copy
        digest.update(
            np.array(
                [*self.image_size, self.focal_baseline, self.total_variance, self.n_train],
                dtype=np.float64,
            ).tobytes()
        )
        return digest.hexdigest()[:16]


def default_basis_path() -> Path:
    """Return where the built-in basis file is installed (it may be missing).

    Returns:
        The path of ``pcainterp_stream/data/default_basis.npz`` in this installation.
    """
    package = importlib.resources.files("pcainterp_stream")
    return Path(str(package.joinpath("data", DEFAULT_BASIS_FILE)))


def indoor_basis_path() -> Path:
    """Return where the built-in indoor basis file is installed (it may be missing).

    Returns:
        The path of ``pcainterp_stream/data/indoor_basis.npz`` in this installation.
    """
    return default_basis_path().with_name(INDOOR_BASIS_FILE)


def default_basis_recipe(indoor: bool = False) -> dict[str, Any]:
    """Return a built-in basis's sidecar JSON (its sha256 and recipe); {} when absent.

    Args:
        indoor: the indoor basis's sidecar instead of the street one's.

    Returns:
        The parsed ``pcainterp_stream/data/default_basis.json`` (``indoor_basis.json``), or
        {} when it is missing or not a JSON object.
    """
    sidecar = (
        indoor_basis_path().with_name(INDOOR_BASIS_SIDECAR)
        if indoor
        else default_basis_path().with_name(DEFAULT_BASIS_SIDECAR)
    )
    try:
        recipe = json.loads(sidecar.read_text())
    except (OSError, ValueError):
        return {}
    return recipe if isinstance(recipe, dict) else {}


_DEFAULTS: dict[str, Basis] = {}
"""The built-in basis once loaded, by path (a test may point the package data elsewhere)."""


_DEFAULTS_LOCK = threading.Lock()
"""Held while a built-in basis loads: a load already under way (:func:`preload_builtin`) is
waited for, never repeated."""


def _load_default(path: str) -> Basis:
    """Load the built-in basis at ``path`` once and keep it."""
    cached = _DEFAULTS.get(path)
    if cached is not None:
        return cached
    with _DEFAULTS_LOCK:
        cached = _DEFAULTS.get(path)
        if cached is not None:
            return cached
        if not Path(path).is_file():
            raise BasisError(
                f"the built-in basis {path} is missing from this installation of "
                "pcainterp-stream; reinstall it (pip install .), or pass --basis BASIS.npz "
                "(learn one with `pcainterp learn`)"
            )
        basis = _DEFAULTS[path] = Basis.load(path)
        return basis


def preload_builtin(kind: str) -> None:
    """Start loading the built-in basis of a kind in a thread of its own, and return.

    Reading and checking the street basis (17 MB) takes ~0.03-0.08 s: a command that will
    need it starts the load first and does its other start-up work meanwhile; the first
    :func:`builtin_basis` call then waits for this load instead of making its own. The
    thread also computes the basis's :attr:`~Basis.fingerprint` (a densified log records
    it; sha256 of 17 MB, ~0.015-0.03 s, without the interpreter lock). An error (a missing
    or damaged file) is left for that call to raise.
    """

    def load() -> None:
        with contextlib.suppress(BasisError, ValueError, OSError):
            _ = builtin_basis(kind).fingerprint

    threading.Thread(target=load, name="basis-load", daemon=True).start()


def is_default(basis: Basis) -> bool:
    """Return True if ``basis`` is a built-in basis object (street or indoor)."""
    return any(basis is loaded for loaded in _DEFAULTS.values())


BUILTIN_KINDS = ("street", "indoor")
"""The built-in bases: :meth:`Basis.default` (street) and :meth:`Basis.indoor`."""

BUILTIN_LABELS = {"street": BUILT_IN, "indoor": BUILT_IN_INDOOR}
"""How a densified log names each built-in basis."""


def builtin_basis(kind: str) -> Basis:
    """Return the built-in basis of a kind ("street" or "indoor").

    Raises:
        ValueError: an unknown kind.
        BasisError: its file is missing from this installation or damaged.
    """
    if kind == "street":
        return Basis.default()
    if kind == "indoor":
        return Basis.indoor()
    raise ValueError(f"Expected a built-in basis kind in {BUILTIN_KINDS}, got {kind!r}")


def builtin_basis_installed(kind: str) -> bool:
    """Return whether the built-in basis of a kind is installed ("street" or "indoor")."""
    path = indoor_basis_path() if kind == "indoor" else default_basis_path()
    return path.is_file()


def builtin_kind(basis: Basis) -> str | None:
    """Return "street" or "indoor" if ``basis`` is that built-in basis object, else None."""
    for path, loaded in _DEFAULTS.items():
        if basis is loaded:
            return "indoor" if Path(path).name == INDOOR_BASIS_FILE else "street"
    return None


def _expect(
    data: dict[str, npt.NDArray[Any]],
    key: str,
    kind: str,
    ndim: int,
    where: Path,
) -> npt.NDArray[Any]:
    value = data[key]
    if value.dtype.kind not in kind:
        raise BasisError(
            f"basis file {where}: key {key!r} has dtype {value.dtype}, expected "
            f"{_KIND_NAMES[kind]}; the file is not a pcainterp-basis/1 basis"
        )
    if value.ndim != ndim:
        raise BasisError(
            f"basis file {where}: key {key!r} has shape {value.shape}, expected {ndim} "
            "dimensions; the file is not a pcainterp-basis/1 basis"
        )
    if value.dtype.kind == "f" and not np.all(np.isfinite(value)):
        raise BasisError(
            f"basis file {where}: key {key!r} has non-finite values; the basis is damaged, "
            "re-run `pcainterp learn`"
        )
    return value


_KIND_NAMES = {"U": "a string", "f": "floating point", "iu": "integer"}


def _from_arrays(data: dict[str, npt.NDArray[Any]], where: Path) -> Basis:
    fmt = _expect(data, "format", "U", 0, where)
    if str(fmt) != FORMAT:
        raise BasisError(
            f"basis file {where}: key 'format' is {str(fmt)!r}, expected {FORMAT!r}; "
            "this version reads only that format"
        )
    mean = _expect(data, "mean", "f", 2, where)
    components = _expect(data, "components", "f", 3, where)
    eigenvalues = _expect(data, "eigenvalues", "f", 1, where)
    total_variance = _expect(data, "total_variance", "f", 0, where)
    image_size = _expect(data, "image_size", "iu", 1, where)
    focal_baseline = _expect(data, "focal_baseline", "f", 0, where)
    n_train = _expect(data, "n_train", "iu", 0, where)
    meta_text = _expect(data, "meta", "U", 0, where)
    try:
        meta = json.loads(str(meta_text))
    except json.JSONDecodeError as err:
        raise BasisError(
            f"basis file {where}: key 'meta' is not valid JSON ({err}); the basis is damaged"
        ) from err
    if not isinstance(meta, dict):
        raise BasisError(f"basis file {where}: key 'meta' is not a JSON object; damaged basis")
    try:
        check_fitted_prior(meta)
    except ValueError as err:
        raise BasisError(f"basis file {where}: {err}") from err
    if image_size.shape != (2,):
        raise BasisError(
            f"basis file {where}: key 'image_size' has shape {image_size.shape}, expected (2,)"
        )
    naming = _NAMING.set(_file_key)
    try:
        # read-only: the arrays are the basis's own, and a loaded basis may be shared
        return Basis(
            mean=_read_only(mean.astype(np.float32, copy=False)),
            components=_read_only(components.astype(np.float32, copy=False)),
            eigenvalues=_read_only(eigenvalues.astype(np.float64, copy=False)),
            total_variance=float(total_variance),
            image_size=(int(image_size[0]), int(image_size[1])),
            focal_baseline=float(focal_baseline),
            n_train=int(n_train),
            meta=meta,
        )
    except ValueError as err:
        raise BasisError(f"basis file {where}: {err}") from err
    finally:
        _NAMING.reset(naming)


def _argument(name: str) -> str:
    return f"Basis argument `{name}`"


def _file_key(name: str) -> str:
    return f"key {name!r}"


_NAMING: contextvars.ContextVar[Callable[[str], str]] = contextvars.ContextVar(
    "basis_naming", default=_argument
)
"""How :func:`_check_arrays` names a field: an argument of ``Basis()``, or while
:func:`_from_arrays` builds a basis from a file, a key of that file."""


def _check_arrays(basis: Basis, name: Callable[[str], str]) -> None:
    """Validate shapes, order and orthonormality; raise ValueError naming the problem.

    Args:
        basis: the basis to check.
        name: how to name a field in a message (``key 'mean'`` for a file).
    """
    if basis.mean.ndim != 2:
        raise ValueError(f"{name('mean')} must be (gh, gw), got shape {basis.mean.shape}")
    if basis.components.ndim != 3 or basis.components.shape[1:] != basis.mean.shape:
        raise ValueError(
            f"{name('components')} has shape {basis.components.shape}, expected "
            f"(l, {basis.mean.shape[0]}, {basis.mean.shape[1]}) to match 'mean'"
        )
    n_components = basis.components.shape[0]
    if n_components == 0:
        raise ValueError(
            f"{name('components')} holds no component; learn the basis again from maps that vary"
        )
    if basis.eigenvalues.shape != (n_components,):
        raise ValueError(
            f"{name('eigenvalues')} has shape {basis.eigenvalues.shape}, expected ({n_components},)"
        )
    if np.any(basis.eigenvalues < 0) or np.any(np.diff(basis.eigenvalues) > 0):
        raise ValueError(f"{name('eigenvalues')} must be non-negative and descending")
    if basis.image_size[0] < 1 or basis.image_size[1] < 1:
        raise ValueError(f"{name('image_size')} must be positive, got {basis.image_size}")
    if not (np.isfinite(basis.focal_baseline) and basis.focal_baseline >= 0):
        raise ValueError(
            f"{name('focal_baseline')} must be finite and >= 0 (px*m; 0 when unknown), "
            f"got {basis.focal_baseline}"
        )
    if basis.n_train < 0:
        raise ValueError(f"{name('n_train')} must be >= 0, got {basis.n_train}")
    # float32 Gram (s * l^2 flops): its rounding, ~sqrt(s) * 6e-8, is far below the tolerance.
    # One BLAS thread: on a busy 2-core machine a two-thread OpenBLAS spun 0.7 s on the
    # 150-component KITTI-size Gram that one thread does in 0.02 s.
    rows = basis.components.reshape(n_components, -1).astype(np.float32, copy=False)
    with threadpool_limits(1, user_api="blas"):
        gram = rows @ rows.T
    error = float(np.abs(gram - np.eye(n_components, dtype=np.float32)).max())
    if error > ORTHONORMALITY_TOLERANCE:
        raise ValueError(
            f"{name('components')} is not orthonormal over grid pixels (max |B^T B - I| = "
            f"{error:.3g} > {ORTHONORMALITY_TOLERANCE})"
        )
