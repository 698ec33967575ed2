"""Depth image codecs of ROS's ``compressed_depth_image_transport``: encode and decode.

A ``sensor_msgs/CompressedImage`` whose ``format`` is ``"<encoding>; compressedDepth <codec>"``
holds a 12-byte header, ``ConfigHeader`` {int32 format (0: inverse depth), float32
depthQuantA, float32 depthQuantB}, little endian, then the 16-bit image:

- ``png``: a 16-bit greyscale PNG (any PNG decoder reads it, e.g. ``cv2.imdecode``; written
  here by :func:`png16`, deflated by ISA-L, read with OpenCV);
- ``rvl``: uint32 width, uint32 height, then the RVL code of the pixels in row order (Wilson,
  "Fast Lossless Depth Image Compression", ISS 2017: runs of zeros and of non-zeros, each
  non-zero pixel as the zigzag delta to the previous one, in 3-bit nibbles with a
  continuation bit packed eight to a little-endian 32-bit word, first nibble highest).

``16UC1`` images are stored as they are (millimetres by REP 118; the header's parameters
are unused). ``32FC1`` depth (metres) is stored as quantised *inverse* depth, which is
linear in disparity: ``q = A / z + B`` and a decoder returns ``A / (q - B)`` for ``q != 0``
and NaN for ``q == 0``. ROS's own encoder truncates and drops depths beyond a ``depth_max``;
:func:`encode_depth` rounds, and takes ``B = 1`` so that REP 118 survives any standard
decoder: NaN (no estimate) is ``q = 0`` and ``+inf`` (farther than measurable) is ``q = 1``,
which decodes to ``A / 0 = +inf``. With ``A = f*b / step`` the decoded disparity ``f*b / z``
is ``(q - 1) * step``: the depth is the disparity rounded to a multiple of ``step`` px
(:func:`inverse_depth_scale` picks ``A``). No code decodes to 0: a 0 is stored as the
nearest value, ``A / 65534``, or (``zero_as_nan``: a std image, whose 0 claims certainty, not
a tiny value) as NaN.

Everything here is vectorised numpy (and OpenCV for PNG); the RVL decoder loops in Python
once per run of zeros, so an image made of many tiny holes decodes slower, never wrongly.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt
from isal import isal_zlib
from zlib_ng import zlib_ng

HEADER = struct.Struct("<iff")
"""``ConfigHeader``: int32 format (0 = inverse depth), float32 depthQuantA, depthQuantB."""
INVERSE_DEPTH = 0
"""``ConfigHeader.format`` of every compressedDepth message (ROS's ``INV_DEPTH``)."""
CODECS = ("png", "rvl")
ENCODINGS = ("32FC1", "16UC1")
MAX_CODE = 65535
PNG_LEVELS = (0, 1, 2, 3)
"""Deflate levels of the PNG codec: ISA-L's (``isal.isal_zlib``), any zlib inflater reads them."""
DEFAULT_PNG_LEVEL = 1
"""ISA-L level of the PNG codec: on KITTI depth the size of zlib-ng's level 2 (the default
before) in ~2/5 of its time, ~1.8 ms per 1241x376 image (docs/output_speed.md)."""
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
RVL_MAX_SIDE = 1 << 20
"""Largest width or height an RVL header may give (px): OpenCV's limit on a PNG's
(``CV_IO_MAX_IMAGE_WIDTH``), so that both codecs read the same images."""
RVL_MAX_PIXELS = 1 << 30
"""Largest width x height an RVL header may give: OpenCV's ``CV_IO_MAX_IMAGE_PIXELS``."""


class DepthCodecError(ValueError):
    """A compressedDepth message that cannot be decoded (says why)."""


@dataclass(frozen=True)
class CompressedDepth:
    """One encoded depth image: the ``format`` string and ``data`` of a CompressedImage."""

    format: str
    data: bytes


def compressed_format(encoding: str, codec: str) -> str:
    """Return the ``CompressedImage.format`` of an image encoding and codec."""
    return f"{encoding}; compressedDepth {codec}"


def parse_format(image_format: str) -> tuple[str, str] | None:
    """Return (encoding, codec) of a compressedDepth ``format``; None for any other format.

    ``"32FC1; compressedDepth"`` (older ROS publishers) means png, as in ROS's decoder.
    """
    encoding, _, rest = image_format.partition(";")
    rest = rest.strip()
    if not rest.startswith("compressedDepth"):
        return None
    codec = rest[len("compressedDepth") :].strip() or "png"
    return encoding.strip(), codec


def is_compressed_depth(image_format: str) -> bool:
    """Return whether a ``CompressedImage.format`` names a compressedDepth image."""
    return parse_format(image_format) is not None


def inverse_depth_scale(focal_baseline: float, step: float, max_disparity: float) -> float:
    """Return the ``depthQuantA`` that stores disparity in multiples of ``step`` px.

    Args:
        focal_baseline: f*b (px*m) of the depth image's camera.
        step: the disparity quantum (px); the decoded depth's disparity is within
            ``step / 2`` of the encoded one.
        max_disparity: the largest disparity (px) to store; when ``step`` cannot reach it
            in 16 bits the step grows by powers of two until it can.

    Returns:
        A = f*b / step' for the step' used.
    """
    if not (focal_baseline > 0 and step > 0):
        raise ValueError(f"focal_baseline and step must be > 0, got {focal_baseline}, {step}")
    while max_disparity / step + 1.5 > MAX_CODE:
        step *= 2.0
    return focal_baseline / step


def quantise_inverse_depth(
    depth: npt.NDArray[np.floating],
    quant_a: float,
    quant_b: float = 1.0,
    *,
    zero_as_nan: bool = False,
) -> npt.NDArray[np.uint16]:
    """Return the 16-bit codes ``rint(A / z + B)`` of a depth image (m), REP 118 kept.

    NaN -> 0, ``+inf`` -> ``B`` (``A / 0`` when decoded), a finite depth never to 0 nor ``B``
    (so never to NaN or infinity), codes clipped to 16 bits (the nearest storable value: 0
    becomes the smallest, ``A / 65534``, and so does -0.0). Negative values (no depth) are
    stored as NaN.

    ``zero_as_nan``: store 0 as NaN (code 0, "no value") instead: no code decodes to 0, and
    for an image that is not depth (a std) 0 is not a small value to round to ``A / 65534``.
    """
    depth = np.asarray(depth, dtype=np.float32)
    # in place on one float32 buffer (a few passes over the image, no temporaries)
    code = np.empty_like(depth)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        np.divide(np.float32(quant_a), depth, out=code)
        np.abs(code, out=code)  # -0.0 (A / -0 = -inf) is the nearest depth, as +0.0 is
        code += np.float32(quant_b)
        np.rint(code, out=code)
        np.clip(code, quant_b + 1.0, MAX_CODE, out=code)  # a finite depth: never 0 nor B
        no_depth = ~(depth > 0) if zero_as_nan else ~(depth >= 0)  # NaN, negative, -inf
    code[no_depth] = 0.0
    code[depth == np.inf] = quant_b
    return code.astype(np.uint16)


def dequantise_inverse_depth(
    code: npt.NDArray[np.uint16], quant_a: float, quant_b: float
) -> npt.NDArray[np.float32]:
    """Return the depth (m) of 16-bit codes as ROS's decoder does: ``A / (q - B)``, 0 -> NaN."""
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.float32(quant_a) / (code.astype(np.float32) - np.float32(quant_b))
    depth[code == 0] = np.nan
    return depth.astype(np.float32, copy=False)


def encode_depth(
    depth: npt.NDArray[np.floating],
    *,
    quant_a: float,
    codec: str = "png",
    png_level: int = DEFAULT_PNG_LEVEL,
    zero_as_nan: bool = False,
) -> CompressedDepth:
    """Encode a ``32FC1`` depth image (m, REP 118) as ``32FC1; compressedDepth <codec>``.

    Args:
        depth: (H, W) depth (m); NaN no estimate, ``+inf`` too far.
        quant_a: depthQuantA (:func:`inverse_depth_scale`); depthQuantB is 1.
        codec: "png" or "rvl".
        png_level: deflate level of the PNG (:data:`PNG_LEVELS`, ISA-L's).
        zero_as_nan: store 0 as NaN (:func:`quantise_inverse_depth`), not as ``A / 65534``.
    """
    code = quantise_inverse_depth(depth, quant_a, 1.0, zero_as_nan=zero_as_nan)
    header = HEADER.pack(INVERSE_DEPTH, float(quant_a), 1.0)
    return CompressedDepth(
        compressed_format("32FC1", codec), header + _encode_16(code, codec, png_level)
    )


def encode_16(
    image: npt.NDArray[np.uint16], *, codec: str = "png", png_level: int = DEFAULT_PNG_LEVEL
) -> CompressedDepth:
    """Encode a ``16UC1`` image (REP 118: mm, 0 = no estimate) as ``16UC1; compressedDepth``."""
    header = HEADER.pack(INVERSE_DEPTH, 0.0, 0.0)
    return CompressedDepth(
        compressed_format("16UC1", codec),
        header + _encode_16(np.asarray(image, dtype=np.uint16), codec, png_level),
    )


def decode(image_format: str, data: bytes | memoryview | npt.NDArray[np.uint8]) -> np.ndarray:
    """Decode a compressedDepth message as ROS's subscriber does.

    Returns:
        (H, W) float32 depth (m; NaN, ``+inf`` per REP 118) for ``32FC1``, or the (H, W)
        uint16 image for ``16UC1``.

    Raises:
        DepthCodecError: not a compressedDepth format, an unknown codec or encoding, or
            data that does not decode.
    """
    parsed = parse_format(image_format)
    if parsed is None:
        raise DepthCodecError(f"format {image_format!r} is not a compressedDepth format")
    encoding, codec = parsed
    if encoding not in ENCODINGS:
        raise DepthCodecError(
            f"compressedDepth encoding {encoding!r} is not supported; expected 32FC1 or 16UC1"
        )
    raw = np.frombuffer(bytes(data) if isinstance(data, memoryview) else data, dtype=np.uint8)
    if raw.size <= HEADER.size:
        raise DepthCodecError(
            f"compressedDepth data has {raw.size} bytes, no image after the header"
        )
    _, quant_a, quant_b = HEADER.unpack_from(raw.tobytes()[: HEADER.size])
    code = decode_16(raw[HEADER.size :], codec)
    if encoding == "16UC1":
        return code
    return dequantise_inverse_depth(code, quant_a, quant_b)


def decode_16(payload: npt.NDArray[np.uint8], codec: str) -> npt.NDArray[np.uint16]:
    """Decode the 16-bit image after the header (PNG or width, height and RVL)."""
    if codec == "png":
        image = cv2.imdecode(payload, cv2.IMREAD_UNCHANGED)
        if image is None or image.dtype != np.uint16 or image.ndim != 2:
            raise DepthCodecError("compressedDepth png data is not a 16-bit greyscale PNG")
        return np.asarray(image, dtype=np.uint16)
    if codec == "rvl":
        if payload.size < 8:
            raise DepthCodecError("compressedDepth rvl data is shorter than its 8-byte size")
        width, height = (int(value) for value in payload[:8].view("<u4"))
        if width == 0 or height == 0:
            raise DepthCodecError(f"compressedDepth rvl image has size {width}x{height}")
        if max(width, height) > RVL_MAX_SIDE or width * height > RVL_MAX_PIXELS:
            raise DepthCodecError(
                f"RVL header says {width}x{height} px, more than an image holds (at most "
                f"{RVL_MAX_SIDE} px a side, {RVL_MAX_PIXELS} px); the data are damaged or "
                "not RVL"
            )
        try:
            return rvl_decode(payload[8:], width * height).reshape(height, width)
        except DepthCodecError as err:
            raise DepthCodecError(
                f"RVL header says {width}x{height} px; the data are damaged: {err}"
            ) from err
    raise DepthCodecError(f"compressedDepth codec {codec!r} is not supported; expected png or rvl")


def _encode_16(code: npt.NDArray[np.uint16], codec: str, png_level: int) -> bytes:
    if code.ndim != 2:
        raise ValueError(f"expected an (H, W) image, got shape {code.shape}")
    if codec == "png":
        return png16(code, png_level)
    if codec == "rvl":
        height, width = code.shape
        return struct.pack("<II", width, height) + rvl_encode(code.reshape(-1))
    raise ValueError(f"unknown compressedDepth codec {codec!r}; choose png or rvl")


# ----------------------------------------------------------------------------- PNG


def png16(image: npt.NDArray[np.uint16], level: int = DEFAULT_PNG_LEVEL) -> bytes:
    """Return a 16-bit greyscale PNG of an image: every row filtered "Up", ISA-L at ``level``.

    The "Up" filter (each row's bytes minus the row above's, the first row as it is) suits
    smooth depth: ~20 % smaller than OpenCV's filter choice. ISA-L's deflate (level 1: the
    size of zlib's level 2 here in ~2/5 of the time; its level 3 is bigger on depth)
    writes a standard zlib stream: any PNG reader decodes it.
    """
    if level not in PNG_LEVELS:
        raise ValueError(f"PNG level {level} is not one of {PNG_LEVELS} (ISA-L's levels)")
    height, width = image.shape
    rows = np.ascontiguousarray(image, dtype=">u2").view(np.uint8).reshape(height, 2 * width)
    filtered = np.empty((height, 2 * width + 1), dtype=np.uint8)
    filtered[:, 0] = 2  # filter type Up
    filtered[0, 1:] = rows[0]  # above the first row is zero
    np.subtract(rows[1:], rows[:-1], out=filtered[1:, 1:])
    header = struct.pack(">IIBBBBB", width, height, 16, 0, 0, 0, 0)
    return b"".join(
        (
            PNG_SIGNATURE,
            _png_chunk(b"IHDR", header),
            _png_chunk(b"IDAT", isal_zlib.compress(filtered.data, level)),
            _png_chunk(b"IEND", b""),
        )
    )


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return (
        struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib_ng.crc32(kind + data))
    )


