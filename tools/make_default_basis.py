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

    python tools/make_default_basis.py                 # the shipped file (minutes)
    python tools/make_default_basis.py --small --out /tmp/small   # the test's small recipe

Writes ``default_basis.npz`` and ``default_basis.json`` (the recipe, the file's sha256 and
size, the command and the run time) into ``--out``. The same recipe gives the same bytes on
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


def _cached_maps(
    render: Callable[[tuple[Recipe, int, tuple[int, int]]], npt.NDArray[np.float32]],
    jobs: tuple[Recipe, range, tuple[int, int]],
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

    from pcainterp_stream.estimate.learning import learn_basis
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
    with threadpool_limits(1, user_api="blas"):  # one thread: the same bytes every run
        basis = learn_basis(
            iter(maps),
            n_components=min(recipe.components, maps.shape[0] - 1),
            grid_scale=recipe.grid_scale,
            preprocessed=True,
            image_size=(camera.height, camera.width),
            focal_baseline=camera.focal_baseline,
            meta=meta,
            exact_max_maps=15_000,
            exact_max_bytes=8 << 30,
        )
    harness.log(f"learned {basis.n_components} components ({time.perf_counter() - started:.0f} s)")
    del maps
    with tempfile.TemporaryDirectory() as scratch:
        fit_log = Path(scratch) / f"fit_s{recipe.fit_seed}.mcap"
        synth(fit_log, frames=recipe.fit_frames, seed=recipe.fit_seed, scale=1.0, fmt=None)
        local = None
        if recipe.local_kernel is not None:
            kernel, length_scale, variance = recipe.local_kernel
            local = LocalPrior(variance, length_scale, Kernel(kernel))
        with threadpool_limits(1, user_api="blas"):
            fitted = fit_prior(basis, [(fit_log, 0)], LearnOptions(), PairingConfig(), local)
    fitted.pop("seconds", None)  # keep the file's bytes independent of the machine's speed
    fitted["fit_logs"] = [f"pcainterp synth --frames {recipe.fit_frames} --seed {recipe.fit_seed}"]
    meta = {**basis.meta, "prior": fitted}
    basis = dataclasses.replace(basis, meta=meta)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{NAME}.npz"
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
    harness.write_json(out / f"{NAME}.json", sidecar, indent=2)
    return sidecar


def main(argv: Sequence[str] | None = None) -> int:
    """Make the default basis; print its sidecar."""
    parser = harness.argument_parser(__doc__)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output folder")
    parser.add_argument("--work-dir", type=Path, help="cache the rendered maps here")
    parser.add_argument("--small", action="store_true", help="the small test recipe")
    for field in ("drives", "frames", "step", "components", "indoor_seeds"):
        flag = field.replace("_", "-")
        parser.add_argument(
            f"--{flag}", type=int, dest=field, help=f"override the recipe's {field}"
        )
    args = parser.parse_args(argv)
    recipe = SMALL if args.small else Recipe()
    fields = ("drives", "frames", "step", "components", "indoor_seeds")
    overrides = {f: getattr(args, f) for f in fields}
    recipe = dataclasses.replace(recipe, **{k: v for k, v in overrides.items() if v is not None})
    # the recipe's options only: where the files go does not change what they hold
    command = "python tools/make_default_basis.py" + (" --small" if args.small else "")
    command += "".join(
        f" --{key.replace('_', '-')} {value}"
        for key, value in overrides.items()
        if value is not None
    )
    cache = None if args.work_dir is None else harness.work_dir(args.work_dir)
    sidecar = make(recipe, args.out, cache, command)
    print(json.dumps(sidecar, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
