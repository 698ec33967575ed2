"""Import a KITTI stereo sequence into a log with the same topics as a synthetic log.

Two layouts are recognised:

* **raw drive**: ``<date>/<date>_drive_XXXX_sync`` with ``image_00/data/*.png`` (left grey)
  and ``image_01/data/*.png`` (right grey), ``image_00/timestamps.txt`` (one
  ``YYYY-MM-DD HH:MM:SS.fffffffff`` per frame) and ``calib_cam_to_cam.txt`` in the drive
  folder or one level up in the date folder (``P_rect_00``, ``P_rect_01``). The date folder
  itself is accepted when it holds exactly one drive.
* **odometry sequence**: ``sequences/XX`` with ``image_0/*.png``, ``image_1/*.png``,
  ``calib.txt`` (``P0:``, ``P1:`` lines of 12 numbers), optional ``times.txt`` (seconds, one
  per frame) and optional ground truth ``poses/XX.txt`` two levels up (a 3x4
  camera-to-world matrix per line, row-major).

The camera comes from the rectified projection matrices: fx, fy, cx, cy of the left one and
baseline b = (P_left[0, 3] - P_right[0, 3]) / P_right[0, 0] (= -P1[0, 3] / P1[0, 0] in
KITTI, where P_left[0, 3] = 0). Without timestamps frames are 10 Hz from t = 0. Frames are
read and written one at a time.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from enum import Enum
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import DatasetImportError
from pcainterp_stream.io.logwriter import LogFormat, ProgressCallback, WriteSummary, open_writer
from pcainterp_stream.io.stereo_log import POSE, pose_message, stereo_messages
from pcainterp_stream.records import StereoCamera

FRAME_PERIOD_NS = 100_000_000
"""KITTI records at 10 Hz."""

RAW_CALIBRATION = "calib_cam_to_cam.txt"
ODOMETRY_CALIBRATION = "calib.txt"

EXPECTED_LAYOUTS = (
    "expected a KITTI raw drive folder (<date>_drive_XXXX_sync with image_00/data and "
    "image_01/data, and calib_cam_to_cam.txt in it or one level up) or an odometry sequence "
    "folder (sequences/XX with image_0, image_1 and calib.txt)"
)


class KittiLayout(Enum):
    """The KITTI folder layouts the importer reads."""

    RAW = "raw drive"
    ODOMETRY = "odometry sequence"


@dataclass(frozen=True)
class KittiSequence:
    """A validated KITTI stereo sequence, with file lists but no image data loaded.

    Attributes:
        layout: which KITTI layout the folder has.
        folder: the drive or sequence folder.
        left_paths: left (camera 0) image files in frame order.
        right_paths: right (camera 1) image files, same length and names.
        camera: the rectified stereo calibration (size of the first left image).
        stamps_ns: (n,) int64 capture times (ns).
        camera_to_world: (n, 4, 4) float64 left-camera poses, or None without ground truth.
    """

    layout: KittiLayout
    folder: Path
    left_paths: list[Path]
    right_paths: list[Path]
    camera: StereoCamera
    stamps_ns: npt.NDArray[np.int64]
    camera_to_world: npt.NDArray[np.float64] | None

    def __len__(self) -> int:
        return len(self.left_paths)


class KittiFrame(NamedTuple):
    """One KITTI stereo pair.

    Attributes:
        frame_index: 0-based frame number.
        stamp_ns: capture time (ns).
        left: (H, W) uint8 rectified left grey image.
        right: (H, W) uint8 rectified right grey image.
        camera_to_world: (4, 4) float64 left-camera pose, or None without ground truth.
    """

    frame_index: int
    stamp_ns: int
    left: npt.NDArray[np.uint8]
    right: npt.NDArray[np.uint8]
    camera_to_world: npt.NDArray[np.float64] | None


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


def _pngs(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() == ".png")


def _paired_images(left_dir: Path, right_dir: Path) -> tuple[list[Path], list[Path]]:
    left, right = _pngs(left_dir), _pngs(right_dir)
    if len(left) != len(right):
        raise DatasetImportError(
            f"{left_dir} has {len(left)} images but {right_dir} has {len(right)}; "
            "every left image needs its right image: restore the missing files"
        )
    if not left:
        raise DatasetImportError(f"{left_dir} holds no .png images; {EXPECTED_LAYOUTS}")
    for a, b in zip(left, right, strict=True):
        if a.name != b.name:
            raise DatasetImportError(
                f"left image {a} has no right image of the same name in {right_dir} "
                f"(found {b.name}); restore the missing files"
            )
    return left, right


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
    return stamps


def _odometry_stamps(path: Path, count: int) -> npt.NDArray[np.int64]:
    """Parse an odometry ``times.txt`` (seconds from the start, one per frame)."""
    if not path.is_file():
        return np.arange(count, dtype=np.int64) * FRAME_PERIOD_NS
    lines = [line for line in path.read_text().splitlines() if line.strip()]
    if len(lines) != count:
        raise DatasetImportError(
            f"{path} has {len(lines)} times for {count} images; "
            "restore the file or the missing images"
        )
    try:
        seconds = np.array([float(line) for line in lines])
    except ValueError as err:
        raise DatasetImportError(
            f"{path} must hold one number (seconds) per line: {err}; fix or restore the file"
        ) from err
    return np.round(seconds * 1e9).astype(np.int64)


def _poses(path: Path, count: int) -> npt.NDArray[np.float64] | None:
    """Parse KITTI odometry ground truth: a row-major 3x4 camera-to-world per line."""
    if not path.is_file():
        return None
    lines = [line for line in path.read_text().splitlines() if line.strip()]
    if len(lines) != count:
        raise DatasetImportError(
            f"pose file {path} has {len(lines)} poses for {count} images; "
            "it must have one line per frame: restore the file"
        )
    poses = np.tile(np.eye(4), (count, 1, 1))
    for i, line in enumerate(lines):
        try:
            numbers = [float(item) for item in line.split()]
        except ValueError:
            numbers = []
        if len(numbers) != 12:
            raise DatasetImportError(
                f"line {i + 1} of pose file {path} must hold 12 numbers (a 3x4 matrix); "
                "fix or restore the file"
            )
        poses[i, :3, :] = np.reshape(numbers, (3, 4))
    return poses


def _raw_drive_folder(folder: Path) -> Path | None:
    """Return the drive folder for a drive or a date folder holding one drive, else None."""
    if (folder / "image_00" / "data").is_dir():
        return folder
    drives = sorted(p for p in folder.glob("*_sync") if (p / "image_00" / "data").is_dir())
    if len(drives) > 1:
        names = ", ".join(p.name for p in drives)
        raise DatasetImportError(
            f"{folder} holds {len(drives)} KITTI raw drives ({names}); pass one drive folder"
        )
    return drives[0] if drives else None


def _open_raw(drive: Path) -> KittiSequence:
    for name in ("image_00", "image_01"):
        if not (drive / name / "data").is_dir():
            raise DatasetImportError(
                f"KITTI raw drive {drive} has no {name}/data folder; {EXPECTED_LAYOUTS}"
            )
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
    left_p = _projection(calibration, values, "P_rect_00")
    right_p = _projection(calibration, values, "P_rect_01")
    left, right = _paired_images(drive / "image_00" / "data", drive / "image_01" / "data")
    camera = camera_from_projections(left_p, right_p, read_grey(left[0]).shape[:2], calibration)
    stamps = _raw_stamps(drive / "image_00" / "timestamps.txt", len(left))
    return KittiSequence(KittiLayout.RAW, drive, left, right, camera, stamps, None)


def _open_odometry(sequence: Path) -> KittiSequence:
    calibration = sequence / ODOMETRY_CALIBRATION
    if not calibration.is_file():
        raise DatasetImportError(
            f"KITTI odometry sequence {sequence} has no {ODOMETRY_CALIBRATION}; copy it from "
            "KITTI's odometry calibration download (data_odometry_calib)"
        )
    values = _key_values(calibration)
    left_p = _projection(calibration, values, "P0")
    right_p = _projection(calibration, values, "P1")
    left, right = _paired_images(sequence / "image_0", sequence / "image_1")
    camera = camera_from_projections(left_p, right_p, read_grey(left[0]).shape[:2], calibration)
    stamps = _odometry_stamps(sequence / "times.txt", len(left))
    poses = _poses(sequence.parent.parent / "poses" / f"{sequence.name}.txt", len(left))
    return KittiSequence(KittiLayout.ODOMETRY, sequence, left, right, camera, stamps, poses)


def open_kitti(folder: str | os.PathLike[str]) -> KittiSequence:
    """Detect and validate a KITTI raw drive or odometry sequence (reads one image).

    Raises:
        DatasetImportError: the folder is missing, not a KITTI layout, or has a missing or
            malformed calibration, timestamp or pose file, or unequal image counts.
    """
    root = Path(folder)
    if not root.is_dir():
        raise DatasetImportError(f"KITTI folder {root} does not exist; {EXPECTED_LAYOUTS}")
    if (root / "image_0").is_dir() or (root / "image_1").is_dir():
        if not ((root / "image_0").is_dir() and (root / "image_1").is_dir()):
            raise DatasetImportError(
                f"KITTI odometry sequence {root} needs both image_0 and image_1; "
                "restore the missing camera folder"
            )
        return _open_odometry(root)
    drive = _raw_drive_folder(root)
    if drive is not None or (root / "image_01").is_dir():
        return _open_raw(drive or root)
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
        yield KittiFrame(index, int(sequence.stamps_ns[index]), pair[0], pair[1], pose)


def import_kitti(
    folder: str | os.PathLike[str],
    out_path: str | os.PathLike[str],
    *,
    format: LogFormat | str | None = None,
    max_frames: int | None = None,
    progress: ProgressCallback | None = None,
) -> WriteSummary:
    """Convert a KITTI raw drive or odometry sequence into a log (synthetic-log topics).

    Writes, per frame, the left/right images (mono8), both camera infos and, when the
    sequence has ground-truth poses, ``/ground_truth/pose``; log time = header stamp.

    Args:
        folder: a raw drive ``<date>_drive_XXXX_sync`` (or its date folder holding one drive)
            or an odometry ``sequences/XX`` folder.
        out_path: output ``.mcap``, ``.bag`` or rosbag2 folder; written atomically.
        format: output format; chosen from ``out_path``'s name when None.
        max_frames: import only the first frames (all when None).
        progress: called as ``progress(frames_done, total)`` after every frame.

    Returns:
        What was written.

    Raises:
        DatasetImportError: the folder is not a usable KITTI sequence (see :func:`open_kitti`,
            :func:`iter_frames`).
        LogWriteError: the output cannot be written.
    """
    sequence = open_kitti(folder)
    total = len(sequence) if max_frames is None else min(len(sequence), max_frames)
    with open_writer(out_path, format, inputs=[sequence.folder]) as writer:
        for frame in iter_frames(sequence, max_frames=max_frames):
            for topic, message in stereo_messages(
                frame.stamp_ns, frame.left, frame.right, sequence.camera
            ):
                writer.add_message(topic, message, frame.stamp_ns)
            if frame.camera_to_world is not None:
                writer.add_message(
                    POSE, pose_message(frame.camera_to_world, frame.stamp_ns), frame.stamp_ns
                )
            if progress is not None:
                progress(frame.frame_index + 1, total)
    return writer.summary()
