"""Message construction details that other readers rely on (see also test_interop.py)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pcainterp_stream.frontend.feature_match import features_from_pointcloud
from pcainterp_stream.io import rosmsg


def test_pointcloud2_is_dense_only_without_non_finite_values() -> None:
    finite = {name: np.arange(3, dtype=np.float32) for name in ("x", "y", "z")}
    cloud = rosmsg.deserialize(
        rosmsg.serialize(rosmsg.pointcloud2_message(finite, 5, "left")), rosmsg.POINT_CLOUD2
    )
    assert cloud.is_dense
    np.testing.assert_array_equal(rosmsg.pointcloud2_arrays(cloud)["z"], [0, 1, 2])
    with_nan = dict(finite, z=np.array([1.0, np.nan, 2.0], dtype=np.float32))
    assert not rosmsg.pointcloud2_message(with_nan, 5, "left").is_dense
    assert rosmsg.pointcloud2_message({}, 5, "left").is_dense  # an empty cloud has no NaN


def _raw_image(data: np.ndarray, encoding: str) -> object:
    height, width = data.shape[:2]
    return rosmsg.TYPESTORE.types[rosmsg.IMAGE](
        header=rosmsg.header(0, "cam"),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=data.nbytes // height,
        data=np.ascontiguousarray(data).reshape(-1),
    )


def _mosaic(rgb: np.ndarray, pattern: str) -> np.ndarray:
    """A Bayer mosaic of an RGB image; ``pattern`` names the first 2x2 cell (ROS)."""
    out = np.empty(rgb.shape[:2], dtype=np.uint8)
    for k, colour in enumerate(pattern):
        out[k // 2 :: 2, k % 2 :: 2] = rgb[k // 2 :: 2, k % 2 :: 2, "rgb".index(colour)]
    return out


def test_camera_encodings_of_real_drivers_decode_to_rgb() -> None:
    rng = np.random.default_rng(0)
    rgb = cv2.GaussianBlur(rng.integers(0, 256, (24, 32, 3), dtype=np.uint8), (7, 7), 2)
    bgr = np.ascontiguousarray(rgb[:, :, ::-1])
    alpha = np.full((24, 32, 1), 255, np.uint8)
    exact = {
        "bgr8": bgr,
        "8UC3": bgr,  # three 8-bit channels are BGR to cv_bridge
        "bgra8": np.concatenate([bgr, alpha], axis=2),
        "8UC4": np.concatenate([bgr, alpha], axis=2),  # bug hunt 10C F6: BGRA to cv_bridge
        "rgba8": np.concatenate([rgb, alpha], axis=2),
    }
    for encoding, data in exact.items():
        np.testing.assert_array_equal(rosmsg.image_array(_raw_image(data, encoding)), rgb)
    for pattern in ("rggb", "bggr", "gbrg", "grbg"):
        mosaic = _mosaic(rgb, pattern)
        decoded = rosmsg.image_array(_raw_image(mosaic, f"bayer_{pattern}8"))
        assert decoded.shape == rgb.shape
        inner = (slice(3, -3), slice(3, -3))
        error = np.abs(decoded[inner].astype(int) - rgb[inner]).mean()
        assert error < 3, pattern  # a wrong pattern swaps red and blue: tens of levels
    yuv = cv2.cvtColor(bgr, cv2.COLOR_BGR2YUV)
    uyvy = np.empty((24, 32, 2), np.uint8)  # U Y0 V Y1 per two pixels
    uyvy[:, :, 1] = yuv[:, :, 0]
    uyvy[:, 0::2, 0], uyvy[:, 1::2, 0] = yuv[:, 0::2, 1], yuv[:, 0::2, 2]
    decoded = rosmsg.image_array(_raw_image(uyvy, "yuv422")).astype(int)
    assert np.abs(decoded - rgb).mean() < 6
    yuy2 = uyvy[:, :, ::-1].copy()  # Y0 U Y1 V
    decoded = rosmsg.image_array(_raw_image(yuy2, "yuv422_yuy2")).astype(int)
    assert np.abs(decoded - rgb).mean() < 6


def test_a_step_shorter_than_a_row_is_said_to_be_the_step() -> None:
    # bug hunt 10C F6: mono8 images with step 0 were told "convert the images to mono8"
    from pcainterp_stream.frontend.pairing import _reason
    from pcainterp_stream.frontend.pairing_stats import PairingStats

    for step in (0, 31):
        message = _raw_image(np.zeros((24, 32), np.uint8), "mono8")
        message.step = step
        with pytest.raises(ValueError, match="image step") as err:
            rosmsg.image_array(message)
        assert str(err.value) == (
            f"image step {step} is shorter than a row of 32 px mono8 (32 bytes; data 768 "
            "bytes for 24 rows): the publisher's step field is wrong (step = width * bytes "
            "per pixel)"
        )
        stats = PairingStats(undecodable={_reason(err.value): 4})
        assert "convert" not in stats.undecodable_fix()
        assert "step field" in stats.undecodable_fix()
    encoding = PairingStats(undecodable={"unsupported image encoding '32FC1'": 4})
    assert encoding.undecodable_fix().startswith("convert the images to mono8")


def _organized_cloud(points: np.ndarray, padding: int, row_step: int | None = None) -> object:
    """An organized (H, W) cloud of x, y, z float32 whose rows end in ``padding`` bytes."""
    height, width = points.shape[:2]
    rows = np.ascontiguousarray(points, "<f4").view(np.uint8).reshape(height, width * 12)
    rows = np.concatenate([rows, np.full((height, padding), 0xAB, np.uint8)], axis=1)
    types = rosmsg.TYPESTORE.types
    return types[rosmsg.POINT_CLOUD2](
        header=rosmsg.header(0, "left"),
        height=height,
        width=width,
        fields=[
            types["sensor_msgs/msg/PointField"](name=name, offset=4 * i, datatype=7, count=1)
            for i, name in enumerate("xyz")
        ],
        is_bigendian=False,
        point_step=12,
        row_step=width * 12 + padding if row_step is None else row_step,
        data=rows.reshape(-1),
        is_dense=True,
    )


def test_organized_pointcloud2_rows_are_read_at_row_step() -> None:
    points = np.arange(2 * 3 * 3, dtype=np.float32).reshape(2, 3, 3) / 10 + 1
    for padding in (0, 8):
        fields = rosmsg.pointcloud2_arrays(_organized_cloud(points, padding))
        read = np.stack([fields["x"], fields["y"], fields["z"]], axis=1)
        np.testing.assert_array_equal(read, points.reshape(-1, 3).astype(np.float64))


def test_a_pointcloud2_field_of_unknown_datatype_is_skipped_when_not_needed() -> None:
    """Bug hunt 8C F11: one extra field of datatype 0 (left unset by a publisher that fills
    only the fields it uses) made every cloud unreadable, though x, y and z were fine."""
    points = {name: np.arange(3, dtype=np.float32) + i for i, name in enumerate("xyz")}
    cloud = rosmsg.pointcloud2_message(dict(points, label=np.zeros(3, np.float32)), 5, "left")
    cloud.fields[3].datatype = 0
    with pytest.raises(ValueError, match="point field 'label' has unknown datatype 0"):
        rosmsg.pointcloud2_arrays(cloud)  # every field asked for: still said
    fields = rosmsg.pointcloud2_arrays(cloud, ("x", "y", "z"))
    assert list(fields) == ["x", "y", "z"]
    np.testing.assert_array_equal(fields["z"], [2, 3, 4])
    features = features_from_pointcloud(cloud, 7)
    np.testing.assert_array_equal(features.points[:, 2], [2, 3, 4])
    cloud.fields[2].datatype = 0  # a needed field of unknown datatype is an error still
    with pytest.raises(ValueError, match="point field 'z' has unknown datatype 0"):
        features_from_pointcloud(cloud, 7)


def test_pointcloud2_row_step_shorter_than_a_row_is_refused() -> None:
    cloud = _organized_cloud(np.ones((2, 3, 3), np.float32), 0, row_step=24)
    with pytest.raises(ValueError, match="row_step 24 is shorter than its 3 points"):
        rosmsg.pointcloud2_arrays(cloud)


def test_the_16_bit_and_renamed_encodings_of_real_drivers_decode() -> None:
    """Bug hunt 7A F13: ``uyvy``/``yuyv`` (sensor_msgs' current names of yuv422 and
    yuv422_yuy2), ``rgb16``/``bgr16``/``rgba16``/``bgra16`` and ``bayer_*16`` (FLIR
    Spinnaker and Basler pylon drivers' 12-bit formats) were refused as unsupported."""
    rng = np.random.default_rng(4)
    rgb8 = cv2.GaussianBlur(rng.integers(0, 256, (24, 32, 3), dtype=np.uint8), (7, 7), 2)
    rgb = rgb8.astype(np.uint16) * 16 + 5  # 12-bit values, low bits not all zero
    bgr = np.ascontiguousarray(rgb[:, :, ::-1])
    alpha = np.full((24, 32, 1), 4095, np.uint16)
    exact = {
        "rgb16": rgb,
        "bgr16": bgr,
        "rgba16": np.concatenate([rgb, alpha], axis=2),
        "bgra16": np.concatenate([bgr, alpha], axis=2),
    }
    for encoding, data in exact.items():
        decoded = rosmsg.image_array(_raw_image(data.astype("<u2").view(np.uint8), encoding))
        assert decoded.dtype == np.uint16, encoding
        np.testing.assert_array_equal(decoded, rgb, err_msg=encoding)
    # big endian, as a camera may publish it
    message = _raw_image(rgb.astype(">u2").view(np.uint8), "rgb16")
    message.is_bigendian = 1  # type: ignore[attr-defined]
    np.testing.assert_array_equal(rosmsg.image_array(message), rgb)
    inner = (slice(3, -3), slice(3, -3))
    for pattern in ("rggb", "bggr", "gbrg", "grbg"):
        mosaic = np.empty(rgb.shape[:2], np.uint16)
        for k, colour in enumerate(pattern):
            mosaic[k // 2 :: 2, k % 2 :: 2] = rgb[k // 2 :: 2, k % 2 :: 2, "rgb".index(colour)]
        data = mosaic.astype("<u2").view(np.uint8).reshape(24, 32, 2)  # 2 bytes a pixel
        image = _raw_image(data, f"bayer_{pattern}16")
        decoded = rosmsg.image_array(image)
        assert decoded.dtype == np.uint16
        assert decoded.shape == rgb.shape
        error = np.abs(decoded[inner].astype(int) - rgb[inner]).mean()
        assert error < 3 * 16, pattern  # a wrong pattern swaps red and blue: hundreds
    yuv = cv2.cvtColor(rgb8, cv2.COLOR_RGB2YUV)
    uyvy = np.empty((24, 32, 2), np.uint8)  # U Y0 V Y1 per two pixels
    uyvy[:, :, 1] = yuv[:, :, 0]
    uyvy[:, 0::2, 0], uyvy[:, 1::2, 0] = yuv[:, 0::2, 1], yuv[:, 0::2, 2]
    yuyv = uyvy[:, :, ::-1].copy()  # Y0 U Y1 V
    for encoding, data in (("uyvy", uyvy), ("yuyv", yuyv)):
        decoded = rosmsg.image_array(_raw_image(data, encoding))
        assert decoded.dtype == np.uint8
        assert np.abs(decoded.astype(int) - rgb8).mean() < 6, encoding
    with pytest.raises(ValueError, match="a yuyv image needs an even width, got 3"):
        rosmsg.image_array(_raw_image(np.zeros((2, 3, 2), np.uint8), "yuyv"))
