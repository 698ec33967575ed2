"""Other people's readers on our output (issue 8): TypeScript MCAP libraries, rosbags, Rerun.

One small densified log is built with the project's own commands (``pcainterp synth``,
``learn``, ``densify --depth-mm``). Python's reference decoding of it is the mcap library's
own ROS 2 decoder (``mcap_ros2``, which shares no code with the rosbags-based writer); each
foreign reader must agree with it message by message:

- the TypeScript reference implementation (``@mcap/core`` indexed and streaming readers,
  ``@foxglove/rosmsg`` for the ``ros2msg`` schema text, ``@foxglove/rosmsg2-serialization``
  for CDR) run by node on ``tests/js/read_mcap.mjs``; its npm packages are installed from
  the committed ``tests/js/package-lock.json`` into the pytest cache (skipped with the reason
  when node or npm is missing or the install fails);
- rosbags' ``AnyReader``, with no typestore of its own: it must build the message types from
  the schemas embedded in the file;
- Rerun's MCAP importer (``rerun.chunk.McapReader``, the code behind ``rerun mcap convert``
  and the viewer's MCAP loading): which topics it turns into images, a pinhole and points,
  and that those carry our values.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

from pcainterp_stream import cli
from pcainterp_stream.defaults import DISPLAY_MAX_DEPTH
from pcainterp_stream.io import rosmsg
from pcainterp_stream.version import __version__

JS_DIR = Path(__file__).resolve().parents[1] / "js"
FRAMES = 3
HEIGHT, WIDTH = 94, 310  # a --scale 0.25 synthetic log
PREFIX = "/pcainterp/"
OUTPUT_TYPES = {
    "/pcainterp/depth": "sensor_msgs/msg/Image",
    "/pcainterp/depth_std": "sensor_msgs/msg/Image",
    "/pcainterp/disparity": "stereo_msgs/msg/DisparityImage",
    "/pcainterp/disparity_std": "sensor_msgs/msg/Image",
    "/pcainterp/features": "sensor_msgs/msg/PointCloud2",
    "/pcainterp/camera_info": "sensor_msgs/msg/CameraInfo",
    "/pcainterp/depth_mm": "sensor_msgs/msg/Image",
}
IMAGE_ENCODINGS = {  # topic -> (encoding, numpy dtype)
    "/pcainterp/depth": ("32FC1", "<f4"),
    "/pcainterp/depth_std": ("32FC1", "<f4"),
    "/pcainterp/disparity": ("32FC1", "<f4"),
    "/pcainterp/disparity_std": ("32FC1", "<f4"),
    "/pcainterp/depth_mm": ("16UC1", "<u2"),
}
IMAGE_ENCODINGS_BY_NAME = {encoding: dtype for encoding, dtype in IMAGE_ENCODINGS.values()}
POINT_FIELDS = ["x", "y", "z", "u", "v", "disparity"]
POINT_FIELD_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


@dataclass(frozen=True)
class Decoded:
    """One message as Python's reference decoder (mcap_ros2) reads it."""

    topic: str
    schema_name: str
    log_time_ns: int
    publish_time_ns: int
    message: Any


# ----------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def dense_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 3-frame quarter-size synthetic drive densified with --depth-mm."""
    folder = tmp_path_factory.mktemp("interop")
    log, basis, dense = folder / "drive.mcap", folder / "basis.npz", folder / "dense.mcap"
    commands: list[list[str | Path]] = [
        ["synth", log, "--frames", str(FRAMES), "--scale", "0.25", "--seed", "5"],
        # the true depth makes a basis without SGBM; 3 maps give at most 2 components
        [
            "learn",
            log,
            "-o",
            basis,
            "--components",
            "5",
            "--depth-topic",
            "/ground_truth/depth",
            "--no-fit-prior",
        ],
        ["densify", log, "-o", dense, "--basis", basis, "--depth-mm", "--precision", "full"],
        ["densify", log, "-o", folder / "compact.mcap", "--basis", basis],
    ]
    for command in commands:
        assert cli.main([str(arg) for arg in command]) == 0, command
    return dense


@pytest.fixture(scope="module")
def compact_log(dense_log: Path) -> Path:
    """The same drive densified with the defaults (compact precision)."""
    return dense_log.parent / "compact.mcap"


