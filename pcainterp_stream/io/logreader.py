"""Read recorded logs (MCAP, ROS 1 bags, rosbag2 folders) as a stream of raw messages.

:func:`open_log` looks at a path and returns an opened :class:`LogReader`, a context manager
in the manner of rosbags' ``AnyReader``. Every reader yields :class:`~records.RawMessage`
records in log-time order (an MCAP without a chunk index, a bag without its index: in file
order) with bounded memory, and normalises what it yields so that the rest of the pipeline
sees one kind of log: ROS messages are CDR with a ``ros2msg`` schema and type names in ROS 2
spelling (``sensor_msgs/msg/Image``), whatever the input format.

Damaged input is read as far as it can be: the reader yields every message before the
damage, then stops (or skips a damaged chunk whose framing is intact) and records a
one-line description in :attr:`LogReader.damage`. Only a path that is not a log at all, or
one that cannot be read from its start, raises :class:`~errors.LogReadError`. No library
exception escapes as such.

The MCAP reader walks the records itself (one record, at most one chunk, in memory at a
time) rather than through ``mcap.reader``: that reader raises ``KeyError`` on files whose
summary does not repeat schemas and channels, and cannot resume after a corrupt chunk.
The record classes of the ``mcap`` package still parse the rare records (schemas, channels,
summary); messages, the hot path, are unpacked with :mod:`struct`.
"""

from __future__ import annotations

import os
import re
import shlex
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.mcap_reader import McapLogReader
from pcainterp_stream.io.reader_base import (
    _LOG_KINDS,
    MCAP_MAGIC,
    SQLITE_MAGIC,
    LogFormat,
    LogReader,
    TopicInfo,
    _one_line,
)

if TYPE_CHECKING:  # imported on first use, by the module's __getattr__ below
    from pcainterp_stream.io.rosbags_reader import RosbagsLogReader

__all__ = [
    "LogFormat",
    "LogReader",
    "McapLogReader",
    "RosbagsLogReader",
    "TopicInfo",
    "decode_image",
    "log_files",
    "looks_like_kitti",
    "open_log",
    "sniff_format",
]


