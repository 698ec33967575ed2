"""The comparison on fabricated summaries: counts, element-wise std units, lines, stamps."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

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
