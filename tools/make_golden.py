"""Regenerate the golden synthetic log and its expected summary.

Writes ``tests/data/golden_synth.mcap`` (a tiny synthetic log: 4 frames, scale 0.25,
seed 0) and ``tests/data/golden_synth.json`` (what the log must contain), then densifies
that log with ``tests/data/golden_basis.npz`` (16 components learned from the SGBM maps of
another 40-frame drive, seed 7; re-learned only when missing or with ``--new-basis``) and
writes ``tests/data/golden_dense.json``, the expected summary of ``pcainterp densify``'s
output. Like the MCAP
conformance suite's ``.json`` beside each ``.mcap``, the JSON records channels, message
counts, per-message log times and header stamps, and for every array robust statistics
(mean, std, quantiles, rounded sum, NaN count) rather than a byte hash, so that tiny
floating-point differences of the renderer across machines stay within the tolerances
stated in the JSON itself.

Usage::

    PYTHONPATH=. python tools/make_golden.py            # regenerate tests/data/golden_synth.*
    PYTHONPATH=. python tools/make_golden.py --check    # compare a fresh render with the JSON

(from the repository root; or ``pip install -e .`` and drop ``PYTHONPATH=.``).
"""

from __future__ import annotations

import math
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from mcap.reader import make_reader

from pcainterp_stream.io import depth_codec, rosmsg
from pcainterp_stream.io.logwriter import LogFormat
from pcainterp_stream.synth.log import write_synthetic_log

try:
    import harness
except ModuleNotFoundError:  # loaded by its path (the golden tests): tools/ is not on sys.path
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import harness

FORMAT = "pcainterp-golden/1"
DATA_DIR = Path(__file__).resolve().parents[1] / "tests" / "data"
GOLDEN_LOG = DATA_DIR / "golden_synth.mcap"
GOLDEN_JSON = DATA_DIR / "golden_synth.json"
SEED, FRAMES, SCALE = 0, 4, 0.25
GOLDEN_BASIS = DATA_DIR / "golden_basis.npz"
GOLDEN_DENSE_JSON = DATA_DIR / "golden_dense.json"
BASIS_SEED, BASIS_FRAMES, BASIS_COMPONENTS = 7, 40, 16
QUANTILES = (0.01, 0.1, 0.25, 0.5, 0.75, 0.9, 0.99)

TOLERANCE: dict[str, Any] = {
    "note": (
        "Arrays are compared by statistics, not bytes. 8-bit images: mean and std within "
        "mean_std_abs grey levels, quantiles within quantile_abs levels, rounded sum within "
        "sum_rel of the expected sum. Float images (32FC1, metres): mean, std, quantiles "
        "and rounded sum within rel (relative) or abs (absolute), whichever is larger; "
        "NaN and inf counts within nan_fraction of the pixel count. Camera infos and poses: "
        "every number within numbers_abs. Times, counts, topics, types and encodings: exact."
    ),
    "uint8": {"mean_std_abs": 0.5, "quantile_abs": 2.0, "sum_rel": 0.005},
    "float": {"rel": 0.002, "abs": 0.001, "nan_fraction": 0.002},
    "numbers_abs": 1e-6,
}


def _array_stats(values: npt.NDArray[np.generic]) -> dict[str, Any]:
    """Statistics of an image: dtype, shape, NaN and inf counts, over finite values mean etc."""
    data = np.asarray(values, dtype=np.float64)
    finite = data[np.isfinite(data)]
    stats: dict[str, Any] = {
        "dtype": str(values.dtype),
        "shape": list(values.shape),
        "nan_count": int(np.isnan(data).sum()),
        "inf_count": int(np.isinf(data).sum()),
    }
    if finite.size:
        stats.update(
            mean=float(finite.mean()),
            std=float(finite.std()),
            quantiles=[float(q) for q in np.quantile(finite, QUANTILES)],
            rounded_sum=float(np.round(finite).sum()),
        )
    return stats


def _message_summary(message: Any) -> dict[str, Any]:
    msgtype = str(message.__msgtype__)
    summary: dict[str, Any] = {
        "stamp_ns": rosmsg.stamp_ns(message),
        "frame_id": str(message.header.frame_id),
    }
    if msgtype == rosmsg.IMAGE:
        summary["encoding"] = str(message.encoding)
        summary["image"] = _array_stats(rosmsg.image_array(message))
    elif msgtype == rosmsg.COMPRESSED_IMAGE and depth_codec.is_compressed_depth(message.format):
        summary["encoding"] = str(message.format)
        summary["image"] = _array_stats(
            depth_codec.decode(message.format, np.asarray(message.data, dtype=np.uint8))
        )
    elif msgtype == rosmsg.CAMERA_INFO:
        summary["size"] = [int(message.width), int(message.height)]
        summary["p"] = [float(v) for v in rosmsg.projection_matrix(message).reshape(-1)]
    elif msgtype == rosmsg.POSE_STAMPED:
        summary["camera_to_world"] = [float(v) for v in rosmsg.pose_matrix(message)[:3].reshape(-1)]
    elif msgtype == rosmsg.DISPARITY_IMAGE:
        summary["encoding"] = str(message.image.encoding)
        summary["image"] = _array_stats(rosmsg.image_array(message.image))
        summary["f_t"] = [float(message.f), float(message.t)]
    elif msgtype == rosmsg.POINT_CLOUD2:
        fields = rosmsg.pointcloud2_arrays(message)
        summary["fields"] = list(fields)
        summary["point_stats"] = {
            name: _array_stats(values.astype(np.float32)) for name, values in fields.items()
        }
    return summary