# ----------------------------------------------------------------------------- RVL


def rvl_encode(pixels: npt.NDArray[np.uint16]) -> bytes:
    """Return the RVL code of a run of uint16 pixels (whole 32-bit words, little endian)."""
    values = np.asarray(pixels, dtype=np.uint16).reshape(-1)
    n = values.size
    if n == 0:
        return b""
    nonzero = values != 0
    # runs: a run of zeros (maybe empty) then a run of non-zeros (maybe empty), repeated
    change = np.flatnonzero(np.diff(nonzero.astype(np.int8))) + 1
    bounds = np.concatenate(([0], change, [n]))
    lengths = np.diff(bounds)
    starts_nonzero = bool(nonzero[0])
    run_is_nonzero = (np.arange(lengths.size) % 2 == 0) == starts_nonzero
    if starts_nonzero:  # an empty run of zeros first
        lengths = np.concatenate(([0], lengths))
        run_is_nonzero = np.concatenate(([False], run_is_nonzero))
    if not run_is_nonzero[-1]:  # ends with zeros: the encoder still writes 0 non-zeros
        lengths = np.concatenate((lengths, [0]))
    pairs = lengths.reshape(-1, 2)  # (zeros, nonzeros) per pair
    # zigzag deltas of the non-zero pixels to the previous non-zero pixel (first: to 0)
    kept = values[nonzero].astype(np.int64)
    delta = np.diff(kept, prepend=0)
    zigzag = np.where(delta >= 0, 2 * delta, -2 * delta - 1)
    # the stream of values: z0, n0, deltas of run 0, z1, n1, ...
    n_pairs = pairs.shape[0]
    before = np.concatenate(([0], np.cumsum(pairs[:, 1])[:-1]))
    pair_at = 2 * np.arange(n_pairs) + before
    stream = np.empty(2 * n_pairs + kept.size, dtype=np.int64)
    stream[pair_at] = pairs[:, 0]
    stream[pair_at + 1] = pairs[:, 1]
    is_delta = np.ones(stream.size, dtype=bool)
    is_delta[pair_at] = False
    is_delta[pair_at + 1] = False
    stream[is_delta] = zigzag
    return _pack_nibbles(stream)


