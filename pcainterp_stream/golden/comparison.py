"""Compare a log's summary with a golden one, within the tolerances the golden file states.

Exact: the set of channels, their schemas and encodings, message counts, log times (unless
``log_time.abs_ns`` allows more), header stamps, strings and integers. Within tolerance:
floating-point values, the statistics of every array, the counts of non-finite elements,
the number of points of a point cloud and, when the golden file stores the arrays, every
element. :data:`DEFAULT_TOLERANCE` is written
into each golden file, where it can be edited; :func:`compare` reads it from there.

Messages are matched by header stamp (by log time for messages without a header), so a
dropped message shows as one missing message rather than as every later message changed.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from pcainterp_stream.golden.summary import QUANTILES

__all__ = [
    "DEFAULT_TOLERANCE",
    "Difference",
    "compare",
    "count_differences",
    "format_differences",
    "format_stamp",
]

DEFAULT_TOLERANCE: dict[str, Any] = {
    "note": (
        "Exact: channels, schemas, encodings, message counts, header stamps, strings and "
        "integers; log times within log_time.abs_ns (0: exact; raise it for a log recorded "
        "live, whose log times are receive times). uint8 arrays (grey levels): mean, std, "
        "median and mad within "
        "uint8.stat_abs, quantiles within uint8.quantile_abs. Other arrays: each statistic "
        "within float.rel of its value plus float.spread of the golden 1%-99% quantile "
        "spread plus float.abs. NaN/inf counts within nonfinite_fraction of the element "
        "count. Images: the means of a grid of blocks (per channel) within blocks.scale "
        "times the tolerance of the image mean (a block holds 1/16 of the pixels: its mean "
        "is 4 times as noisy). Float values (CameraInfo K, P...): within values.rel plus "
        "values.abs; "
        "a DisparityImage's min_disparity and max_disparity (taken from its image) within "
        "the tolerance of that image's mean. "
        "Point-cloud sizes (width, row_step) and the lengths of its fields: within "
        "point_count.rel plus point_count.abs points. Stored arrays (--arrays): "
        "|actual - golden| <= pixels.atol + pixels.rtol * "
        "|golden|, or where a channel <topic>_std is in the log (depth and its posterior std) "
        "<= pixels.std_atol * that std (for a depth beside a disparity std, /ns/depth with "
        "/ns/disparity_std: depth^2 / (f*b) * the disparity std, f*b from the depth "
        "channel's metadata as recorded under focal_baseline); at most pixels.bad_fraction "
        "of the elements may exceed it (NaN/inf where the golden has a number, or the "
        "reverse, count as beyond), of a point cloud's fields as many as point_count allows. "
        "channels: per-topic overrides of any of these, e.g. "
        '{"/pcainterp/depth": {"float": {"rel": 0.01}}}.'
    ),
    "uint8": {"stat_abs": 0.5, "quantile_abs": 2.0},
    "float": {"rel": 0.002, "spread": 0.002, "abs": 1e-6},
    "nonfinite_fraction": 0.002,
    "values": {"rel": 1e-6, "abs": 1e-9},
    "point_count": {"rel": 0.05, "abs": 1},
    "log_time": {"abs_ns": 0},
    "blocks": {"scale": 4.0},
    "pixels": {"atol": 1e-4, "rtol": 1e-3, "std_atol": 0.05, "bad_fraction": 0.002},
    "channels": {},
}

# PointCloud2 fields that count points: the front end may find a corner more or less
_POINT_COUNT_VALUES = frozenset({"width", "row_step"})
_POINT_CLOUD = "sensor_msgs/msg/PointCloud2"
# header scalars derived from a message's own image (a DisparityImage's largest pixel and
# the floor it was cut at): compared like that image's statistics, not like a constant
_DATA_SCALARS = {
    "stereo_msgs/msg/DisparityImage": ("image.image", ("min_disparity", "max_disparity"))
}
_STAT_NAMES = ("mean", "std", "median", "mad")


class Difference(NamedTuple):
    """One way a log differs from its golden file beyond tolerance.

    Attributes:
        topic: the channel.
        index: message index within the channel (golden numbering), None for the channel.
        stamp_ns: the message's header stamp (or log time), None for the channel.
        what: the quantity, e.g. ``"image median"``, ``"message_count"``, ``"p[2]"``.
        text: the difference as a sentence fragment ("24.91 -> 26.13 (moved 1.22,
            tolerance 0.05)").
    """

    topic: str
    index: int | None  # type: ignore[assignment]  # shadows tuple.index: the message number
    stamp_ns: int | None
    what: str
    text: str

    def __str__(self) -> str:
        where = self.topic
        if self.index is not None:
            where += f" #{self.index}"
            if self.stamp_ns is not None:
                where += f" (stamp {format_stamp(self.stamp_ns)})"
        return f"{where}: {self.what} {self.text}"


def format_stamp(stamp_ns: int) -> str:
    """Return a stamp in ns as seconds with nine decimals (``1.200000000 s``)."""
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return f"{sec}.{nsec:09d} s"


def count_differences(differences: list[Difference]) -> str:
    """Return "N places beyond tolerance" / "compared exactly" / both, for a summary line."""
    count = len(differences)
    exact = sum(1 for d in differences if "tolerance" not in d.text and "beyond" not in d.text)
    places = f"{count} place{'s' if count != 1 else ''}"
    if exact == 0:
        return f"{places} beyond tolerance"
    if exact == count:
        return f"{places} compared exactly"
    return f"{places} ({count - exact} beyond tolerance, {exact} compared exactly)"


def format_differences(differences: list[Difference], max_lines: int | None = 20) -> str:
    """Return the differences one per line, at most ``max_lines`` then a count of the rest."""
    shown = differences if max_lines is None else differences[: max(max_lines, 0)]
    lines = [str(d) for d in shown]
    hidden = len(differences) - len(shown)
    if hidden:
        lines.append(f"... and {hidden} more difference{'s' if hidden > 1 else ''}")
    return "\n".join(lines)


def _merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    merged = dict(base)
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(merged.get(key), Mapping):
            merged[key] = _merge(merged[key], value)
        else:
            merged[key] = value
    return merged


def _number(value: Any) -> float:
    return float(value)  # "nan", "inf" strings of the JSON come back as floats too


def _g(value: float) -> str:
    return f"{value:.6g}"


class _Comparer:
    def __init__(
        self,
        tolerance: Mapping[str, Any],
        golden_arrays: Mapping[str, npt.NDArray[Any]] | None,
        actual_arrays: Mapping[str, npt.NDArray[Any]] | None,
    ) -> None:
        self.base = _merge(DEFAULT_TOLERANCE, tolerance)
        self.golden_arrays = golden_arrays
        self.actual_arrays = actual_arrays
        self.out: list[Difference] = []
        self.actual_channels: Mapping[str, Any] = {}
        self.golden_channels: Mapping[str, Any] = {}
        self.cloud = False  # the channel being compared holds point clouds
        self.schema = ""  # the schema of the channel being compared

    def tolerance(self, topic: str) -> dict[str, Any]:
        return _merge(self.base, self.base.get("channels", {}).get(topic, {}))

    # channels ---------------------------------------------------------------------------
    def channels(self, golden: Mapping[str, Any], actual: Mapping[str, Any]) -> None:
        for topic, want in golden.items():
            have = actual.get(topic)
            if have is None:
                self.out.append(
                    Difference(
                        topic,
                        None,
                        None,
                        "channel",
                        f"missing from the log (golden: {want['message_count']} messages "
                        f"of {want['schema'] or 'no schema'})",
                    )
                )
                continue
            self.channel(topic, want, have, golden)
        for topic, have in actual.items():
            if topic not in golden:
                self.out.append(
                    Difference(
                        topic,
                        None,
                        None,
                        "channel",
                        f"not in the golden file ({have['message_count']} messages of "
                        f"{have['schema'] or 'no schema'})",
                    )
                )

    def channel(
        self,
        topic: str,
        want: Mapping[str, Any],
        have: Mapping[str, Any],
        golden: Mapping[str, Any],
    ) -> None:
        for name in ("schema", "schema_encoding", "message_encoding", "message_count"):
            if want[name] != have[name]:
                self.out.append(
                    Difference(topic, None, None, name, f"{have[name]!r}, golden {want[name]!r}")
                )
        tolerance = self.tolerance(topic)
        self.cloud = want["schema"] == _POINT_CLOUD
        self.schema = str(want["schema"])
        # the posterior std published beside a channel (depth and depth_std, or the
        # disparity std of a compact depth) sets its element-wise tolerance in std units
        source = _std_source(topic, self.golden_channels, self.actual_channels)
        std_messages = _by_stamp(self.golden_channels[source.topic]["messages"]) if source else {}
        matched = _by_stamp(have["messages"])
        seen: set[tuple[int, int]] = set()
        for index, (key, message) in enumerate(_by_stamp(want["messages"]).items()):
            stamp = message.get("stamp_ns", message["log_time_ns"])
            other = matched.get(key)
            if other is None:
                self.out.append(Difference(topic, index, stamp, "message", "missing from the log"))
                continue
            seen.add(key)
            std = std_messages.get(key)
            self.message(topic, index, stamp, message, other, tolerance, std, source)
        for key, message in matched.items():
            if key not in seen:
                stamp = message.get("stamp_ns", message["log_time_ns"])
                text = f"with stamp {format_stamp(stamp)} not in the golden file"
                self.out.append(Difference(topic, None, None, "message", text))

    # messages ---------------------------------------------------------------------------
    def message(
        self,
        topic: str,
        index: int,
        stamp: int,
        want: Mapping[str, Any],
        have: Mapping[str, Any],
        tolerance: Mapping[str, Any],
        std_message: Mapping[str, Any] | None,
        source: _StdSource | None,
    ) -> None:
        def add(what: str, text: str) -> None:
            self.out.append(Difference(topic, index, stamp, what, text))

        if want.get("stamp_ns") != have.get("stamp_ns"):
            add("stamp_ns", f"{have.get('stamp_ns')}, golden {want.get('stamp_ns')}")
        allowed_ns = int(tolerance["log_time"]["abs_ns"])
        want_time, have_time = want.get("log_time_ns"), have.get("log_time_ns")
        if want_time != have_time:
            if allowed_ns == 0 or not (isinstance(want_time, int) and isinstance(have_time, int)):
                add("log_time_ns", f"{have_time}, golden {want_time}")
            elif abs(have_time - want_time) > allowed_ns:
                add(
                    "log_time_ns",
                    f"{want_time} -> {have_time} (moved {have_time - want_time} ns, tolerance "
                    f"{allowed_ns} ns)",
                )
        want_values, have_values = want.get("values", {}), have.get("values", {})
        image, derived = _DATA_SCALARS.get(self.schema, ("", ()))
        image_stats = want.get("arrays", {}).get(image)
        for name, value in want_values.items():
            if name not in have_values:
                add(name, "missing")
                continue
            if self.cloud and name in _POINT_COUNT_VALUES:
                self.count(add, name, value, have_values[name], tolerance)
                continue
            if name in derived and image_stats is not None:
                self.derived(add, name, value, have_values[name], image_stats, tolerance)
                continue
            self.value(add, name, value, have_values[name], tolerance)
        for name in have_values:
            if name not in want_values:
                add(name, "not in the golden file")
        want_arrays, have_arrays = want.get("arrays", {}), have.get("arrays", {})
        for name, stats in want_arrays.items():
            if name not in have_arrays:
                add(name, "missing")
                continue
            self.statistics(add, name, stats, have_arrays[name], tolerance)
        for name in have_arrays:
            if name not in want_arrays:
                add(name, "not in the golden file")
        if self.golden_arrays is not None and self.actual_arrays is not None:
            self.elements(add, want, have, tolerance, std_message, source)

    def count(
        self, add: Any, name: str, want: Any, have: Any, tolerance: Mapping[str, Any]
    ) -> None:
        if not (isinstance(want, int) and isinstance(have, int)):
            self.value(add, name, want, have, tolerance)
            return
        limits = tolerance["point_count"]
        allowed = limits["rel"] * abs(want) + limits["abs"]
        if abs(have - want) > allowed:
            add(name, f"{want} -> {have} (moved {have - want}, tolerance {allowed:g})")

    def points(
        self, want: Mapping[str, Any], have: Mapping[str, Any], tolerance: Mapping[str, Any]
    ) -> bool:
        """Return True for point-cloud fields of lengths within the point count's tolerance.

        Their statistics are then compared as usual (the width already had its tolerance).
        """
        if not self.cloud or want["shape"][1:] != have["shape"][1:] or not want["shape"]:
            return False  # (n,) or (n, count) of a field of count > 1
        limits = tolerance["point_count"]
        count = int(want["shape"][0])
        allowed = float(limits["rel"]) * count + float(limits["abs"])
        return abs(int(have["shape"][0]) - count) <= allowed

    def derived(
        self,
        add: Any,
        name: str,
        want: Any,
        have: Any,
        image: Mapping[str, Any],
        tolerance: Mapping[str, Any],
    ) -> None:
        """Compare a scalar taken from an image within that image's statistics' tolerance."""
        if not (isinstance(want, int | float) and isinstance(have, int | float)):
            self.value(add, name, want, have, tolerance)
            return
        expected, actual = float(want), float(have)
        if math.isnan(expected) and math.isnan(actual):
            return
        allowed = _statistic_limits(image, tolerance)(expected)
        if not abs(actual - expected) <= allowed and actual != expected:
            add(name, _moved(actual, expected, allowed))

    def value(
        self, add: Any, name: str, want: Any, have: Any, tolerance: Mapping[str, Any]
    ) -> None:
        if isinstance(want, list) and isinstance(have, list):
            if len(want) != len(have):
                add(name, f"has {len(have)} elements, golden {len(want)}")
                return
            for i, (a, b) in enumerate(zip(want, have, strict=True)):
                self.value(add, f"{name}[{i}]", a, b, tolerance)
            return
        if isinstance(want, float) or isinstance(have, float):
            if isinstance(want, str | bool) or isinstance(have, str | bool):
                add(name, f"{have!r}, golden {want!r}")
                return
            expected, actual = _number(want), _number(have)
            limits = tolerance["values"]
            allowed = limits["rel"] * abs(expected) + limits["abs"]
            if math.isnan(expected) and math.isnan(actual):
                return
            if not abs(actual - expected) <= allowed and actual != expected:
                add(name, _moved(actual, expected, allowed))
            return
        if want != have:
            add(name, f"{have!r}, golden {want!r}")

    def statistics(
        self,
        add: Any,
        name: str,
        want: Mapping[str, Any],
        have: Mapping[str, Any],
        tolerance: Mapping[str, Any],
    ) -> None:
        for key in ("dtype", "shape"):
            if want[key] != have[key] and not (
                key == "shape" and self.points(want, have, tolerance)
            ):
                text = f"{have[key]}, golden {want[key]}"
                if key == "shape" and self.cloud and want[key][1:] == have[key][1:]:
                    limits = tolerance["point_count"]
                    allowed = float(limits["rel"]) * int(want[key][0]) + float(limits["abs"])
                    text += f" (points beyond the point count's tolerance {allowed:g})"
                add(f"{name} {key}", text)
                return
        size = math.prod(want["shape"])
        allowed_count = tolerance["nonfinite_fraction"] * size
        for key in ("nan", "posinf", "neginf"):
            moved = abs(have[key] - want[key])
            if moved > allowed_count:
                add(
                    f"{name} {key} count",
                    f"{want[key]} -> {have[key]} (moved {moved}, tolerance {allowed_count:.0f})",
                )
        if ("mean" in want) != ("mean" in have):
            add(name, "has no finite element" if "mean" not in have else "golden had none finite")
            return
        if "mean" not in want:
            return
        limit = _statistic_limits(want, tolerance)
        stat_limit = {key: limit(want[key]) for key in _STAT_NAMES}
        if want["dtype"] == "uint8":
            quantile_limit = dict.fromkeys(QUANTILES, tolerance["uint8"]["quantile_abs"])
        else:
            quantile_limit = {
                q: limit(v) for q, v in zip(QUANTILES, want["quantiles"], strict=True)
            }
        for key in _STAT_NAMES:
            if abs(have[key] - want[key]) > stat_limit[key]:
                add(f"{name} {key}", _moved(have[key], want[key], stat_limit[key]))
        for q, value, actual in zip(QUANTILES, want["quantiles"], have["quantiles"], strict=True):
            if abs(actual - value) > quantile_limit[q]:
                add(f"{name} quantile {q:g}", _moved(actual, value, quantile_limit[q]))
        if "blocks" in want and "blocks" in have:  # golden files before blocks have none
            scale = float(tolerance["blocks"]["scale"])
            self.blocks(add, name, want["blocks"], have["blocks"], lambda v: scale * limit(v))

    def blocks(
        self,
        add: Any,
        name: str,
        want: Mapping[str, Any],
        have: Mapping[str, Any],
        limit: Callable[[float], float],
    ) -> None:
        """Compare block means (where the values are) within the mean's tolerance."""
        if want["grid"] != have["grid"] or len(want["means"]) != len(have["means"]):
            add(f"{name} blocks", f"grid {have['grid']}, golden {want['grid']}")
            return
        columns = int(want["grid"][1])
        beyond: list[tuple[float, str]] = []
        total = 0
        for channel, (expected, actual) in enumerate(
            zip(want["means"], have["means"], strict=True)
        ):
            for cell, (golden, value) in enumerate(zip(expected, actual, strict=True)):
                total += 1
                where = f"({cell // columns}, {cell % columns}"
                where += f", channel {channel})" if len(want["means"]) > 1 else ")"
                if golden is None or value is None:
                    if (golden is None) != (value is None):
                        text = "has no number" if value is None else "golden had no number"
                        beyond.append((math.inf, f"{where} {text}"))
                    continue
                allowed = limit(golden)
                if abs(value - golden) > allowed:
                    moved = abs(value - golden) / allowed if allowed > 0 else math.inf
                    beyond.append((moved, f"{where}: {_moved(value, golden, allowed)}"))
        if beyond:
            worst = max(beyond, key=lambda item: item[0])[1]
            add(
                f"{name} block means",
                f"{len(beyond)} of {total} blocks beyond tolerance; e.g. block {worst}",
            )

    def elements(
        self,
        add: Any,
        want: Mapping[str, Any],
        have: Mapping[str, Any],
        tolerance: Mapping[str, Any],
        std_message: Mapping[str, Any] | None,
        source: _StdSource | None,
    ) -> None:
        assert self.golden_arrays is not None
        assert self.actual_arrays is not None
        limits = tolerance["pixels"]
        std_arrays = (std_message or {}).get("array_keys", {})
        for name, key in want.get("array_keys", {}).items():
            have_key = have.get("array_keys", {}).get(name)
            if key not in self.golden_arrays or have_key is None:
                continue
            golden = np.asarray(self.golden_arrays[key], dtype=np.float64)
            actual = np.asarray(self.actual_arrays[have_key], dtype=np.float64)
            size, came_or_went, compared = golden.size, 0, ""
            if golden.shape != actual.shape:
                if not (self.cloud and golden.ndim >= 1 and golden.shape[1:] == actual.shape[1:]):
                    continue  # the statistics already name the shape
                # a cloud whose point count moved within tolerance: its common prefix is
                # compared, and the points that came or went count as beyond
                common = min(len(golden), len(actual))
                came_or_went = abs(golden.size - actual.size)
                compared = (
                    f" (first {common} points compared; {len(actual)} points, golden {len(golden)})"
                )
                golden, actual = golden[:common], actual[:common]
            std_key = std_arrays.get(name)
            std: npt.NDArray[np.float64] | None = None
            used = source  # with the f*b of this message's camera
            if (
                source is not None
                and std_key in self.golden_arrays
                and self.golden_arrays[std_key].shape == golden.shape
            ):
                std = np.asarray(self.golden_arrays[std_key], dtype=np.float64)
                focal_baseline = source.focal_baseline
                if focal_baseline is not None:
                    # a message of a log whose camera changed records its own (summary): the
                    # golden file's, else (saved before it was recorded) the log's under test
                    own = want.get("focal_baseline", have.get("focal_baseline"))
                    focal_baseline = focal_baseline if own is None else float(own)
                    used = source._replace(focal_baseline=focal_baseline)
                    # delta method: z = f*b / d, so std_z = z^2 / (f*b) * std_d
                    with np.errstate(invalid="ignore", over="ignore"):
                        std = golden * golden / focal_baseline * std
            if std is not None and used is not None:
                allowed = np.where(np.isfinite(std), limits["std_atol"] * std, np.inf)
                unit = f"{limits['std_atol']:g} std ({used.describe()})"
            else:
                allowed = limits["atol"] + limits["rtol"] * np.abs(golden)
                unit = f"atol {limits['atol']:g} + rtol {limits['rtol']:g}"
            both_finite = np.isfinite(golden) & np.isfinite(actual)
            same_special = (np.isnan(golden) & np.isnan(actual)) | (
                np.isinf(golden) & (golden == actual)
            )
            with np.errstate(invalid="ignore"):  # inf - inf where both are +inf
                error = np.where(both_finite, np.abs(actual - golden), 0.0)
            beyond = (both_finite & (error > allowed)) | ~(both_finite | same_special)
            count = int(beyond.sum()) + came_or_went
            limit = limits["bad_fraction"] * size
            if self.cloud:  # as many points may move as may come or go
                counts = tolerance["point_count"]
                limit = max(limit, counts["rel"] * size + counts["abs"])
            if count > limit:
                score = error
                if std is not None:  # the element that moved most in units of its std
                    with np.errstate(divide="ignore", invalid="ignore"):
                        score = np.where(std > 0, error / std, np.inf)
                worst = np.unravel_index(
                    int(np.argmax(np.where(beyond, np.where(both_finite, score, np.inf), -1.0))),
                    golden.shape,
                )
                moved = ""
                if std is not None and both_finite[worst] and std[worst] > 0:
                    moved = f" ({_g(float(error[worst] / std[worst]))} std)"
                add(
                    f"{name} elements",
                    f"{count} of {size} beyond {unit} (allowed {limit:.0f}){compared}; e.g. "
                    f"at {tuple(int(i) for i in worst)}: {_g(actual[worst])}, golden "
                    f"{_g(golden[worst])}{moved}",
                )


