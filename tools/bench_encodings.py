"""Output encodings benchmark: bytes, CPU and precision of each channel's candidate forms.

Reads a log densified at full precision (``pcainterp densify IN -o OUT --precision full``:
float32 depth, depth_std, disparity, disparity_std) and, for every ``--every``-th frame,
encodes each channel in each candidate form, then decodes it again:

- bytes per frame as written (a PNG / RVL is stored as it is; a raw image's bytes after the
  MCAP writer's zstd at level -1, the chunk compression ``densify`` uses);
- encode and decode CPU ms per frame (one thread);
- the quantisation error against the float result in units of the pixel's posterior std
  (disparity std for depth and disparity, the std itself for the stds: relative error),
  the largest over near pixels (depth < 20 m) and far ones (>= 20 m), and over all;
- whether REP 118 survives (NaN where NaN, ``+inf`` where ``+inf``).

Example::

    python tools/bench_encodings.py kitti_odometry_full.mcap --every 5
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import harness
import numpy as np
import numpy.typing as npt
import zstandard

from pcainterp_stream.io import depth_codec, outputs, rosmsg
from pcainterp_stream.io.logreader import open_log

NEAR_M = 20.0
Floats = npt.NDArray[np.float32]
Encoder = Callable[[dict[str, Any]], tuple[bytes, Callable[[], Floats]]]


def frames(path: Path, every: int) -> list[dict[str, Any]]:
    """Return every ``every``-th frame's float channels, f*b and min disparity."""
    topics = outputs.OutputTopics()
    wanted = [topics.depth, topics.depth_std, topics.disparity, topics.disparity_std]
    grouped: dict[int, dict[str, Any]] = defaultdict(dict)
    with open_log(path) as reader:
        missing = [topic for topic in wanted if topic not in reader.topics()]
        if missing:
            raise SystemExit(
                f"{path} has no {', '.join(missing)}; densify it with --precision full"
            )
        for raw in reader.messages(wanted):
            message = reader.decode(raw)
            name = raw.topic.rsplit("/", 1)[1]
            if name == "disparity":
                grouped[rosmsg.stamp_ns(message)].update(
                    disparity=rosmsg.image_array(message.image),
                    focal_baseline=float(message.f) * float(message.t),
                )
            else:
                grouped[rosmsg.stamp_ns(message)][name] = rosmsg.image_array(message)
    return [grouped[stamp] for stamp in sorted(grouped)][::every]


_ZSTD = zstandard.ZstdCompressor(level=-1)
_UNZSTD = zstandard.ZstdDecompressor()


def raw_zstd(array: npt.NDArray[np.generic]) -> tuple[bytes, Callable[[], Floats]]:
    """A raw Image's bytes in a zstd -1 chunk; decoding gives the same array back."""
    data = _ZSTD.compress(np.ascontiguousarray(array).tobytes())
    dtype, shape = array.dtype, array.shape

    def decode() -> Floats:
        values = np.frombuffer(_UNZSTD.decompress(data), dtype=dtype).reshape(shape)
        return values.astype(np.float32)

    return data, decode


def compressed(encoded: depth_codec.CompressedDepth) -> tuple[bytes, Callable[[], Floats]]:
    """A compressedDepth message's bytes; decoding as ROS's subscriber does."""
    return encoded.data, lambda: depth_codec.decode(encoded.format, encoded.data).astype(np.float32)


def depth_quant_a(frame: dict[str, Any]) -> float:
    """Return the compact depth's depthQuantA of a frame, as densify chooses it."""
    finite = np.isfinite(frame["depth"])
    max_disparity = frame["focal_baseline"] / float(np.min(frame["depth"][finite]))
    step = outputs.depth_step(frame["disparity_std"])
    return depth_codec.inverse_depth_scale(frame["focal_baseline"], step, max_disparity)


def millimetres(depth: Floats, step_mm: int = 1, far_mm: float = 65535.0) -> Any:
    """Return depth (m) as 16UC1 millimetres: 0 = NaN, far_mm for +inf and beyond."""
    values = np.nan_to_num(depth * 1000.0, nan=0.0, posinf=far_mm, neginf=0.0)
    values = np.rint(values / step_mm) * step_mm
    return np.clip(values, 0, far_mm).astype(np.uint16)


def from_mm(code: npt.NDArray[np.uint16]) -> Floats:
    """16UC1 millimetres back to metres per REP 118 (0: no estimate)."""
    metres = code.astype(np.float32) / 1000.0
    metres[code == 0] = np.nan
    return metres


