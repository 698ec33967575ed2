"""The compressedDepth codecs: round trips, REP 118, and our bytes read by independent decoders."""

from __future__ import annotations

import struct
import tracemalloc
import zlib

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from pcainterp_stream.io import depth_codec

FOCAL_BASELINE = 387.0


def _depth_image(seed: int = 0, shape: tuple[int, int] = (60, 90)) -> np.ndarray:
    """A smooth disparity field turned into REP 118 depth with NaN and +inf patches."""
    rng = np.random.default_rng(seed)
    rows, _ = np.mgrid[0 : shape[0], 0 : shape[1]]
    disparity = 2.0 + 60.0 * rows / shape[0] + rng.normal(0.0, 0.3, shape)
    depth = (FOCAL_BASELINE / disparity).astype(np.float32)
    depth[:5, :20] = np.nan
    depth[:3, 40:] = np.inf
    return depth


def _ros_decode_inverse_depth(codes: np.ndarray, quant_a: float, quant_b: float) -> np.ndarray:
    """ROS's compressed_depth_image_transport formula, written out pixel by pixel."""
    out = np.empty(codes.shape, dtype=np.float32)
    for index, code in np.ndenumerate(codes):
        if code:
            with np.errstate(divide="ignore"):
                out[index] = np.float32(quant_a) / (np.float32(code) - np.float32(quant_b))
        else:
            out[index] = np.nan
    return out


def test_png_depth_read_by_opencv_and_the_ros_formula() -> None:
    depth = _depth_image()
    step = 1.0 / 64.0
    quant_a = depth_codec.inverse_depth_scale(FOCAL_BASELINE, step, 70.0)
    encoded = depth_codec.encode_depth(depth, quant_a=quant_a)
    assert encoded.format == "32FC1; compressedDepth png"
    kind, header_a, header_b = struct.unpack("<iff", encoded.data[:12])
    assert (kind, header_b) == (0, 1.0)
    assert header_a == pytest.approx(quant_a, rel=1e-6)
    codes = cv2.imdecode(np.frombuffer(encoded.data[12:], np.uint8), cv2.IMREAD_UNCHANGED)
    assert codes.dtype == np.uint16
    assert codes.shape == depth.shape
    independent = _ros_decode_inverse_depth(codes, header_a, header_b)
    ours = depth_codec.decode(encoded.format, encoded.data)
    np.testing.assert_array_equal(ours, independent)
    # REP 118 survives: NaN no estimate, +inf too far
    np.testing.assert_array_equal(np.isnan(independent), np.isnan(depth))
    np.testing.assert_array_equal(np.isposinf(independent), np.isposinf(depth))
    finite = np.isfinite(depth)
    disparity_error = np.abs(FOCAL_BASELINE / independent[finite] - FOCAL_BASELINE / depth[finite])
    assert disparity_error.max() <= step / 2 * 1.001


@pytest.mark.parametrize("codec", depth_codec.CODECS)
def test_16uc1_is_lossless(codec: str) -> None:
    rng = np.random.default_rng(3)
    image = rng.integers(0, 60000, size=(37, 53), dtype=np.uint16)
    image[5:9] = 0
    encoded = depth_codec.encode_16(image, codec=codec)
    assert encoded.format == f"16UC1; compressedDepth {codec}"
    np.testing.assert_array_equal(depth_codec.decode(encoded.format, encoded.data), image)
    if codec == "png":
        independent = cv2.imdecode(np.frombuffer(encoded.data[12:], np.uint8), -1)
        np.testing.assert_array_equal(independent, image)


@pytest.mark.parametrize("codec", depth_codec.CODECS)
def test_depth_round_trip_both_codecs_agree(codec: str) -> None:
    depth = _depth_image(1)
    quant_a = depth_codec.inverse_depth_scale(FOCAL_BASELINE, 1.0 / 256.0, 70.0)
    png = depth_codec.encode_depth(depth, quant_a=quant_a, codec="png")
    other = depth_codec.encode_depth(depth, quant_a=quant_a, codec=codec)
    np.testing.assert_array_equal(
        depth_codec.decode(other.format, other.data), depth_codec.decode(png.format, png.data)
    )


pixels = hnp.arrays(
    np.uint16,
    st.integers(0, 400),
    elements=st.one_of(st.just(0), st.integers(0, 65535), st.integers(1000, 1010)),
)


