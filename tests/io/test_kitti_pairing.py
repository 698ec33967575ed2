"""import-kitti pairs a sequence's images by name and names the unpaired ones (bug hunt 16A F8).

Before, the images were paired by position: a stray ``frame.png`` in image_0 with left
``000001.png`` missing (3 images in each folder) was reported as "left image 000002.png has
no right image of the same name (found 000001.png)", though image_1/000002.png exists.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from pcainterp_stream.errors import DatasetImportError
from pcainterp_stream.io.kitti import open_kitti

P0 = "707.0912 0 601.8873 0 0 707.0912 183.1104 0 0 0 1 0"
P1 = "707.0912 0 601.8873 -379.8145 0 707.0912 183.1104 0 0 0 1 0"


def _sequence(root: Path, left: list[str], right: list[str]) -> Path:
    """An odometry sequence folder with these image names in image_0 and image_1."""
    rng = np.random.default_rng(0)
    for folder, names in (("image_0", left), ("image_1", right)):
        (root / folder).mkdir(parents=True)
        for name in names:
            image = rng.integers(0, 256, size=(24, 40), dtype=np.uint8)
            assert cv2.imwrite(str(root / folder / name), image)
    (root / "calib.txt").write_text(f"P0: {P0}\nP1: {P1}\n")
    return root


def _refusal(sequence: Path) -> str:
    with pytest.raises(DatasetImportError) as caught:
        open_kitti(sequence)
    message = str(caught.value)
    assert "\n" not in message
    return message


def test_a_stray_left_image_and_a_missing_one_are_both_named(tmp_path: Path) -> None:
    left = ["000000.png", "000002.png", "frame.png"]
    right = ["000000.png", "000001.png", "000002.png"]
    sequence = _sequence(tmp_path / "k", left, right)
    message = _refusal(sequence)
    assert "000002.png has no" not in message  # image_1/000002.png exists
    assert (
        f"left image {sequence / 'image_0' / 'frame.png'} has no right image of the same name "
        f"in {sequence / 'image_1'}; right image {sequence / 'image_1' / '000001.png'} has no "
        f"left image of the same name in {sequence / 'image_0'}; "
    ) in message
    assert message.endswith("restore the missing files or remove the extra ones")


def test_unequal_counts_name_the_images_without_a_partner(tmp_path: Path) -> None:
    names = [f"{i:06d}.png" for i in range(6)]
    sequence = _sequence(tmp_path / "k", names, names[:2])
    message = _refusal(sequence)
    assert message.startswith(
        f"{sequence / 'image_0'} has 6 images but {sequence / 'image_1'} has 2: 4 left images "
        f"of {sequence / 'image_0'} have no right image of the same name in "
        f"{sequence / 'image_1'} (000002.png, 000003.png, 000004.png and 1 more); "
    )


def test_images_are_paired_by_name(tmp_path: Path) -> None:
    names = ["2.png", "10.png", "1.png"]
    sequence = open_kitti(_sequence(tmp_path / "k", names, list(reversed(names))))
    assert [path.name for path in sequence.left_paths] == ["1.png", "2.png", "10.png"]
    assert [path.name for path in sequence.right_paths] == ["1.png", "2.png", "10.png"]