ROS1_MAGIC = b"#ROSBAG V2.0"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def __getattr__(name: str) -> Any:
    """``RosbagsLogReader``, imported on first use (rosbags' readers: ~65 ms to import)."""
    if name == "RosbagsLogReader":
        from pcainterp_stream.io.rosbags_reader import RosbagsLogReader

        return RosbagsLogReader
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def sniff_format(path: str | Path) -> LogFormat:
    """Return the format of a log path, by its kind and magic bytes.

    Raises:
        LogReadError: the path does not exist or is not a log (with a hint for a KITTI folder).
    """
    path = Path(path)
    if not path.exists():
        raise LogReadError(f"{path} does not exist; pass {_LOG_KINDS}")
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return LogFormat.ROSBAG2
        from pcainterp_stream.io.rosbags_reader import _storage_files

        storage = _storage_files(path)
        logs = sorted({*storage, *(p for p in path.glob("*.bag") if p.is_file())})
        if looks_like_kitti(path):
            hint = "; it looks like a KITTI folder: convert it with `pcainterp import-kitti`"
        elif len(storage) == 1 and len(logs) == 1:
            hint = f"; pass its storage file {storage[0]} directly"
        elif len(logs) > 1 and logs == storage and _split_bag(path, storage):
            hint = f"; pass its storage files directly ({_files_glob(path, storage, bag=True)})"
        elif len(logs) > 1 and (prefix := _split_ros1(logs)) is not None:
            hint = (
                f"; it holds {len(logs)} ROS 1 bags named as the parts of one split recording "
                f"({_names(logs)}): pass them together, read as one log (densify "
                f"{_shell_glob(path, prefix + '_', '*.bag')} -o OUTPUT; docs/raw_logs.md, "
                '"A recording split into several bags")'
            )
        elif len(logs) > 1:  # separate logs, not one recording's storage: never one of them
            hint = (
                f"; it holds {len(logs)} logs ({_names(logs)}), not one recording: pass the log "
                f"files themselves (all of them, {_files_glob(path, logs)}, to learn or "
                "densify --out-dir DIR)"
            )
        else:
            hint = "; pass an MCAP file, a ROS 1 .bag or a rosbag2 folder (with metadata.yaml)"
        raise LogReadError(f"{path} is a folder but not a rosbag2 bag (no metadata.yaml){hint}")
    try:
        with path.open("rb") as f:
            head = f.read(16)
    except OSError as err:
        raise LogReadError(f"cannot open {path}: {_one_line(err)}") from err
    if head.startswith(MCAP_MAGIC):
        return LogFormat.MCAP
    if head.startswith(ROS1_MAGIC):
        return LogFormat.ROS1
    if head.startswith(SQLITE_MAGIC):
        return LogFormat.ROSBAG2
    if not head:
        raise LogReadError(f"{path} is empty, not a log; pass {_LOG_KINDS}")
    if head.startswith(b"\x28\xb5\x2f\xfd"):  # a rosbag2 --compression-mode file storage file
        folder = path.parent if (path.parent / "metadata.yaml").is_file() else None
        where = (
            f"its folder {folder}" if folder else "the rosbag2 bag's folder (with metadata.yaml)"
        )
        raise LogReadError(
            f"{path} is zstd-compressed (a rosbag2 bag recorded with --compression-mode file?); "
            f"pass {where}, or decompress it first (`zstd -d {shlex.quote(str(path))}`)"
        )
    suffix = {".mcap": "an MCAP file", ".bag": "a ROS 1 bag", ".db3": "a rosbag2 sqlite3 file"}
    expected = suffix.get(path.suffix.lower())
    what = (
        f"named like {expected} but does not start with its magic bytes"
        if expected
        else ("not a log (no MCAP, ROS 1 bag or SQLite magic bytes)")
    )
    raise LogReadError(f"{path} is {what}; pass an MCAP file, a ROS 1 .bag or a rosbag2 folder")


def _split_bag(folder: Path, files: list[Path]) -> bool:
    """Whether ``files`` are named as rosbag2 names a split bag's: ``<folder>_<n>.<ext>``."""
    pattern = re.compile(re.escape(folder.name) + r"_\d+\.(mcap|db3)")
    return all(pattern.fullmatch(file.name) for file in files)


def _split_ros1(files: list[Path]) -> str | None:
    """The prefix of ROS 1 bags named as ``rosbag record --split`` names its parts, else None.

    ``<prefix>_<n>.bag`` (``run_2026-11-28-10-00-00_0.bag``, ``_1.bag``, ...): one prefix, the
    indices 0, 1, 2, ... with none missing.
    """
    pattern = re.compile(r"(.+)_(\d+)\.bag")
    matches = [pattern.fullmatch(file.name) for file in files]
    if not all(matches):
        return None
    prefixes = {match.group(1) for match in matches if match}
    indices = sorted(int(match.group(2)) for match in matches if match)
    if len(prefixes) != 1 or indices != list(range(len(indices))):
        return None
    return prefixes.pop()


def _files_glob(folder: Path, files: list[Path], *, bag: bool = False) -> str:
    """A shell pattern for ``files`` in ``folder``: ``logs/*.mcap``, ``bag/bag_*.mcap``."""
    suffixes = sorted({f.suffix for f in files})
    start = f"{folder.name}_" if bag else ""
    return " ".join(_shell_glob(folder, start, f"*{suffix}") for suffix in suffixes)


def _shell_glob(folder: Path, start: str, wildcard: str) -> str:
    """``folder/start`` quoted for a shell where it needs it, then ``wildcard`` unquoted.

    ``'my logs'/*.mcap``, ``'my logs/run 1_'*.bag``: pasted as they are, the shell still
    expands the pattern (review 15e R5: a folder with a space broke the suggestion).
    """
    literal = f"{folder / start}" if start else f"{folder}/"
    return f"{shlex.quote(literal)}{wildcard}"