@given(pixels)
def test_rvl_round_trip(values: np.ndarray) -> None:
    code = depth_codec.rvl_encode(values)
    assert len(code) % 4 == 0
    np.testing.assert_array_equal(depth_codec.rvl_decode(code, values.size), values)


@given(
    hnp.arrays(
        np.uint16,
        st.integers(0, 400),
        elements=st.one_of(st.just(0), st.integers(0, 32767), st.integers(1000, 1010)),
    )
)
def test_rvl_bytes_match_an_independent_codec(values: np.ndarray) -> None:
    """The ``rvl`` library is Wilson's original on int16 pixels; ROS's (and ours) takes
    uint16: they agree below 32768, where signed and unsigned deltas are the same."""
    rvl = pytest.importorskip("rvl", reason="the independent RVL codec (pip install rvl)")
    ours = depth_codec.rvl_encode(values)
    # that library prefixes the pixel count (uint32) to the same RVL words
    theirs = rvl.compress(values.astype("<u2").tobytes())
    assert theirs == struct.pack("<I", values.size) + ours
    decoded = np.frombuffer(rvl.decompress(struct.pack("<I", values.size) + ours), "<u2")
    np.testing.assert_array_equal(decoded, values)


def test_rvl_message_layout() -> None:
    image = np.arange(12, dtype=np.uint16).reshape(3, 4)
    encoded = depth_codec.encode_16(image, codec="rvl")
    width, height = struct.unpack("<II", encoded.data[12:20])
    assert (width, height) == (4, 3)
    np.testing.assert_array_equal(depth_codec.rvl_decode(encoded.data[20:], 12), image.ravel())


@given(
    hnp.arrays(
        np.float32,
        st.tuples(st.integers(1, 12), st.integers(1, 12)),
        elements=st.one_of(st.floats(0.25, 4096.0, width=32), st.just(np.nan), st.just(np.inf)),
    )
)
def test_inverse_depth_keeps_rep118_and_the_step(depth: np.ndarray) -> None:
    step = 1.0 / 128.0
    finite = np.isfinite(depth)
    max_disparity = float(FOCAL_BASELINE / depth[finite].min()) if finite.any() else 1.0
    quant_a = depth_codec.inverse_depth_scale(FOCAL_BASELINE, step, max_disparity)
    used_step = FOCAL_BASELINE / quant_a
    encoded = depth_codec.encode_depth(depth, quant_a=quant_a)
    back = depth_codec.decode(encoded.format, encoded.data)
    np.testing.assert_array_equal(np.isnan(back), np.isnan(depth))
    np.testing.assert_array_equal(np.isposinf(back), np.isposinf(depth))
    error = np.abs(FOCAL_BASELINE / back[finite] - FOCAL_BASELINE / depth[finite])
    # float32 arithmetic of A / z adds a relative 1e-6 of the disparity
    assert np.all(error <= used_step / 2 + 2e-6 * FOCAL_BASELINE / depth[finite] + 1e-9)


def test_decode_refuses_what_it_cannot_read() -> None:
    with pytest.raises(depth_codec.DepthCodecError, match="not a compressedDepth"):
        depth_codec.decode("png", b"x" * 20)
    with pytest.raises(depth_codec.DepthCodecError, match="no image after the header"):
        depth_codec.decode("32FC1; compressedDepth png", b"\0" * 12)
    with pytest.raises(depth_codec.DepthCodecError, match="16-bit greyscale PNG"):
        depth_codec.decode("32FC1; compressedDepth png", b"\0" * 40)
    with pytest.raises(depth_codec.DepthCodecError, match="codec 'jpeg'"):
        depth_codec.decode("32FC1; compressedDepth jpeg", b"\0" * 40)
    with pytest.raises(depth_codec.DepthCodecError, match="ends after"):
        depth_codec.rvl_decode(depth_codec.rvl_encode(np.ones(10, np.uint16)), 20)
    assert depth_codec.parse_format("32FC1; compressedDepth") == ("32FC1", "png")


def _rvl_message(width: int, height: int, code: bytes = bytes(64)) -> bytes:
    return struct.pack("<iff", 0, 100.0, 0.0) + struct.pack("<II", width, height) + code


@pytest.mark.parametrize(("width", "height"), [(100_000, 100_000), (2_000_000_000, 1)])
def test_a_damaged_rvl_header_is_refused_before_allocating(width: int, height: int) -> None:
    with pytest.raises(
        depth_codec.DepthCodecError,
        match=rf"^RVL header says {width}x{height} px, more than an image holds .* damaged",
    ):
        depth_codec.decode("32FC1; compressedDepth rvl", _rvl_message(width, height))