def summarize_log(path: Path) -> dict[str, Any]:
    """Summarize an MCAP log: header profile, channels, and per-message statistics."""
    with path.open("rb") as stream:
        reader = make_reader(stream)
        header = reader.get_header()
        summary = reader.get_summary()
        messages: list[dict[str, Any]] = []
        for schema, channel, record in reader.iter_messages(log_time_order=False):
            entry: dict[str, Any] = {"topic": channel.topic, "log_time_ns": record.log_time}
            if schema is not None and schema.encoding == "ros2msg":
                entry.update(_message_summary(rosmsg.deserialize(record.data, schema.name)))
            messages.append(entry)
    channels = []
    if summary is not None:
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        for channel in summary.channels.values():
            schema = summary.schemas.get(channel.schema_id)
            channels.append(
                {
                    "topic": channel.topic,
                    "schema_name": schema.name if schema else "",
                    "schema_encoding": schema.encoding if schema else "",
                    "message_encoding": channel.message_encoding,
                    "message_count": int(counts.get(channel.id, 0)),
                }
            )
    return {"profile": header.profile, "channels": channels, "messages": messages}


def _close(expected: float, actual: float, *, rel: float, abs_: float) -> bool:
    return math.isclose(expected, actual, rel_tol=rel, abs_tol=abs_)


def _compare_stats(
    where: str, expected: dict[str, Any], actual: dict[str, Any], tolerance: dict[str, Any]
) -> list[str]:
    problems: list[str] = []
    for key in ("dtype", "shape"):
        if expected[key] != actual[key]:
            problems.append(f"{where}: {key} {actual[key]} != expected {expected[key]}")
    if problems:
        return problems
    pixels = math.prod(expected["shape"])
    if expected["dtype"] == "uint8":
        limits = tolerance["uint8"]
        checks = [
            ("mean", expected.get("mean"), actual.get("mean"), 0.0, limits["mean_std_abs"]),
            ("std", expected.get("std"), actual.get("std"), 0.0, limits["mean_std_abs"]),
            (
                "rounded_sum",
                expected.get("rounded_sum"),
                actual.get("rounded_sum"),
                limits["sum_rel"],
                0.0,
            ),
        ]
        checks += [
            (f"quantile {q}", e, a, 0.0, limits["quantile_abs"])
            for q, e, a in zip(
                QUANTILES, expected.get("quantiles", []), actual.get("quantiles", []), strict=False
            )
        ]
        nan_limit = 0.0
    else:
        limits = tolerance["float"]
        checks = [
            (key, expected.get(key), actual.get(key), limits["rel"], limits["abs"])
            for key in ("mean", "std", "rounded_sum")
        ]
        checks += [
            (f"quantile {q}", e, a, limits["rel"], limits["abs"])
            for q, e, a in zip(
                QUANTILES, expected.get("quantiles", []), actual.get("quantiles", []), strict=False
            )
        ]
        nan_limit = limits["nan_fraction"] * pixels
    for count, name in (("nan_count", "NaN"), ("inf_count", "inf")):
        if count in expected and abs(expected[count] - actual.get(count, 0)) > nan_limit:
            problems.append(
                f"{where}: {actual.get(count, 0)} {name} pixels, expected {expected[count]} "
                f"+- {nan_limit:.0f}"
            )
    for name, want, have, rel, abs_ in checks:
        if want is None or have is None:
            if want != have:
                problems.append(f"{where}: {name} is {have}, expected {want}")
        elif not _close(float(want), float(have), rel=rel, abs_=abs_):
            problems.append(f"{where}: {name} {have:.6g} differs from expected {want:.6g}")
    return problems


