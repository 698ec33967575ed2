"""Import a KITTI stereo sequence into a log with the same topics as a synthetic log.

Two layouts are recognised:

* **raw drive**: ``<date>/<date>_drive_XXXX_sync`` with ``image_00/data/*.png`` (left grey)
  and ``image_01/data/*.png`` (right grey), ``image_00/timestamps.txt`` (one
  ``YYYY-MM-DD HH:MM:SS.fffffffff`` per frame) and ``calib_cam_to_cam.txt`` in the drive
  folder or one level up in the date folder (``P_rect_00``, ``P_rect_01``). The date folder
  itself is accepted when it holds exactly one drive. The images must have the rectified
  size ``S_rect_00`` of the calibration file, or its raw size ``S_00`` (below).
* **unrectified raw drive**: ``<date>_drive_XXXX_extract`` (KITTI's "unsynced+unrectified"
  download), images of the raw size ``S_00`` (1392x512, distorted, the two cameras not
  rectified) with a ``timestamps.txt`` per camera. Written as a driver records a raw
  camera (:mod:`pcainterp_stream.io.raw_log`): ``/camera/{left,right}/image_raw`` with
  ``CameraInfo`` K = ``K_00``, D = ``D_00`` (plumb_bob), R = ``R_rect_00``, P =
  ``P_rect_00`` at ``S_00``'s size (camera 01 the same), which ``densify`` rectifies as
  ``image_proc`` does. The cameras' own stamps are not synchronised: each left image is
  paired with the right image nearest its stamp (each the other's nearest, within a
  quarter frame; the rest is left out and counted), and both are stamped with the left
  image's time: KITTI triggers the cameras together, the stamps differ by the recording
  PC's jitter (up to 2.7 ms on drive 2011_09_26_0001), more than densify's 1 ms pairing.
* **odometry sequence**: ``sequences/XX`` with ``image_0/*.png``, ``image_1/*.png``,
  ``calib.txt`` (``P0:``, ``P1:`` lines of 12 numbers), optional ``times.txt`` (seconds, one
  per frame) and optional ground truth ``poses/XX.txt`` two levels up (a 3x4
  camera-to-world matrix per line, row-major).

KITTI's stereo 2012/2015 benchmark folders (``image_2/000000_10.png``, scenes of two frames
each, calibrated one by one) look like an odometry sequence but are no sequence: refused.

Either layout may hold the colour pair instead of (or beside) the grey one
(:class:`KittiPair`): cameras 2 and 3, ``image_2``/``image_3`` with ``P2``/``P3`` (odometry),
``image_02``/``image_03`` with ``P_rect_02``/``P_rect_03`` and ``image_02/timestamps.txt``
(raw). The grey pair is imported when the folder has it, the colour one otherwise or when
asked; colour images are converted to grey (what densify matches).

The camera comes from the rectified projection matrices: fx, fy, cx, cy of the left one and
baseline b = (P_left[0, 3] - P_right[0, 3]) / P_right[0, 0] (= -P1[0, 3] / P1[0, 0] in
KITTI, where P0[0, 3] = 0; the colour cameras' P2[0, 3] is not 0, camera 2 being ~6 cm left
of camera 0). KITTI's poses are camera 0's: for the colour pair they are moved to camera 2,
whose centre is -K^-1 P2[:, 3] in camera 0's frame. Without timestamps frames are 10 Hz from
t = 0. Frames are read and written one at a time, in the order of the numbers in their
names (KITTI's ``000010.png``; also ``2.png`` before ``10.png``), the n-th taking the n-th
line of the timestamps and poses.

KITTI's depth-completion truth (uint16 PNG, depth in m = value / 256, 0 = no truth) belongs to
camera 2, so it comes along with the colour pair: a raw drive's
``proj_depth/groundtruth/image_02/*.png`` or a sequence's ``image_depth_annotated/*.png``,
matched to the left images by file name, written as ``/ground_truth/lidar_depth`` (32FC1 m,
NaN = no truth). Frames without a truth file (the depth-completion set skips a drive's first
and last five) get none.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from enum import Enum
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import CalibrationError, DatasetImportError
from pcainterp_stream.io.calibration import kitti_calibration
from pcainterp_stream.io.camera_model import StereoCalibration
from pcainterp_stream.io.kitti_images import EXPECTED_LAYOUTS, paired_images, png_images
from pcainterp_stream.io.logwriter import LogFormat, ProgressCallback, WriteSummary, open_writer
from pcainterp_stream.io.raw_log import raw_stereo_messages
from pcainterp_stream.io.rosmsg import image_message
from pcainterp_stream.io.stereo_log import (
    LEFT_FRAME,
    LIDAR_DEPTH,
    POSE,
    pose_message,
    stereo_messages,
)
from pcainterp_stream.records import StereoCamera

FRAME_PERIOD_NS = 100_000_000
"""KITTI records at 10 Hz."""

RAW_CALIBRATION = "calib_cam_to_cam.txt"
ODOMETRY_CALIBRATION = "calib.txt"


class KittiLayout(Enum):
    """The KITTI folder layouts the importer reads."""

    RAW = "raw drive"
    ODOMETRY = "odometry sequence"


class KittiPair(Enum):
    """Which stereo pair of a KITTI recording: the grey cameras 0/1 or the colour ones 2/3."""

    GREY = 0
    COLOUR = 2

    def folders(self, layout: KittiLayout) -> tuple[str, str]:
        """Return the left and right image folders (a raw drive's hold ``data/``)."""
        left = self.value
        if layout is KittiLayout.RAW:
            return f"image_{left:02d}", f"image_{left + 1:02d}"
        return f"image_{left}", f"image_{left + 1}"

    def projection_keys(self, layout: KittiLayout) -> tuple[str, str]:
        """Return the calibration file's keys of the left and right projection matrices."""
        left = self.value
        if layout is KittiLayout.RAW:
            return f"P_rect_{left:02d}", f"P_rect_{left + 1:02d}"
        return f"P{left}", f"P{left + 1}"


@dataclass(frozen=True)
class KittiSequence:
    """A validated KITTI stereo sequence, with file lists but no image data loaded.

    Attributes:
        layout: which KITTI layout the folder has.
        folder: the drive or sequence folder.
        left_paths: left (camera 0, or 2 for the colour pair) image files in frame order.
        right_paths: right (camera 1, or 3) image files, same length and names.
        camera: the rectified stereo calibration (size of the first left image).
        stamps_ns: (n,) int64 capture times (ns).
        camera_to_world: (n, 4, 4) float64 left-camera poses, or None without ground truth.
        pair: the grey or the colour pair.
        truth_folder: the folder of the left camera's depth-completion truth, or None.
        unused_truth: a truth folder that was found but not imported (it belongs to the
            colour camera 2 and the grey pair is imported), else None.
        warnings: lines (no ``warning:`` prefix) for the import to print.
        lens: the raw cameras (K, D, R_rect, P_rect at the raw size) of an unrectified
            drive, whose images are written raw with them; None for rectified images.
        unpaired: left and right images of an unrectified drive left out, with no image of
            the other camera near their stamp.
    """

    layout: KittiLayout
    folder: Path
    left_paths: list[Path]
    right_paths: list[Path]
    camera: StereoCamera
    stamps_ns: npt.NDArray[np.int64]
    camera_to_world: npt.NDArray[np.float64] | None
    pair: KittiPair = KittiPair.GREY
    truth_folder: Path | None = None
    unused_truth: Path | None = None
    warnings: tuple[str, ...] = ()
    lens: StereoCalibration | None = None
    unpaired: tuple[int, int] = (0, 0)

    def __len__(self) -> int:
        return len(self.left_paths)


class KittiFrame(NamedTuple):
    """One KITTI stereo pair.

    Attributes:
        frame_index: 0-based frame number.
        stamp_ns: capture time (ns).
        left: (H, W) uint8 left grey image (rectified, or raw with ``sequence.lens``).
        right: (H, W) uint8 right grey image.
        camera_to_world: (4, 4) float64 left-camera pose, or None without ground truth.
        depth_truth: (H, W) float32 depth-completion truth (m, NaN = none), or None.
    """

    frame_index: int
    stamp_ns: int
    left: npt.NDArray[np.uint8]
    right: npt.NDArray[np.uint8]
    camera_to_world: npt.NDArray[np.float64] | None
    depth_truth: npt.NDArray[np.float32] | None = None


def _key_values(path: Path) -> dict[str, tuple[int, str]]:
    """Return ``key -> (line number, text after the colon)`` of a KITTI calibration file."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise DatasetImportError(
            f"cannot read calibration file {path}: {err}; restore it from the KITTI download"
        ) from err
    values: dict[str, tuple[int, str]] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        key, colon, rest = line.partition(":")
        if colon:
            values.setdefault(key.strip(), (number, rest))
    return values


def _projection(
    path: Path, values: dict[str, tuple[int, str]], key: str
) -> npt.NDArray[np.float64]:
    """Parse the 3x4 projection matrix ``key`` of a calibration file."""
    if key not in values:
        raise DatasetImportError(
            f"calibration file {path} has no {key}: line; it needs the rectified projection "
            f"matrices; restore the file from the KITTI download"
        )
    number, text = values[key]
    try:
        numbers = [float(item) for item in text.split()]
    except ValueError:
        numbers = []
    if len(numbers) != 12 or not np.all(np.isfinite(numbers)):
        raise DatasetImportError(
            f"line {number} ({key}) of calibration file {path} must hold 12 finite numbers "
            f"(a 3x4 matrix, row-major); fix or restore the file"
        )
    return np.array(numbers).reshape(3, 4)


def camera_from_projections(
    left: npt.NDArray[np.float64],
    right: npt.NDArray[np.float64],
    image_size: tuple[int, int],
    source: Path,
) -> StereoCamera:
    """Return the stereo camera of two rectified 3x4 projection matrices.

    Args:
        left: (3, 4) float64 left projection matrix (px).
        right: (3, 4) float64 right projection matrix (px); P[0, 3] = -fx * b.
        image_size: (height, width) of the images (px).
        source: the calibration file, named in errors.

    Raises:
        DatasetImportError: non-positive focal length or baseline.
    """
    fx, fy = float(left[0, 0]), float(left[1, 1])
    if fx <= 0 or fy <= 0 or right[0, 0] <= 0:
        raise DatasetImportError(
            f"calibration file {source} has focal lengths fx={fx}, fy={fy}, right "
            f"fx={right[0, 0]}; they must be positive; fix or restore the file"
        )
    baseline = float(left[0, 3] - right[0, 3]) / float(right[0, 0])
    if baseline <= 0:
        raise DatasetImportError(
            f"calibration file {source} gives a baseline of {baseline:.4g} m (from P[0, 3] of "
            "the left and right cameras); the right camera must be to the right of the left one"
        )
    return StereoCamera(
        width=image_size[1],
        height=image_size[0],
        fx=fx,
        fy=fy,
        cx=float(left[0, 2]),
        cy=float(left[1, 2]),
        baseline=baseline,
    )


def read_grey(path: Path) -> npt.NDArray[np.uint8]:
    """Read a KITTI image as (H, W) uint8 grey (colour images are converted).

    Raises:
        DatasetImportError: the file cannot be decoded or is not 8-bit.
    """
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise DatasetImportError(
            f"cannot read image {path} (missing, damaged or not an image); "
            "restore it from the KITTI download"
        )
    if image.dtype != np.uint8:
        raise DatasetImportError(
            f"image {path} is {image.dtype}, expected 8-bit grey; use KITTI's grey cameras"
        )
    if image.ndim == 3:
        image = cv2.cvtColor(
            image, cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        )
    return np.ascontiguousarray(image)


TRUTH_FOLDERS = {
    KittiLayout.RAW: Path("proj_depth", "groundtruth", "image_02"),
    KittiLayout.ODOMETRY: Path("image_depth_annotated"),
}
"""Where each layout keeps camera 2's depth-completion truth (beside the images)."""


def _truth_folders(
    folder: Path, layout: KittiLayout, pair: KittiPair
) -> tuple[Path | None, Path | None]:
    """Return (truth folder to import, truth folder found but not usable with ``pair``)."""
    truth = folder / TRUTH_FOLDERS[layout]
    if not truth.is_dir() or not png_images(truth):
        return None, None
    return (truth, None) if pair is KittiPair.COLOUR else (None, truth)


def read_depth_truth(path: Path, image_size: tuple[int, int]) -> npt.NDArray[np.float32]:
    """Read a depth-completion truth PNG as (H, W) float32 metres, NaN where it has none.

    Raises:
        DatasetImportError: the file cannot be decoded, is not 16-bit single-channel or has
            another size than the images.
    """
    png = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if png is None or png.dtype != np.uint16 or png.ndim != 2:
        raise DatasetImportError(
            f"depth truth {path} is not a 16-bit single-channel PNG (depth * 256); "
            "restore it from KITTI's depth-completion download"
        )
    if png.shape != image_size:
        raise DatasetImportError(
            f"depth truth {path} is {png.shape[1]}x{png.shape[0]} but the images are "
            f"{image_size[1]}x{image_size[0]}; it belongs to another sequence"
        )
    depth = png.astype(np.float32) / np.float32(256.0)
    depth[png == 0] = np.nan
    return depth


def _check_increasing(stamps: npt.NDArray[np.int64], path: Path, lines: list[int]) -> None:
    """Refuse times that do not increase: evaluate tells frames apart by their stamps.

    Args:
        stamps: (n,) int64 frame times (ns), in frame order.
        path: the file they were read from.
        lines: (n,) the line number of each.
    """
    for i in np.flatnonzero(np.diff(stamps) <= 0):
        raise DatasetImportError(
            f"line {lines[i + 1]} of {path} ({stamps[i + 1] / 1e9:.9f} s) is not after line "
            f"{lines[i]} ({stamps[i] / 1e9:.9f} s): frames need increasing times; fix or "
            "restore the file (without it frames are 10 Hz)"
        )


def _raw_stamps(path: Path, count: int) -> npt.NDArray[np.int64]:
    """Parse a raw drive's ``timestamps.txt`` (``YYYY-MM-DD HH:MM:SS.fffffffff``, UTC)."""
    if not path.is_file():
        return np.arange(count, dtype=np.int64) * FRAME_PERIOD_NS
    lines = [line.strip() for line in path.read_text().splitlines() if line.strip()]
    if len(lines) != count:
        raise DatasetImportError(
            f"{path} has {len(lines)} timestamps for {count} images; "
            "restore the file or the missing images"
        )
    stamps = np.empty(count, dtype=np.int64)
    for i, line in enumerate(lines):
        whole, _, fraction = line.partition(".")
        try:
            moment = datetime.strptime(whole, "%Y-%m-%d %H:%M:%S").replace(tzinfo=UTC)
            nanoseconds = int((fraction + "000000000")[:9]) if fraction else 0
        except ValueError as err:
            raise DatasetImportError(
                f"line {i + 1} of {path} is {line!r}, expected 'YYYY-MM-DD HH:MM:SS.fffffffff'; "
                "fix or restore the file"
            ) from err
        stamps[i] = int(moment.timestamp()) * 1_000_000_000 + nanoseconds
    _check_increasing(stamps, path, list(range(1, count + 1)))
    return stamps


def _frame_lines(lines: list[str], images: list[Path]) -> list[tuple[int, str]] | None:
    """Return (line number, line) of the images' frames: all lines, or by frame number.

    A folder may hold some frames of a sequence (``000168.png``...) beside the whole
    sequence's ``times.txt`` or poses: each image then takes the line of its number.
    None when neither fits.
    """
    if len(lines) == len(images):
        return list(enumerate(lines, start=1))
    if len(lines) > len(images) and all(path.stem.isdigit() for path in images):
        numbers = [int(path.stem) for path in images]
        if max(numbers, default=0) < len(lines):
            return [(number + 1, lines[number]) for number in numbers]
    return None


def _odometry_stamps(path: Path, images: list[Path]) -> npt.NDArray[np.int64]:
    """Parse an odometry ``times.txt`` (seconds from the start, one per frame)."""
    count = len(images)
    if not path.is_file():
        return np.arange(count, dtype=np.int64) * FRAME_PERIOD_NS
    every = [line for line in path.read_text().splitlines() if line.strip()]
    lines = _frame_lines(every, images)
    if lines is None:
        raise DatasetImportError(
            f"{path} has {len(every)} times for {count} images; "
            "restore the file or the missing images"
        )
    try:
        seconds = np.array([float(line) for _, line in lines])
    except ValueError as err:
        raise DatasetImportError(
            f"{path} must hold one number (seconds) per line: {err}; fix or restore the file"
        ) from err
    stamps = np.round(seconds * 1e9).astype(np.int64)
    _check_increasing(stamps, path, [number for number, _ in lines])
    return stamps


def _poses(path: Path, images: list[Path]) -> npt.NDArray[np.float64] | None:
    """Parse KITTI odometry ground truth: a row-major 3x4 camera-to-world per line."""
    if not path.is_file():
        return None
    count = len(images)
    every = [line for line in path.read_text().splitlines() if line.strip()]
    lines = _frame_lines(every, images)
    if lines is None:
        raise DatasetImportError(
            f"pose file {path} has {len(every)} poses for {count} images; "
            "it must have one line per frame: restore the file"
        )
    poses = np.tile(np.eye(4), (count, 1, 1))
    for i, (number, line) in enumerate(lines):
        try:
            numbers = [float(item) for item in line.split()]
        except ValueError:
            numbers = []
        if len(numbers) != 12:
            raise DatasetImportError(
                f"line {number} of pose file {path} must hold 12 numbers (a 3x4 matrix); "
                "fix or restore the file"
            )
        poses[i, :3, :] = np.reshape(numbers, (3, 4))
    return poses


def _is_raw_drive(folder: Path) -> bool:
    """Return whether a folder holds a raw drive's grey or colour left images."""
    return any((folder / name / "data").is_dir() for name in ("image_00", "image_02"))


def _choose_pair(folder: Path, layout: KittiLayout, pair: KittiPair | None, what: str) -> KittiPair:
    """Return the pair to import: ``pair``, else the grey one when the folder has it.

    Raises:
        DatasetImportError: the chosen pair's left or right folder is missing.
    """
    suffix = "/data" if layout is KittiLayout.RAW else ""
    if pair is None:
        grey = KittiPair.GREY.folders(layout)
        has_grey = any((folder / f"{name}{suffix}").is_dir() for name in grey)
        pair = KittiPair.GREY if has_grey else KittiPair.COLOUR
    names = [f"{name}{suffix}" for name in pair.folders(layout)]
    found = [(folder / name).is_dir() for name in names]
    if not all(found):
        fix = "restore the missing camera folder" if any(found) else EXPECTED_LAYOUTS
        raise DatasetImportError(f"{what} {folder} needs both {names[0]} and {names[1]}; {fix}")
    return pair


def _raw_drive_folder(folder: Path) -> Path | None:
    """Return the drive folder for a drive or a date folder holding one drive, else None."""
    if _is_raw_drive(folder):
        return folder
    drives = sorted(
        p for p in [*folder.glob("*_sync"), *folder.glob("*_extract")] if _is_raw_drive(p)
    )
    if len(drives) > 1:
        names = ", ".join(p.name for p in drives)
        raise DatasetImportError(
            f"{folder} holds {len(drives)} KITTI raw drives ({names}); pass one drive folder"
        )
    return drives[0] if drives else None


def _size_line(path: Path, values: dict[str, tuple[int, str]], key: str) -> tuple[int, int] | None:
    """Return the (height, width) of a calibration file's ``S_xx``/``S_rect_xx``, None without."""
    if key not in values:
        return None
    number, text = values[key]
    try:
        width, height = (float(item) for item in text.split())
    except ValueError:
        width = height = 0.0
    if not (width >= 1 and height >= 1 and width == int(width) and height == int(height)):
        raise DatasetImportError(
            f"line {number} ({key}) of calibration file {path} must hold an image width and "
            "height; fix or restore the file"
        )
    return int(height), int(width)


def _wxh(size: tuple[int, int]) -> str:
    return f"{size[1]}x{size[0]}"


def _is_rectified(
    calibration: Path, values: dict[str, tuple[int, str]], camera: int, first: Path
) -> bool | None:
    """Return whether a raw drive's first image has the rectified size, False for the raw one.

    None: the file has no ``S_rect_xx`` (one written by hand) and the image is not of the
    raw size: rectified, its size unchecked.

    Raises:
        DatasetImportError: an image of neither size.
    """
    rect_key, raw_key = f"S_rect_{camera:02d}", f"S_{camera:02d}"
    rect = _size_line(calibration, values, rect_key)
    raw = _size_line(calibration, values, raw_key)
    size = read_grey(first).shape[:2]
    if rect is None:
        return False if size == raw else None
    if size == rect and not (size == raw and first.parents[2].name.endswith("_extract")):
        return True
    if size == raw:
        return False
    sizes = f"{rect_key} {_wxh(rect)}" + ("" if raw is None else f", {raw_key} {_wxh(raw)}")
    raise DatasetImportError(
        f"image {first} is {_wxh(size)} but calibration file {calibration} is for images of "
        f"{sizes}: the drive's images are not the ones it calibrates (resized or from "
        "another date); import the drive as KITTI ships it (<date>_drive_XXXX_sync, "
        "rectified, or _extract, raw) with the calib_cam_to_cam.txt of its date"
    )


def _pair_by_stamp(
    left: npt.NDArray[np.int64], right: npt.NDArray[np.int64]
) -> list[tuple[int, int]]:
    """Return (left index, right index) of the images each the other's nearest by stamp.

    Within a quarter of the left camera's median frame interval (10 Hz without one): an
    image whose partner was dropped is left out, not paired with a neighbour's.
    """
    period = int(np.median(np.diff(left))) if len(left) > 1 else FRAME_PERIOD_NS
    if len(right) == 0:
        return []

    def nearest(stamps: npt.NDArray[np.int64], to: npt.NDArray[np.int64]) -> npt.NDArray[np.intp]:
        after = np.clip(np.searchsorted(stamps, to), 0, len(stamps) - 1)
        before = np.clip(after - 1, 0, len(stamps) - 1)
        take_before = np.abs(stamps[before] - to) <= np.abs(stamps[after] - to)
        return np.where(take_before, before, after)

    of_left, of_right = nearest(right, left), nearest(left, right)
    return [
        (i, int(j))
        for i, j in enumerate(of_left)
        if of_right[j] == i and abs(int(right[j]) - int(left[i])) <= period // 4
    ]


def _open_raw(drive: Path, pair: KittiPair | None) -> KittiSequence:
    pair = _choose_pair(drive, KittiLayout.RAW, pair, "KITTI raw drive")
    left_name, right_name = pair.folders(KittiLayout.RAW)
    calibration = next(
        (p for p in (drive / RAW_CALIBRATION, drive.parent / RAW_CALIBRATION) if p.is_file()),
        None,
    )
    if calibration is None:
        raise DatasetImportError(
            f"no {RAW_CALIBRATION} in {drive} or {drive.parent}; copy it from the KITTI "
            "raw calibration download of that date into the date folder"
        )
    values = _key_values(calibration)
    left_key, right_key = pair.projection_keys(KittiLayout.RAW)
    left_p = _projection(calibration, values, left_key)
    right_p = _projection(calibration, values, right_key)
    left_dir, right_dir = drive / left_name / "data", drive / right_name / "data"
    lefts = png_images(left_dir)
    if not lefts:
        raise DatasetImportError(f"{left_dir} holds no .png images; {EXPECTED_LAYOUTS}")
    rectified = _is_rectified(calibration, values, pair.value, lefts[0])
    if rectified is False:
        return _open_unrectified(drive, pair, calibration, left_p, right_p)
    left, right = paired_images(left_dir, right_dir)
    camera = camera_from_projections(left_p, right_p, read_grey(left[0]).shape[:2], calibration)
    # no S_rect: the size as far as P tells it
    warned = () if rectified else _check_centre(camera, left[0], calibration, left_key)
    stamps = _raw_stamps(drive / left_name / "timestamps.txt", len(left))
    truth, unused = _truth_folders(drive, KittiLayout.RAW, pair)
    return KittiSequence(
        KittiLayout.RAW, drive, left, right, camera, stamps, None, pair, truth, unused, warned
    )


def _open_unrectified(
    drive: Path,
    pair: KittiPair,
    calibration: Path,
    left_p: npt.NDArray[np.float64],
    right_p: npt.NDArray[np.float64],
) -> KittiSequence:
    """Open a drive of raw images (``S_xx``'s size): its pairs by stamp and its raw cameras."""
    left_name, right_name = pair.folders(KittiLayout.RAW)
    names = f"{pair.value:02d}", f"{pair.value + 1:02d}"
    try:
        lens = kitti_calibration(calibration, *names)
    except CalibrationError as err:
        raise DatasetImportError(
            f"{drive} holds unrectified images, which need the raw cameras of the calibration "
            f"file: {err}; restore the file from the KITTI download"
        ) from err
    lefts = png_images(drive / left_name / "data")
    rights = png_images(drive / right_name / "data")
    left_stamps = _raw_stamps(drive / left_name / "timestamps.txt", len(lefts))
    if (drive / right_name / "timestamps.txt").is_file():
        right_stamps = _raw_stamps(drive / right_name / "timestamps.txt", len(rights))
        pairs = _pair_by_stamp(left_stamps, right_stamps)
    else:  # no stamps of its own: the right image of the left one's name
        lefts, rights = paired_images(drive / left_name / "data", drive / right_name / "data")
        pairs = [(i, i) for i in range(len(lefts))]
    if not pairs:
        raise DatasetImportError(
            f"no image of {drive / left_name} has an image of {drive / right_name} within a "
            "quarter frame of its stamp (timestamps.txt of each); restore the drive's files"
        )
    camera = camera_from_projections(left_p, right_p, read_grey(lefts[0]).shape[:2], calibration)
    return KittiSequence(
        KittiLayout.RAW,
        drive,
        [lefts[i] for i, _ in pairs],
        [rights[j] for _, j in pairs],
        camera,
        left_stamps[[i for i, _ in pairs]],
        None,
        pair,
        lens=lens,
        unpaired=(len(lefts) - len(pairs), len(rights) - len(pairs)),
    )


def _from_camera_0(
    poses: npt.NDArray[np.float64] | None, left: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64] | None:
    """Return camera 0's poses moved to the camera of projection ``left`` (rectified).

    ``left`` = K [I | t] in camera 0's rectified frame, so that camera sits at -t = -K^-1
    P[:, 3] there, with the same axes: its camera-to-world is pose @ [[I, -t], [0, 1]].
    """
    if poses is None:
        return None
    offset = np.eye(4)
    offset[:3, 3] = -np.linalg.solve(left[:, :3], left[:, 3])
    return np.asarray(poses @ offset, dtype=np.float64)


CENTRE_TOLERANCE = 0.1
"""Farthest the principal point of an odometry sequence (or of a raw drive's calibration
without ``S_rect``) may be off its images' centre, as a share of their width and height,
without a warning: KITTI's rectified cameras are within 1-4 %, KITTI-360's perspective pair
(1408x376, cy 238.8) 13.5 %; P_rect of a drive in the unrectified 1392x512 images is 14-16 %
off vertically."""

KITTI_RAW_SIZE = (512, 1392)
"""(height, width) of KITTI's unrectified images (``S_00`` to ``S_03``), refused with a
rectified projection off their centre where no calibration size says what they are."""


def _check_centre(
    camera: StereoCamera, first: Path, calibration: Path, key: str
) -> tuple[str, ...]:
    """Check the images fit the rectified camera, where no S_rect gives their size.

    Returns:
        a warning when the principal point is off the centre by more than
        :data:`CENTRE_TOLERANCE` (a rectified camera may be: KITTI-360's, a crop's), else ().

    Raises:
        DatasetImportError: the images have KITTI's unrectified size
            (:data:`KITTI_RAW_SIZE`) and the principal point is that far off: a drive's raw
            images with its rectified calibration.
    """
    off = max(
        abs(camera.cx - camera.width / 2) / camera.width,
        abs(camera.cy - camera.height / 2) / camera.height,
    )
    if off <= CENTRE_TOLERANCE:
        return ()
    where = (
        f"{key} of calibration file {calibration} puts the principal point at "
        f"({camera.cx:.1f}, {camera.cy:.1f}), {off:.0%} of the image off its centre"
    )
    if camera.image_size == KITTI_RAW_SIZE:
        raise DatasetImportError(
            f"image {first} is {camera.width}x{camera.height} but {where}: these are KITTI's "
            "unrectified images, not the rectified ones it describes (KITTI's rectified images "
            "are 1226x370 to 1242x376); import the raw drive's _extract download with the "
            "calib_cam_to_cam.txt of its date, or the rectified images with this file"
        )
    return (
        f"{where} ({camera.width}x{camera.height}, first image {first}): imported as the "
        "rectified camera it describes (KITTI-360's is 13.5 % off, a crop's may be); if these "
        "images are resized or not rectified, the depths are wrong",
    )


def _open_odometry(sequence: Path, pair: KittiPair | None) -> KittiSequence:
    calibration = sequence / ODOMETRY_CALIBRATION
    if not calibration.is_file():
        raise DatasetImportError(
            f"KITTI odometry sequence {sequence} has no {ODOMETRY_CALIBRATION}; copy it from "
            "KITTI's odometry calibration download (data_odometry_calib)"
        )
    pair = _choose_pair(sequence, KittiLayout.ODOMETRY, pair, "KITTI odometry sequence")
    values = _key_values(calibration)
    left_key, right_key = pair.projection_keys(KittiLayout.ODOMETRY)
    left_p = _projection(calibration, values, left_key)
    right_p = _projection(calibration, values, right_key)
    left_name, right_name = pair.folders(KittiLayout.ODOMETRY)
    left, right = paired_images(sequence / left_name, sequence / right_name)
    camera = camera_from_projections(left_p, right_p, read_grey(left[0]).shape[:2], calibration)
    warned = _check_centre(camera, left[0], calibration, left_key)
    stamps = _odometry_stamps(sequence / "times.txt", left)
    poses = _poses(sequence.parent.parent / "poses" / f"{sequence.name}.txt", left)
    poses = _from_camera_0(poses, left_p)
    truths = _truth_folders(sequence, KittiLayout.ODOMETRY, pair)
    return KittiSequence(
        KittiLayout.ODOMETRY, sequence, left, right, camera, stamps, poses, pair, *truths, warned
    )


STEREO_BENCHMARK_IMAGE = re.compile(r"\d{6}_1[01]\.png")
"""An image name of KITTI's stereo 2012 and 2015 benchmarks: the scene's number, then ``10``
(the frame with disparity truth) or ``11`` (the one after it)."""


def _stereo_benchmark_image(root: Path) -> Path | None:
    """Return an image showing a folder (or its ``training``) is a stereo benchmark's, else None.

    Those folders have ``image_0``..``image_3`` (2012: also ``colored_0``) as an odometry
    sequence has, but of unrelated scenes calibrated one by one (``calib_cam_to_cam/`` or
    ``calib/``): no sequence.
    """
    for folder in (root, root / "training", root / "testing"):
        for camera in ("image_0", "image_2", "colored_0"):
            if not (folder / camera).is_dir():
                continue
            for path in (folder / camera).iterdir():
                if STEREO_BENCHMARK_IMAGE.fullmatch(path.name):
                    return path
    return None


def open_kitti(folder: str | os.PathLike[str], *, pair: KittiPair | None = None) -> KittiSequence:
    """Detect and validate a KITTI raw drive or odometry sequence (reads one image).

    Args:
        folder: a raw drive (or its date folder holding one drive) or an odometry sequence.
        pair: the grey or the colour pair; None: the grey one when the folder has it, else
            the colour one.

    Raises:
        DatasetImportError: the folder is missing, not a KITTI layout, or has a missing or
            malformed calibration, timestamp or pose file, or unequal image counts.
    """
    root = Path(folder)
    if not root.is_dir():
        raise DatasetImportError(f"KITTI folder {root} does not exist; {EXPECTED_LAYOUTS}")
    benchmark = _stereo_benchmark_image(root)
    if benchmark is not None:
        raise DatasetImportError(
            f"{root} holds KITTI's stereo 2012/2015 benchmark layout ({benchmark}: "
            "unrelated scenes of two frames each, _10 and _11, each with its own calibration), "
            "not a sequence; import the KITTI raw drive the scenes come from, or an odometry "
            "sequence"
        )
    if any((root / f"image_{camera}").is_dir() for camera in range(4)):
        return _open_odometry(root, pair)
    drive = _raw_drive_folder(root)
    if drive is not None or any((root / f"image_{c:02d}").is_dir() for c in range(4)):
        return _open_raw(drive or root, pair)
    raise DatasetImportError(f"{root} is not a KITTI folder; {EXPECTED_LAYOUTS}")


def iter_frames(sequence: KittiSequence, *, max_frames: int | None = None) -> Iterator[KittiFrame]:
    """Yield the sequence's stereo pairs one at a time (one pair in memory).

    Raises:
        DatasetImportError: an image cannot be read or has another size than the first.
    """
    count = len(sequence) if max_frames is None else min(len(sequence), max_frames)
    for index in range(count):
        pair = []
        for path in (sequence.left_paths[index], sequence.right_paths[index]):
            image = read_grey(path)
            if image.shape != sequence.camera.image_size:
                raise DatasetImportError(
                    f"image {path} is {image.shape[1]}x{image.shape[0]} but the sequence's "
                    f"first image is {sequence.camera.width}x{sequence.camera.height}; "
                    "restore the file"
                )
            pair.append(image)
        pose = None if sequence.camera_to_world is None else sequence.camera_to_world[index]
        truth = None
        if sequence.truth_folder is not None:
            path = sequence.truth_folder / sequence.left_paths[index].name
            if path.is_file():
                truth = read_depth_truth(path, sequence.camera.image_size)
        yield KittiFrame(index, int(sequence.stamps_ns[index]), pair[0], pair[1], pose, truth)


def import_kitti(
    folder: str | os.PathLike[str] | KittiSequence,
    out_path: str | os.PathLike[str],
    *,
    format: LogFormat | str | None = None,
    max_frames: int | None = None,
    progress: ProgressCallback | None = None,
    pair: KittiPair | None = None,
) -> WriteSummary:
    """Convert a KITTI raw drive or odometry sequence into a log (synthetic-log topics).

    Writes, per frame, the left/right images (mono8), both camera infos, when the sequence
    has ground-truth poses ``/ground_truth/pose``, and with the colour pair the frame's
    depth-completion truth as ``/ground_truth/lidar_depth``; log time = header stamp. An
    unrectified drive (``sequence.lens``) is written as a raw log: driver topic names and
    the raw cameras' infos (:func:`~pcainterp_stream.io.raw_log.raw_stereo_messages`).

    Args:
        folder: a raw drive ``<date>_drive_XXXX_sync`` or ``_extract`` (or its date folder
            holding one drive) or an odometry ``sequences/XX`` folder, or one already opened by
            :func:`open_kitti` (``pair`` is then ignored).
        out_path: output ``.mcap``, ``.bag`` or rosbag2 folder; written atomically.
        format: output format; chosen from ``out_path``'s name when None.
        max_frames: import only the first frames (all when None).
        progress: called as ``progress(frames_done, total)`` after every frame.
        pair: the grey or the colour pair (see :func:`open_kitti`).

    Returns:
        What was written.

    Raises:
        DatasetImportError: the folder is not a usable KITTI sequence (see :func:`open_kitti`,
            :func:`iter_frames`).
        LogWriteError: the output cannot be written.
    """
    sequence = folder if isinstance(folder, KittiSequence) else open_kitti(folder, pair=pair)
    total = len(sequence) if max_frames is None else min(len(sequence), max_frames)
    # the images too: an output path that is a link to one of them must not replace it
    inputs = [sequence.folder, *sequence.left_paths, *sequence.right_paths]
    with open_writer(out_path, format, inputs=inputs) as writer:
        for frame in iter_frames(sequence, max_frames=max_frames):
            if sequence.lens is None:
                messages = stereo_messages(frame.stamp_ns, frame.left, frame.right, sequence.camera)
            else:
                messages = raw_stereo_messages(
                    frame.stamp_ns, frame.left, frame.right, sequence.lens
                )
            for topic, message in messages:
                writer.add_message(topic, message, frame.stamp_ns)
            if frame.camera_to_world is not None:
                writer.add_message(
                    POSE, pose_message(frame.camera_to_world, frame.stamp_ns), frame.stamp_ns
                )
            if frame.depth_truth is not None:
                truth = frame.depth_truth
                message = image_message(truth, frame.stamp_ns, LEFT_FRAME, encoding="32FC1")
                writer.add_message(LIDAR_DEPTH, message, frame.stamp_ns)
            if progress is not None:
                progress(frame.frame_index + 1, total)
    return writer.summary()
