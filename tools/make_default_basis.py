"""Regenerate the built-in default basis (``pcainterp_stream/data/default_basis.npz``) from seeds.

The basis is learned only from the project's own synthetic world, so its licence is the
project's: the true depth of many distinct synthetic drives (seeds ``first_seed`` on), every
``step``-th of ``frames`` frames, rendered for the KITTI grey camera, as the camera of the
synthetic drives sees them. The recipe can also give each map its own camera placement
(``pitch_px``: the horizon moved, a vertical shift of the principal point that the
level-only renderer can draw; ``roll_deg``: the depth image rotated about the principal
point; camera height and place across the road): measured on the real KITTI clips, that made
the basis worse (docs/bases.md, "The built-in basis"), so the shipped recipe has none.
``--indoor-seeds N`` adds N synthetic indoor walks (rooms, corridors, halls; hand-held, drone
and ground-robot placements), seen by the same camera: measured, even 0.8-2 % of indoor
maps cost the real KITTI clips 4-5 % while much improving indoor logs (docs/bases.md,
"A built-in basis for streets and rooms?"), so the shipped recipe has none either.

The hybrid prior's local kernel is fixed by the recipe (``local_kernel``): the evidence on
synthetic frames, which the basis explains well, picks a weak short kernel (Gaussian 8-16 px,
v ~2 px^2) that leaves the basis alone on real streets, which it explains less well; the
kernel was chosen among a few on the two real KITTI clips, each choice made on one clip and
checked on the other (docs/bases.md). sigma, the temporal process noise and the std
calibration are then fitted as ``pcainterp learn`` fits them, on the front end's
measurements of a separate synthetic drive (``fit_seed``): no real map is in the basis.

``--indoor`` makes the second built-in basis, ``indoor_basis.npz`` (:class:`IndoorRecipe`):
150 synthetic indoor walks (rooms, corridors, halls with clutter; hand-held, drone and
ground-robot heights and pitches; each seen by one of four cameras, 68-102 degrees across,
stretched onto a 752x480 image with disparity in that camera's f*b), 30 components, the
prior fitted by the evidence on a separate synthetic indoor log. ``densify`` checks it
against the street basis on the first frames of a log and uses the one that fits.

    python tools/make_default_basis.py                 # the shipped street basis (minutes)
    python tools/make_default_basis.py --indoor        # the shipped indoor basis (~10 min)
    python tools/make_default_basis.py --small --out /tmp/small   # the test's small recipe
    python tools/make_default_basis.py --indoor --small --out /tmp/small

Writes ``default_basis.npz`` and ``default_basis.json`` (``indoor_basis.*`` with
``--indoor``: the recipe, the file's sha256 and size, the command and the run time) into
``--out``. The same recipe gives the same bytes on
the same platform and library versions (``content_sha256`` in the sidecar: the arrays and the
metadata; the zip's own bytes carry write times): rendering is quantised, BLAS runs on one
thread.
``--work-dir`` caches the rendered maps of each drive between runs.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import harness
import numpy as np
import numpy.typing as npt

DEFAULT_OUT = harness.REPO / "pcainterp_stream" / "data"
NAME = "default_basis"


@dataclass(frozen=True)
class Recipe:
    """Everything the default basis is made from (stored in its metadata and sidecar)."""

    first_seed: int = 1000
    drives: int = 200
    frames: int = 300
    step: int = 10
    components: int = 150
    grid_scale: float = 0.25
    pitch_px: float = 0.0
    roll_deg: float = 0.0
    height_m: tuple[float, float] = (0.0, 0.0)
    lateral_m: tuple[float, float] = (0.0, 0.0)
    fit_seed: int = 150
    fit_frames: int = 40
    local_kernel: tuple[str, float, float] | None = ("laplace", 64.0, 40.0)
    # the edge-aware kernel's weight between cells (1: stationary), chosen on the real clips
    # (docs/sharper_sparse.md); the fit does not use it (no SGBM partitions there)
    cell_weight: float = 0.75
    indoor_seeds: int = 0
    indoor_first_seed: int = 5000
    indoor_frames: int = 120
    indoor_step: int = 10
    indoor_render_scale: float = 0.5

    @property
    def varied(self) -> bool:
        """Whether the maps get their own camera placement (any range not zero)."""
        return any((self.pitch_px, self.roll_deg, *self.height_m, *self.lateral_m))

    @property
    def maps(self) -> int:
        """Training maps: ``drives`` x ceil(frames / step), plus the indoor walks' maps."""
        street = self.drives * len(range(0, self.frames, self.step))
        return street + self.indoor_seeds * len(range(0, self.indoor_frames, self.indoor_step))


