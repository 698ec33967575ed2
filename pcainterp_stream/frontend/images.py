"""The input stereo images of a densified log, in the frame of its outputs (for ``evaluate``).

A densified log keeps its input's images as recorded: raw ones too. The baselines ``evaluate``
computes from them (SGBM, the figures) need them rectified as ``densify`` rectified them, at
the outputs' size: :class:`PairImages` finds the pair (named or discovered), reads its
calibration (camera infos or files) and remaps each image the way
:meth:`frontend.pairing.StereoPairer.rectification` decides.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.frontend.pairing import PairingConfig, StereoPairer
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.reader_base import LogReader


class PairImages:
    """Topics and rectification of a log's input pair.

    Args:
        config: the pairing (topics, ``rectify``, ``calibration``); a ``discover`` one is
            resolved on the log with :meth:`resolve`.
    """

    def __init__(self, config: PairingConfig | None = None) -> None:
        self.config = dataclasses.replace(config or PairingConfig(), check_rows=False)
        self._pairer = StereoPairer(self.config)

    def resolve(self, reader: LogReader, exclude_prefix: str | None = None) -> None:
        """Find the pair in the log when its topics were not named (outputs are not inputs)."""
        if not self.config.discover:
            from pcainterp_stream.frontend.discovery import resolve_pairing

            self.config = resolve_pairing(reader, self.config)
            self._pairer = StereoPairer(self.config)
            self._pairer.read_ahead(reader)  # as densify read the infos
            return
        from pcainterp_stream.frontend.discovery import resolve_pairing

        class _Inputs:
            """The reader without the output channels, for discovery."""

            path = reader.path
            damage = reader.damage

            @staticmethod
            def topics() -> dict[str, Any]:
                return {
                    t: i
                    for t, i in reader.topics().items()
                    if exclude_prefix is None or not t.startswith(exclude_prefix + "/")
                }

            @staticmethod
            def messages(topics: Any = None) -> Any:
                return reader.messages(topics)

            @staticmethod
            def decode(raw: Any) -> Any:
                return reader.decode(raw)

        self.config = resolve_pairing(_Inputs(), self.config)  # type: ignore[arg-type]
        self._pairer = StereoPairer(self.config)
        self._pairer.read_ahead(reader)  # as densify read the infos

    @property
    def left_topic(self) -> str:
        """Return the left image topic."""
        return self.config.left_topic

    @property
    def right_topic(self) -> str:
        """Return the right image topic."""
        return self.config.right_topic

    @property
    def info_topics(self) -> list[str]:
        """Return the camera info topics to read (none with calibration files)."""
        if self.config.calibration is not None:
            return []
        return [self.config.left_info_topic, self.config.right_info_topic]

    def cx_offset(self) -> float | None:
        """Return cx_left - cx_right of the pair's camera infos' P (px), None when unknown.

        The P's cx as the infos give it, as ``image_geometry``'s ``StereoCameraModel`` reads
        it (stereo_image_proc shifts its disparities by -(cx_left - cx_right) with it). None
        with calibration files (a driver's DisparityImage was made from camera infos the log
        does not hold), before both infos are read, or when a P gives no camera.
        """
        pairer = self._pairer
        if self.config.calibration is not None:
            return None
        infos = (pairer._left_info, pairer._right_info)
        if infos[0] is None or infos[1] is None:
            return None
        try:
            cx = [rosmsg.projection_matrix(info) for info in infos]
        except (TypeError, ValueError, AttributeError):
            return None
        if not all(np.isfinite(p).all() and p[0, 0] > 0 for p in cx):
            return None
        return float(cx[0][0, 2] - cx[1][0, 2])

    def see_info(self, topic: str, message: Any) -> None:
        """Take a camera info message of the pair."""
        self._pairer.push(topic, 0, 0, message)

    def rectified(self, image: npt.NDArray[Any], side: str) -> npt.NDArray[Any]:
        """Return one image of the pair rectified as densify did (full rectified size)."""
        pairer = self._pairer
        if self.config.calibration is None and (
            pairer._left_info is None or pairer._right_info is None
        ):
            return image  # no calibration seen yet: as recorded
        rectifier = pairer.rectification()
        if rectifier is None:
            return np.asarray(pairer.as_is(image, side))  # a right one on the left's cx
        out = rectifier.rectify_one(image, side)
        return np.asarray(out)
