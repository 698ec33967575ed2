"""Grey levels outside the normal (bug hunt 16F): a 16-bit offset, dark images, a left/right
gain mismatch, over-exposure; and normal pairs converted exactly as before."""

from __future__ import annotations

from collections.abc import Iterator

import cv2
import numpy as np
import pytest

from pcainterp_stream.frontend import levels
from pcainterp_stream.frontend.grey import is_blank, to_grey8_pair


@pytest.fixture(autouse=True)
def _fresh_notes() -> Iterator[None]:
    levels._said.clear()
    yield
    levels._said.clear()


def _pair(shift: float = 8.0, size: tuple[int, int] = (160, 320)) -> tuple[np.ndarray, np.ndarray]:
    """A textured 8-bit pair using 10..245: the right view is the left shifted."""
    rng = np.random.default_rng(3)
    small = rng.integers(10, 246, (size[0] // 4 + 1, size[1] // 4 + 1), dtype=np.uint8)
    left = cv2.resize(small, (size[1], size[0]), interpolation=cv2.INTER_LINEAR)
    right = cv2.warpAffine(
        left, np.float32([[1, 0, -shift], [0, 1, 0]]), (size[1], size[0]), borderMode=4
    )
    return left, right


def test_a_well_exposed_8_bit_pair_is_passed_through() -> None:
    left, right = _pair()
    out_left, out_right = to_grey8_pair(left, right)
    assert np.array_equal(out_left, left)
    assert np.array_equal(out_right, right)


def test_a_16_bit_pair_from_0_is_scaled_as_before() -> None:
    left, right = _pair()
    wide = [(image.astype(np.uint16) * 16) for image in (left, right)]  # 12-bit data
    top = max(float(np.percentile(image[::4, ::4], 99.9)) for image in wide)
    expected = [cv2.convertScaleAbs(image, alpha=255.0 / top) for image in wide]
    out = to_grey8_pair(*wide)
    assert np.array_equal(out[0], expected[0])
    assert np.array_equal(out[1], expected[1])


def test_a_16_bit_pair_on_an_offset_keeps_its_grey_levels(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # 300 counts of signal on 30000 (thermal, a large black level): was judged blank
    left, right = _pair()
    narrow = [
        (30000 + image.astype(np.float64) * 300 / 255).astype(np.uint16) for image in (left, right)
    ]
    out_left, out_right = to_grey8_pair(*narrow)
    assert not is_blank(out_left)
    assert not is_blank(out_right)
    assert int(out_left.max()) - int(out_left.min()) > 200
    assert np.abs(out_left.astype(int) - left.astype(int)).mean() < 25  # ~the 8-bit image
    assert "16-bit images use counts" in capsys.readouterr().err


def test_a_dark_pair_is_stretched_once_for_both(capsys: pytest.CaptureFixture[str]) -> None:
    left, right = _pair()
    dark = [(image.astype(np.float64) * 40 / 255).astype(np.uint8) for image in (left, right)]
    out_left, out_right = to_grey8_pair(*dark)
    assert np.percentile(out_left, 99.9) > 200
    both = np.concatenate([dark[0].ravel(), dark[1].ravel()])
    order = np.argsort(both, kind="stable")
    mapped = np.concatenate([out_left.ravel(), out_right.ravel()])[order]
    assert np.all(np.diff(mapped.astype(int)) >= 0)  # one monotonic mapping for both views
    err = capsys.readouterr().err
    assert err.count("note: dark images") == 1
    to_grey8_pair(*dark)
    assert "dark images" not in capsys.readouterr().err  # once per process


def test_a_blank_dark_image_stays_blank() -> None:
    black = np.zeros((120, 160), np.uint8)
    noisy = np.random.default_rng(0).integers(0, 2, (120, 160), dtype=np.uint8)
    for left, right in ((black, black), (black, noisy), (noisy, black)):
        out_left, out_right = to_grey8_pair(left, right)
        assert is_blank(out_left)
        assert is_blank(out_right)


@pytest.mark.parametrize("case", ["gain 0.7", "offset 30", "gamma 0.6"])
def test_a_right_camera_with_other_levels_is_mapped_onto_the_left(
    case: str, capsys: pytest.CaptureFixture[str]
) -> None:
    left, right = _pair()
    values = right.astype(np.float64)
    changed = {
        "gain 0.7": values * 0.7,
        "offset 30": values + 30,
        "gamma 0.6": 255 * (values / 255) ** 0.6,
    }[case]
    other = np.clip(np.rint(changed), 0, 255).astype(np.uint8)
    before = np.abs(other.astype(int) - right.astype(int)).mean()
    out_left, out_right = to_grey8_pair(left, other)
    assert np.array_equal(out_left, left)
    after = np.abs(out_right.astype(int) - right.astype(int)).mean()
    assert after < 3.0 < before
    assert "grey levels differ" in capsys.readouterr().err


def test_natural_left_right_differences_are_left_alone() -> None:
    left, right = _pair()
    slightly = np.clip(right.astype(int) + 6, 0, 255).astype(np.uint8)  # KITTI: up to 7 levels
    assert np.array_equal(to_grey8_pair(left, slightly)[1], slightly)


def test_an_over_exposed_pair_is_noted(capsys: pytest.CaptureFixture[str]) -> None:
    left, right = _pair()
    bright = [np.clip(image.astype(int) * 3, 0, 255).astype(np.uint8) for image in (left, right)]
    to_grey8_pair(*bright)
    err = capsys.readouterr().err
    assert "over-exposed images" in err
    assert "% of an image is at 255" in err
    to_grey8_pair(left, right)
    assert capsys.readouterr().err == ""


def test_the_normal_path_agrees_with_every_step() -> None:
    """adjust_pair's one-histogram shortcut is taken exactly when no step would act."""
    from pcainterp_stream.frontend import levels

    rng = np.random.default_rng(3)
    base = rng.integers(0, 256, (96, 128)).astype(np.uint8)
    cases = [
        (base, base),
        (base, np.clip(base.astype(int) + 8, 0, 255).astype(np.uint8)),  # within the margin
        (base, np.clip(base.astype(int) + 40, 0, 255).astype(np.uint8)),  # a clear offset
        ((base // 7).astype(np.uint8), (base // 7).astype(np.uint8)),  # dark
        (np.maximum(base, 200).astype(np.uint8) | 0x7F, base),  # bright
    ]
    clipped = base.copy()
    clipped[:60] = 255
    cases.append((clipped, clipped))  # over half at 255
    for left, right in cases:
        samples = levels._sample(left), levels._sample(right)
        acts = (
            levels.match_right_levels(left, right, samples) is not right
            or levels.stretch_dark(left, right, samples)[0] is not left
            or levels.saturation_share(*samples) > levels.SATURATED_SHARE
        )
        assert levels._normal(*samples) is not acts
