"""The ``/pcainterp/*`` output messages of one densified frame (DESIGN.md section 3).

Every output message carries the left image's header (stamp, frame_id); the caller writes
them at the left image's log time. The output channels' MCAP metadata
(:func:`channel_metadata`) names the basis the log was densified with, so that
``evaluate`` can use the same one.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from pcainterp_stream.defaults import DISPLAY_MAX_DEPTH
from pcainterp_stream.io import rosmsg
from pcainterp_stream.records import DensifiedFrame

CHANNELS = ("depth", "depth_std", "disparity", "disparity_std", "features", "camera_info")
"""The output channels DESIGN.md section 3 lists, by the :class:`OutputTopics` field naming
each; ``densify --outputs`` writes a subset (all by default)."""


@dataclass(frozen=True)
class OutputTopics:
    """Names of the output channels; the defaults are DESIGN.md's.

    Depth and disparity (and their stds) are each other's reciprocal given f*b, and the
    float32 images dominate what ``densify`` writes and compresses: :meth:`only` keeps a
    subset of :data:`CHANNELS` (``--outputs``); ``evaluate`` needs disparity, disparity_std,
    features and camera_info.
    """

    depth: str = "/pcainterp/depth"
    depth_std: str = "/pcainterp/depth_std"
    disparity: str = "/pcainterp/disparity"
    disparity_std: str = "/pcainterp/disparity_std"
    features: str = "/pcainterp/features"
    camera_info: str = "/pcainterp/camera_info"
    depth_mm: str | None = None
    """When set, also a ``16UC1`` millimetre copy of the depth, which Foxglove's image panel
    colour-maps (it draws ``32FC1`` as grey): 0 = no estimate, depths clipped to the fixed
    range 0 to :data:`~pcainterp_stream.defaults.DISPLAY_MAX_DEPTH` (too far: its end)."""
    skipped: frozenset[str] = frozenset()
    """Channels of :data:`CHANNELS` not written (see :meth:`only`)."""

    def only(self, channels: Iterable[str]) -> OutputTopics:
        """Return these topics writing only ``channels`` (names of :data:`CHANNELS`).

        Raises:
            ValueError: an unknown channel name, or no channel at all.
        """
        chosen = set(channels)
        unknown = sorted(chosen - set(CHANNELS))
        if unknown:
            raise ValueError(
                f"unknown output channel {', '.join(unknown)}; choose from {', '.join(CHANNELS)}"
            )
        if not chosen:
            raise ValueError(f"no output channel chosen; choose from {', '.join(CHANNELS)}")
        return replace(self, skipped=frozenset(set(CHANNELS) - chosen))

    def writes(self, channel: str) -> bool:
        """Return whether the channel (a name of :data:`CHANNELS`) is written."""
        return channel not in self.skipped

    @classmethod
    def with_prefix(cls, prefix: str, *, depth_mm: bool = False) -> OutputTopics:
        """Return the default topics under another prefix (``/pcainterp`` by default)."""
        prefix = "/" + prefix.strip("/")
        return cls(
            depth=f"{prefix}/depth",
            depth_std=f"{prefix}/depth_std",
            disparity=f"{prefix}/disparity",
            disparity_std=f"{prefix}/disparity_std",
            features=f"{prefix}/features",
            camera_info=f"{prefix}/camera_info",
            depth_mm=f"{prefix}/depth_mm" if depth_mm else None,
        )

    def all(self) -> list[str]:
        """Return every output topic in use."""
        topics = [str(getattr(self, name)) for name in CHANNELS if self.writes(name)]
        return topics + ([self.depth_mm] if self.depth_mm else [])


BASIS_KEY = "pcainterp.basis"
"""Channel metadata key: the basis densify used, ``built-in`` or the path of its file as given
(or ``in-memory`` for a basis passed as an object)."""

BASIS_FINGERPRINT_KEY = "pcainterp.basis_fingerprint"
"""Channel metadata key: the basis's content fingerprint (``Basis.fingerprint``)."""


MEASUREMENTS_KEY = "pcainterp.measurements"
"""Channel metadata key: ``sparse`` (the paper's GFTT lookups or a feature stream) or
``dense`` (the whole SGBM map too; ``/pcainterp/features`` still holds the sparse points
that shaped the estimate)."""