def _statistic_limits(
    stats: Mapping[str, Any], tolerance: Mapping[str, Any]
) -> Callable[[float], float]:
    """Return value -> allowed move of a statistic of an array with golden ``stats``.

    uint8: ``uint8.stat_abs`` grey levels. Other dtypes: ``float.rel`` of the value plus
    ``float.spread`` of the golden 1 %-99 % quantile spread plus ``float.abs``.
    """
    if stats["dtype"] == "uint8":
        allowed = float(tolerance["uint8"]["stat_abs"])
        return lambda value: allowed
    limits = tolerance["float"]
    quantiles = stats.get("quantiles") or [0.0] * len(QUANTILES)
    spread = quantiles[-1] - quantiles[0]
    floor = limits["spread"] * spread + limits["abs"]
    return lambda value: limits["rel"] * abs(value) + floor


class _StdSource(NamedTuple):
    """Where a channel's element-wise std comes from.

    ``topic`` publishes the std of the channel itself, or (``focal_baseline`` set) the std
    of the disparity d behind a depth z = f*b / d.
    """

    topic: str
    focal_baseline: float | None = None

    def describe(self) -> str:
        if self.focal_baseline is None:
            return self.topic
        return f"depth^2 / f*b * {self.topic}, f*b {self.focal_baseline:g}"


