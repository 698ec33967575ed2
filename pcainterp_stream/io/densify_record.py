"""The ``pcainterp.densify`` metadata record of a densified MCAP log: what made it.

Written by ``densify`` when its output is complete, so that it names what was decided while
streaming: the basis of the first outputs as the output channels name it (every basis in
force is in the ``pcainterp.basis`` record), how the input pair was read and matched
(:class:`FrontEnd`: the topics, the calibration's source, ``--rectify`` and what it decided,
the SGBM settings), and the options in force. Options are written as JSON of the values the
command line takes (:func:`option_value`: ``"sgbm_3way"``, not ``SgbmMode.SGBM_3WAY``), with
sorted keys, so that a record reads the same on every run with the same options.
``io.outputs.recorded_front_end`` reads the front end back.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, fields
from enum import Enum
from typing import TYPE_CHECKING, Any

import numpy as np

from pcainterp_stream.errors import CalibrationError

if TYPE_CHECKING:
    from pcainterp_stream.io.camera_model import StereoCalibration

DENSIFY_RECORD = "pcainterp.densify"
"""Name of the MCAP metadata record of what made a densified log, written when the output is
complete: ``version``; ``basis``, ``basis_fingerprint`` and ``basis_scope`` as the output
channels have them (the basis of the first outputs; every basis in force: the record
``pcainterp.basis``);
``front_end`` (:class:`FrontEnd`), ``pairing`` and ``processor`` as JSON of option values
(:func:`options_json`); ``output_prefix`` (:data:`OUTPUT_PREFIX_KEY`)."""

OUTPUT_PREFIX_KEY = "output_prefix"
"""The key of :data:`DENSIFY_RECORD` (and of ``pcainterp.basis``) naming the prefix of the
output topics the record is about (``/pcainterp``): a log densified again under another
``--output-prefix`` (its second stereo pair) holds one record per prefix. Records of older
versions have no such key."""

FRONT_END_KEY = "front_end"
"""The key of :data:`DENSIFY_RECORD` holding :class:`FrontEnd` as JSON."""

IMAGES = ("as recorded", "remapped", "remapped in part")
""":attr:`FrontEnd.images`: what ``--rectify`` decided for the pairs of a log."""

CALIBRATIONS = ("camera_info", "files")
""":attr:`FrontEnd.calibration`: the camera infos of the log or ``--calibration`` files."""


def option_value(value: Any) -> Any:
    """Return a value JSON cannot hold as the command line spells it (``json.dumps`` default).

    An enum is its value when that is text (``MeasurementSource.STEREO``: ``"stereo"``),
    else its name in lower case (``SgbmMode.SGBM_3WAY``: ``"sgbm_3way"``, as ``--sgbm-mode``
    takes it); a set is a sorted list, an array nested lists, anything else its text.

    Examples:
        >>> from enum import Enum
        >>> option_value(Enum("Mode", {"SGBM_3WAY": 2}).SGBM_3WAY)
        'sgbm_3way'
    """
    if isinstance(value, Enum):
        return value.value if isinstance(value.value, str) else value.name.lower()
    if isinstance(value, set | frozenset):
        return sorted(value)
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    return str(value)


def options_json(options: Any) -> str:
    """Return an options dataclass as JSON of option values (:func:`option_value`), keys sorted."""
    return json.dumps(dataclasses.asdict(options), default=option_value, sort_keys=True)


@dataclass(frozen=True)
class FrontEnd:
    """How ``densify`` read a log's stereo pair and matched it: what ``evaluate`` needs to redo it.

    Attributes:
        left_topic: the left image topic densify read.
        right_topic: the right image topic.
        left_info_topic: the left camera info topic (not read when ``calibration`` is
            ``files``).
        right_info_topic: the right camera info topic.
        stamp_tolerance_ns: the largest left/right stamp difference that paired (ns).
        baseline: ``--baseline`` (m); None: the calibration's.
        calibration: where the calibration came from: ``camera_info`` (the info topics) or
            ``files`` (``--calibration``).
        calibration_files: those files as given (a Kalibr file's cameras as ``FILE:cam0``,
            ``FILE:cam1``); () with camera infos.
        calibration_values: the files' calibration itself (``io.camera_model.StereoCalibration``),
            so that no file is needed to redo it; None with camera infos.
        rectify: ``--rectify`` as given: ``auto``, ``always`` or ``never``.
        images: what it decided (:data:`IMAGES`): ``as recorded`` (used as they are, with
            P; the right ones moved onto the left's cx when the two P's cx differ, as the
            ``rectify`` line says: the value keeps its name for the records written before),
            ``remapped`` (rectified from the calibration) or ``remapped in part`` (the
            camera infos changed, and the decision with them).
        remapped_pairs: the pairs remapped, of ``pairs``.
        pairs: the stereo pairs made.
        source: the sparse measurements' source: ``stereo`` (SGBM) or ``features`` (a feature
            stream, ``features_topic``; no SGBM ran).
        features_topic: the feature stream's topic, None for ``stereo``.
        sgbm: the SGBM settings by ``SgbmConfig`` field, as option values (``mode`` as
            ``--sgbm-mode`` spells it; ``downscale`` is ``--stereo-downscale``):
            ``SgbmConfig(**{**sgbm, "mode": SgbmMode[sgbm["mode"].upper()]})`` is the matcher.
    """

    left_topic: str
    right_topic: str
    left_info_topic: str
    right_info_topic: str
    stamp_tolerance_ns: int
    baseline: float | None
    calibration: str
    calibration_files: tuple[str, ...]
    calibration_values: StereoCalibration | None
    rectify: str
    images: str
    remapped_pairs: int
    pairs: int
    source: str
    features_topic: str | None
    sgbm: dict[str, Any]

    def to_json(self) -> str:
        """Return the JSON :data:`DENSIFY_RECORD` holds under :data:`FRONT_END_KEY`."""
        return json.dumps(dataclasses.asdict(self), default=option_value, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> FrontEnd:
        """Return the front end :meth:`to_json` wrote (keys of a later version ignored).

        Raises:
            ValueError: not such JSON (a key missing, a value of another kind).
        """
        every = [field.name for field in fields(cls)]
        names = [name for name in every if name not in ("calibration_files", "calibration_values")]
        try:
            values = json.loads(text)
            missing = [name for name in every if name not in values]
            if missing:
                raise ValueError(f"no {', '.join(missing)}")
            front_end = cls(
                **{name: values[name] for name in names},
                calibration_files=tuple(values["calibration_files"]),
                calibration_values=_stereo_calibration(values["calibration_values"]),
            )
            if front_end.images not in IMAGES or front_end.calibration not in CALIBRATIONS:
                raise ValueError(f"images {front_end.images!r} or {front_end.calibration!r}")
            return front_end
        except (TypeError, ValueError, KeyError, CalibrationError) as err:
            raise ValueError(f"not a {FRONT_END_KEY} of {DENSIFY_RECORD}: {err}") from err


def _stereo_calibration(values: dict[str, Any] | None) -> StereoCalibration | None:
    """Return the ``StereoCalibration`` of :func:`options_json`'s form of it (None: None)."""
    if values is None:
        return None
    from pcainterp_stream.io.camera_model import CameraCalibration, StereoCalibration

    def camera(side: dict[str, Any]) -> CameraCalibration:
        arrays = {key: np.asarray(side[key], dtype=np.float64) for key in ("k", "d", "r", "p")}
        tuples = {key: tuple(side[key]) for key in ("binning", "roi")}
        return CameraCalibration(**{**side, **arrays, **tuples})

    return StereoCalibration(camera(values["left"]), camera(values["right"]))
