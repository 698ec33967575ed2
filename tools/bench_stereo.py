"""Benchmark the stereo front end (GFTT + SGBM + lookup) on real KITTI frames.

Prints Markdown tables: SGBM time per frame by mode, disparity range, block size, thread
count and resolution; how far the sparse lookups of each setting are from a reference
setting on the same corners; the value and cost of the explicit left-right check; whether
two threads calling SGBM at once scale; GFTT and lookup times.

Example:
    python tools/bench_stereo.py --frames 8
    python tools/bench_stereo.py --kitti ../shared/realdata/kitti_raw/2011_09_26/\
2011_09_26_drive_0001_sync --frames 4 --sections sgbm
"""

from __future__ import annotations

import argparse
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.stereo import (
    GfttConfig,
    LookupConfig,
    LookupMethod,
    SgbmConfig,
    SgbmMode,
    StereoFrontEnd,
    compute_disparity,
    compute_right_disparity,
    detect_corners,
    lookup_disparities,
    to_grey8_pair,
)

DEFAULT_DRIVE = (
    Path(__file__).resolve().parents[2]
    / "shared"
    / "realdata"
    / "kitti_raw"
    / "2011_09_26"
    / "2011_09_26_drive_0001_sync"
)
SECTIONS = ("sgbm", "threads", "lr", "gftt", "front")
REFERENCE = SgbmConfig(mode=SgbmMode.SGBM, num_disparities=128, block_size=5)

Image = npt.NDArray[np.uint8]
Pair = tuple[Image, Image]


