"""Tests of the full-resolution match where half-resolution SGBM reads 0 (frontend/far.py)."""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from pcainterp_stream.frontend.far import FarZeros
from pcainterp_stream.frontend.stereo import SgbmConfig, StereoFrontEnd

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


@pytest.mark.parametrize("disparity", [6.3])
def test_a_plane_the_half_map_measures_is_left_alone(disparity: float) -> None:
    left, right = _pair(disparity)
    config = SgbmConfig(downscale=2)
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
