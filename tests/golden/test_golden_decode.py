"""Generic decoding for golden summaries: every image encoding, compressedDepth, clouds."""

from __future__ import annotations

import struct

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from pcainterp_stream.golden import decode_compressed_depth, message_content
from pcainterp_stream.golden.decode import rvl_decode
from pcainterp_stream.io import rosmsg
from pcainterp_stream.records import StereoCamera


def rvl_encode(values: np.ndarray) -> bytes:
    """RVL as Wilson (2017) writes it: runs of zeros / non-zeros, zig-zag deltas, nibbles."""
    words: list[int] = []
    state = {"word": 0, "nibbles": 0}

    def vle(value: int) -> None:
        while True:
            nibble = value & 0x7
            value >>= 3
            if value:
                nibble |= 0x8
            state["word"] = ((state["word"] << 4) | nibble) & 0xFFFFFFFF
            state["nibbles"] += 1
            if state["nibbles"] == 8:
                words.append(state["word"])
                state["word"], state["nibbles"] = 0, 0
            if not value:
                break

    flat = [int(v) for v in values.reshape(-1)]
    i, previous = 0, 0
    while i < len(flat):
        zeros = 0
        while i < len(flat) and flat[i] == 0:
            zeros, i = zeros + 1, i + 1
        vle(zeros)
        run = []
        while i < len(flat) and flat[i] != 0:
            run.append(flat[i])
            i += 1
        vle(len(run))
        for current in run:
            delta = current - previous
            vle((delta << 1) ^ (delta >> 31))
            previous = current
    if state["nibbles"]:
        words.append((state["word"] << (4 * (8 - state["nibbles"]))) & 0xFFFFFFFF)
    return struct.pack(f"<{len(words)}I", *words)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rvl_round_trip(seed: int) -> None:
    rng = np.random.default_rng(seed)
    values = rng.integers(0, 65536, size=(7, 13)).astype(np.uint16)
    values[rng.random(values.shape) < 0.4] = 0
    values[0, :5] = 0
    values[-1, -3:] = 65535
    decoded = rvl_decode(rvl_encode(values), values.size)
    np.testing.assert_array_equal(decoded.reshape(values.shape), values)


@given(
    arrays(np.uint16, st.integers(1, 300), elements=st.sampled_from([0, 1, 2, 7, 8, 300, 65535]))
)
def test_rvl_round_trip_property(values: np.ndarray) -> None:
    np.testing.assert_array_equal(rvl_decode(rvl_encode(values), values.size), values)


def test_rvl_short_stream_is_an_error() -> None:
    with pytest.raises(ValueError, match="RVL data"):
        rvl_decode(b"", 10)


def _header(quant_a: float, quant_b: float) -> bytes:
    return struct.pack("<iff", 0, quant_a, quant_b)


def _inverse_depth(depth: np.ndarray, quant_a: float, quant_b: float) -> np.ndarray:
    inverse = np.zeros(depth.shape, dtype=np.uint16)
    valid = np.isfinite(depth) & (depth > 0)
    inverse[valid] = np.round(quant_a / depth[valid] + quant_b).astype(np.uint16)
    return inverse


def _depth() -> np.ndarray:
    rng = np.random.default_rng(3)
    depth = rng.uniform(1.0, 40.0, size=(6, 9)).astype(np.float32)
    depth[0, 0] = np.nan
    return depth


def test_compressed_depth_32fc1_png() -> None:
    quant = 100.0
    quant_a = quant * (quant + 1.0)
    quant_b = 1.0 - quant_a / 50.0
    depth = _depth()
    inverse = _inverse_depth(depth, quant_a, quant_b)
    ok, png = cv2.imencode(".png", inverse)
    assert ok
    decoded = decode_compressed_depth(
        "32FC1; compressedDepth png", _header(quant_a, quant_b) + png.tobytes()
    )
    assert decoded.dtype == np.float32
    assert np.isnan(decoded[0, 0])
    expected = np.float32(quant_a) / (inverse.astype(np.float32) - np.float32(quant_b))
    np.testing.assert_allclose(decoded[1:], expected[1:], rtol=1e-6)
    np.testing.assert_allclose(decoded[1:], depth[1:], rtol=0.02)  # the quantisation