def load_pairs(drive: Path, count: int) -> list[Pair]:
    """Read ``count`` evenly spaced grey pairs of a KITTI raw ``*_sync`` drive folder."""
    lefts = sorted((drive / "image_00" / "data").glob("*.png"))
    rights = sorted((drive / "image_01" / "data").glob("*.png"))
    if not lefts or len(lefts) != len(rights):
        raise SystemExit(f"no matching image_00/image_01 PNGs under {drive}; pass --kitti")
    picks = np.linspace(0, len(lefts) - 1, min(count, len(lefts))).round().astype(int)
    pairs = []
    for index in picks:
        left = cv2.imread(str(lefts[index]), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(str(rights[index]), cv2.IMREAD_GRAYSCALE)
        pairs.append((np.asarray(left, np.uint8), np.asarray(right, np.uint8)))
    return pairs


def time_ms(function: Callable[[], Any], repeats: int) -> float:
    """Return the median wall time (ms) of ``repeats`` calls, after one warm-up call."""
    function()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return 1000.0 * float(np.median(times))


def sgbm_ms(config: SgbmConfig, pairs: Sequence[Pair]) -> tuple[float, list[Any]]:
    """Return the median SGBM time per frame (ms) and the maps of all pairs."""
    compute_disparity(pairs[0][0], pairs[0][1], config)  # warm-up, builds the matcher
    times, maps = [], []
    for left, right in pairs:
        start = time.perf_counter()
        maps.append(compute_disparity(left, right, config))
        times.append(time.perf_counter() - start)
    return 1000.0 * float(np.median(times)), maps


def compare(
    maps: Sequence[Any], reference: Sequence[Any], corners: Sequence[Any]
) -> tuple[float, float, float]:
    """Compare lookups of two settings on the same corners.

    Returns:
        (valid lookups per frame, share of common lookups within 1 px of the reference,
        mean absolute difference (px) on common lookups).
    """
    valid, within, diffs = [], [], []
    for disparity, ref, points in zip(maps, reference, corners, strict=True):
        ours = lookup_disparities(disparity, points)
        theirs = lookup_disparities(ref, points)
        valid.append(ours.counts.kept)
        _, ours_at, theirs_at = np.intersect1d(ours.indices, theirs.indices, return_indices=True)
        diff = np.abs(ours.disparities[ours_at] - theirs.disparities[theirs_at])
        within.append(diff <= 1.0)
        diffs.append(diff)
    every_within = np.concatenate(within)
    every_diff = np.concatenate(diffs)
    return float(np.mean(valid)), float(every_within.mean()), float(every_diff.mean())


def section_sgbm(pairs: Sequence[Pair], default_threads: int) -> None:
    """Time SGBM settings and compare their lookups with the reference setting."""
    corners = [detect_corners(left, GfttConfig(), min_x=128) for left, _ in pairs]
    ref_ms, reference = sgbm_ms(REFERENCE, pairs)
    print(f"\nReference: {REFERENCE.mode.name} block 5, 128 disparities, full resolution")
    print(f"({ref_ms:.0f} ms/frame at {default_threads} threads).\n")
    print(
        "| mode | num_disp | block | scale | threads | ms/frame | valid/frame "
        "| within 1 px of ref | mean abs diff (px) |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for downscale in (1, 2):
        for mode in (SgbmMode.SGBM, SgbmMode.SGBM_3WAY, SgbmMode.HH4):
            for num in (64, 96, 128):
                for block in (3, 5, 7):
                    config = SgbmConfig(
                        mode=mode, num_disparities=num, block_size=block, downscale=downscale
                    )
                    thread_counts = [default_threads]
                    if num == 128 and block == 5:
                        thread_counts = [1, default_threads]
                    for threads in thread_counts:
                        cv2.setNumThreads(threads)
                        ms, maps = sgbm_ms(config, pairs)
                        valid, share, mean_diff = compare(maps, reference, corners)
                        scale = "full" if downscale == 1 else "half"
                        print(
                            f"| {mode.name} | {num} | {block} | {scale} | {threads} | {ms:.0f} "
                            f"| {valid:.0f} | {share:.3f} | {mean_diff:.3f} |",
                            flush=True,
                        )
    cv2.setNumThreads(default_threads)


def section_threads(pairs: Sequence[Pair], default_threads: int) -> None:
    """Check whether two Python threads calling SGBM at once scale on this machine."""
    print("\n| mode | cv2 threads | 1 Python thread ms/frame | 2 Python threads ms/frame |")
    print("| --- | --- | --- | --- |")
    work = list(pairs) * 2
    for mode in (SgbmMode.SGBM_3WAY, SgbmMode.SGBM):
        config = SgbmConfig(mode=mode)
        for threads in (1, default_threads):
            cv2.setNumThreads(threads)
            compute_disparity(work[0][0], work[0][1], config)
            start = time.perf_counter()
            for left, right in work:
                compute_disparity(left, right, config)
            sequential = (time.perf_counter() - start) / len(work)

            def run(share: Sequence[Pair], config: SgbmConfig = config) -> None:
                for left, right in share:
                    compute_disparity(left, right, config)

            workers = [threading.Thread(target=run, args=(work[k::2],)) for k in range(2)]
            start = time.perf_counter()
            for worker in workers:
                worker.start()
            for worker in workers:
                worker.join()
            parallel = (time.perf_counter() - start) / len(work)
            print(
                f"| {mode.name} | {threads} | {1000 * sequential:.0f} | {1000 * parallel:.0f} |",
                flush=True,
            )
    cv2.setNumThreads(default_threads)


def section_lr(pairs: Sequence[Pair]) -> None:
    """Measure what the explicit left-right check removes and what it costs."""
    config = SgbmConfig()
    corners = [detect_corners(left, GfttConfig(), min_x=config.valid_min_x) for left, _ in pairs]
    left_ms = time_ms(lambda: compute_disparity(pairs[0][0], pairs[0][1], config), 5)
    right_ms = time_ms(lambda: compute_right_disparity(pairs[0][0], pairs[0][1], config), 5)
    kept, removed, removed_far, kept_far = 0, 0, 0, 0
    for (left, right), points in zip(pairs, corners, strict=True):
        disparity = compute_disparity(left, right, config)
        right_map = compute_right_disparity(left, right, config)
        reference = compute_disparity(left, right, REFERENCE)
        plain = lookup_disparities(disparity, points)
        checked = lookup_disparities(disparity, points, right_disparity=right_map)
        ref = lookup_disparities(reference, points)
        ref_by_index = dict(zip(ref.indices.tolist(), ref.disparities.tolist(), strict=True))
        kept_set = set(checked.indices.tolist())
        for index, value in zip(plain.indices.tolist(), plain.disparities.tolist(), strict=True):
            other = ref_by_index.get(index)
            far = other is None or abs(other - value) > 1.0
            if index in kept_set:
                kept += 1
                kept_far += far
            else:
                removed += 1
                removed_far += far
    frames = len(pairs)
    print(f"\nSGBM left map {left_ms:.0f} ms, right map (flipped pair) {right_ms:.0f} ms/frame.")
    print(
        f"Lookups per frame: {(kept + removed) / frames:.1f} without the check, "
        f"{kept / frames:.1f} with it ({removed / frames:.1f} removed)."
    )
    print(
        f"Disagreeing with the {REFERENCE.mode.name}-mode reference by > 1 px (or invalid "
        f"there): {removed_far / max(removed, 1):.1%} of the removed, "
        f"{kept_far / max(kept, 1):.1%} of the kept."
    )


def section_gftt(pairs: Sequence[Pair]) -> None:
    """Time corner detection and lookups; count valid lookups by setting."""
    left, right = pairs[0]
    disparity = compute_disparity(left, right)
    print(
        "\n| GFTT max_corners | subpixel | ms | valid lookups/frame | rejected/frame "
        "(invalid, discontinuity) | grid cells used of 24 |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    maps = [compute_disparity(lft, rgt) for lft, rgt in pairs]
    for max_corners in (200, 300, 400, 500):
        for subpixel in (False, True):
            config = GfttConfig(max_corners=max_corners, subpixel=subpixel)
            ms = time_ms(partial(detect_corners, left, config, min_x=128), 5)
            kept, invalid, jump, cells = [], [], [], []
            for (lft, _), dmap in zip(pairs, maps, strict=True):
                found = lookup_disparities(dmap, detect_corners(lft, config, min_x=128))
                kept.append(found.counts.kept)
                invalid.append(found.counts.invalid)
                jump.append(found.counts.discontinuity)
                col = ((found.pixels[:, 0] - 128) / (lft.shape[1] - 128) * 6).astype(int)
                row = (found.pixels[:, 1] / lft.shape[0] * 4).astype(int)
                cells.append(len(set(zip(col.tolist(), row.tolist(), strict=True))))
            print(
                f"| {max_corners} | {subpixel} | {ms:.1f} | {np.mean(kept):.0f} | "
                f"{np.mean(invalid):.0f}, {np.mean(jump):.0f} | {np.mean(cells):.1f} |"
            )
    corners = detect_corners(left, GfttConfig(), min_x=128)
    print("\n| lookup | ms (400 corners) |")
    print("| --- | --- |")
    for method in LookupMethod:
        ms = time_ms(partial(lookup_disparities, disparity, corners, method=method), 20)
        print(f"| {method.value} | {ms:.2f} |")
    right_map = compute_right_disparity(left, right)
    ms = time_ms(lambda: lookup_disparities(disparity, corners, right_disparity=right_map), 20)
    print(f"| bilinear + LR check | {ms:.2f} |")
    left16 = left.astype(np.uint16) * 16
    right16 = right.astype(np.uint16) * 16
    ms = time_ms(lambda: to_grey8_pair(left16, right16), 10)
    print(f"| uint16 pair -> 8 bit (percentile scaling) | {ms:.2f} |")
    print("\n| max_gradient | radius | valid lookups/frame (400 corners) |")
    print("| --- | --- | --- |")
    corners_all = [detect_corners(lft, GfttConfig(), min_x=128) for lft, _ in pairs]
    for radius in (0, 1, 2):
        for gradient in (0.5, 1.0, 2.0):
            kept = [
                lookup_disparities(
                    dmap, pts, max_gradient=gradient, discontinuity_radius=radius
                ).counts.kept
                for dmap, pts in zip(maps, corners_all, strict=True)
            ]
            print(f"| {gradient} | {radius} | {np.mean(kept):.0f} |")


def section_front(pairs: Sequence[Pair]) -> None:
    """Time the whole front end per frame with the defaults, with and without LR check."""
    print("\n| front end | ms/frame | valid/frame |")
    print("| --- | --- | --- |")
    for name, front_end in (
        ("defaults", StereoFrontEnd()),
        ("defaults + LR check", StereoFrontEnd(lr_check=True)),
        ("half resolution", StereoFrontEnd(sgbm=replace(SgbmConfig(), downscale=2))),
        ("median lookup", StereoFrontEnd(lookup=LookupConfig(method=LookupMethod.MEDIAN))),
    ):
        front_end.measure(*pairs[0])
        times, kept = [], []
        for left, right in pairs:
            start = time.perf_counter()
            result = front_end.measure(left, right)
            times.append(time.perf_counter() - start)
            kept.append(result.counts.kept)
        print(f"| {name} | {1000 * np.median(times):.0f} | {np.mean(kept):.0f} |")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the chosen benchmark sections and print Markdown tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--kitti",
        type=Path,
        default=DEFAULT_DRIVE,
        help="a KITTI raw *_sync drive folder (image_00, image_01)",
    )
    parser.add_argument("--frames", type=int, default=8, help="evenly spaced pairs to use")
    parser.add_argument("--sections", nargs="+", choices=SECTIONS, default=list(SECTIONS))
    args = parser.parse_args(argv)
    pairs = load_pairs(args.kitti, args.frames)
    default_threads = cv2.getNumThreads()
    height, width = pairs[0][0].shape
    print(
        f"{len(pairs)} KITTI pairs {width}x{height} from {args.kitti.name}; OpenCV "
        f"{cv2.__version__}, {default_threads} threads by default; median over frames."
    )
    for section in args.sections:
        {
            "sgbm": lambda: section_sgbm(pairs, default_threads),
            "threads": lambda: section_threads(pairs, default_threads),
            "lr": lambda: section_lr(pairs),
            "gftt": lambda: section_gftt(pairs),
            "front": lambda: section_front(pairs),
        }[section]()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
