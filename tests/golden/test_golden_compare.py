"""The comparison on fabricated summaries: counts, element-wise std units, lines, stamps."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pcainterp_stream.golden import array_statistics, compare, format_differences


def _channel(schema: str, messages: list[dict[str, Any]]) -> dict[str, Any]:
    return {
        "schema": schema,
        "schema_encoding": "ros2msg",
        "message_encoding": "cdr",
        "message_count": len(messages),
        "messages": messages,
    }


def _copy(document: dict[str, Any]) -> dict[str, Any]:
    return json.loads(json.dumps(document))


def test_point_counts_have_a_tolerance_other_integers_none() -> None:
    values = {"width": 40, "row_step": 40 * 24, "height": 1}
    message = {"log_time_ns": 1, "stamp_ns": 1, "values": values, "arrays": {}}
    golden = {
        "channels": {
            "/cloud": _channel("sensor_msgs/msg/PointCloud2", [message]),
            "/info": _channel("sensor_msgs/msg/CameraInfo", [message]),
        }
    }
    actual = _copy(golden)
    for channel in actual["channels"].values():
        channel["messages"][0]["values"].update(width=41, row_step=41 * 24)
    assert [(d.topic, d.what) for d in compare(golden, actual)] == [
        ("/info", "width"),
        ("/info", "row_step"),
    ]
    actual["channels"]["/cloud"]["messages"][0]["values"]["width"] = 15
    assert ("/cloud", "width") in [(d.topic, d.what) for d in compare(golden, actual)]


def test_elements_are_checked_in_units_of_the_published_std() -> None:
    rng = np.random.default_rng(0)
    depth = rng.uniform(2.0, 50.0, size=(20, 30))
    depth[0, 0] = np.nan
    std = 0.1 * depth
    arrays = {"a0": depth, "a1": std}

    def document(depth_key: str, std_key: str, values: dict[str, Any]) -> dict[str, Any]:
        def message(key: str, array: np.ndarray) -> dict[str, Any]:
            return {
                "log_time_ns": 5,
                "stamp_ns": 5,
                "values": {},
                "arrays": {"image": array_statistics(array)},
                "array_keys": {"image": key},
            }

        return {
            "channels": {
                "/pcainterp/depth": _channel(
                    "sensor_msgs/msg/Image", [message(depth_key, values[depth_key])]
                ),
                "/pcainterp/depth_std": _channel(
                    "sensor_msgs/msg/Image", [message(std_key, values[std_key])]
                ),
            }
        }

    golden = document("a0", "a1", arrays)
    # 0.01 std everywhere: within 0.05 std, though beyond rtol 1e-3 at every pixel
    close = {"b0": depth + 0.01 * std, "b1": std}
    assert (
        compare(golden, document("b0", "b1", close), golden_arrays=arrays, actual_arrays=close)
        == []
    )
    # 1 std at 5 % of the pixels: the statistics barely move, the elements do
    moved = depth.copy()
    moved[:1, :] += std[:1, :]
    far = {"b0": moved, "b1": std}
    differences = compare(
        golden, document("b0", "b1", far), golden_arrays=arrays, actual_arrays=far
    )
    elements = [d for d in differences if d.what == "image elements"]
    assert len(elements) == 1
    assert elements[0].topic == "/pcainterp/depth"
    assert "29 of 600 beyond 0.05 std" in elements[0].text


def test_at_most_n_lines_then_a_count() -> None:
    golden = {
        "channels": {
            f"/t{i}": _channel(
                "std_msgs/msg/Float64", [{"log_time_ns": 1, "values": {"data": 1.0}}]
            )
            for i in range(5)
        }
    }
    actual = _copy(golden)
    for channel in actual["channels"].values():
        channel["messages"][0]["values"]["data"] = 2.0
    differences = compare(golden, actual)
    assert len(differences) == 5
    text = format_differences(differences, 2).splitlines()
    assert text == [
        "/t0 #0 (stamp 0.000000001 s): data 1 -> 2 (moved 1, tolerance 1.001e-06)",
        "/t1 #0 (stamp 0.000000001 s): data 1 -> 2 (moved 1, tolerance 1.001e-06)",
        "... and 3 more differences",
    ]


def test_a_channel_tolerance_override_applies_to_that_channel_only() -> None:
    message = {"log_time_ns": 1, "values": {"data": 1.0}}
    golden = {
        "tolerance": {"channels": {"/loose": {"values": {"rel": 0.5}}}},
        "channels": {
            "/loose": _channel("std_msgs/msg/Float64", [message]),
            "/tight": _channel("std_msgs/msg/Float64", [message]),
        },
    }
    actual = _copy(golden)
    for channel in actual["channels"].values():
        channel["messages"][0]["values"]["data"] = 1.1
    assert [d.topic for d in compare(golden, actual)] == ["/tight"]


def _disparity_document(disparity: np.ndarray, key: str) -> dict[str, Any]:
    finite = disparity[np.isfinite(disparity)]
    message = {
        "log_time_ns": 7,
        "stamp_ns": 7,
        "values": {
            "f": 500.0,
            "t": 0.5,
            "min_disparity": 0.0,
            "max_disparity": float(finite.max()),
        },
        "arrays": {"image.image": array_statistics(disparity)},
        "array_keys": {"image.image": key},
    }
    return {
        "channels": {"/pcainterp/disparity": _channel("stereo_msgs/msg/DisparityImage", [message])}
    }


def test_max_disparity_has_the_tolerance_of_its_image() -> None:
    rng = np.random.default_rng(3)
    disparity = rng.uniform(5.0, 80.0, size=(40, 60)).astype(np.float32)
    golden = _disparity_document(disparity, "a0")
    # input noise moves the largest pixel by 0.04 px: the image statistics accept it, and
    # so must max_disparity (it was held to 1e-6 relative)
    noisy = disparity.copy()
    noisy[np.unravel_index(np.argmax(disparity), disparity.shape)] += 0.04
    assert compare(golden, _disparity_document(noisy, "b0")) == []
    # the constants of the same message keep their tight tolerance
    moved_f = _disparity_document(noisy, "b0")
    moved_f["channels"]["/pcainterp/disparity"]["messages"][0]["values"]["f"] = 500.01
    assert [d.what for d in compare(golden, moved_f)] == ["f"]
    # a real change of the largest disparity fails, naming it
    far = disparity.copy()
    far[0, 0] = float(disparity.max()) + 5.0
    differences = compare(golden, _disparity_document(far, "b0"))
    assert [d.what for d in differences] == ["max_disparity"]
    assert "tolerance 0.3" in differences[0].text  # 0.2 % of 80 + 0.2 % of the ~74 px spread


def _cloud_document(y: np.ndarray, key: str) -> dict[str, Any]:
    message = {
        "log_time_ns": 9,
        "stamp_ns": 9,
        "values": {"width": int(y.size), "row_step": int(y.size) * 24, "height": 1},
        "arrays": {"points.y": array_statistics(y)},
        "array_keys": {"points.y": key},
    }
    return {"channels": {"/pcainterp/features": _channel("sensor_msgs/msg/PointCloud2", [message])}}


def test_a_point_cloud_may_move_as_many_points_as_it_may_lose() -> None:
    rng = np.random.default_rng(4)
    y = rng.uniform(-2.0, 2.0, size=200).astype(np.float32)
    golden, arrays = _cloud_document(y, "a0"), {"a0": y}
    # 5 corners found 4 mm off (a few input bits): within the 5 % + 1 points a cloud's
    # size may change by (0.2 % of 200 points allowed none to move)
    few = y.copy()
    few[:5] += 4e-3
    assert (
        compare(golden, _cloud_document(few, "b0"), golden_arrays=arrays, actual_arrays={"b0": few})
        == []
    )
    many = y.copy()
    many[:40] += 4e-3
    differences = compare(
        golden, _cloud_document(many, "b0"), golden_arrays=arrays, actual_arrays={"b0": many}
    )
    assert [d.what for d in differences] == ["points.y elements"]
    assert "40 of 200 beyond" in differences[0].text
    assert "(allowed 11)" in differences[0].text
    # one corner more: the width is within its tolerance, so are the fields' lengths (the
    # statistics of 201 points are compared as usual)
    more = np.append(y, y[:1])
    whats = {d.what for d in compare(golden, _cloud_document(more, "b0"))}
    assert not whats & {"width", "row_step", "points.y shape"}
    fewer = y[:150]
    whats = {d.what for d in compare(golden, _cloud_document(fewer, "b0"))}
    assert {"width", "points.y shape"} <= whats


def _image_document(image: np.ndarray) -> dict[str, Any]:
    message = {
        "log_time_ns": 3,
        "stamp_ns": 3,
        "values": {},
        "arrays": {"image": array_statistics(image)},
    }
    return {"channels": {"/camera/image": _channel("sensor_msgs/msg/Image", [message])}}


def test_red_and_blue_exchanged_fail_by_their_block_means() -> None:
    rng = np.random.default_rng(4)  # (a point more moves no statistic of these)
    rgb = np.empty((48, 64, 3), dtype=np.uint8)
    rgb[:20] = (110, 160, 230)  # sky
    rgb[20:] = (150, 120, 90)  # road
    rgb = np.clip(rgb + rng.normal(0, 20, rgb.shape), 0, 255).astype(np.uint8)
    golden = _image_document(rgb)
    blocks = golden["channels"]["/camera/image"]["messages"][0]["arrays"]["image"]["blocks"]
    assert blocks["grid"] == [4, 4]
    assert len(blocks["means"]) == 3  # one list per channel
    noisy = rgb.copy()
    noisy[rng.random(rgb.shape[:2]) < 0.01] ^= 1  # the last bit of 1 % of the pixels
    assert compare(golden, _image_document(noisy)) == []
    differences = compare(golden, _image_document(rgb[:, :, ::-1]))
    assert [d.what for d in differences] == ["image block means"]  # the pooled stats pass
    assert "channel 0" in differences[0].text


def test_blocks_leave_out_nan_and_clip_inf() -> None:
    depth = np.full((8, 8), 10.0)
    depth[:4, :4] = np.nan
    depth[7, 7] = np.inf
    blocks = array_statistics(depth)["blocks"]
    assert blocks["means"][0][0] is None
    assert blocks["means"][0][-1] == 10.0  # +inf counts as the 99 % quantile, not as inf
    json.dumps(blocks, allow_nan=False)


ALOE = Path(__file__).resolve().parents[3] / "shared" / "realdata" / "stereo_aloe" / "aloe-L.png"


@pytest.mark.realdata
@pytest.mark.skipif(not ALOE.is_file(), reason="../shared/realdata is absent")
def test_a_real_photo_swapped_or_mirrored_fails_its_noise_passes() -> None:
    """Middlebury's Aloe (553x640 colour): what block means see on a real image."""
    import cv2

    rgb = np.ascontiguousarray(cv2.imread(str(ALOE))[:, :, ::-1])
    golden = _image_document(rgb)
    swapped = compare(golden, _image_document(np.ascontiguousarray(rgb[:, :, ::-1])))
    assert [d.what for d in swapped] == ["image block means"]
    mirrored = compare(golden, _image_document(np.ascontiguousarray(rgb[:, ::-1])))
    assert [d.what for d in mirrored] == ["image block means"]
    noisy = rgb.copy()
    noisy[np.random.default_rng(0).random(rgb.shape[:2]) < 0.01] ^= 1
    assert compare(golden, _image_document(noisy)) == []


def test_a_point_cloud_of_another_length_is_still_compared_element_wise() -> None:
    rng = np.random.default_rng(4)
    y = rng.uniform(-2.0, 2.0, size=200).astype(np.float32)
    golden, arrays = _cloud_document(y, "a0"), {"a0": y}

    def elements(points: np.ndarray) -> list[str]:
        found = compare(
            golden,
            _cloud_document(points, "b0"),
            golden_arrays=arrays,
            actual_arrays={"b0": points},
        )
        return [d.text for d in found if d.what == "points.y elements"]

    more = np.append(y, y[:1])  # a corner more, within the point count's tolerance
    assert elements(more) == []
    moved = more.copy()
    moved[:40] += 4e-3  # no longer skipped because the length moved
    texts = elements(moved)
    assert len(texts) == 1
    assert "41 of 200 beyond" in texts[0]  # 40 moved + 1 that came
    assert "(first 200 points compared; 201 points, golden 200)" in texts[0]
