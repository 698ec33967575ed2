"""The stored std's +-2 sigma coverage by region of a densified log, and of widenings of it.

Reads a log written by ``pcainterp densify`` as ``pcainterp evaluate`` does (its frame
reader and reference: ``/ground_truth/depth``, else ``/ground_truth/lidar_depth``, else a
full-resolution SGBM map of the pair, stereo mode) and prints, for the stored std and for
``variance.widen_off_plane`` at several settings (a, sigma, window, b): +-2 sigma over all
counted pixels, +-1 sigma, the mean Gaussian negative log-likelihood (nats), +-2 sigma at
depth edges / on smooth surfaces (edge: the 7x7 range of the nearest-filled reference
> 2 px and > 15 % of its value), within 4 px of a reference step (a jump > 2 px and
> 15 % between 4-neighbours) and in the outermost 8 px. The widenings need only the
estimate and the stored std, so they are applied here, after the fact (bug hunt 17D;
docs/options.md, "The std at depth edges and at the border").

Example::

    pcainterp densify street.mcap -o street_dense.mcap
    python tools/std_regions.py street_dense.mcap --every 1
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.ndimage import distance_transform_edt, maximum_filter, minimum_filter

from pcainterp_stream.estimate.variance import widen_off_plane
from pcainterp_stream.evaluate.input_pair import follow_densify
from pcainterp_stream.evaluate.left_out import reference_tolerance
from pcainterp_stream.evaluate.log_frames import GROUND_TRUTH_DEPTH, ReadState, read_frames
from pcainterp_stream.evaluate.metrics import (
    ReferenceKind,
    disparity_from_reference,
    fill_nearest,
    reference_view,
    stereo_transform,
)
from pcainterp_stream.evaluate.reference import reference_disparity, resolve_reference
from pcainterp_stream.frontend.images import PairImages
from pcainterp_stream.frontend.sgbm_limits import fitting
from pcainterp_stream.frontend.stereo import SgbmConfig, compute_disparity
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.outputs import OutputTopics
from pcainterp_stream.io.stereo_log import LIDAR_DEPTH

Array = npt.NDArray[Any]
SETTINGS = [(0.85, 6.0, 9, 2.0), (0.9, 6.0, 9, 1.5), (0.7, 8.0, 9, 2.5), (1.0, 8.0, 9, 2.0)]


def frames(path: Path, every: int) -> Iterator[tuple[Array, Array, Array, Array]]:
    """Yield (estimate, std, reference disparity, counted mask) of every ``every``-th frame."""
    topics = OutputTopics()
    with open_log(path) as reader:
        present = reader.topics()
        pairing, _, _ = follow_densify(path, None, present, topics.prefix)
        images = PairImages(pairing)
        if pairing is not None:
            images.resolve(reader, exclude_prefix="/pcainterp")
        reference = None
        if GROUND_TRUTH_DEPTH not in present and LIDAR_DEPTH in present:
            reference = resolve_reference(
                LIDAR_DEPTH, ReferenceKind.AUTO, present, path, outputs=topics.prefix, reader=reader
            )
    state = ReadState()
    if reference is not None:
        reference_tolerance(state, None, path, topics, None)
    for frame in read_frames(path, topics, None, reference, state, images, None, poses=False):
        if frame.index % every or frame.std is None:
            continue
        camera = frame.camera
        fb = camera.focal_baseline
        if reference is not None:
            if frame.reference is None:
                continue
            ref = reference_disparity(
                frame.reference,
                reference,
                focal_baseline=fb,
                image_size=camera.image_size,
                cx_offset=frame.cx_offset or 0.0,
            )
        elif frame.depth is not None:
            ref = disparity_from_reference(frame.depth, kind=ReferenceKind.DEPTH, focal_baseline=fb)
        else:
            narrow = fitting(SgbmConfig(), int(frame.left.shape[1]))
            if frame.right is None or narrow is None:
                continue
            ref = compute_disparity(frame.left, frame.right, narrow).astype(np.float64)
        counted = reference_view(ref, camera, stereo_transform(camera)).counted
        estimate = np.asarray(frame.estimate, np.float32)
        yield (
            estimate,
            np.asarray(frame.std, np.float32),
            np.asarray(ref),
            counted & ~np.isnan(estimate),
        )


def regions(ref: Array) -> dict[str, Array]:
    """Return the edge / smooth / near-step / border masks of a reference map."""
    found = fill_nearest(np.where(np.isfinite(ref), ref, np.nan))
    filled: Array = np.zeros(ref.shape) if found is None else np.asarray(found, np.float64)
    spread = maximum_filter(filled, 7) - minimum_filter(filled, 7)
    edge = (spread > 2.0) & (spread / np.maximum(filled, 1.0) > 0.15)
    jump_x = np.abs(np.diff(filled, axis=1))
    jump_y = np.abs(np.diff(filled, axis=0))
    step_x = (jump_x > 2) & (jump_x / np.maximum(filled[:, 1:], 1) > 0.15)
    step_y = (jump_y > 2) & (jump_y / np.maximum(filled[1:], 1) > 0.15)
    steps = np.zeros(ref.shape, bool)
    steps[:, 1:] |= step_x
    steps[:, :-1] |= step_x
    steps[1:] |= step_y
    steps[:-1] |= step_y
    near = distance_transform_edt(~steps) < 4 if steps.any() else np.zeros(ref.shape, bool)
    height, width = ref.shape
    ys, xs = np.mgrid[0:height, 0:width]
    border = np.minimum.reduce([xs, ys, width - 1 - xs, height - 1 - ys]) < 8
    return {"edge": edge, "smooth": ~edge, "step<4": near, "border<8": border}


def _widening(setting: tuple[float, float, int, float]) -> Callable[[Array, Array], Array]:
    def widen(estimate: Array, std: Array) -> Array:
        return widen_off_plane(estimate, std, setting)

    return widen


def _stored(estimate: Array, std: Array) -> Array:
    return std


def main(argv: list[str] | None = None) -> None:
    """Print the table for one log."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log", type=Path, help="a log written by pcainterp densify")
    parser.add_argument("--every", type=int, default=1, help="every n-th frame (default 1)")
    args = parser.parse_args(argv)
    variants: list[tuple[str, Callable[[Array, Array], Array]]] = [("stored", _stored)]
    variants += [(f"off-plane {setting}", _widening(setting)) for setting in SETTINGS]
    names = ["all", "edge", "smooth", "step<4", "border<8"]
    totals = {name: dict.fromkeys([*names, "1sigma"], 0) for name, _ in variants}
    counts = dict.fromkeys(names, 0)
    nll = dict.fromkeys([name for name, _ in variants], 0.0)
    for estimate, std, ref, mask in frames(args.log, args.every):
        masks = {"all": mask, **{k: v & mask for k, v in regions(ref).items()}}
        for key in names:
            counts[key] += int(masks[key].sum())
        for name, widen in variants:
            spread = widen(estimate, std)
            z = np.abs((estimate - ref) / spread)
            inside = z <= 2.0
            for key in names:
                totals[name][key] += int((inside & masks[key]).sum())
            totals[name]["1sigma"] += int(((z <= 1.0) & mask).sum())
            nll[name] += float(np.sum(np.log(spread[mask]) + 0.5 * z[mask] ** 2 + 0.9189385))
    print(f"{args.log}: +-2 sigma % (all / edge / smooth / step<4 / border<8), +-1 sigma %, NLL")
    for name, _ in variants:
        shares = " / ".join(f"{100 * totals[name][k] / max(counts[k], 1):5.1f}" for k in names)
        one = 100 * totals[name]["1sigma"] / max(counts["all"], 1)
        print(f"  {name:34s} {shares}  {one:5.1f}  {nll[name] / max(counts['all'], 1):.3f}")


if __name__ == "__main__":
    main()
