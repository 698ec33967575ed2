"""Grey levels at the edges (bug hunt 17G F2, F5, F6): levels under the floor clipped, not
mirrored; a blank 16-bit pair not noted as over-exposed; a mixed 8/16-bit rig's 8-bit side
kept, the pair stretched with one mapping."""

from __future__ import annotations

from collections.abc import Iterator

import cv2
import numpy as np
import pytest

from pcainterp_stream.frontend import levels
from pcainterp_stream.frontend.grey import is_blank, to_grey8_pair
from pcainterp_stream.frontend.pair_forms import grey_alike


@pytest.fixture(autouse=True)
def _fresh_notes() -> Iterator[None]:
    levels._said.clear()
    yield
    levels._said.clear()


def _scene(shift: float = 0.0, size: tuple[int, int] = (160, 320)) -> np.ndarray:
    """A smooth textured float image on 10..245, shifted left by ``shift`` px."""
    rng = np.random.default_rng(3)
    small = rng.integers(10, 246, (size[0] // 4 + 1, size[1] // 4 + 1)).astype(np.float64)
    image = cv2.resize(small, (size[1], size[0]), interpolation=cv2.INTER_CUBIC)
    move = np.float64([[1, 0, -shift], [0, 1, 0]])
    return np.clip(cv2.warpAffine(image, move, (size[1], size[0]), borderMode=4), 10, 245)


def test_16_bit_counts_under_the_floor_are_clipped_not_mirrored() -> None:
    # 16-bit pair on 28000..30000 (the floor mapping acts), a dead pixel at 0 and one at
    # 27000: they were mirrored to 255 and 128
    rng = np.random.default_rng(0)
    left = rng.integers(28000, 30000, (240, 320)).astype(np.uint16)
    right = left.copy()
    left[100, 100], left[101, 101] = 0, 27000
    out_left, out_right = to_grey8_pair(left, right)
    assert out_left[100, 100] == 0
    assert out_left[101, 101] == 0
    order = np.argsort(left, axis=None, kind="stable")
    assert np.all(np.diff(out_left.reshape(-1)[order].astype(int)) >= 0)  # monotonic
    assert 120 <= np.median(out_right) <= 135


def test_a_dark_pair_clips_the_levels_under_its_floor() -> None:
    # a dark 8-bit pair on 10..40 with one black pixel: it was mirrored to 85 (10 gives 0)
    rng = np.random.default_rng(0)
    left = rng.integers(10, 41, (240, 320)).astype(np.uint8)
    right = left.copy()
    left[50, 50] = 0
    out_left, out_right = to_grey8_pair(left, right)
    assert out_left[50, 50] == 0
    assert np.all(out_left[left == 10] == 0)
    both = np.concatenate([left.ravel(), right.ravel()])
    mapped = np.concatenate([out_left.ravel(), out_right.ravel()])[np.argsort(both, kind="stable")]
    assert np.all(np.diff(mapped.astype(int)) >= 0)  # one monotonic mapping for both views
    assert out_left.max() == 255


def test_a_blank_16_bit_pair_is_blank_not_over_exposed(capsys: pytest.CaptureFixture[str]) -> None:
    # a capped 12-bit camera at its black level (256 counts): scaled to all 255, it was
    # noted as "over-exposed 100 %" and the once-per-process note was spent
    capped = np.full((120, 160), 256, np.uint16)
    out_left, out_right = to_grey8_pair(capped, capped.copy())
    assert is_blank(out_left)
    assert is_blank(out_right)
    assert "over-exposed" not in capsys.readouterr().err
    assert levels.clipped_pixels(out_left, out_right, np.zeros((120, 160))) is None
    bright = np.clip(_scene() * 3, 0, 255).astype(np.uint8)  # really over-exposed later on
    to_grey8_pair(bright, bright.copy())
    assert "over-exposed images" in capsys.readouterr().err


def test_an_over_exposed_image_beside_a_blank_one_is_still_noted(
    capsys: pytest.CaptureFixture[str],
) -> None:
    bright = np.clip(_scene() * 3, 0, 255).astype(np.uint8)
    to_grey8_pair(bright, np.zeros_like(bright))
    assert "over-exposed images" in capsys.readouterr().err


@pytest.mark.parametrize("eight_bit_side", ["left", "right"])
def test_a_mixed_rig_keeps_the_8_bit_side_and_maps_the_pair_as_one(
    eight_bit_side: str, capsys: pytest.CaptureFixture[str]
) -> None:
    # a dark mono8 camera (levels 0..40) beside a mono16 one (12-bit, black level 256), the
    # right view shifted 8 px: each side was stretched on its own (the 8-bit one 0..40 to
    # 0..255), contrary to "the 8-bit side keeps its grey levels"
    left_scene, right_scene = _scene(), _scene(8.0)
    eight = lambda x: np.rint(x * 40 / 255).astype(np.uint8)  # noqa: E731
    sixteen = lambda x: np.rint(x * 40 / 255 * 16 + 256).astype(np.uint16)  # noqa: E731
    if eight_bit_side == "left":
        left, right = eight(left_scene), sixteen(right_scene)
    else:
        left, right = sixteen(left_scene), eight(right_scene)
    grey_left, grey_right, said = grey_alike(left, right)
    assert "16-bit side scaled on its own" in said
    kept = grey_left if eight_bit_side == "left" else grey_right
    assert np.array_equal(kept, left if eight_bit_side == "left" else right)
    out_left, out_right = to_grey8_pair(grey_left, grey_right)
    assert out_left.max() > 200  # the dark pair stretched
    assert out_right.max() > 200
    difference = np.abs(out_left.astype(int) - np.roll(out_right, 8, axis=1).astype(int))
    assert difference[:, 40:].mean() < 3.0  # issue-29: 5.2 (8-bit left), 6.2 (right)
    err = capsys.readouterr().err
    if eight_bit_side == "left":  # the 16-bit right side mapped onto it, the pair stretched
        assert "one mapping for both views" in err
    else:  # the dark 8-bit right side mapped onto the left's levels
        assert "mapped onto the left's levels" in err
