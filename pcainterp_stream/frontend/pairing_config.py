"""Which topics make a stereo pair and how the pairer matches them (:class:`PairingConfig`).

Read by :class:`frontend.pairing.StereoPairer` (which re-exports it), discovery and the
command line; no stream state here.
"""

from __future__ import annotations

from dataclasses import dataclass

from pcainterp_stream.frontend import rectify as rect
from pcainterp_stream.frontend.pairing_window import HoldLimits

__all__ = ["PairingConfig"]


@dataclass(frozen=True)
class PairingConfig:
    """Which topics make a stereo frame and how stamps are matched.

    Attributes:
        left_topic: left rectified image (``Image`` or ``CompressedImage``).
        right_topic: right rectified image.
        left_info_topic: left ``CameraInfo`` (P gives fx, fy, cx, cy).
        right_info_topic: right ``CameraInfo`` (baseline b = -P[0, 3] / P[0, 0]).
        features_topic: optional ``PointCloud2`` of sparse points (x, y, z, m, left optical
            frame); None for no feature stream.
        tolerance_ns: largest difference of header stamps that still pairs (ns).
        window: pairs held waiting for camera infos (the oldest beyond it is dropped and
            counted), and the least of each other queue held whatever its log-time span.
        hold_ns: how long (log time, ns) an unpaired image waits for the other side's image
            of its stamp, a frame for its feature cloud, a cloud for its frame: streams
            recorded that far apart still pair (see :mod:`frontend.pairing_window`).
        hold_count: the most messages a queue holds (unpaired images of a side, frames,
            clouds), whatever ``hold_ns``.
        hold_bytes: the most bytes (images, frames and clouds) the queues hold together,
            whatever ``hold_ns``.
        baseline: baseline override (m); when set, the right camera info's P[0, 3] is not
            used and may be 0.
        fail_on_size_mismatch: raise :class:`~errors.LogReadError` on a left/right size
            mismatch instead of counting it and skipping the pair.
        rectify: ``auto`` (remap when the calibration says the images are raw, see
            :meth:`StereoPairer.rectification`), ``always`` (remap from the calibration) or
            ``never`` (use the images as recorded and P of the camera infos, unchecked).
        calibration: the pair's calibration from files, for logs without camera infos
            (the info topics are then not read).
        discover: the topics were not named: find the pair in the log
            (:func:`frontend.discovery.resolve_pairing`).
        named_sides: with ``discover``: the sides (``left``, ``right``) whose image topic was
            named, the default one included; the pair found must have it.
        named_infos: the sides whose info topic was named on the command line, the default
            one included: that topic is read, not the image's own camera info.
        calibration_topics: with ``discover``: the image topics the calibration file names
            (the ``rostopic`` of a Kalibr camchain's cameras), the pair unless a side is
            named; when the log has not both, the pair is found in it.
        check_rows: on the first frames, refuse a pair whose matched corners are not on the
            same rows (or have negative disparities); off with ``rectify="never"``.
    """

    left_topic: str = "/stereo/left/image_rect"
    right_topic: str = "/stereo/right/image_rect"
    left_info_topic: str = "/stereo/left/camera_info"
    right_info_topic: str = "/stereo/right/camera_info"
    features_topic: str | None = None
    tolerance_ns: int = 1_000_000
    window: int = 8
    hold_ns: int = 3_000_000_000
    hold_count: int = 2000
    hold_bytes: int = 512 * 2**20
    baseline: float | None = None
    fail_on_size_mismatch: bool = False
    rectify: str = "auto"
    calibration: rect.StereoCalibration | None = None
    discover: bool = False
    named_sides: tuple[str, ...] = ()
    named_infos: tuple[str, ...] = ()
    calibration_topics: tuple[str, str] | None = None
    check_rows: bool = True

    def __post_init__(self) -> None:
        if self.rectify not in ("auto", "always", "never"):
            raise ValueError(f"rectify must be auto, always or never, got {self.rectify!r}")
        if self.tolerance_ns < 0:
            raise ValueError(f"tolerance_ns must be >= 0, got {self.tolerance_ns}")
        if self.window < 1:
            raise ValueError(f"window must be >= 1, got {self.window}")
        HoldLimits(self.window, self.hold_ns, self.hold_count, self.hold_bytes)  # checks them
        if self.baseline is not None and not self.baseline > 0:
            raise ValueError(f"baseline override must be > 0 m, got {self.baseline}")

    def required_topics(self) -> dict[str, str]:
        """Return topic -> command-line option, for :meth:`LogReader.require_topics`."""
        topics = {self.left_topic: "--left-topic", self.right_topic: "--right-topic"}
        if self.calibration is None:
            topics[self.left_info_topic] = "--left-info-topic"
            topics[self.right_info_topic] = "--right-info-topic"
        if self.features_topic is not None:
            topics[self.features_topic] = "--features-topic"
        return topics

    @property
    def topics(self) -> list[str]:
        """Return every topic the pairer reads (to pass to :meth:`LogReader.messages`)."""
        return list(self.required_topics())