def test_compressed_depth_16uc1_png_and_rvl() -> None:
    depth_mm = (np.nan_to_num(_depth()) * 1000).astype(np.uint16)
    ok, png = cv2.imencode(".png", depth_mm)
    assert ok
    from_png = decode_compressed_depth("16UC1; compressedDepth png", _header(0, 0) + png.tobytes())
    np.testing.assert_array_equal(from_png, depth_mm)
    payload = struct.pack("<ii", 9, 6) + rvl_encode(depth_mm)
    from_rvl = decode_compressed_depth("16UC1; compressedDepth rvl", _header(0, 0) + payload)
    assert from_rvl.dtype == np.uint16
    np.testing.assert_array_equal(from_rvl, depth_mm)


def test_compressed_depth_32fc1_rvl() -> None:
    quant_a, quant_b = 10100.0, -201.0
    inverse = _inverse_depth(_depth(), quant_a, quant_b)
    payload = struct.pack("<ii", 9, 6) + rvl_encode(inverse)
    decoded = decode_compressed_depth(
        "32FC1; compressedDepth rvl", _header(quant_a, quant_b) + payload
    )
    expected = np.float32(quant_a) / (inverse.astype(np.float32) - np.float32(quant_b))
    expected[inverse == 0] = np.nan
    np.testing.assert_allclose(decoded, expected, rtol=1e-6)


def test_compressed_depth_refuses_other_formats() -> None:
    with pytest.raises(ValueError, match="not a compressedDepth format"):
        decode_compressed_depth("png", b"")
    with pytest.raises(ValueError, match="no image after the header"):
        decode_compressed_depth("32FC1; compressedDepth png", b"\x00")


def test_a_damaged_rvl_header_leaves_a_one_line_note() -> None:
    """A header of 100000 x 100000 px: a note, not a 74.5 GiB allocation (MemoryError)."""
    payload = _header(100.0, 0.0) + struct.pack("<II", 100_000, 100_000) + bytes(64)
    damaged = rosmsg.compressed_image_message(payload, "32FC1; compressedDepth rvl", 5, "cam")
    content = message_content(rosmsg.COMPRESSED_IMAGE, damaged)
    assert list(content.arrays) == ["data"]  # its raw bytes, not the image
    np.testing.assert_array_equal(content.arrays["data"], np.frombuffer(payload, np.uint8))
    assert len(content.notes) == 1
    assert "RVL header says 100000x100000 px" in content.notes[0]
    assert "\n" not in content.notes[0]


@pytest.mark.parametrize(
    "encoding", ["mono8", "8UC1", "rgb8", "bgr8", "8UC3", "mono16", "16UC1", "32FC1"]
)
def test_every_image_encoding_is_summarised(encoding: str) -> None:
    dtype, channels = rosmsg.IMAGE_ENCODINGS[encoding]
    shape = (5, 7, channels) if channels > 1 else (5, 7)
    array = (np.arange(np.prod(shape)) % 200).reshape(shape).astype(dtype)
    message = rosmsg.image_message(array, 1_000, "cam", encoding=encoding)
    content = message_content(rosmsg.IMAGE, message)
    assert content.values["encoding"] == encoding
    assert content.values["header.frame_id"] == "cam"
    assert "data" not in content.values
    image = content.arrays["image"]
    assert image.shape == shape
    expected = array[:, :, ::-1] if encoding in ("bgr8", "8UC3") else array  # BGR to RGB
    np.testing.assert_array_equal(image, expected)


def test_compressed_png_point_cloud_camera_info_and_disparity() -> None:
    grey = (np.arange(35) * 7 % 256).astype(np.uint8).reshape(5, 7)
    ok, png = cv2.imencode(".png", grey)
    assert ok
    compressed = rosmsg.compressed_image_message(png.tobytes(), "png", 5, "cam")
    np.testing.assert_array_equal(
        message_content(rosmsg.COMPRESSED_IMAGE, compressed).arrays["image"], grey
    )

    cloud = rosmsg.pointcloud2_message(
        {"x": np.arange(100, dtype=np.float32), "y": np.ones(100, dtype=np.float32)}, 5, "cam"
    )
    content = message_content(rosmsg.POINT_CLOUD2, cloud)
    assert set(content.arrays) == {"points.x", "points.y"}
    assert content.values["width"] == 100
    assert content.values["fields[0].name"] == "x"

    camera = StereoCamera(width=7, height=5, fx=30.0, fy=30.0, cx=3.0, cy=2.0, baseline=0.5)
    info = message_content(
        rosmsg.CAMERA_INFO, rosmsg.camera_info_message(camera, 5, "cam", right=True)
    )
    assert info.values["p"][3] == pytest.approx(-15.0)
    assert info.values["distortion_model"] == "plumb_bob"

    disparity = rosmsg.disparity_image_message(
        np.full((40, 40), 3.0, np.float32),
        5,
        "cam",
        focal=30.0,
        baseline=0.5,
        min_disparity=0.0,
        max_disparity=64.0,
    )
    content = message_content(rosmsg.DISPARITY_IMAGE, disparity)
    assert content.arrays["image.image"].shape == (40, 40)
    assert content.values["f"] == 30.0