def _std_source(
    topic: str, golden: Mapping[str, Any], actual: Mapping[str, Any]
) -> _StdSource | None:
    """Return the std published for ``topic``'s elements, or None when the log has none.

    ``<topic>_std`` when the golden file has it; else, for a depth channel, the disparity
    std beside it (``/ns/depth`` -> ``/ns/disparity_std``) with f*b from the channel
    metadata recorded in the golden file (else in the log under test, for golden files
    saved before it was recorded), else from a sibling ``camera_info`` whose projection
    states it (P[3] = -f*b, a right camera's).
    """
    direct = f"{topic}_std"
    if direct in golden:
        return _StdSource(direct)
    namespace, _, leaf = topic.rpartition("/")
    if "depth" not in leaf:
        return None
    head, _, tail = leaf.rpartition("depth")
    disparity_std = f"{namespace}/{head}disparity{tail}_std"
    if disparity_std not in golden:
        return None
    focal_baseline = _focal_baseline(topic, disparity_std, namespace, golden, actual)
    return None if focal_baseline is None else _StdSource(disparity_std, focal_baseline)


def _focal_baseline(
    topic: str,
    disparity_std: str,
    namespace: str,
    golden: Mapping[str, Any],
    actual: Mapping[str, Any],
) -> float | None:
    for channels in (golden, actual):
        for name in (topic, disparity_std):
            value = channels.get(name, {}).get("focal_baseline")
            if value is not None and math.isfinite(float(value)) and float(value) > 0:
                return float(value)
    info = golden.get(f"{namespace}/camera_info", {})
    for message in info.get("messages", [])[:1]:
        projection = message.get("values", {}).get("p")
        if isinstance(projection, list) and len(projection) == 12:
            tx = _number(projection[3])
            if math.isfinite(tx) and tx < 0:
                return -tx
    return None