@pytest.fixture(scope="module")
def reference(dense_log: Path) -> list[Decoded]:
    """Every message of the densified log, decoded by mcap + mcap_ros2, in file order."""
    with dense_log.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return [
            Decoded(channel.topic, schema.name, message.log_time, message.publish_time, decoded)
            for schema, channel, message, decoded in reader.iter_decoded_messages(
                log_time_order=False
            )
        ]


@pytest.fixture(scope="module")
def outputs(reference: list[Decoded]) -> list[Decoded]:
    """The /pcainterp/* messages of :func:`reference`."""
    return [item for item in reference if item.topic.startswith(PREFIX)]


def _install_js(folder: Path) -> None:
    """Install tests/js's locked npm packages into ``folder`` unless already there."""
    manifest = (JS_DIR / "package.json").read_bytes()
    lock = (JS_DIR / "package-lock.json").read_bytes()
    digest = hashlib.sha256(manifest + lock).hexdigest()
    stamp = folder / "installed.sha256"
    if stamp.is_file() and stamp.read_text() == digest and (folder / "node_modules").is_dir():
        return
    stamp.unlink(missing_ok=True)
    (folder / "package.json").write_bytes(manifest)
    (folder / "package-lock.json").write_bytes(lock)
    try:
        done = subprocess.run(
            ["npm", "ci", "--no-audit", "--no-fund", "--ignore-scripts", "--prefer-offline"],
            cwd=folder,
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
        )
    except subprocess.TimeoutExpired:
        pytest.skip(f"npm ci in {folder} took more than 300 s (no registry access?)")
    if done.returncode != 0:
        tail = " | ".join(done.stderr.strip().splitlines()[-3:])
        pytest.skip(f"npm ci of tests/js/package-lock.json failed in {folder}: {tail}")
    stamp.write_text(digest)