def test_undecodable_payload_leaves_a_note() -> None:
    broken = rosmsg.compressed_image_message(b"not an image", "jpeg", 5, "cam")
    content = message_content(rosmsg.COMPRESSED_IMAGE, broken)
    assert list(content.arrays) == ["data"]
    assert content.values["data.length"] == len(b"not an image")
    assert content.notes
    legacy = message_content(rosmsg.COMPRESSED_IMAGE, broken, legacy=True)  # format 2
    assert legacy.arrays == {}
    assert legacy.values == {k: v for k, v in content.values.items()}


def test_an_empty_compressed_payload_leaves_a_note() -> None:
    """Bug hunt 7A F2: a 0-byte payload reached cv2.imdecode's assertion (a cv2.error)."""
    empty = rosmsg.compressed_image_message(b"", "jpeg", 5, "cam")
    content = message_content(rosmsg.COMPRESSED_IMAGE, empty)
    assert content.arrays["data"].shape == (0,)
    assert content.values["data.length"] == 0
    raw = "; its raw data bytes are recorded instead"
    assert content.notes == [f"CompressedImage of format 'jpeg' is empty (0 bytes){raw}"]
    zero = message_content(rosmsg.IMAGE, rosmsg.image_message(np.zeros((0, 0), np.uint8), 5, "c"))
    assert zero.notes == [f"image is empty (0x0 mono8){raw}"]


def test_a_compressed_bayer_mosaic_is_summarised_as_its_image() -> None:
    """Bug hunt 7A F1: ``bayer_rggb8; png compressed `` is the mosaic; demosaiced as the raw
    ``bayer_rggb8`` Image is, not summarised as a grey image."""
    mosaic = (np.arange(20 * 16) * 37 % 256).astype(np.uint8).reshape(20, 16)
    image = rosmsg.image_message(mosaic, 5, "cam", encoding="bayer_rggb8")
    ok, png = cv2.imencode(".png", mosaic)
    assert ok
    compressed = rosmsg.compressed_image_message(
        png.tobytes(), "bayer_rggb8; png compressed ", 5, "cam"
    )
    raw = message_content(rosmsg.IMAGE, image).arrays["image"]
    assert raw.shape == (20, 16, 3)
    got = message_content(rosmsg.COMPRESSED_IMAGE, compressed).arrays["image"]
    np.testing.assert_array_equal(got, raw)


def test_a_16_bit_bayer_image_and_its_compressed_mosaic_are_summarised_alike() -> None:
    """Bug hunt 7A F13: ``bayer_rggb16`` was a note ("unsupported image encoding")."""
    mosaic = (np.arange(20 * 16) * 2311 % 65536).astype(np.uint16).reshape(20, 16)
    image = rosmsg.image_message(mosaic, 5, "cam", encoding="bayer_rggb16")
    raw = message_content(rosmsg.IMAGE, image)
    assert raw.notes == []
    assert raw.arrays["image"].shape == (20, 16, 3)
    assert raw.arrays["image"].dtype == np.uint16
    # the pixels of a red cell are kept exactly (bilinear demosaicing)
    assert raw.arrays["image"][2, 2, 0] == mosaic[2, 2]
    ok, png = cv2.imencode(".png", mosaic)
    assert ok
    compressed = rosmsg.compressed_image_message(
        png.tobytes(), "bayer_rggb16; png compressed ", 5, "cam"
    )
    got = message_content(rosmsg.COMPRESSED_IMAGE, compressed).arrays["image"]
    np.testing.assert_array_equal(got, raw.arrays["image"])