def _moved(actual: float, expected: float, allowed: float) -> str:
    return (
        f"{_g(expected)} -> {_g(actual)} (moved {_g(actual - expected)}, tolerance {_g(allowed)})"
    )


def _by_stamp(messages: list[Any]) -> dict[tuple[int, int], Any]:
    """Return (stamp or log time, occurrence of that stamp so far) -> message, in order."""
    keyed: dict[tuple[int, int], Any] = {}
    counts: dict[int, int] = {}
    for message in messages:
        stamp = int(message.get("stamp_ns", message["log_time_ns"]))
        occurrence = counts.get(stamp, 0)
        counts[stamp] = occurrence + 1
        keyed[(stamp, occurrence)] = message
    return keyed


def compare(
    golden: Mapping[str, Any],
    actual: Mapping[str, Any],
    *,
    golden_arrays: Mapping[str, npt.NDArray[Any]] | None = None,
    actual_arrays: Mapping[str, npt.NDArray[Any]] | None = None,
    std_channels: Mapping[str, Any] | None = None,
) -> list[Difference]:
    """Return every difference between a log's summary and a golden one beyond tolerance.

    Args:
        golden: the golden file's content (its ``"tolerance"`` and ``"channels"``).
        actual: the same form, of the log under test (``"channels"``).
        golden_arrays: the golden file's stored arrays, for an element-wise check.
        actual_arrays: the log's arrays (keys named by its messages' ``array_keys``).
        std_channels: the golden channels to find the stds published beside a channel in
            (default ``golden["channels"]``; all of them when only some are compared).

    Returns:
        The differences, channel by channel in golden order; empty when the log matches.
    """
    comparer = _Comparer(golden.get("tolerance", {}), golden_arrays, actual_arrays)
    comparer.actual_channels = actual["channels"]
    comparer.golden_channels = golden["channels"] if std_channels is None else std_channels
    comparer.channels(golden["channels"], actual["channels"])
    return comparer.out