def _names(files: list[Path], shown: int = 3) -> str:
    """``a.mcap, b.mcap``; past ``shown`` names, the first ones and how many more."""
    names = [file.name for file in files[:shown]]
    more = f" and {len(files) - shown} more" if len(files) > shown else ""
    return ", ".join(names) + more


def log_files(path: str | Path) -> list[Path]:
    """Return the files reading a log path opens: a rosbag2 folder's storage files, else it.

    A rosbag2 folder's files are those its ``metadata.yaml`` lists (``relative_file_paths``),
    or, when that does not parse, the ``.mcap`` and ``.db3`` files in it. Two paths that
    share a file are one log given twice (a folder and its own storage file).
    """
    import yaml

    path = Path(path)
    if not path.is_dir():
        return [path]
    try:
        info = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        return [path / str(name) for name in info["relative_file_paths"]] or [path]
    except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError):
        files = [p for p in path.iterdir() if p.suffix in (".mcap", ".db3") and p.is_file()]
        return sorted(files) or [path]


def looks_like_kitti(path: str | Path) -> bool:
    """Return True for a KITTI raw drive (``image_00/data``) or odometry sequence folder."""
    path = Path(path)
    if not path.is_dir():
        return False
    markers = [
        path / "image_00" / "data",
        path / "image_0",
        path / "sequences",
        path / "calib_cam_to_cam.txt",
    ]
    if any(p.exists() for p in markers):
        return True
    return any(child.is_dir() and child.name.endswith("_sync") for child in path.iterdir())


def open_log(path: str | Path | Sequence[str | Path]) -> LogReader:
    """Open a log for reading: an MCAP file, a ROS 1 ``.bag``, or a rosbag2 folder / ``.db3``.

    The reader is returned open; use it as a context manager to close it::

        with open_log("drive.mcap") as reader:
            for raw in reader.messages(["/stereo/left/image_rect"]):
                image = decode_image(reader.decode(raw))

    A sequence of paths is the parts of one split recording (``rosbag record --split``:
    ``a_0.bag``, ``a_1.bag``), read as one log in log-time order
    (:class:`~.logreader_parts.PartsLogReader`).

    Raises:
        LogReadError: the path is missing, not a log, or unreadable from its start; parts
            of several formats, given twice or overlapping in log time.
    """
    if not isinstance(path, str | os.PathLike):
        paths = [Path(item) for item in path]
        if len(paths) != 1:
            from pcainterp_stream.io.logreader_parts import PartsLogReader

            if not paths:
                raise LogReadError(f"no log given; pass {_LOG_KINDS}")
            formats = [sniff_format(item) for item in paths]
            parts = PartsLogReader(paths, formats, [log_files(item) for item in paths], open_log)
            parts.open()
            return parts
        path = paths[0]
    path = Path(path)
    log_format = sniff_format(path)
    if log_format is not LogFormat.ROS1 and path.is_file():
        from pcainterp_stream.io.rosbag2_mcap import lone_storage_problem

        problem = lone_storage_problem(path, sqlite=log_format is LogFormat.ROSBAG2)
        if problem is not None:
            raise LogReadError(problem)
    reader: LogReader
    if log_format is LogFormat.MCAP:
        reader = McapLogReader(path)
    elif log_format is LogFormat.ROS1:
        # an indexed bag through rosbags; one without a usable index in file order
        from pcainterp_stream.io.rosbag1_walk import open_ros1_bag

        return open_ros1_bag(path)
    else:
        from pcainterp_stream.io.rosbag2_mcap import (
            Rosbag2McapReader,
            mcap_storage_files,
            message_zstd,
        )

        files = mcap_storage_files(path) if path.is_dir() else None
        if files is not None:  # its MCAP files, as given directly: attachments, publish times
            reader = Rosbag2McapReader(path, files, message_zstd=message_zstd(path))
        else:
            # imported here: rosbags' readers take ~65 ms to import, which an MCAP job never uses
            from pcainterp_stream.io.rosbags_reader import RosbagsLogReader

            reader = RosbagsLogReader(path, log_format)
    reader.open()
    return reader


