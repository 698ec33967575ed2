"""Tests of the match centred on 0 where SGBM reads exactly 0 (frontend/far.py)."""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from pcainterp_stream.frontend.far import FarZeros, rematch_far
from pcainterp_stream.frontend.stereo import (
    Lookup,
    RejectionCounts,
    SgbmConfig,
    StereoFrontEnd,
)

HEIGHT, WIDTH = 240, 320


def _pair(disparity: float) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
    """A textured fronto-parallel plane at a sub-pixel ``disparity`` (px)."""
    rng = np.random.default_rng(5)
    noise = rng.random((HEIGHT, WIDTH + 16)).astype(np.float32)
    texture = cv2.GaussianBlur(noise, (0, 0), 1.5)
    texture = (texture - texture.min()) / (texture.max() - texture.min()) * 255
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)

    def view(shift: float) -> npt.NDArray[np.uint8]:
        image = cv2.remap(texture, cols + np.float32(shift), rows, cv2.INTER_LINEAR)
        return np.asarray(np.clip(np.rint(image), 0, 255), np.uint8)

    return view(0.0), view(disparity)  # right pixel x sees the left's x + d


def test_a_far_plane_below_one_px_is_measured_not_zero() -> None:
    """Half-resolution SGBM reads 0.6 px as exactly 0 (no sub-pixel at 0): matched again."""
    left, right = _pair(0.6)
    front_end = StereoFrontEnd(sgbm=SgbmConfig(downscale=2))
    found = front_end.measure(left, right)
    assert found.counts.kept > 50
    assert found.counts.far_zeros > 0.5 * found.counts.kept  # the half map's 0s
    assert found.counts.far_rematched > 0.9 * found.counts.far_zeros
    assert np.mean(found.disparities == 0) < 0.1
    # SGBM's sub-pixel values lean to whole px (0.8 here on a bilinearly shifted texture)
    assert abs(float(np.median(found.disparities)) - 0.6) < 0.3
    # the map too: the fit check and the adaptation read it
    inner = found.disparity_map[:, 160:]
    assert abs(float(np.nanmedian(inner)) - 0.6) < 0.3


def test_a_far_plane_below_half_a_px_is_measured_at_full_resolution() -> None:
    """Full-resolution SGBM reads 0.3 px as exactly 0 (no sub-pixel at 0): matched again."""
    left, right = _pair(0.3)
    found = StereoFrontEnd(sgbm=SgbmConfig(downscale=1)).measure(left, right)
    assert found.counts.kept > 50
    assert found.counts.far_zeros > 0.5 * found.counts.kept  # before: 100 % of them read 0
    assert found.counts.far_rematched > 0.9 * found.counts.far_zeros
    assert np.mean(found.disparities == 0) < 0.1
    # pixel locking again: 0.19 px here
    assert abs(float(np.median(found.disparities)) - 0.3) < 0.2
    assert abs(float(np.nanmedian(found.disparity_map[:, 160:])) - 0.3) < 0.2


def _fake_lookup(points: npt.NDArray[np.float32], values: npt.NDArray[np.float32]) -> Lookup:
    count = len(points)
    counts = RejectionCounts(count, count, 0, 0, 0, 0)
    return Lookup(points, values, np.arange(count, dtype=np.int64), counts)


@pytest.mark.parametrize(("downscale", "replaced"), [(1, False), (2, True)])
def test_the_thresholds_are_in_px_of_the_matching_resolution(
    downscale: int, replaced: bool
) -> None:
    """A 0.8 px value is a refined match at full resolution (below 0.5 px is 0 there), a
    blend with 0 at half resolution; a new 1.5 px value is trusted only at half resolution."""
    left, right = _pair(0.3)
    disparity_map = np.zeros((HEIGHT, WIDTH), np.float32)
    disparity_map[:, WIDTH // 2 :] = 0.8
    xs, ys = np.meshgrid(np.arange(140.0, 300.0, 20.0), np.arange(40.0, 200.0, 20.0))
    points = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float32)
    values = disparity_map[points[:, 1].astype(int), points[:, 0].astype(int)]
    found = _fake_lookup(points, values)
    boxes: list[tuple[int, ...]] = []

    def match(left: object, right: object, config: SgbmConfig, full: bool) -> object:
        boxes.append(np.shape(left))
        assert (config.min_disparity, config.num_disparities, config.downscale) == (-8, 16, 1)
        return np.full(np.shape(left), 1.5, np.float32)

    def look_up(spliced: npt.NDArray[np.float32], where: npt.NDArray[np.float32]) -> Lookup:
        return _fake_lookup(where, spliced[where[:, 1].astype(int), where[:, 0].astype(int)])

    far = rematch_far(
        left,
        right,
        disparity_map,
        found,
        SgbmConfig(downscale=downscale),
        match=match,
        look_up=look_up,
    )
    assert far.zeros == int(np.sum(values == 0))
    assert len(boxes) == 1  # matched in both cases; only what is taken differs
    if replaced:  # half resolution: < 1.0 px replaced by a value < 2.0 px
        assert np.all(far.lookup.disparities == 1.5)
        assert np.all(far.disparity_map[60:180, 140:300] == 1.5)
    else:  # full resolution: 0.8 px is SGBM's own refined value; 1.5 px is not "far"
        np.testing.assert_array_equal(far.lookup.disparities, values)
        np.testing.assert_array_equal(far.disparity_map, disparity_map)


@pytest.mark.parametrize(("disparity", "downscale"), [(6.3, 2), (6.3, 1), (0.8, 1)])
def test_a_plane_the_map_measures_is_left_alone(disparity: float, downscale: int) -> None:
    left, right = _pair(disparity)
    config = SgbmConfig(downscale=downscale)
    found = StereoFrontEnd(sgbm=config).measure(left, right)
    assert found.counts.far_zeros == 0
    assert found.counts.far_rematched == 0
    assert abs(float(np.median(found.disparities)) - disparity) < 0.3


def test_far_zeros_warn_only_when_many_lookups_stay_zero() -> None:
    check = FarZeros()
    check.result({"kept": 200, "far_zeros": 150, "far_rematched": 148})  # measured again
    check.result({"kept": 200, "far_zeros": 6, "far_rematched": 0})  # a few: 3 %
    assert check.warnings(2) == []
    check.result({"kept": 200, "far_zeros": 120, "far_rematched": 0})  # 60 % stay 0
    (warning,) = check.warnings(3)
    assert warning.startswith("1 of 3 frames had up to 60 % of their lookups at disparity 0")
    assert "--stereo-downscale 1" in warning


def test_far_zeros_at_full_resolution_say_so_and_do_not_advise_full_resolution() -> None:
    check = FarZeros(downscale=1)
    check.result({"kept": 200, "far_zeros": 120, "far_rematched": 0})
    (warning,) = check.warnings(1)
    assert "in the full-resolution match (surfaces below ~0.5 px of disparity)" in warning
    assert "--stereo-downscale" not in warning