def channel_metadata(basis: str, fingerprint: str, measurements: str = "sparse") -> dict[str, str]:
    """Return the metadata of the output channels of a densified log.

    Args:
        basis: the basis used: ``built-in``, a file path or ``in-memory``.
        fingerprint: its content fingerprint.
        measurements: ``sparse`` or ``dense`` (``densify --measurements``).

    Returns:
        {:data:`BASIS_KEY`: basis, :data:`BASIS_FINGERPRINT_KEY`: fingerprint,
        :data:`MEASUREMENTS_KEY`: measurements}.
    """
    return {BASIS_KEY: basis, BASIS_FINGERPRINT_KEY: fingerprint, MEASUREMENTS_KEY: measurements}


def recorded_metadata(path: Path, topics: OutputTopics | None = None) -> dict[str, str]:
    """Return the channel metadata of a densified log's disparity channel ({} if none).

    Args:
        path: a log written by ``pcainterp densify``.
        topics: its output topics (default DESIGN.md's).

    Returns:
        The metadata of the first message's channel on ``topics.disparity``; {} when the
        log has no such message or its format keeps no channel metadata.
    """
    from pcainterp_stream.io.logreader import open_log

    topic = (topics or OutputTopics()).disparity
    with open_log(path) as reader:
        if topic not in reader.topics():
            return {}
        for raw in reader.messages([topic]):
            return dict(raw.channel_metadata)
    return {}


def output_messages(result: DensifiedFrame, topics: OutputTopics) -> list[tuple[str, Any]]:
    """Build the output messages of one frame.

    Args:
        result: the densified frame.
        topics: output channel names.

    Returns:
        (topic, typestore message) pairs, in a fixed order.
    """
    frame = result.frame
    camera = frame.camera
    stamp, frame_id = frame.stamp_ns, frame.frame_id
    messages: list[tuple[str, Any]] = []
    if topics.writes("depth"):
        depth = rosmsg.image_message(result.depth, stamp, frame_id, encoding="32FC1")
        messages.append((topics.depth, depth))
    if topics.writes("depth_std"):
        depth_std = rosmsg.image_message(result.depth_std, stamp, frame_id, encoding="32FC1")
        messages.append((topics.depth_std, depth_std))
    if topics.writes("disparity"):
        # DisparityImage's valid window starts at the smallest resolvable disparity, so no
        # value <= 0 (nor any below it, "farther than measurable") is valid (REP 118)
        with np.errstate(invalid="ignore"):
            finite = np.isfinite(result.disparity) & (result.disparity >= result.min_disparity)
        min_disparity = result.min_disparity if result.min_disparity > 0 else 0.0
        disparity = rosmsg.disparity_image_message(
            result.disparity,
            stamp,
            frame_id,
            focal=camera.fx,
            baseline=camera.baseline,
            min_disparity=min_disparity,
            max_disparity=(
                float(np.max(result.disparity[finite])) if finite.any() else min_disparity
            ),
        )
        messages.append((topics.disparity, disparity))
    if topics.writes("disparity_std"):
        disparity_std = rosmsg.image_message(
            result.disparity_std, stamp, frame_id, encoding="32FC1"
        )
        messages.append((topics.disparity_std, disparity_std))
    if topics.writes("features"):
        messages.append((topics.features, _features_message(result)))
    if topics.writes("camera_info"):
        messages.append((topics.camera_info, rosmsg.camera_info_message(camera, stamp, frame_id)))
    if topics.depth_mm:
        # fixed range: 0 = no estimate, DISPLAY_MAX_DEPTH for it and beyond (+inf: too far)
        far_mm = 1000.0 * DISPLAY_MAX_DEPTH
        millimetres = np.nan_to_num(result.depth * 1000.0, nan=0.0, posinf=far_mm, neginf=0.0)
        depth_mm = np.clip(np.rint(millimetres), 0, far_mm).astype(np.uint16)
        messages.append(
            (topics.depth_mm, rosmsg.image_message(depth_mm, stamp, frame_id, encoding="16UC1"))
        )
    return messages


def _features_message(result: DensifiedFrame) -> Any:
    """Return the PointCloud2 of the measurements used (x y z in the left optical frame)."""
    camera = result.frame.camera
    pixels = result.pixels.astype(np.float32, copy=False)
    disparities = result.disparities.astype(np.float32, copy=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(disparities > 0, camera.focal_baseline / disparities, np.nan)
    x = (pixels[:, 0] - camera.cx) * z / camera.fx
    y = (pixels[:, 1] - camera.cy) * z / camera.fy
    return rosmsg.pointcloud2_message(
        {
            "x": x.astype(np.float32),
            "y": y.astype(np.float32),
            "z": z.astype(np.float32),
            "u": pixels[:, 0],
            "v": pixels[:, 1],
            "disparity": disparities,
        },
        result.frame.stamp_ns,
        result.frame.frame_id,
    )