def compare_summary(expected: dict[str, Any], actual: dict[str, Any]) -> list[str]:
    """Return every difference between an expected and an actual summary beyond tolerance.

    Args:
        expected: the golden JSON (with its ``tolerance``).
        actual: :func:`summarize_log` of the log under test.

    Returns:
        One line per difference; empty when the log matches.
    """
    tolerance = expected["tolerance"]
    problems: list[str] = []
    if actual["profile"] != expected["profile"]:
        problems.append(f"profile {actual['profile']!r} != expected {expected['profile']!r}")
    if actual["channels"] != expected["channels"]:
        problems.append(f"channels {actual['channels']} != expected {expected['channels']}")
    if len(actual["messages"]) != len(expected["messages"]):
        problems.append(f"{len(actual['messages'])} messages, expected {len(expected['messages'])}")
        return problems
    numbers_abs = float(tolerance["numbers_abs"])
    for i, (want, have) in enumerate(zip(expected["messages"], actual["messages"], strict=True)):
        where = f"message {i} ({want['topic']})"
        for key in ("topic", "log_time_ns", "stamp_ns", "frame_id", "encoding", "size"):
            if want.get(key) != have.get(key):
                problems.append(f"{where}: {key} {have.get(key)!r} != expected {want.get(key)!r}")
        if want.get("fields") != have.get("fields"):
            problems.append(f"{where}: fields {have.get('fields')} != {want.get('fields')}")
        for name, stats in want.get("point_stats", {}).items():
            if name in have.get("point_stats", {}):
                problems += _compare_stats(
                    f"{where} field {name}", stats, have["point_stats"][name], tolerance
                )
        for key in ("p", "camera_to_world", "f_t"):
            if key in want:
                a, b = np.asarray(want[key]), np.asarray(have.get(key, []))
                if a.shape != b.shape or not np.allclose(a, b, rtol=0.0, atol=numbers_abs):
                    problems.append(f"{where}: {key} {have.get(key)} != expected {want[key]}")
        if "image" in want:
            if "image" not in have:
                problems.append(f"{where}: no image")
            else:
                problems += _compare_stats(where, want["image"], have["image"], tolerance)
    return problems


def render_golden(log_path: Path, *, seed: int, frames: int, scale: float) -> dict[str, Any]:
    """Render the synthetic log to ``log_path`` and return its expected summary (JSON)."""
    from pcainterp_stream.synth import SynthConfig, generate

    config = SynthConfig(seed=seed, frames=frames, scale=scale)
    write_synthetic_log(generate(config), log_path, format=LogFormat.MCAP, total=frames)
    return {
        "format": FORMAT,
        "generator": {"seed": seed, "frames": frames, "scale": scale},
        "command": "PYTHONPATH=. python tools/make_golden.py",
        "tolerance": TOLERANCE,
        **summarize_log(log_path),
    }


def learn_golden_basis(basis_path: Path) -> None:
    """Learn the small basis the dense golden test uses, from a separate synthetic drive."""
    from pcainterp_stream.frontend.pairing import PairingConfig
    from pcainterp_stream.pipeline.jobs import LearnOptions, learn
    from pcainterp_stream.synth import SynthConfig, generate

    with tempfile.TemporaryDirectory() as folder:
        train = Path(folder) / "train.mcap"
        config = SynthConfig(seed=BASIS_SEED, frames=BASIS_FRAMES, scale=SCALE)
        write_synthetic_log(generate(config), train, format=LogFormat.MCAP)
        learn([train], basis_path, LearnOptions(n_components=BASIS_COMPONENTS), PairingConfig())


def densify_golden(log_path: Path, basis_path: Path, out_path: Path) -> dict[str, Any]:
    """Densify the golden log with the golden basis and return the output's summary (JSON)."""
    from pcainterp_stream.pipeline.jobs import densify

    densify(log_path, out_path, basis_path)
    return {
        "format": FORMAT,
        "generator": {"log": log_path.name, "basis": basis_path.name},
        "command": "PYTHONPATH=. python tools/make_golden.py",
        "tolerance": TOLERANCE,
        **summarize_log(out_path),
    }


def main(argv: list[str] | None = None) -> int:
    """Regenerate (or, with --check, verify) the golden synthetic log and JSON."""
    parser = harness.argument_parser(__doc__)
    parser.add_argument("--out-dir", type=Path, default=DATA_DIR, help="default: tests/data")
    parser.add_argument(
        "--check", action="store_true", help="render to a temporary file and compare"
    )
    parser.add_argument(
        "--new-basis", action="store_true", help="re-learn golden_basis.npz too (else kept)"
    )
    args = parser.parse_args(argv)
    if args.check:
        expected = harness.read_json(args.out_dir / GOLDEN_JSON.name)
        with tempfile.TemporaryDirectory() as folder:
            actual = render_golden(Path(folder) / "golden.mcap", **expected["generator"])
        problems = compare_summary(expected, actual)
        for line in problems:
            print(line)
        print("golden log matches" if not problems else f"{len(problems)} differences")
        return 1 if problems else 0
    harness.work_dir(args.out_dir)
    log_path = args.out_dir / GOLDEN_LOG.name
    summary = render_golden(log_path, seed=SEED, frames=FRAMES, scale=SCALE)
    harness.write_json(args.out_dir / GOLDEN_JSON.name, summary)
    print(f"wrote {log_path} ({log_path.stat().st_size} bytes) and {GOLDEN_JSON.name}")
    basis_path = args.out_dir / GOLDEN_BASIS.name
    if args.new_basis or not basis_path.exists():
        learn_golden_basis(basis_path)
        print(f"wrote {basis_path} ({basis_path.stat().st_size} bytes)")
    with tempfile.TemporaryDirectory() as folder:
        dense = densify_golden(log_path, basis_path, Path(folder) / "dense.mcap")
    harness.write_json(args.out_dir / GOLDEN_DENSE_JSON.name, dense)
    print(f"wrote {GOLDEN_DENSE_JSON.name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