@pytest.fixture(scope="session")
def js_reader(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """tests/js/read_mcap.mjs beside its installed node_modules (in the pytest cache)."""
    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("node and npm are needed for the TypeScript MCAP reader; install Node.js")
    cache = getattr(request.config, "cache", None)  # None with -p no:cacheprovider
    folder = cache.mkdir("pcainterp-js") if cache is not None else tmp_path_factory.mktemp("js")
    _install_js(Path(folder))
    script = Path(folder) / "read_mcap.mjs"
    shutil.copyfile(JS_DIR / "read_mcap.mjs", script)
    return script


@pytest.fixture(scope="module")
def js_output(js_reader: Path, dense_log: Path) -> dict[str, Any]:
    """What the TypeScript libraries read from the densified log (read_mcap.mjs's JSON)."""
    done = subprocess.run(
        ["node", js_reader.name, str(dense_log), PREFIX],
        cwd=js_reader.parent,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, f"read_mcap.mjs failed:\n{done.stderr}"
    output: dict[str, Any] = json.loads(done.stdout)
    return output


# ----------------------------------------------------------------------------- helpers


def floats(values: list[float | str]) -> npt.NDArray[np.float64]:
    """JSON numbers and "NaN" / "Infinity" / "-Infinity" strings as a float array."""
    return np.array([float(value) for value in values], dtype=np.float64)


def image_values(image: Any) -> npt.NDArray[np.float64]:
    """The pixels of a decoded sensor_msgs/Image, row-major, honouring step and endianness."""
    encoding = str(image.encoding)
    dtype = np.dtype(IMAGE_ENCODINGS_BY_NAME[encoding])
    dtype = dtype.newbyteorder(">" if image.is_bigendian else "<")
    raw = np.frombuffer(bytes(image.data), dtype=np.uint8)
    rows = raw[: image.height * image.step].reshape(image.height, image.step)
    pixels = np.ascontiguousarray(rows[:, : image.width * dtype.itemsize]).view(dtype)
    return pixels.astype(np.float64).reshape(-1)


def point_values(cloud: Any) -> dict[str, npt.NDArray[np.float64]]:
    """Every field of a decoded sensor_msgs/PointCloud2, as float arrays of length n."""
    raw = bytes(cloud.data)
    order = ">" if cloud.is_bigendian else "<"
    n = cloud.height * cloud.width
    points: dict[str, npt.NDArray[np.float64]] = {}
    for field in cloud.fields:
        dtype = np.dtype(order + POINT_FIELD_DTYPES[field.datatype])
        values = np.ndarray(
            (n,), dtype=dtype, buffer=raw, offset=field.offset, strides=(cloud.point_step,)
        )
        points[field.name] = values.astype(np.float64)
    return points


def assert_same_values(actual: Any, expected: Any, what: str) -> None:
    """Exact equality of float arrays, NaN where NaN (float32 survives JSON exactly)."""
    np.testing.assert_array_equal(
        np.asarray(actual, dtype=np.float64), np.asarray(expected, dtype=np.float64), err_msg=what
    )


def header_of(message: Any) -> dict[str, Any]:
    return {
        "stamp": {"sec": message.header.stamp.sec, "nanosec": message.header.stamp.nanosec},
        "frame_id": message.header.frame_id,
    }


def assert_image_matches(js: dict[str, Any], image: Any, topic: str) -> None:
    """A JS image summary against the reference decoding: sizes, encoding, pixels."""
    encoding, dtype = IMAGE_ENCODINGS[topic]
    itemsize = np.dtype(dtype).itemsize
    assert (js["height"], js["width"]) == (HEIGHT, WIDTH), topic
    assert js["encoding"] == encoding, topic
    assert js["is_bigendian"] == 0, topic
    assert js["step"] == WIDTH * itemsize, topic
    assert js["data_length"] == HEIGHT * WIDTH * itemsize, topic
    assert js["header"] == header_of(image), topic
    assert (image.height, image.width, image.step) == (js["height"], js["width"], js["step"])
    assert image.encoding == js["encoding"]
    assert_same_values(floats(js["values"]), image_values(image), topic)


# ----------------------------------------------------------------------------- TypeScript


@pytest.mark.slow  # npm ci on the first run, then node
def test_js_reads_summary_and_every_channel(
    js_output: dict[str, Any], reference: list[Decoded]
) -> None:
    indexed, stream = js_output["indexed"], js_output["stream"]
    assert indexed["profile"] == "ros2"
    assert indexed["library"] == f"pcainterp_stream {__version__}"  # the version that wrote it
    assert indexed["chunk_compression"] == ["zstd"]
    counts: dict[str, int] = defaultdict(int)
    for item in reference:
        counts[item.topic] += 1
    assert indexed["message_count"] == len(reference)
    assert {topic: info["message_count"] for topic, info in indexed["channels"].items()} == counts
    # the streaming reader (no index) reaches the footer and sees the same messages
    assert stream["done"] is True
    assert stream["message_counts"] == counts
    for topic, schema_name in OUTPUT_TYPES.items():
        channel = indexed["channels"][topic]
        assert channel["message_encoding"] == "cdr"
        assert channel["schema_encoding"] == "ros2msg"
        assert channel["schema_name"] == schema_name
        assert counts[topic] == FRAMES


@pytest.mark.slow  # npm ci on the first run, then node
def test_js_decodes_every_output_message(js_output: dict[str, Any], outputs: list[Decoded]) -> None:
    messages = js_output["indexed"]["messages"]
    assert [item["topic"] for item in messages] == [item.topic for item in outputs]
    assert set(OUTPUT_TYPES) == {item.topic for item in outputs}
    for js, ours in zip(messages, outputs, strict=True):
        topic, message = ours.topic, ours.message
        # CDR decoded to the end of each message: the schema text matches the bytes
        assert js["trailing_bytes"] is False, topic
        assert (int(js["log_time"]), int(js["publish_time"])) == (
            ours.log_time_ns,
            ours.publish_time_ns,
        )
        decoded = js["message"]
        assert decoded["header"] == header_of(message), topic
        if ours.schema_name == "sensor_msgs/msg/Image":
            assert_image_matches(decoded, message, topic)
        elif ours.schema_name == "stereo_msgs/msg/DisparityImage":
            assert_image_matches(decoded["image"], message.image, topic)
            for name in ("f", "t", "min_disparity", "max_disparity", "delta_d"):
                assert_same_values(floats([decoded[name]]), [getattr(message, name)], name)
            window = message.valid_window
            assert decoded["valid_window"] == {
                "x_offset": window.x_offset,
                "y_offset": window.y_offset,
                "height": window.height,
                "width": window.width,
                "do_rectify": window.do_rectify,
            }
        elif ours.schema_name == "sensor_msgs/msg/PointCloud2":
            assert [field["name"] for field in decoded["fields"]] == POINT_FIELDS
            assert all(field["datatype"] == 7 for field in decoded["fields"])  # FLOAT32
            assert decoded["height"] == 1
            assert decoded["point_step"] == 4 * len(POINT_FIELDS)
            assert decoded["row_step"] == decoded["point_step"] * decoded["width"]
            assert decoded["data_length"] == decoded["row_step"]
            assert decoded["width"] == message.width > 0
            assert decoded["is_bigendian"] is False
            assert decoded["is_dense"] == message.is_dense
            expected = point_values(message)
            for name in POINT_FIELDS:
                assert_same_values(floats(decoded["points"][name]), expected[name], name)
        elif ours.schema_name == "sensor_msgs/msg/CameraInfo":
            assert (decoded["height"], decoded["width"]) == (HEIGHT, WIDTH)
            assert decoded["distortion_model"] == message.distortion_model
            for name in ("d", "k", "r", "p"):
                assert_same_values(floats(decoded[name]), getattr(message, name), name)
        else:
            pytest.fail(f"unexpected schema {ours.schema_name} on {topic}")


@pytest.mark.slow  # npm ci on the first run, then node
def test_js_values_are_consistent_across_channels(js_output: dict[str, Any]) -> None:
    """Depth = f*t / disparity, +inf below the resolvable disparity (REP 118 "too far").

    The disparity image's valid window starts at that disparity (> 0); the 16UC1 copy is
    rounded mm over the fixed display range, too far at its end.
    """
    by_topic: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for item in js_output["indexed"]["messages"]:
        by_topic[item["topic"]].append(item["message"])
    for frame in range(FRAMES):
        disparity_message = by_topic["/pcainterp/disparity"][frame]
        disparity = floats(disparity_message["image"]["values"])
        depth = floats(by_topic["/pcainterp/depth"][frame]["values"])
        depth_std = floats(by_topic["/pcainterp/depth_std"][frame]["values"])
        depth_mm = floats(by_topic["/pcainterp/depth_mm"][frame]["values"])
        min_disparity = disparity_message["min_disparity"]
        assert min_disparity > 0
        assert disparity_message["max_disparity"] >= min_disparity
        too_far = np.isposinf(depth)
        assert too_far.any(), "the synthetic sky should be farther than measurable"
        assert (~too_far).any()
        assert not np.isnan(depth).any(), "every pixel has an estimate"
        np.testing.assert_array_equal(too_far, ~(disparity >= min_disparity))
        np.testing.assert_array_equal(np.isposinf(depth_std), too_far)
        assert np.isfinite(depth_std[~too_far]).all()
        focal_baseline = disparity_message["f"] * disparity_message["t"]
        resolved = depth[~too_far]
        np.testing.assert_allclose(resolved, focal_baseline / disparity[~too_far], rtol=1e-5)
        assert resolved.max() <= focal_baseline / min_disparity * (1 + 1e-6)
        far_mm = 1000 * DISPLAY_MAX_DEPTH
        assert np.all(depth_mm[too_far] == far_mm)
        expected_mm = np.minimum(np.rint(resolved * 1000), far_mm)
        np.testing.assert_allclose(depth_mm[~too_far], expected_mm, atol=1)
        camera = by_topic["/pcainterp/camera_info"][frame]
        assert disparity_message["f"] == pytest.approx(camera["k"][0], rel=1e-6)
        points = {
            name: floats(values)
            for name, values in by_topic["/pcainterp/features"][frame]["points"].items()
        }
        # a measured disparity of 0 (sky: at infinity) has no finite z; it is written as NaN
        at_infinity = points["disparity"] <= 0
        assert np.isnan(points["z"][at_infinity]).all()
        np.testing.assert_allclose(
            points["z"][~at_infinity],
            focal_baseline / points["disparity"][~at_infinity],
            rtol=1e-5,
        )


# ----------------------------------------------------------------------------- rosbags


def test_rosbags_anyreader_reads_every_output_message(
    dense_log: Path, outputs: list[Decoded]
) -> None:
    # no default typestore: the types must come from the schemas in the file
    with AnyReader([dense_log]) as reader:
        connections = [conn for conn in reader.connections if conn.topic.startswith(PREFIX)]
        assert {conn.topic: conn.msgtype for conn in connections} == OUTPUT_TYPES
        assert all(conn.msgcount == FRAMES for conn in connections)
        read = [
            (conn.topic, log_time, reader.deserialize(raw, conn.msgtype))
            for conn, log_time, raw in reader.messages(connections=connections)
        ]
    read.sort(key=lambda item: (item[1], list(OUTPUT_TYPES).index(item[0])))
    expected = sorted(
        outputs, key=lambda item: (item.log_time_ns, list(OUTPUT_TYPES).index(item.topic))
    )
    assert [(topic, log_time) for topic, log_time, _ in read] == [
        (item.topic, item.log_time_ns) for item in expected
    ]
    for (topic, _, message), ours in zip(read, expected, strict=True):
        reference = ours.message
        assert header_of(message) == header_of(reference), topic
        if ours.schema_name in ("sensor_msgs/msg/Image", "stereo_msgs/msg/DisparityImage"):
            image = message.image if hasattr(message, "image") else message
            wanted = reference.image if hasattr(reference, "image") else reference
            fields = ("height", "width", "encoding", "is_bigendian", "step")
            assert [getattr(image, name) for name in fields] == [
                getattr(wanted, name) for name in fields
            ], topic
            assert image.data.dtype == np.uint8
            assert_same_values(image_values(image), image_values(wanted), topic)
            if hasattr(message, "f"):
                assert (message.f, message.t) == (reference.f, reference.t)
        elif ours.schema_name == "sensor_msgs/msg/PointCloud2":
            assert [field.name for field in message.fields] == POINT_FIELDS
            assert (message.width, message.point_step, message.is_dense) == (
                reference.width,
                reference.point_step,
                reference.is_dense,
            )
            got, wanted_points = point_values(message), point_values(reference)
            for name in POINT_FIELDS:
                assert_same_values(got[name], wanted_points[name], name)
        else:  # CameraInfo
            assert (message.height, message.width) == (HEIGHT, WIDTH)
            for name in ("d", "k", "r", "p"):
                assert_same_values(getattr(message, name), getattr(reference, name), name)


# ----------------------------------------------------------------------------- Rerun


def _rerun_import(dense_log: Path) -> tuple[Any, dict[str, dict[str, list[Any]]]]:
    """Import the /pcainterp/* topics with Rerun's MCAP importer.

    Returns:
        (the file's McapInfo, entity -> data column name -> its values, one per time point).
    """
    rerun_chunk = pytest.importorskip("rerun.chunk")
    reader_class = getattr(rerun_chunk, "McapReader", None)
    if reader_class is None:
        pytest.skip("this rerun-sdk has no rerun.chunk.McapReader (MCAP import in Python)")
    reader = reader_class(dense_log, include_topic_regex=[f"^{PREFIX}"])
    columns: dict[str, dict[str, list[Any]]] = defaultdict(lambda: defaultdict(list))
    for chunk in reader.stream().to_chunks():
        if chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        for field in batch.schema:
            if (field.metadata or {}).get(b"rerun:kind") == b"data":
                columns[chunk.entity_path][field.name].extend(batch.column(field.name).to_pylist())
    return reader.info(), columns


def test_rerun_imports_the_log(dense_log: Path, reference: list[Decoded]) -> None:
    info, columns = _rerun_import(dense_log)
    assert info.profile == "ros2"
    assert info.summary_source == "embedded"  # our summary is used, not rebuilt by a scan
    assert info.message_count == len(reference)
    schemas = {channel.topic: channel.schema.name for channel in info.channels if channel.schema}
    assert {topic: schemas[topic] for topic in OUTPUT_TYPES} == OUTPUT_TYPES
    assert set(columns) == set(OUTPUT_TYPES)


def test_rerun_understands_images_camera_and_points(
    dense_log: Path, outputs: list[Decoded]
) -> None:
    """Which of our topics Rerun turns into its own types, and that they carry our values.

    Rerun 0.41 maps sensor_msgs/Image with a one-channel encoding to DepthImage,
    CameraInfo to Pinhole and PointCloud2 to Points3D (extra fields as extra components).
    stereo_msgs/DisparityImage has no semantic importer: it is kept as a decoded message.
    """
    _, columns = _rerun_import(dense_log)
    by_topic: dict[str, list[Any]] = defaultdict(list)
    for item in outputs:
        by_topic[item.topic].append(item.message)
    channel_datatype = {"32FC1": 34, "16UC1": 8}  # rerun ChannelDatatype F32, U16
    for topic in (
        "/pcainterp/depth",
        "/pcainterp/depth_std",
        "/pcainterp/disparity_std",
        "/pcainterp/depth_mm",
    ):
        entity = columns[topic]
        assert len(entity["DepthImage:buffer"]) == FRAMES, topic
        for (buffer,), (image_format,), ours in zip(
            entity["DepthImage:buffer"], entity["DepthImage:format"], by_topic[topic], strict=True
        ):
            assert (image_format["width"], image_format["height"]) == (WIDTH, HEIGHT)
            assert image_format["channel_datatype"] == channel_datatype[ours.encoding], topic
            assert bytes(buffer) == bytes(ours.data), topic
        # the image lies in the camera's image plane, so it is drawn in the 3-D view too
        assert entity["CoordinateFrame:frame"][0] == [
            f"{by_topic[topic][0].header.frame_id}_image_plane"
        ]
    camera = columns["/pcainterp/camera_info"]
    assert len(camera["Pinhole:image_from_camera"]) == FRAMES
    for (matrix,), (resolution,), ours in zip(
        camera["Pinhole:image_from_camera"],
        camera["Pinhole:resolution"],
        by_topic["/pcainterp/camera_info"],
        strict=True,
    ):
        # Rerun stores the 3x3 column-major
        np.testing.assert_allclose(
            np.reshape(matrix, (3, 3)).T, np.reshape(ours.k, (3, 3)), rtol=1e-6
        )
        assert resolution == [WIDTH, HEIGHT]
    assert camera["Pinhole:parent_frame"][0] == [
        by_topic["/pcainterp/camera_info"][0].header.frame_id
    ]
    features = columns["/pcainterp/features"]
    assert len(features["Points3D:positions"]) == FRAMES
    for positions, disparity, ours in zip(
        features["Points3D:positions"],
        features["Points3D:disparity"],
        by_topic["/pcainterp/features"],
        strict=True,
    ):
        points = point_values(ours)
        expected = np.stack([points["x"], points["y"], points["z"]], axis=1)
        assert_same_values(positions, expected, "positions")
        assert_same_values(disparity, points["disparity"], "disparity")
    disparity = columns["/pcainterp/disparity"]
    assert not any(name.startswith("DepthImage:") for name in disparity)
    decoded = disparity["stereo_msgs.msg.DisparityImage:message"]
    assert len(decoded) == FRAMES
    for (message,), ours in zip(decoded, by_topic["/pcainterp/disparity"], strict=True):
        assert (message["image"]["width"], message["image"]["height"]) == (WIDTH, HEIGHT)
        assert bytes(message["image"]["data"]) == bytes(ours.image.data)


# ----------------------------------------------------------------------------- compact


def _ros_inverse_depth(data: bytes) -> npt.NDArray[np.float32]:
    """compressedDepth png decoded independently: OpenCV's PNG reader and ROS's formula."""
    import struct

    import cv2

    _, quant_a, quant_b = struct.unpack("<iff", data[:12])
    codes = cv2.imdecode(np.frombuffer(data[12:], np.uint8), cv2.IMREAD_UNCHANGED)
    assert codes.dtype == np.uint16
    with np.errstate(divide="ignore"):
        values = np.float32(quant_a) / (codes.astype(np.float32) - np.float32(quant_b))
    values[codes == 0] = np.nan
    return values


def test_js_reads_the_compact_log_and_opencv_decodes_its_depth(
    js_reader: Path, compact_log: Path, dense_log: Path
) -> None:
    import base64
    import struct

    done = subprocess.run(
        ["node", js_reader.name, str(compact_log), PREFIX],
        cwd=js_reader.parent,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    read = json.loads(done.stdout)["indexed"]
    assert read["channels"]["/pcainterp/depth"]["schema_name"] == "sensor_msgs/msg/CompressedImage"
    full = {
        (item.topic, rosmsg.stamp_ns(item.message)): item.message
        for item in _decoded(dense_log)
        if item.topic in ("/pcainterp/depth", "/pcainterp/disparity_std")
    }
    disparity = _decoded(dense_log, "/pcainterp/disparity")[0].message
    focal_baseline = float(disparity.f) * float(disparity.t)
    seen = 0
    for item in read["messages"]:
        if item["topic"] not in ("/pcainterp/depth", "/pcainterp/disparity_std"):
            continue
        message = item["message"]
        assert message["format"] == "32FC1; compressedDepth png"
        values = _ros_inverse_depth(base64.b64decode(message["data_base64"]))
        stamp = message["header"]["stamp"]
        stamp_ns = int(stamp["sec"]) * 1_000_000_000 + int(stamp["nanosec"])
        exact = _float_image(full[item["topic"], stamp_ns])
        std = _float_image(full["/pcainterp/disparity_std", stamp_ns])
        # a std of 0 (this basis has no local kernel: it never varies at some pixels) is
        # "no value" in the compact form
        no_value = np.isnan(exact) | ((exact == 0) & (item["topic"] == "/pcainterp/disparity_std"))
        np.testing.assert_array_equal(np.isnan(values), no_value)
        np.testing.assert_array_equal(np.isposinf(values), np.isposinf(exact))
        finite = np.isfinite(exact) & ~no_value
        quant_a = struct.unpack("<iff", base64.b64decode(message["data_base64"])[:12])[1]
        if item["topic"] == "/pcainterp/depth":  # error in disparity, in units of the std
            # <= 1/64 of the std, or half the finest step 16 bits hold over the disparities
            step = focal_baseline / quant_a
            bound = np.maximum(std[finite] / 64.0, step / 2.0) * 1.001 + 1e-6
            disparity_error = focal_baseline * np.abs(1.0 / values[finite] - 1.0 / exact[finite])
            assert np.all(disparity_error <= bound)
        else:  # the std itself: relative error, where 16 bits can hold it
            storable = finite & (exact >= quant_a / 65534.0)
            assert np.max(np.abs(values[storable] / exact[storable] - 1.0)) <= 0.0101
        seen += 1
    assert seen == 2 * FRAMES


def _float_image(message: Any) -> npt.NDArray[np.float32]:
    """A 32FC1 Image as mcap_ros2 decodes it (data as bytes)."""
    values = np.frombuffer(bytes(message.data), dtype="<f4")
    return values.reshape(int(message.height), int(message.width))


def _decoded(path: Path, topic: str | None = None) -> list[Decoded]:
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return [
            Decoded(channel.topic, schema.name, message.log_time, message.publish_time, decoded)
            for schema, channel, message, decoded in reader.iter_decoded_messages(
                topics=None if topic is None else [topic], log_time_order=False
            )
        ]


def test_rosbags_reads_the_compact_log(compact_log: Path) -> None:
    from pcainterp_stream.io.depth_codec import decode

    with AnyReader([compact_log]) as reader:
        topics = {connection.topic: connection.msgtype for connection in reader.connections}
        assert topics["/pcainterp/depth"] == "sensor_msgs/msg/CompressedImage"
        assert topics["/pcainterp/depth_mm"] == "sensor_msgs/msg/Image"
        for connection, _, data in reader.messages(
            [c for c in reader.connections if c.topic == "/pcainterp/depth"]
        ):
            message = reader.deserialize(data, connection.msgtype)
            depth = decode(message.format, message.data)
            assert depth.shape == (HEIGHT, WIDTH)
            assert depth.dtype == np.float32


def test_rerun_draws_the_compact_logs_depth_mm(compact_log: Path) -> None:
    """Rerun's importer draws the default log's viewer copy as depth (the compressedDepth
    channels stay encoded blobs: the reason the copy is written)."""
    _, columns = _rerun_import(compact_log)
    entity = columns["/pcainterp/depth_mm"]
    assert len(entity["DepthImage:buffer"]) == FRAMES
    for (image_format,) in entity["DepthImage:format"]:
        assert (image_format["width"], image_format["height"]) == (WIDTH, HEIGHT)
        assert image_format["channel_datatype"] == 8  # U16
    assert not any(key.startswith("DepthImage") for key in columns["/pcainterp/depth"])
