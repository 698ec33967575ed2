"""The image files of a KITTI camera folder: their frame order and the stereo pairs by name.

:mod:`.kitti` reads a sequence's images in the order of the numbers in their names and pairs
each left image with the right image of the same name (KITTI's ``image_0/000010.png`` and
``image_1/000010.png``).
"""

from __future__ import annotations

import re
from pathlib import Path

from pcainterp_stream.errors import DatasetImportError

EXPECTED_LAYOUTS = (
    "expected a KITTI raw drive folder (<date>_drive_XXXX_sync, or the unrectified "
    "<date>_drive_XXXX_extract, with image_00/data and "
    "image_01/data, or the colour image_02/data and image_03/data, and calib_cam_to_cam.txt "
    "in it or one level up) or an odometry sequence folder (sequences/XX with image_0 and "
    "image_1, or the colour image_2 and image_3, and calib.txt)"
)
"""What an import-kitti folder must look like (the end of a refusal's message)."""

NAMES_SHOWN = 3
"""The most unpaired images a message names one by one (the rest are counted)."""


def frame_order(path: Path) -> tuple[list[int | str], str]:
    """Sort key of an image: its name's numbers compared as numbers (``2.png`` < ``10.png``).

    KITTI's names are zero-padded (``000010.png``), where text order is frame order; other
    tools' "KITTI-layout" exports (``0.png`` ... ``11.png``) are not, and text order would
    give frame 10 the second line of ``times.txt`` and the poses.
    """
    parts = re.split(r"(\d+)", path.stem)  # text, number, text, ...: one type per position
    return [int(part) if i % 2 else part for i, part in enumerate(parts)], path.name


def png_images(folder: Path) -> list[Path]:
    """Return a folder's images in frame order; dot-files (macOS's ``._000000.png``) are not."""
    images = (p for p in folder.iterdir() if p.suffix.lower() == ".png" and p.name[0] != ".")
    return sorted(images, key=frame_order)


def paired_images(left_dir: Path, right_dir: Path) -> tuple[list[Path], list[Path]]:
    """Return the left and right images of a stereo pair of folders, the n-th of each a pair.

    Images are paired by name: each left image with the right image of the same name.

    Raises:
        DatasetImportError: an image of either folder has no image of its name in the
            other (the message names them: a stray file, or its partner missing), or the
            folders hold no .png image.
    """
    left, right = png_images(left_dir), png_images(right_dir)
    left_names, right_names = {p.name for p in left}, {p.name for p in right}
    lonely_left = [p for p in left if p.name not in right_names]
    lonely_right = [p for p in right if p.name not in left_names]
    if lonely_left or lonely_right:
        counts = (
            f"{left_dir} has {len(left)} images but {right_dir} has {len(right)}: "
            if len(left) != len(right)
            else ""
        )
        unpaired = [
            _unpaired(images, side, other, folder)
            for images, side, other, folder in (
                (lonely_left, "left", "right", right_dir),
                (lonely_right, "right", "left", left_dir),
            )
            if images
        ]
        raise DatasetImportError(
            f"{counts}{'; '.join(unpaired)}; every left image needs the right image of its "
            "name: restore the missing files or remove the extra ones"
        )
    if not left:
        raise DatasetImportError(f"{left_dir} holds no .png images; {EXPECTED_LAYOUTS}")
    return left, right


def _unpaired(images: list[Path], side: str, other: str, other_dir: Path) -> str:
    """Say which images of one side have no image of their name on the other."""
    if len(images) == 1:
        return f"{side} image {images[0]} has no {other} image of the same name in {other_dir}"
    names = ", ".join(path.name for path in images[:NAMES_SHOWN])
    if len(images) > NAMES_SHOWN:
        names += f" and {len(images) - NAMES_SHOWN} more"
    return (
        f"{len(images)} {side} images of {images[0].parent} have no {other} image of the "
        f"same name in {other_dir} ({names})"
    )
