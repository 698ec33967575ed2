"""Copy a stereo log with a robot's other topics added (LiDAR, IMU) and measure densify on it.

A robot's recording is rarely only the stereo pair: a spinning LiDAR's clouds (1-2 MB each,
10-20 Hz) and an IMU (1-10 kHz) often outweigh the cameras, and they are recorded before
the cameras start and after they stop. ``densify`` copies every input message into its
output in log-time order, holding them while a frame's outputs are still due; this tool
makes such logs from any MCAP stereo log and measures what the copy costs.

Variants (:data:`VARIANTS`), each the input's messages plus, in log-time order:

- ``pre``: ``--seconds`` (default 30) of a LiDAR (``/lidar/points``, PointCloud2, ~1.6 MB,
  10 Hz) and a 1 kHz IMU (``/imu/data``) before the first image, going on until the last;
- ``tail``: the same from the first image until ``--seconds`` after the last;
- ``fast``: a 10 kHz IMU from ``--seconds`` before the first image until the last;
- ``heavy``: 4 LiDARs at 20 Hz and the 1 kHz IMU from the first image to the last.

The span is the left camera's (the pair ``densify`` finds with no topic flags). The extra
messages never share a log time with an input message. Each cloud is one of a few scans
made once (a 64-beam sweep), its header stamp set to its log time.

Without ``--measure`` the busy logs are written to ``--out-dir`` as ``STEM_VARIANT.mcap``.
With ``--measure`` (in ``--out-dir``, or a scratch folder removed at the end),
``densify`` (no flags) runs on the plain log and on each busy one, with the code of this
interpreter and, with ``--before TREE``, again with the package of TREE (a folder holding
``pcainterp_stream``: ``git archive COMMIT | tar -x -C TREE``) first on ``PYTHONPATH``.
The markdown table gives each run's peak RSS (the child's ``ru_maxrss``), wall time, the
output's size over the input's, the output messages written after a message of a later log
time (file order) and whether densify warned that its hold of the input was full::

    pcainterp synth street.mcap --frames 25 --scale 0.5 --seed 1
    python tools/busy_log.py street.mcap --variants pre --out-dir busy
    python tools/busy_log.py street.mcap --measure --before /tmp/before --out-dir runs

Commands run as ``python -m pcainterp_stream.cli`` in the output folder (never a
repository folder: ``-m`` puts the current folder first on ``sys.path``).
"""

from __future__ import annotations

import argparse
import heapq
import os
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SECOND = 1_000_000_000
OFFSET_NS = 317_000
"""The extra topics' phase: never on an image's log time (synth logs tick on whole ms)."""
HOLD_WARNING = "copied ahead of the outputs"
"""Densify's warning that its hold of the input was full (from the fix of bug hunt 17J)."""


@dataclass(frozen=True)
class Variant:
    """The topics a variant adds and when (seconds relative to the left camera's span)."""

    clouds: int
    cloud_hz: float
    imu_hz: float
    before_s: bool  # start --seconds before the first image (else at it)
    after_s: bool  # end --seconds after the last image (else at it)


VARIANTS: dict[str, Variant] = {
    "pre": Variant(clouds=1, cloud_hz=10, imu_hz=1000, before_s=True, after_s=False),
    "tail": Variant(clouds=1, cloud_hz=10, imu_hz=1000, before_s=False, after_s=True),
    "fast": Variant(clouds=0, cloud_hz=10, imu_hz=10_000, before_s=True, after_s=False),
    "heavy": Variant(clouds=4, cloud_hz=20, imu_hz=1000, before_s=False, after_s=False),
}

CLOUD = "sensor_msgs/msg/PointCloud2"
IMU = "sensor_msgs/msg/Imu"


class BadInput(Exception):
    """A log or option this tool cannot use (the message is the one line printed)."""


def _with_stamp(data: bytes, stamp_ns: int) -> bytes:
    """CDR bytes of a message whose first field is a header, with the stamp set."""
    sec, nanosec = divmod(stamp_ns, SECOND)
    return data[:4] + struct.pack("<iI", sec, nanosec) + data[12:]