def _pack_nibbles(stream: npt.NDArray[np.int64]) -> bytes:
    """Variable-length code of non-negative values: 3 bits per nibble, low bits first."""
    counts = np.ones(stream.size, dtype=np.int64)
    for bits in range(3, 33, 3):
        counts += stream >= (1 << bits)
    total = int(counts.sum())
    owner = np.repeat(np.arange(stream.size), counts)
    first = np.cumsum(counts) - counts
    index = np.arange(total) - first[owner]
    nibbles = (stream[owner] >> (3 * index)) & 7
    nibbles |= (index < counts[owner] - 1).astype(np.int64) << 3
    padded = np.zeros(-(-total // 8) * 8, dtype=np.uint32)
    padded[:total] = nibbles
    shifts = np.arange(28, -1, -4, dtype=np.uint32)
    words = (padded.reshape(-1, 8) << shifts).sum(axis=1, dtype=np.uint32)
    return bytes(words.astype("<u4").tobytes())


def rvl_decode(data: npt.NDArray[np.uint8] | bytes, n_pixels: int) -> npt.NDArray[np.uint16]:
    """Decode ``n_pixels`` uint16 pixels from RVL words.

    The runs are walked before the image is allocated: a damaged count (an RVL header's
    width x height) is refused, not allocated.

    Raises:
        DepthCodecError: the code ends before ``n_pixels`` pixels or its runs overflow them.
    """
    raw = np.frombuffer(data, dtype=np.uint8) if isinstance(data, bytes) else data
    if n_pixels == 0:
        return np.zeros(0, dtype=np.uint16)
    usable = raw.size // 4 * 4
    words = raw[:usable].view("<u4").astype(np.uint32)
    shifts = np.arange(28, -1, -4, dtype=np.uint32)
    nibbles = ((words[:, None] >> shifts) & 0xF).reshape(-1).astype(np.int64)
    ends = np.flatnonzero((nibbles & 8) == 0)
    if ends.size == 0:
        raise DepthCodecError("RVL data holds no complete value")
    starts = np.concatenate(([0], ends[:-1] + 1))
    cut = int(ends[-1]) + 1
    position = np.arange(cut) - np.repeat(starts, ends - starts + 1)
    parts = (nibbles[:cut] & 7) << np.minimum(3 * position, 62)
    stream = np.add.reduceat(parts, starts)
    is_delta = np.zeros(stream.size, dtype=bool)
    run_starts: list[int] = []  # first pixel of each run of non-zeros
    run_lengths: list[int] = []
    pixel = 0
    cursor = 0
    while pixel < n_pixels:
        if cursor + 1 >= stream.size:
            raise DepthCodecError(f"RVL data ends after {pixel} of {n_pixels} pixels")
        zeros, nonzeros = int(stream[cursor]), int(stream[cursor + 1])
        pixel += zeros
        cursor += 2
        if pixel + nonzeros > n_pixels or cursor + nonzeros > stream.size:
            raise DepthCodecError(f"RVL runs overflow the image's {n_pixels} pixels")
        is_delta[cursor : cursor + nonzeros] = True
        run_starts.append(pixel)
        run_lengths.append(nonzeros)
        pixel += nonzeros
        cursor += nonzeros
    zigzag = stream[is_delta]
    delta = np.where(zigzag & 1, -((zigzag + 1) >> 1), zigzag >> 1)
    # the j-th non-zero value, in run r (b_r values before that run, starting at pixel p_r),
    # is pixel p_r + (j - b_r)
    lengths = np.asarray(run_lengths, dtype=np.int64)
    before = np.cumsum(lengths) - lengths
    shift = np.repeat(np.asarray(run_starts, dtype=np.int64) - before, lengths)
    out = np.zeros(n_pixels, dtype=np.uint16)
    out[shift + np.arange(zigzag.size)] = np.cumsum(delta) & 0xFFFF
    return out