def decode_image(message: Any) -> npt.NDArray[np.generic]:
    """Decode a camera's ``sensor_msgs/Image`` or ``sensor_msgs/CompressedImage`` into an array.

    Args:
        message: a typestore ``Image`` (mono8, rgb8, bgr8, mono16 and the other encodings of
            :data:`rosmsg.CAMERA_IMAGE_ENCODINGS`) or ``CompressedImage`` (png, jpeg; a
            compressed_image_transport format's encoding prefix is read: a
            ``bayer_rggb8; png compressed `` mosaic is demosaiced as the raw ``Image`` is,
            ``... compressed rgb8`` bytes are taken in RGB order, others in BGR).

    Returns:
        (H, W) grey or (H, W, 3) RGB array: uint8 for 8-bit encodings, uint16 for 16-bit
        ones (mono16 stays uint16).

    Raises:
        ValueError: for an unsupported encoding or format (named; a float image such as
            32FC1 depth is no camera image), an empty image (0x0, or a 0-byte payload), or
            data that does not decode.
    """
    if hasattr(message, "encoding"):
        encoding = str(message.encoding)
        if encoding not in rosmsg.CAMERA_IMAGE_ENCODINGS:
            supported = ", ".join(rosmsg.CAMERA_IMAGE_ENCODINGS)
            raise ValueError(
                f"unsupported image encoding {encoding!r}; camera images are {supported}"
            )
        return rosmsg.image_array(message)
    image_format = str(getattr(message, "format", ""))
    kind = image_format.lower().replace(";", " ").split()
    if not kind:  # an empty format (hand-written publishers, some bridges): the bytes decide
        kind = _sniffed_kind(message.data)
    known = {"png", "jpeg", "jpg"}
    if not known.intersection(kind) or "compresseddepth" in kind:
        raise ValueError(
            f"unsupported compressed image format {image_format!r}; supported: png, jpeg"
        )
    data = np.asarray(message.data, dtype=np.uint8)
    codec = "png" if "png" in kind else "jpeg"
    if data.size == 0:  # cv2.imdecode asserts on it
        raise ValueError(f"compressed {codec} image is empty (0 bytes, format {image_format!r})")
    # the content decides, not the format's word (imdecode sniffs it: JPEG bytes labelled
    # png decode as PNG bytes labelled jpeg do). A cut-off PNG: said here, or libpng prints
    # its own lines (a JPEG may carry padding after its end marker, as some UVC cameras
    # send it: no such check)
    if bytes(data[:8]) == PNG_SIGNATURE:
        codec = "png"
        if b"IEND" not in bytes(data[-4096:]):
            raise ValueError(
                f"compressed png image is cut off (no end marker; {data.size} bytes, format "
                f"{image_format!r})"
            )
    elif bytes(data[:2]) == b"\xff\xd8":
        codec = "jpeg"
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(
            f"compressed {codec} image does not decode ({data.size} bytes, format {image_format!r})"
        )
    if image.ndim == 2:  # grey, or a Bayer mosaic the format's prefix names
        return np.asarray(rosmsg.demosaic_compressed(image, image_format))
    # the encoded bytes are BGR (OpenCV's order, compressed_image_transport's "compressed
    # bgr8"), unless the format says "compressed rgb8"
    stored_rgb = rosmsg.compressed_format_encoding(image_format)[1].startswith("rgb")
    if image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_RGBA2RGB if stored_rgb else cv2.COLOR_BGRA2RGB)
    elif not stored_rgb:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    return np.asarray(image)


def _sniffed_kind(data: Any) -> list[str]:
    """Return ["png"] or ["jpeg"] by a compressed image's magic bytes, [] for neither."""
    head = bytes(np.asarray(data[:8], dtype=np.uint8))
    if head == PNG_SIGNATURE:
        return ["png"]
    if head[:2] == b"\xff\xd8":
        return ["jpeg"]
    return []