CANDIDATES: dict[str, dict[str, Encoder]] = {
    "depth": {
        "Image 32FC1 (full)": lambda f: raw_zstd(f["depth"]),
        "Image 16UC1 mm": lambda f: (
            (encoded := raw_zstd(millimetres(f["depth"])))[0],
            lambda: from_mm(np.rint(encoded[1]()).astype(np.uint16)),
        ),
        "compressedDepth 16UC1 png (mm)": lambda f: (
            (encoded := depth_codec.encode_16(millimetres(f["depth"]))).data,
            lambda: from_mm(depth_codec.decode(encoded.format, encoded.data)),
        ),
        "compressedDepth 32FC1 png (default)": lambda f: compressed(
            depth_codec.encode_depth(f["depth"], quant_a=depth_quant_a(f))
        ),
        "compressedDepth 32FC1 rvl": lambda f: compressed(
            depth_codec.encode_depth(f["depth"], quant_a=depth_quant_a(f), codec="rvl")
        ),
    },
    "disparity_std": {
        "Image 32FC1 (full)": lambda f: raw_zstd(f["disparity_std"]),
        "compressedDepth 32FC1 png (default)": lambda f: compressed(
            depth_codec.encode_depth(
                f["disparity_std"], quant_a=outputs.std_scale(f["disparity_std"])
            )
        ),
        "compressedDepth 32FC1 rvl": lambda f: compressed(
            depth_codec.encode_depth(
                f["disparity_std"], quant_a=outputs.std_scale(f["disparity_std"]), codec="rvl"
            )
        ),
    },
    "depth_std": {
        "Image 32FC1 (full)": lambda f: raw_zstd(f["depth_std"]),
        "compressedDepth 16UC1 png (mm)": lambda f: (
            (encoded := depth_codec.encode_16(millimetres(f["depth_std"]))).data,
            lambda: from_mm(depth_codec.decode(encoded.format, encoded.data)),
        ),
        "compressedDepth 32FC1 png": lambda f: compressed(
            depth_codec.encode_depth(f["depth_std"], quant_a=outputs.std_scale(f["depth_std"]))
        ),
    },
    "disparity": {
        "DisparityImage 32FC1 (full)": lambda f: raw_zstd(f["disparity"]),
    },
    "depth_mm (viewers)": {
        "Image 16UC1 mm, 0-60 m": lambda f: (
            (encoded := raw_zstd(millimetres(f["depth"], 1, 60000.0)))[0],
            lambda: from_mm(np.rint(encoded[1]()).astype(np.uint16)),
        ),
        "Image 16UC1 mm, 0-60 m, 5 cm steps (default)": lambda f: (
            (encoded := raw_zstd(millimetres(f["depth"], 50, 60000.0)))[0],
            lambda: from_mm(np.rint(encoded[1]()).astype(np.uint16)),
        ),
    },
}


def errors(channel: str, frame: dict[str, Any], decoded: Floats) -> tuple[float, float, bool]:
    """Return the largest error in std units near and far, and whether REP 118 survives."""
    depth = frame["depth"]
    std = frame["disparity_std"]
    exact = frame["depth" if channel.startswith("depth_mm") else channel]
    fb = frame["focal_baseline"]
    rep118 = bool(
        np.array_equal(np.isnan(decoded), np.isnan(exact))
        and np.array_equal(np.isposinf(decoded), np.isposinf(exact))
    )
    both = np.isfinite(exact) & np.isfinite(decoded) & (exact > 0) & (std > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        if channel in ("depth", "depth_mm (viewers)"):
            error = fb * np.abs(1.0 / decoded - 1.0 / exact) / std
        elif channel == "disparity":
            error = np.abs(decoded - exact) / std
        else:  # a std: relative error
            error = np.abs(decoded / exact - 1.0)
    near = both & (depth < NEAR_M)
    far = both & ~(depth < NEAR_M)
    return (
        float(np.max(error[near])) if near.any() else 0.0,
        float(np.max(error[far])) if far.any() else 0.0,
        rep118,
    )


def measure(path: Path, every: int) -> str:
    """Return the Markdown table of every candidate over the frames of a log."""
    chosen = frames(path, every)
    header = ["channel", "form", "KB/frame", "encode ms", "decode ms"]
    header += [f"max error / std, near (< {NEAR_M:.0f} m)", "far", "REP 118 kept"]
    lines = [f"{path}: {len(chosen)} frames", harness.table_header(header)]
    for channel, candidates in CANDIDATES.items():
        for name, encode in candidates.items():
            sizes, encode_ms, decode_ms, near, far, kept = [], [], [], [], [], True
            for frame in chosen:
                started = time.process_time()
                data, decode = encode(frame)
                encode_ms.append(1000 * (time.process_time() - started))
                started = time.process_time()
                decoded = decode()
                decode_ms.append(1000 * (time.process_time() - started))
                sizes.append(len(data))
                n, f, k = errors(channel, frame, decoded)
                near.append(n)
                far.append(f)
                kept = kept and k
            lines.append(
                harness.table_row(
                    [
                        channel,
                        name,
                        f"{np.mean(sizes) / 1e3:.0f}",
                        f"{np.median(encode_ms):.1f}",
                        f"{np.median(decode_ms):.1f}",
                        f"{max(near):.3g}",
                        f"{max(far):.3g}",
                        "yes" if kept else "no",
                    ]
                )
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Measure the candidate encodings of a full-precision densified log."""
    parser = harness.argument_parser(__doc__)
    parser.add_argument("log", type=Path, help="a log densified with --precision full")
    parser.add_argument("--every", type=int, default=5, help="measure every n-th frame")
    args = parser.parse_args(argv)
    print(measure(args.log, args.every))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