def cloud_pool(points: int, count: int = 4) -> list[bytes]:
    """``count`` serialized 64-beam sweeps of ``points`` points (x y z intensity ring time)."""
    from pcainterp_stream.io import rosmsg

    rng = np.random.default_rng(17)
    beams = 64
    columns = max(1, points // beams)
    azimuth = np.linspace(-np.pi, np.pi, columns, endpoint=False, dtype=np.float32)[None, :]
    elevation = np.linspace(-0.4, 0.05, beams, dtype=np.float32)[:, None]
    pool = []
    for _ in range(count):
        distance = (4 + 50 * rng.random((beams, columns)) ** 2).astype(np.float32)
        fields = {
            "x": distance * np.cos(elevation) * np.cos(azimuth),
            "y": distance * np.cos(elevation) * np.sin(azimuth),
            "z": distance * np.sin(elevation),
            "intensity": rng.integers(0, 256, (beams, columns)).astype(np.float32),
            "ring": np.broadcast_to(np.arange(beams, dtype=np.float32)[:, None], (beams, columns)),
            "time": np.broadcast_to(
                np.linspace(0, 0.1, columns, dtype=np.float32), (beams, columns)
            ),
        }
        flat = {
            name: np.ascontiguousarray(value, np.float32).reshape(-1)
            for name, value in fields.items()
        }
        pool.append(rosmsg.serialize(rosmsg.pointcloud2_message(flat, 0, "lidar")))
    return pool


def imu_pool(count: int = 64) -> list[bytes]:
    """``count`` serialized ``sensor_msgs/msg/Imu`` readings of a robot standing still."""
    from pcainterp_stream.io import rosmsg

    types = rosmsg.TYPESTORE.types
    rng = np.random.default_rng(18)
    vector, quaternion = types["geometry_msgs/msg/Vector3"], types["geometry_msgs/msg/Quaternion"]
    pool = []
    for _ in range(count):
        gyro, accel = rng.normal(0, 0.01, 3), rng.normal(0, 0.1, 3) + np.array([0, 0, 9.81])
        message = types[IMU](
            header=rosmsg.header(0, "imu"),
            orientation=quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.zeros(9),
            angular_velocity=vector(x=gyro[0], y=gyro[1], z=gyro[2]),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=vector(x=accel[0], y=accel[1], z=accel[2]),
            linear_acceleration_covariance=np.zeros(9),
        )
        pool.append(rosmsg.serialize(message))
    return pool


def camera_span(log: Path) -> tuple[str, int, int]:
    """The left topic densify finds in ``log`` and its first and last log times (ns)."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    from pcainterp_stream.errors import PcaInterpError
    from pcainterp_stream.frontend.discovery import resolve_pairing
    from pcainterp_stream.frontend.pairing import PairingConfig
    from pcainterp_stream.io import logreader

    try:
        with logreader.open_log(log) as reader:
            left = resolve_pairing(reader, PairingConfig(discover=True)).left_topic
    except (PcaInterpError, OSError, ValueError) as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise BadInput(first if str(log) in first else f"{log}: {first}") from None
    times = []
    with log.open("rb") as stream:
        try:
            messages = make_reader(stream).iter_messages(topics=[left], log_time_order=False)
            times = [message.log_time for _, _, message in messages]
        except (McapError, ValueError) as err:
            raise BadInput(f"{log}: not an MCAP file ({err}); convert it first") from None
    if not times:
        raise BadInput(f"{log}: no message on {left}; a stereo log is needed")
    return left, min(times), max(times)


def _ticks(
    topic: str, start: int, end: int, hz: float, pool: list[bytes]
) -> Iterator[tuple[int, str, bytes]]:
    step = round(SECOND / hz)
    for index, log_time in enumerate(range(start + OFFSET_NS, end + 1, step)):
        yield log_time, topic, _with_stamp(pool[index % len(pool)], log_time)


def extra_messages(
    variant: Variant, first: int, last: int, seconds: float, cloud_points: int
) -> Iterator[tuple[int, str, bytes]]:
    """The variant's messages in log-time order: (log time, topic, CDR data)."""
    start = first - round(seconds * SECOND) if variant.before_s else first
    end = last + round(seconds * SECOND) if variant.after_s else last
    streams = [_ticks("/imu/data", start, end, variant.imu_hz, imu_pool())]
    if variant.clouds:
        clouds = cloud_pool(cloud_points)
        for lidar in range(variant.clouds):
            topic = "/lidar/points" if lidar == 0 else f"/lidar{lidar}/points"
            # the LiDARs spin out of phase, as separately clocked sensors do
            phase = round(lidar * SECOND / variant.cloud_hz / max(1, variant.clouds))
            streams.append(_ticks(topic, start + phase, end, variant.cloud_hz, clouds))
    return heapq.merge(*streams, key=lambda item: item[0])


def write_busy(
    log: Path, out: Path, name: str, *, seconds: float = 30.0, cloud_points: int = 65536
) -> int:
    """Write ``log`` with variant ``name``'s topics added to ``out``; return the extra count."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    from pcainterp_stream.io import rosmsg

    _, first, last = camera_span(log)
    extras = extra_messages(VARIANTS[name], first, last, seconds, cloud_points)
    added = 0
    with log.open("rb") as source, out.open("wb") as target:
        reader = make_reader(source)
        writer = Writer(target)
        writer.start(profile=reader.get_header().profile, library="tools/busy_log.py")
        schemas: dict[int, int] = {}
        channels: dict[int | str, int] = {}

        def extra_channel(topic: str) -> int:
            if topic not in channels:
                typename = IMU if topic == "/imu/data" else CLOUD
                schema = writer.register_schema(
                    typename, "ros2msg", rosmsg.schema_text(typename).encode()
                )
                channels[topic] = writer.register_channel(topic, "cdr", schema)
            return channels[topic]

        pending = next(extras, None)
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            while pending is not None and pending[0] < message.log_time:
                writer.add_message(
                    extra_channel(pending[1]), pending[0], pending[2], pending[0], added
                )
                added += 1
                pending = next(extras, None)
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(
                    schema.name, schema.encoding, schema.data
                )
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic,
                    channel.message_encoding,
                    schemas[schema.id] if schema is not None else 0,
                    dict(channel.metadata),
                )
            writer.add_message(
                channels[channel.id],
                log_time=message.log_time,
                data=message.data,
                publish_time=message.publish_time,
                sequence=message.sequence,
            )
        while pending is not None:
            writer.add_message(extra_channel(pending[1]), pending[0], pending[2], pending[0], added)
            added += 1
            pending = next(extras, None)
        writer.finish()  # type: ignore[no-untyped-call]
    return added


def out_of_order(path: Path) -> int:
    """Messages of ``path`` written after a message of a later log time (file order)."""
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    latest, late = -1, 0
    with path.open("rb") as stream:
        for record in StreamReader(stream, emit_chunks=False).records:
            if isinstance(record, Message):
                late += record.log_time < latest
                latest = max(latest, record.log_time)
    return late


@dataclass
class Run:
    """One densify run's figures (``failed``: densify's last line)."""

    tree: str
    log: str
    input_mb: float
    peak_mb: float = 0.0
    wall_s: float = 0.0
    ratio: float = 0.0
    late: int = 0
    warned: bool = False
    failed: str = ""


def densify(log: Path, tree: Path, label: str, folder: Path) -> Run:
    """Run ``densify LOG`` with the package of ``tree`` in ``folder``; measure it."""
    out = folder / f"{log.stem}_{label}_dense.mcap"
    out.unlink(missing_ok=True)
    row = Run(label, log.stem, log.stat().st_size / 1e6)
    command = [sys.executable, "-m", "pcainterp_stream.cli", "densify", str(log), "-o", str(out)]
    env = {**os.environ, "PYTHONPATH": str(tree)}
    started = time.perf_counter()
    child = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, cwd=folder, env=env
    )
    assert child.stdout is not None
    text = child.stdout.read().decode(errors="replace")
    _, status, usage = os.wait4(child.pid, 0)
    row.wall_s = time.perf_counter() - started
    row.peak_mb = usage.ru_maxrss / 1024  # KiB on Linux
    (folder / f"{log.stem}_{label}.densify.txt").write_text(text)
    if os.waitstatus_to_exitcode(status) != 0:
        lines = [line for line in text.replace("\r", "\n").splitlines() if line.strip()]
        row.failed = lines[-1] if lines else f"exit status {status}"
        return row
    row.ratio = out.stat().st_size / log.stat().st_size
    row.late = out_of_order(out)
    row.warned = HOLD_WARNING in text
    out.unlink()  # the outputs of the busy logs are hundreds of MB
    return row


def table(rows: list[Run]) -> str:
    """The markdown table of the runs."""
    lines = [
        "| tree | log | input MB | peak RSS MB | wall s | output / input | out of order "
        "| hold full warning |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for row in rows:
        if row.failed:
            cells = ["-", "-", "-", "-", row.failed.replace("|", "/")]
        else:
            cells = [
                f"{row.peak_mb:.0f}",
                f"{row.wall_s:.1f}",
                f"{row.ratio:.2f}",
                str(row.late),
                "yes" if row.warned else "no",
            ]
        lines.append(f"| {row.tree} | {row.log} | {row.input_mb:.1f} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _run(args: argparse.Namespace, folder: Path) -> list[Run]:
    import pcainterp_stream

    log = args.log.resolve()
    busy = []
    for name in args.variants:
        path = folder / f"{log.stem}_{name}.mcap"
        added = write_busy(log, path, name, seconds=args.seconds, cloud_points=args.cloud_points)
        print(
            f"{path.name}: {added} messages added, {path.stat().st_size / 1e6:.1f} MB",
            file=sys.stderr,
        )
        busy.append(path)
    if not args.measure:
        return []
    trees = [("after", Path(pcainterp_stream.__file__).resolve().parents[1])]
    if args.before is not None:
        trees.insert(0, ("before", args.before.resolve()))
    rows = []
    for path in [log, *busy]:
        for label, tree in trees:
            rows.append(densify(path, tree, label, folder))
            print(table(rows[-1:]).splitlines()[-1], file=sys.stderr, flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    """Run the command line; return the exit status."""
    parser = argparse.ArgumentParser(
        prog="busy_log.py", description=(__doc__ or "").split("\n\n")[0]
    )
    parser.add_argument("log", type=Path, help="an MCAP stereo log")
    parser.add_argument(
        "--variants",
        nargs="+",
        choices=list(VARIANTS),
        default=list(VARIANTS),
        metavar="NAME",
        help=f"the busy logs to make, in this order (default: all: {', '.join(VARIANTS)})",
    )
    parser.add_argument(
        "--seconds", type=float, default=30.0, help="length of a pre/tail/fast lead (s)"
    )
    parser.add_argument(
        "--cloud-points", type=int, default=65536, help="points per cloud (24 B each)"
    )
    parser.add_argument("--out-dir", type=Path, help="folder of the busy logs (and runs); kept")
    parser.add_argument("--measure", action="store_true", help="run densify on each log; a table")
    parser.add_argument(
        "--before", type=Path, help="a second tree (holding pcainterp_stream) to run"
    )
    args = parser.parse_args(argv)
    problem = None
    if not args.log.is_file():
        problem = f"{args.log}: no such file (an MCAP stereo log)"
    elif args.before is not None and not (args.before / "pcainterp_stream").is_dir():
        problem = f"--before {args.before} holds no pcainterp_stream package (git archive it there)"
    elif args.before is not None and not args.measure:
        problem = "--before is a tree to measure: give --measure too"
    elif args.out_dir is None and not args.measure:
        problem = "give --out-dir (where the busy logs go) or --measure"
    elif args.seconds < 0 or args.cloud_points < 64:
        problem = "--seconds must be >= 0 and --cloud-points >= 64"
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    try:
        if args.out_dir is not None:
            args.out_dir.mkdir(parents=True, exist_ok=True)
            rows = _run(args, args.out_dir.resolve())
        else:
            with tempfile.TemporaryDirectory(prefix="busy_log_") as scratch:
                rows = _run(args, Path(scratch))
    except BadInput as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if args.measure:
        print(f"{args.log.name}: densify (no flags) on the log and its busy copies\n")
        print(table(rows))
    return 1 if any(row.failed for row in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