SMALL = Recipe(drives=4, frames=40, step=10, components=12, fit_frames=8)
"""A small recipe for the regeneration test (seconds, not minutes)."""

INDOOR_NAME = "indoor_basis"

INDOOR_CAMERAS = ("752x480", "640x480", "1280x720", "fisheye-752x480")
"""The ``synth --camera`` presets the indoor walks are seen by (one per walk, by its seed):
several fields of view (68-102 degrees across)."""


@dataclass(frozen=True)
class IndoorRecipe:
    """Everything the built-in indoor basis is made from (metadata and sidecar).

    ``walks`` synthetic indoor walks (seeds ``first_seed`` on): a room, corridor or hall
    with clutter, a hand-held, drone or ground-robot placement, and a camera among
    :data:`INDOOR_CAMERAS`, all drawn from the seed as ``pcainterp synth --scene indoor``
    draws them; every ``step``-th of ``frames`` frames, ray cast at ``render_scale`` of that
    camera's size. Each view is stretched onto the basis camera's image (``camera``), the
    way ``densify`` maps a log onto a basis, and stored as disparity in the basis camera's
    units (its f*b over the true depth). The prior (sigma, local kernel, process noise,
    std calibration) is fitted on the front end's measurements of a separate indoor log
    (``fit_seed``, ``fit_camera``) by the evidence, as ``pcainterp learn`` fits it.
    """

    camera: str = "752x480"
    first_seed: int = 5000
    walks: int = 150
    frames: int = 120
    step: int = 10
    render_scale: float = 0.5
    components: int = 30
    grid_scale: float = 0.25
    fit_seed: int = 9000
    fit_frames: int = 40
    fit_camera: str = "752x480"

    @property
    def maps(self) -> int:
        """Training maps: ``walks`` x ceil(frames / step)."""
        return self.walks * len(range(0, self.frames, self.step))


INDOOR_SMALL = IndoorRecipe(walks=3, frames=40, components=8, fit_frames=6)
"""A small indoor recipe for the regeneration test."""


# ----------------------------------------------------------------------------- rendering


def drive_maps(job: tuple[Recipe, int, tuple[int, int]]) -> npt.NDArray[np.float32]:
    """The preprocessed grid maps (n, gh, gw) of one drive, each with its own camera placement."""
    import cv2

    from pcainterp_stream.estimate.learning import preprocess_disparity
    from pcainterp_stream.evaluate.metrics import disparity_from_depth
    from pcainterp_stream.synth import SynthConfig, camera_pose
    from pcainterp_stream.synth.render import render_view
    from pcainterp_stream.synth.world import World

    recipe, seed, grid = job
    config = SynthConfig(seed=seed, frames=recipe.frames)
    camera = config.camera
    world = World(seed)
    rng = np.random.default_rng([seed, 77])
    maps = []
    for index in range(0, recipe.frames, recipe.step):
        pose = camera_pose(world, config, index).copy()
        shift = float(rng.uniform(-recipe.pitch_px, recipe.pitch_px))
        roll = float(rng.uniform(-recipe.roll_deg, recipe.roll_deg))
        pose[2, 3] += float(rng.uniform(*recipe.height_m))
        pose[:3, 3] += float(rng.uniform(*recipe.lateral_m)) * pose[:3, 0]
        placed = dataclasses.replace(camera, cy=camera.cy + shift)
        depth = render_view(world, placed, pose).depth.astype(np.float32)
        if roll:
            rotation = cv2.getRotationMatrix2D((placed.cx, placed.cy), roll, 1.0)
            depth = cv2.warpAffine(  # nearest: never a depth between two surfaces
                depth,
                rotation,
                (camera.width, camera.height),
                flags=cv2.INTER_NEAREST,
                borderMode=cv2.BORDER_REPLICATE,
            ).astype(np.float32)
        disparity = disparity_from_depth(depth, camera.focal_baseline).astype(np.float32)
        maps.append(preprocess_disparity(disparity, grid))
    return np.stack(maps)