def test_an_rvl_header_bigger_than_its_code_allocates_nothing() -> None:
    """30000 x 30000 px may be an image; 64 bytes of code hold none of it: no 7 GB buffer."""
    tracemalloc.start()
    try:
        with pytest.raises(
            depth_codec.DepthCodecError,
            match=r"RVL header says 30000x30000 px; the data are damaged: RVL data ends after "
            r"0 of 900000000 pixels",
        ):
            depth_codec.decode("16UC1; compressedDepth rvl", _rvl_message(30_000, 30_000))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 10 << 20


def test_png_data_read_as_rvl_is_a_codec_error() -> None:
    """A wrong format string: the PNG signature read as an RVL width x height."""
    encoded = depth_codec.encode_depth(_depth_image(), quant_a=1000.0, codec="png")
    with pytest.raises(depth_codec.DepthCodecError, match=r"not RVL"):
        depth_codec.decode("32FC1; compressedDepth rvl", encoded.data)


@given(
    hnp.arrays(
        np.uint16,
        st.tuples(st.integers(1, 9), st.integers(1, 9)),
        elements=st.integers(0, 65535),
    )
)
def test_our_png_is_read_by_opencv(image: np.ndarray) -> None:
    decoded = cv2.imdecode(np.frombuffer(depth_codec.png16(image), np.uint8), -1)
    assert decoded.dtype == np.uint16
    np.testing.assert_array_equal(decoded.reshape(image.shape), image)


@pytest.mark.parametrize("level", depth_codec.PNG_LEVELS)
def test_every_png_level_is_a_standard_zlib_stream(level: int) -> None:
    """ISA-L's deflate at each level: zlib (not our deflater) inflates the IDAT to the rows."""
    image = depth_codec.quantise_inverse_depth(_depth_image(), 500.0)
    png = depth_codec.png16(image, level)
    (length,) = struct.unpack(">I", png[33:37])
    assert png[37:41] == b"IDAT"
    rows = zlib.decompress(png[41 : 41 + length])
    height, width = image.shape
    assert len(rows) == height * (2 * width + 1)
    assert set(rows[:: 2 * width + 1]) == {2}  # every row filtered "Up"
    decoded = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(decoded, image)


def test_png_level_outside_isal_levels_is_refused() -> None:
    with pytest.raises(ValueError, match="ISA-L"):
        depth_codec.png16(np.zeros((2, 2), np.uint16), 6)


@pytest.mark.parametrize("codec", depth_codec.CODECS)
def test_zero_as_nan_stores_zero_as_no_value_and_the_rest_as_before(codec: str) -> None:
    # bug hunt 14B F1: a std of 0 took the nearest code, 65535, and read back as A / 65534
    image = np.array([[0.0, -0.0, 0.5, 2.0], [np.nan, np.inf, 1e-9, -1.0]], np.float32)
    quant_a = 100.0
    as_before = depth_codec.quantise_inverse_depth(image, quant_a)
    codes = depth_codec.quantise_inverse_depth(image, quant_a, zero_as_nan=True)
    assert as_before[0, 0] == depth_codec.MAX_CODE  # depth 0: the nearest storable value
    # bug hunt 15B F3: -0.0 took the farthest code (A / -0 = -inf, clipped to B + 1)
    assert as_before[0, 1] == depth_codec.MAX_CODE
    assert codes[0, :2].tolist() == [0, 0]  # NaN's code, "no value"; -0.0 too (A / -0 < 0)
    assert np.array_equal(codes.ravel()[2:], as_before.ravel()[2:])  # a tiny value as before
    encoded = depth_codec.encode_depth(image, quant_a=quant_a, codec=codec, zero_as_nan=True)
    decoded = depth_codec.decode(encoded.format, encoded.data)
    assert np.isnan(decoded[0, :2]).all()
    assert decoded[1, 1] == np.inf
    assert decoded[1, 2] == np.float32(quant_a / 65534)
    # a message written before (0 as the nearest code) still reads as it did
    old = depth_codec.encode_depth(image, quant_a=quant_a, codec=codec)
    assert depth_codec.decode(old.format, old.data)[0, 0] == np.float32(quant_a / 65534)