def indoor_maps(job: tuple[Recipe, int, tuple[int, int]]) -> npt.NDArray[np.float32]:
    """The preprocessed grid maps (n, gh, gw) of one indoor walk, seen by the basis's camera.

    The room, corridor or hall and the platform (hand-held, drone, ground robot: height and
    pitch) follow the seed as ``pcainterp synth --scene indoor`` draws them. The view is
    ray cast at ``indoor_render_scale`` of the basis camera's size (the same angles) and
    enlarged by nearest neighbour before the usual preprocessing (box filter, area
    resampling to the grid), which a 1/4 grid barely tells apart from a full-size render.
    Disparity is f*b of the basis camera over depth: inverse depth in the basis's units.
    """
    import cv2

    from pcainterp_stream.estimate.learning import preprocess_disparity
    from pcainterp_stream.evaluate.metrics import disparity_from_depth
    from pcainterp_stream.synth import SynthConfig, indoor

    recipe, seed, grid = job
    full = SynthConfig().camera
    camera = SynthConfig(scale=recipe.indoor_render_scale).camera
    scene = indoor.make_scene(seed, indoor.scene_for("indoor", seed))
    trajectory = indoor.make_trajectory(seed, scene, indoor.platform_for("auto", seed))
    tile = indoor.texture_tile(seed)
    maps = []
    for index in range(0, recipe.indoor_frames, recipe.indoor_step):
        pose = indoor.indoor_pose(scene, trajectory, index, recipe.indoor_frames)
        _, depth = indoor.render_indoor(scene, camera, pose, tile)
        enlarged = cv2.resize(depth, (full.width, full.height), interpolation=cv2.INTER_NEAREST)
        disparity = disparity_from_depth(enlarged, full.focal_baseline).astype(np.float32)
        maps.append(preprocess_disparity(disparity, grid))
    return np.stack(maps)


def indoor_walk_maps(job: tuple[IndoorRecipe, int, tuple[int, int]]) -> npt.NDArray[np.float32]:
    """The preprocessed grid maps (n, gh, gw) of one walk of the indoor basis's recipe.

    The walk's camera (:data:`INDOOR_CAMERAS`, by the seed) is ray cast at
    ``render_scale`` of its size, enlarged by nearest neighbour to the basis camera's image
    (a stretch, as densify maps any camera onto the basis), turned into disparity in the
    basis camera's units, box-filtered and area-resampled to the grid.
    """
    import cv2

    from pcainterp_stream.estimate.learning import preprocess_disparity
    from pcainterp_stream.evaluate.metrics import disparity_from_depth
    from pcainterp_stream.synth import SynthConfig, indoor

    recipe, seed, grid = job
    basis_camera = SynthConfig(**indoor.camera_options(recipe.camera)).camera
    preset = INDOOR_CAMERAS[(seed // 9) % len(INDOOR_CAMERAS)]  # 9 scene x platform pairs
    camera = SynthConfig(scale=recipe.render_scale, **indoor.camera_options(preset)).camera
    scene = indoor.make_scene(seed, indoor.scene_for("indoor", seed))
    trajectory = indoor.make_trajectory(seed, scene, indoor.platform_for("auto", seed))
    tile = indoor.texture_tile(seed)
    size = (basis_camera.width, basis_camera.height)
    maps = []
    for index in range(0, recipe.frames, recipe.step):
        pose = indoor.indoor_pose(scene, trajectory, index, recipe.frames)
        _, depth = indoor.render_indoor(scene, camera, pose, tile)
        enlarged = cv2.resize(depth, size, interpolation=cv2.INTER_NEAREST)
        disparity = disparity_from_depth(enlarged, basis_camera.focal_baseline)
        maps.append(preprocess_disparity(disparity.astype(np.float32), grid))
    return np.stack(maps)


def _cached_maps(
    render: Callable[[tuple[Any, int, tuple[int, int]]], npt.NDArray[np.float32]],
    jobs: tuple[Any, range, tuple[int, int]],
    key: str,
    cache: Path | None,
    what: str,
    every: int,
) -> npt.NDArray[np.float32]:
    """Render ``render`` for every seed (in a process pool), cached per seed; in seed order."""
    recipe, seeds, grid = jobs
    parts: dict[int, npt.NDArray[np.float32]] = {}
    paths = {seed: None if cache is None else cache / f"{key[:12]}_{seed}.npy" for seed in seeds}
    for seed, path in paths.items():
        if path is not None and path.is_file():
            parts[seed] = np.load(path)
    missing = [seed for seed in seeds if seed not in parts]
    started = time.perf_counter()
    with ProcessPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        arguments = [(recipe, seed, grid) for seed in missing]
        for done, (seed, maps) in enumerate(
            zip(missing, pool.map(render, arguments), strict=True), start=1
        ):
            parts[seed] = maps
            path = paths[seed]
            if path is not None:
                np.save(path, maps)
            if done % every == 0 or done == len(missing):
                seconds = time.perf_counter() - started
                harness.log(f"rendered {done}/{len(missing)} {what} ({seconds:.0f} s)")
    return np.concatenate([parts[seed] for seed in seeds])


def render_maps(recipe: Recipe, cache: Path | None) -> npt.NDArray[np.float32]:
    """All training maps of the recipe, in seed order (cached per drive in ``cache``)."""
    from pcainterp_stream.estimate.basis import grid_size_for
    from pcainterp_stream.synth import SynthConfig

    camera = SynthConfig().camera
    grid = grid_size_for((camera.height, camera.width), recipe.grid_scale)
    seeds = range(recipe.first_seed, recipe.first_seed + recipe.drives)
    variety = (recipe.pitch_px, recipe.roll_deg, recipe.height_m, recipe.lateral_m)
    key = hashlib.sha256(repr((recipe.frames, recipe.step, grid, variety)).encode()).hexdigest()
    street = _cached_maps(drive_maps, (recipe, seeds, grid), key, cache, "drives", 20)
    if recipe.indoor_seeds <= 0:
        return street
    walks = range(recipe.indoor_first_seed, recipe.indoor_first_seed + recipe.indoor_seeds)
    view = (recipe.indoor_frames, recipe.indoor_step, recipe.indoor_render_scale, grid)
    key = hashlib.sha256(repr(("indoor", view)).encode()).hexdigest()
    rooms = _cached_maps(indoor_maps, (recipe, walks, grid), key, cache, "indoor walks", 10)
    return np.concatenate([street, rooms])


# ----------------------------------------------------------------------------- learning


def content_sha256(path: Path) -> str:
    """The sha256 of a basis file's arrays and metadata (names, dtypes, shapes, bytes).

    What a regeneration reproduces: the file's own bytes also hold the zip entries' write
    times, which differ on every run.
    """
    digest = hashlib.sha256()
    with np.load(path) as arrays:
        for name in sorted(arrays.files):
            value = np.ascontiguousarray(arrays[name])
            digest.update(f"{name}:{value.dtype.str}:{value.shape}:".encode())
            digest.update(value.tobytes())
    return digest.hexdigest()


def make(recipe: Recipe, out: Path, cache: Path | None, command: str) -> dict[str, Any]:
    """Render, learn, fit and write the basis and its sidecar into ``out``; return the sidecar."""
    import cv2
    from threadpoolctl import threadpool_limits

    from pcainterp_stream.estimate.prior import Kernel, LocalPrior
    from pcainterp_stream.frontend.pairing import PairingConfig
    from pcainterp_stream.pipeline.jobs import synth
    from pcainterp_stream.pipeline.learn import LearnOptions, fit_prior
    from pcainterp_stream.synth import SynthConfig

    cv2.setNumThreads(1)  # the fit's front end and resampling: one thread, the same bytes
    started = time.perf_counter()
    maps = render_maps(recipe, cache)
    harness.log(f"{maps.shape[0]} maps of {recipe.drives} drives")
    camera = SynthConfig().camera
    recipe_meta = dataclasses.asdict(recipe)
    meta = {
        "source": {
            "maps": "synthetic ground-truth depth (true disparity)"
            + (", per-map camera placement" if recipe.varied else ""),
            "drives": recipe.drives,
            "seeds": [recipe.first_seed, recipe.first_seed + recipe.drives - 1],
            "frames_per_drive": len(range(0, recipe.frames, recipe.step)),
            **(
                {
                    "indoor_walks": recipe.indoor_seeds,
                    "indoor_seeds": [
                        recipe.indoor_first_seed,
                        recipe.indoor_first_seed + recipe.indoor_seeds - 1,
                    ],
                    "indoor_maps_per_walk": len(range(0, recipe.indoor_frames, recipe.indoor_step)),
                    "indoor": "rooms, corridors, halls with clutter; hand-held, drone and "
                    "ground-robot heights and pitches (as synth --scene indoor draws them), "
                    "seen by the basis's camera; disparity = its f*b / depth",
                }
                if recipe.indoor_seeds > 0
                else {}
            ),
        },
        "recipe": recipe_meta,
        "command": command,
        "license": "the project's own (learned only from its synthetic world)",
    }
    basis = _learn(
        maps,
        recipe.components,
        recipe.grid_scale,
        (camera.height, camera.width),
        camera.focal_baseline,
        meta,
    )
    harness.log(f"learned {basis.n_components} components ({time.perf_counter() - started:.0f} s)")
    del maps
    with tempfile.TemporaryDirectory() as scratch:
        fit_log = Path(scratch) / f"fit_s{recipe.fit_seed}.mcap"
        synth(fit_log, frames=recipe.fit_frames, seed=recipe.fit_seed, scale=1.0, fmt=None)
        local = None
        if recipe.local_kernel is not None:
            kernel, length_scale, variance = recipe.local_kernel
            local = LocalPrior(variance, length_scale, Kernel(kernel), recipe.cell_weight)
        with threadpool_limits(1, user_api="blas"):
            fitted = fit_prior(basis, [(fit_log, 0)], LearnOptions(), PairingConfig(), local)
    fitted.pop("seconds", None)  # keep the file's bytes independent of the machine's speed
    fitted["fit_logs"] = [f"pcainterp synth --frames {recipe.fit_frames} --seed {recipe.fit_seed}"]
    meta = {**basis.meta, "prior": fitted}
    basis = dataclasses.replace(basis, meta=meta)
    return _write(basis, out, NAME, recipe_meta, command, started)


def update_cell_weight(recipe: Recipe, out: Path) -> dict[str, Any]:
    """Write ``recipe.cell_weight`` into the basis in ``out`` as `make` would; return its sidecar.

    The weight changes nothing :func:`make` computes (the fit runs without SGBM partitions),
    so the arrays and every fitted number stay; only the metadata (the kernel, its row of
    the fit's candidates, the recipe) and the sidecar's hashes change.
    """
    from pcainterp_stream.estimate.basis import Basis
    from pcainterp_stream.estimate.prior import LocalPrior

    path = out / f"{NAME}.npz"
    basis = Basis.load(path)
    stored = dict(basis.meta["recipe"])
    wanted = json.loads(json.dumps(dataclasses.asdict(recipe)))
    changed = sorted(k for k in stored if k != "cell_weight" and stored[k] != wanted.get(k))
    if changed:
        raise SystemExit(f"error: the recipe changed {changed} as well; regenerate the basis")
    prior = dict(basis.meta["prior"])
    local = dataclasses.replace(
        LocalPrior.from_meta(prior["local"]), cell_weight=recipe.cell_weight
    )
    kernel = local.to_meta()
    prior["local"] = kernel
    prior["candidates"] = [
        {**row, **kernel}
        if (row.get("kernel"), row.get("length_scale"))
        == (kernel["kernel"], kernel["length_scale"])
        else row
        for row in prior["candidates"]
    ]
    stored["cell_weight"] = recipe.cell_weight
    basis = dataclasses.replace(basis, meta={**basis.meta, "prior": prior, "recipe": stored})
    basis.save(path)
    sidecar_path = out / f"{NAME}.json"
    sidecar = json.loads(sidecar_path.read_text())
    data = path.read_bytes()
    sidecar.update(
        sha256=hashlib.sha256(data).hexdigest(),
        content_sha256=content_sha256(path),
        bytes=len(data),
        recipe={**sidecar["recipe"], "cell_weight": recipe.cell_weight},
    )
    harness.write_json(sidecar_path, sidecar, indent=2)
    return dict(sidecar)


def make_indoor(
    recipe: IndoorRecipe, out: Path, cache: Path | None, command: str
) -> dict[str, Any]:
    """Render, learn, fit and write the built-in indoor basis and its sidecar into ``out``."""
    import cv2
    from threadpoolctl import threadpool_limits

    from pcainterp_stream.estimate.basis import grid_size_for
    from pcainterp_stream.frontend.pairing import PairingConfig
    from pcainterp_stream.pipeline.jobs import synth
    from pcainterp_stream.pipeline.learn import LearnOptions, fit_prior
    from pcainterp_stream.synth import SynthConfig, indoor

    cv2.setNumThreads(1)
    started = time.perf_counter()
    camera = SynthConfig(**indoor.camera_options(recipe.camera)).camera
    size = (camera.height, camera.width)
    grid = grid_size_for(size, recipe.grid_scale)
    seeds = range(recipe.first_seed, recipe.first_seed + recipe.walks)
    view = (recipe.camera, recipe.frames, recipe.step, recipe.render_scale, grid, INDOOR_CAMERAS)
    key = hashlib.sha256(repr(("indoor-basis", view)).encode()).hexdigest()
    maps = _cached_maps(indoor_walk_maps, (recipe, seeds, grid), key, cache, "indoor walks", 20)
    harness.log(f"{maps.shape[0]} maps of {recipe.walks} indoor walks")
    recipe_meta = dataclasses.asdict(recipe)
    meta = {
        "source": {
            "maps": "synthetic ground-truth depth (true disparity) of indoor walks",
            "indoor_walks": recipe.walks,
            "indoor_seeds": [recipe.first_seed, recipe.first_seed + recipe.walks - 1],
            "indoor_maps_per_walk": len(range(0, recipe.frames, recipe.step)),
            "indoor": "rooms, corridors, halls with clutter; hand-held, drone and ground-robot "
            "heights and pitches (as synth --scene indoor draws them)",
            "cameras": list(INDOOR_CAMERAS),
            "camera_mapping": "each camera's view stretched onto the basis image, disparity = "
            "the basis camera's f*b / depth",
        },
        "recipe": recipe_meta,
        "command": command,
        "license": "the project's own (learned only from its synthetic world)",
    }
    basis = _learn(maps, recipe.components, recipe.grid_scale, size, camera.focal_baseline, meta)
    harness.log(f"learned {basis.n_components} components ({time.perf_counter() - started:.0f} s)")
    del maps
    with tempfile.TemporaryDirectory() as scratch:
        fit_log = Path(scratch) / f"fit_indoor_s{recipe.fit_seed}.mcap"
        synth(
            fit_log,
            frames=recipe.fit_frames,
            seed=recipe.fit_seed,
            scale=1.0,
            fmt=None,
            scene="indoor",
            camera=recipe.fit_camera,
        )
        with threadpool_limits(1, user_api="blas"):
            fitted = fit_prior(basis, [(fit_log, 0)], LearnOptions(), PairingConfig())
    fitted.pop("seconds", None)
    fitted["fit_logs"] = [
        f"pcainterp synth --scene indoor --camera {recipe.fit_camera} "
        f"--frames {recipe.fit_frames} --seed {recipe.fit_seed}"
    ]
    basis = dataclasses.replace(basis, meta={**basis.meta, "prior": fitted})
    return _write(basis, out, INDOOR_NAME, recipe_meta, command, started)


def _write(
    basis: Any, out: Path, name: str, recipe_meta: dict[str, Any], command: str, started: float
) -> dict[str, Any]:
    """Save ``basis`` as ``out/name.npz`` with its sidecar ``out/name.json``; return the sidecar."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.npz"
    basis.save(path)
    data = path.read_bytes()
    sidecar = {
        "file": path.name,
        "sha256": hashlib.sha256(data).hexdigest(),
        "content_sha256": content_sha256(path),
        "bytes": len(data),
        "recipe": recipe_meta,
        "command": command,
        "seconds": round(time.perf_counter() - started, 1),
    }
    harness.write_json(out / f"{name}.json", sidecar, indent=2)
    return sidecar


def _learn(
    maps: Any,
    components: int,
    grid_scale: float,
    size: tuple[int, int],
    focal_baseline: float,
    meta: dict[str, Any],
) -> Any:
    """Learn a basis from preprocessed maps on one BLAS thread (the same bytes every run)."""
    from threadpoolctl import threadpool_limits

    from pcainterp_stream.estimate.learning import learn_basis

    with threadpool_limits(1, user_api="blas"):
        return learn_basis(
            iter(maps),
            n_components=min(components, maps.shape[0] - 1),
            grid_scale=grid_scale,
            preprocessed=True,
            image_size=size,
            focal_baseline=focal_baseline,
            meta=meta,
            exact_max_maps=15_000,
            exact_max_bytes=8 << 30,
        )


def main(argv: Sequence[str] | None = None) -> int:
    """Make the default basis; print its sidecar."""
    parser = harness.argument_parser(__doc__)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output folder")
    parser.add_argument("--work-dir", type=Path, help="cache the rendered maps here")
    parser.add_argument("--small", action="store_true", help="the small test recipe")
    parser.add_argument(
        "--indoor",
        action="store_true",
        help="make the built-in indoor basis (indoor_basis.npz) instead of the street one",
    )
    parser.add_argument(
        "--walks", type=int, help="with --indoor: override the recipe's number of walks"
    )
    parser.add_argument(
        "--cell-weight-only",
        action="store_true",
        help="write the recipe's cell_weight into the basis in --out (no re-rendering)",
    )
    for field in ("drives", "frames", "step", "components", "indoor_seeds"):
        flag = field.replace("_", "-")
        parser.add_argument(
            f"--{flag}", type=int, dest=field, help=f"override the recipe's {field}"
        )
    args = parser.parse_args(argv)
    cache = None if args.work_dir is None else harness.work_dir(args.work_dir)
    if args.indoor:
        return _main_indoor(args, cache)
    recipe = SMALL if args.small else Recipe()
    fields = ("drives", "frames", "step", "components", "indoor_seeds")
    overrides = {f: getattr(args, f) for f in fields}
    recipe = dataclasses.replace(recipe, **{k: v for k, v in overrides.items() if v is not None})
    if args.cell_weight_only:
        print(json.dumps(update_cell_weight(recipe, args.out), indent=2))
        return 0
    # the recipe's options only: where the files go does not change what they hold
    command = "python tools/make_default_basis.py" + (" --small" if args.small else "")
    command += "".join(
        f" --{key.replace('_', '-')} {value}"
        for key, value in overrides.items()
        if value is not None
    )
    sidecar = make(recipe, args.out, cache, command)
    print(json.dumps(sidecar, indent=2))
    return 0


def _main_indoor(args: Any, cache: Path | None) -> int:
    """``--indoor``: make the built-in indoor basis; print its sidecar."""
    if args.drives is not None or args.indoor_seeds is not None:
        print("error: --drives and --indoor-seeds are street options; with --indoor use --walks")
        return 2
    recipe = INDOOR_SMALL if args.small else IndoorRecipe()
    overrides = {
        "walks": args.walks,
        "frames": args.frames,
        "step": args.step,
        "components": args.components,
    }
    recipe = dataclasses.replace(recipe, **{k: v for k, v in overrides.items() if v is not None})
    command = "python tools/make_default_basis.py --indoor" + (" --small" if args.small else "")
    command += "".join(f" --{key} {value}" for key, value in overrides.items() if value is not None)
    sidecar = make_indoor(recipe, args.out, cache, command)
    print(json.dumps(sidecar, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
