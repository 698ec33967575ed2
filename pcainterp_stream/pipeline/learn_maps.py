"""The maps ``learn`` reads from logs and the camera they are learned for.

A map is an SGBM map of a stereo pair or f*b / depth of a depth topic, put in the disparity
units of one f*b: at one depth the disparity is proportional to f*b, so the maps of a
recalibrated rig (or of two rigs of one image size) are scaled to the first log's f*b,
as ``densify`` maps a basis onto another camera (docs/estimator.md, "Camera mapping").
"""

from __future__ import annotations

import dataclasses
import itertools
import os
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import LogReadError, PcaInterpError, TopicNotFoundError
from pcainterp_stream.evaluate.metrics import (
    GROUND_TRUTH_DEPTH,
    ReferenceKind,
    disparity_from_reference,
)
from pcainterp_stream.evaluate.truth_values import DepthValues
from pcainterp_stream.frontend.camera_infos import camera_from_infos, first_infos
from pcainterp_stream.frontend.discovery import resolve_pairing
from pcainterp_stream.frontend.pairing import PairingConfig, StereoPairer, iter_stereo_frames
from pcainterp_stream.frontend.stereo import SgbmConfig, compute_disparity
from pcainterp_stream.io.depth_image import depth_metres
from pcainterp_stream.io.logreader import LogReader, log_files, open_log
from pcainterp_stream.pipeline.common import (
    _check_depth_topic,
    _check_topic_types,
    _echo,
    _pairing_types,
    _require_topics,
    no_pair_message,
)

__all__ = [
    "COVERAGE_IMAGES",
    "FOCAL_BASELINE_NOTE",
    "SIZE_TOLERANCE",
    "SPARSE_DEPTH_COVERAGE",
    "MapOptions",
    "MapSource",
    "check_fit_logs",
    "check_logs_once",
    "close_sizes",
    "depth_disparity",
    "depth_maps",
    "log_camera",
    "log_pairing",
    "no_pair_for_learn",
    "one_camera",
    "resized_to",
    "scaled_to",
    "sgbm_maps",
    "single_info",
]

FOCAL_BASELINE_NOTE = 0.01
"""A log whose f*b differs from the first log's by more than this share is named in a note."""

SIZE_TOLERANCE = 0.03
"""Maps whose sides differ from the first log's by at most this share are resampled to its
size (a raw log's rectified box is a few px smaller than the images a rectified log holds),
as ``densify`` maps a basis onto another image size; others are another camera."""

COVERAGE_IMAGES = 5
"""How many of a depth topic's first images :data:`SPARSE_DEPTH_COVERAGE` is judged on."""

SPARSE_DEPTH_COVERAGE = 0.5
"""A depth topic whose images (median of the first :data:`COVERAGE_IMAGES` that hold any
depth) have a depth at fewer of their pixels is named in a note
(the synthetic street's truth covers 100 %, its projected LiDAR 4 %: learned from, its
holes filled, a basis as good as the dense truth's, docs/estimator.md "Learning")."""


class MapOptions(Protocol):
    """What reading maps needs of the learning options (``learn.LearnOptions`` has it)."""

    @property
    def depth_topic(self) -> str | None:
        """The depth topic learned from instead of SGBM maps, if any."""
        ...

    @property
    def every(self) -> int:
        """Use every N-th frame."""
        ...

    @property
    def sgbm(self) -> SgbmConfig:
        """The matcher options."""
        ...


@dataclass(frozen=True)
class MapSource:
    """The camera of a log's maps.

    Attributes:
        image_size: (height, width) of the maps: the images or their rectified box (px).
        focal_baseline: f*b of the camera (px*m).
        images: (height, width) of raw images remapped, else None.
        rectify: the ``--rectify`` decision said for the log's stereo pair (None: a depth
            topic's maps, or nothing said).
        decisions: (log, its ``rectify`` line) of every log (:func:`one_camera`).
        single: the one camera info of a depth topic's log without a right one, else None.
    """

    image_size: tuple[int, int]
    focal_baseline: float
    images: tuple[int, int] | None = None
    rectify: str | None = None
    decisions: tuple[tuple[str, str], ...] = ()
    single: str | None = None

    def describe(self) -> str:
        """Say the images' size, and their rectified box where it differs: "752x480 images"."""
        height, width = self.image_size
        if self.images is None or self.images == self.image_size:
            return f"{width}x{height} images"
        return f"{self.images[1]}x{self.images[0]} images (rectified box {width}x{height})"

    def describe_maps(self) -> str:
        """Say the maps' size and what it is: "620x186 maps (the rectified box of its ...)"."""
        height, width = self.image_size
        if self.images is None or self.images == self.image_size:
            return f"{width}x{height} maps (its images)"
        raw = f"{self.images[1]}x{self.images[0]}"
        return f"{width}x{height} maps (the rectified box of its {raw} raw images)"


def close_sizes(size: tuple[int, int], other: tuple[int, int]) -> bool:
    """Return whether two (H, W) sizes differ by at most :data:`SIZE_TOLERANCE` per side."""
    return all(abs(a - b) <= SIZE_TOLERANCE * b for a, b in zip(size, other, strict=True))


def resized_to(
    disparity: npt.NDArray[np.float32], image_size: tuple[int, int]
) -> npt.NDArray[np.float32]:
    """Return a map resampled to ``image_size`` (H, W), pixel-centre aligned, nearest pixel.

    Nearest, so a hole (NaN, < 0) stays a hole and no disparity lies between two surfaces;
    ``disparity`` itself when it has that size.
    """
    if disparity.shape == tuple(image_size):
        return disparity
    resized = cv2.resize(
        disparity, (image_size[1], image_size[0]), interpolation=cv2.INTER_NEAREST
    )
    return np.asarray(resized, dtype=np.float32)


def scaled_to(
    disparity: npt.NDArray[np.float32], focal_baseline: float, target: float | None
) -> npt.NDArray[np.float32]:
    """Return a map of a camera of ``focal_baseline`` in the disparity units of ``target``.

    Disparity is f*b / depth, so one depth's disparity in the target camera is
    d * target / focal_baseline; 0, negative (SGBM's invalid) and NaN pixels stay so.

    Args:
        disparity: (H, W) float32 map (px).
        focal_baseline: f*b of its camera (px*m).
        target: f*b to put it in (px*m); None, or either <= 0: the map as it is.

    Returns:
        (H, W) float32 (px): ``disparity`` itself when nothing is scaled.
    """
    if target is None or target <= 0 or focal_baseline <= 0 or target == focal_baseline:
        return disparity
    return disparity * np.float32(target / focal_baseline)


def depth_disparity(
    depth: npt.NDArray[np.floating[Any]], focal_baseline: float
) -> npt.NDArray[np.float32]:
    """Return the disparity f*b / depth of a depth image read as REP 118 says, holes NaN.

    NaN, 0 and negative depth hold no value (a projected LiDAR's pixels without a return,
    16UC1's 0): they are NaN, holes that preprocessing fills from the nearest valid pixel
    as it fills SGBM's; +inf (farther than measurable, the synthetic sky) is disparity 0.
    ``evaluate`` reads a depth truth the same way
    (:func:`~pcainterp_stream.evaluate.metrics.disparity_from_reference`).

    Args:
        depth: (H, W) float depth (m).
        focal_baseline: f*b of the disparity's camera (px*m).

    Returns:
        (H, W) float32 disparity (px): > 0, 0 (infinitely far) or NaN (no value).

    Examples:
        >>> depth = np.array([[2.0, np.inf, np.nan, 0.0, -1.0]], dtype=np.float32)
        >>> depth_disparity(depth, 10.0)
        array([[ 5.,  0., nan, nan, nan]], dtype=float32)
    """
    disparity = disparity_from_reference(
        depth, kind=ReferenceKind.DEPTH, focal_baseline=focal_baseline
    )
    return disparity.astype(np.float32)


def depth_maps(
    log: Path,
    options: MapOptions,
    pairing: PairingConfig,
    info: list[MapSource],
    *,
    focal_baseline: float | None = None,
    note: bool = False,
) -> Iterator[npt.NDArray[np.float32]]:
    """Yield disparity maps f*b/depth of a depth topic, its holes NaN (:func:`depth_disparity`).

    A log with one camera info (an RGB-D camera; :func:`single_info`) is read with that info
    and ``--baseline`` (f*b = fx * baseline): depth needs no right camera, but disparity
    needs a baseline, and without one it is refused (one line naming ``--baseline``).

    The topic is read as :func:`~pcainterp_stream.io.depth_image.depth_metres` reads it:
    32FC1 in metres, 16UC1 in millimetres (0: none), or either as compressedDepth. NaN, 0 and
    negative depth are holes (NaN), filled in preprocessing from the nearest pixel with a
    depth; +inf is infinitely far (disparity 0).

    Args:
        log: the log.
        options: the learning options (``depth_topic``, ``every``).
        pairing: the topics of the camera infos.
        info: the camera of the first map is appended when empty.
        focal_baseline: the f*b every map is put in (:func:`scaled_to`); None: the first
            map's camera's (``info[0]``).
        note: say it when the log's one camera info is used.

    Yields:
        (H, W) float32 disparity maps (px).
    """
    assert options.depth_topic is not None
    with open_log(log) as reader:
        pairing = log_pairing(reader, pairing, options.depth_topic)
        single = single_info(reader, pairing)
        needed = {
            options.depth_topic: "--depth-topic",
            pairing.left_info_topic: "--left-info-topic",
        }
        if single is None:
            needed[pairing.right_info_topic] = "--right-info-topic"
        _require_topics(reader, needed, "depth image")
        _check_depth_topic(reader, options.depth_topic)
        _check_topic_types(
            reader, _pairing_types(dataclasses.replace(pairing, features_topic=None))[2:]
        )
        if single is not None:
            if pairing.baseline is None:
                raise PcaInterpError(
                    f"{log.name} has one camera info ({single}, no "
                    f"{pairing.right_info_topic}): learn --depth-topic puts depth in "
                    "disparity f*b/depth, so pass --baseline METRES (the one densify will use "
                    "for this camera), or --right-info-topic of the stereo pair's right camera"
                )
            if note:
                _echo(
                    f"note: {log.name} has one camera info ({single}): its depth maps are "
                    f"learned as disparity fx * --baseline {pairing.baseline:g} m / depth"
                )
            pairing = dataclasses.replace(pairing, right_info_topic=single)
        info_topics = list(dict.fromkeys([pairing.left_info_topic, pairing.right_info_topic]))
        # camera infos recorded after the first depth images: their first, read ahead
        infos: dict[str, Any] = {
            topic: message for topic, _, message in first_infos(reader, info_topics)
        }
        index = 0
        topics = [options.depth_topic, *info_topics]
        for raw in reader.messages(topics):
            message = reader.decode(raw)
            if raw.topic != options.depth_topic:
                infos[raw.topic] = message
                continue
            index += 1
            if (index - 1) % options.every:
                continue
            if len(infos) < len(info_topics):
                continue  # no calibration yet
            try:
                depth = depth_metres(message)
            except ValueError as err:
                raise LogReadError(
                    f"depth image on {options.depth_topic} at log time {raw.log_time_ns} ns in "
                    f"{log.name} is unusable ({err}); pass a depth topic (32FC1 m, 16UC1 mm or "
                    "compressedDepth) as --depth-topic"
                ) from err
            camera = camera_from_infos(
                infos[pairing.left_info_topic],
                infos[pairing.right_info_topic],
                width=depth.shape[1],
                height=depth.shape[0],
                left_topic=pairing.left_info_topic,
                right_topic=pairing.right_info_topic,
                baseline=pairing.baseline,
            )
            if not info:
                info.append(MapSource(camera.image_size, camera.focal_baseline, single=single))
            target = info[0].focal_baseline if focal_baseline is None else focal_baseline
            # the target's disparity of this depth: f*b_target / depth (REP 118 holes NaN)
            fb = target if target > 0 else camera.focal_baseline
            yield depth_disparity(depth, fb)


def sgbm_maps(
    log: Path,
    options: MapOptions,
    pairing: PairingConfig,
    info: list[MapSource],
    *,
    focal_baseline: float | None = None,
    seen: Callable[[npt.NDArray[Any]], None] | None = None,
) -> Iterator[npt.NDArray[np.float32]]:
    """Yield SGBM maps of every N-th pair, matching the next pair while this one is used.

    Args:
        log: the log.
        options: the learning options (``every``, ``sgbm``).
        pairing: the topics of the stereo pairs.
        info: the camera of the first map is appended when empty.
        focal_baseline: the f*b every map is put in (:func:`scaled_to`); None: the first
            map's camera's (``info[0]``).
        seen: called with each map's left image just before the map is yielded (the
            views' count, :class:`~.map_checks.ViewCount`).

    Yields:
        (H, W) float32 disparity maps (px).
    """
    with open_log(log) as reader, ThreadPoolExecutor(1, thread_name_prefix="sgbm") as pool:
        pairing = log_pairing(reader, pairing)
        _require_topics(reader, pairing.required_topics(), "stereo pair")
        _check_topic_types(reader, _pairing_types(pairing))
        pending: list[tuple[Future[npt.NDArray[np.float32]], float]] = []
        lefts: list[npt.NDArray[Any]] = []
        for frame in iter_stereo_frames(reader, pairing):
            if frame.index % options.every:
                continue
            if not info:
                info.append(MapSource(frame.camera.image_size, frame.camera.focal_baseline))
            future = pool.submit(compute_disparity, frame.left, frame.right, options.sgbm)
            pending.append((future, frame.camera.focal_baseline))
            lefts.append(frame.left)
            if len(pending) > 1:
                if seen is not None:
                    seen(lefts[0])
                lefts.pop(0)
                yield _finished(pending.pop(0), info, focal_baseline)
        for item, left in zip(pending, lefts, strict=True):
            if seen is not None:
                seen(left)
            yield _finished(item, info, focal_baseline)


def _finished(
    item: tuple[Future[npt.NDArray[np.float32]], float],
    info: list[MapSource],
    focal_baseline: float | None,
) -> npt.NDArray[np.float32]:
    future, fb = item
    target = info[0].focal_baseline if focal_baseline is None else focal_baseline
    return scaled_to(future.result(), fb, target)


def log_pairing(
    reader: LogReader,
    pairing: PairingConfig,
    depth_topic: str | None = None,
    echo: Callable[[str], None] | None = None,
) -> PairingConfig:
    r"""Return the pairing one open log is read with: its pair found, or ``pairing``'s.

    Named image topics are kept, each with its own camera info unless an info topic was
    named (:func:`frontend.discovery.resolve_pairing`, as densify reads them). With a
    ``depth_topic`` only the camera infos are needed, so a log whose images cannot be
    paired keeps the default topics.

    Args:
        reader: the open log.
        pairing: the pairing the options ask for.
        depth_topic: the depth topic learned from instead of SGBM maps, if any.
        echo: given the line that says which pair was found.

    Raises:
        TopicNotFoundError: no stereo pair in the log (and no ``depth_topic``), or two
            equally good ones.
    """
    try:
        return resolve_pairing(reader, pairing, echo)
    except TopicNotFoundError as err:
        if depth_topic is None:
            raise no_pair_for_learn(reader, err) from err
        # a depth topic needs only the camera infos: the defaults may do
        return dataclasses.replace(pairing, discover=False)


def single_info(reader: LogReader, pairing: PairingConfig) -> str | None:
    """Return the one camera info of a one-camera log (an RGB-D camera's), else None.

    One info: the left and right info topics are one, or the right one is not in the log
    and the left one is.
    """
    left, right = pairing.left_info_topic, pairing.right_info_topic
    topics = reader.topics()
    if left == right or (right not in topics and left in topics):
        return left
    return None


def no_pair_for_learn(reader: LogReader, err: TopicNotFoundError) -> TopicNotFoundError:
    """Return ``err`` with learn's advice when the log has at most one camera info.

    Such a log (a camera and a feature stream, or a depth camera) has no stereo pair to
    learn SGBM maps from: learn takes a depth topic instead, never a feature cloud.
    """
    topics = reader.topics()
    infos = [t for t, i in topics.items() if i.msgtype and i.msgtype.endswith("CameraInfo")]
    if len(infos) > 1:
        return err
    clouds = sorted(t for t, i in topics.items() if "PointCloud" in str(i.msgtype))
    depths = sorted(t for t in topics if "depth" in t.lower() and "Image" in str(topics[t].msgtype))
    found = str(err).split("; pass --left-topic")[0].split("; pcainterp needs")[0]
    depth = f", e.g. {depths[0]}" if depths else ""
    cloud = (
        f"; it cannot learn from feature clouds ({', '.join(clouds)}: densify reads them with "
        "--features-topic)"
        if clouds
        else ""
    )
    return TopicNotFoundError(
        f"{found}; learn needs a stereo pair (its SGBM maps) or a depth image topic "
        f"(--depth-topic TOPIC{depth}; with one camera info also --baseline METRES){cloud}"
    )


def log_camera(
    log: Path,
    options: MapOptions,
    pairing: PairingConfig,
    why: list[str] | None = None,
    *,
    stereo: bool = False,
    say: Callable[[str], None] | None = None,
) -> MapSource | None:
    """Return the camera of the first map a log gives (reads up to its first map), or None.

    Args:
        log: the log.
        options: the learning options (``depth_topic``: its maps, else SGBM's).
        pairing: the topics of the stereo pairs.
        why: given the one-line reason when the log gives no map: with SGBM maps, the
            pairing's summary and its fix (a stamp tolerance too tight, ...) as ``densify``
            words it.
        stereo: the camera of the stereo pairs even when ``options`` name a depth topic.
        say: given the ``--rectify`` decision for the stereo pair, as ``densify`` prints it
            (also kept in the result's ``rectify``).

    A depth topic whose first images have a depth at fewer than :data:`SPARSE_DEPTH_COVERAGE`
    of their pixels (:data:`COVERAGE_IMAGES`, median) is named in a note.
    """
    reason = ""
    if options.depth_topic and not stereo:
        info: list[MapSource] = []
        values = DepthValues()  # NaN but never +inf: an earlier synthetic log's sky
        shares = []
        maps = depth_maps(log, options, pairing, info, note=True)
        for first in itertools.islice(maps, COVERAGE_IMAGES):
            shares.append(float(np.mean(np.isfinite(first))))
            values.add_disparity(first)
        if shares:
            seen = [share for share in shares if share > 0] or [0.0]  # blank ones: noted apart
            covered = float(np.median(seen))
            if covered < SPARSE_DEPTH_COVERAGE:
                _echo(
                    f"note: {options.depth_topic} in {log.name} has a depth at {covered:.0%} of "
                    f"the pixels of its images (median of the first {len(shares)}); learn fills "
                    "the others from the nearest pixel with a depth, as it fills SGBM's holes: "
                    "what the sensor never returns from (the sky) takes the depth of the points "
                    "nearest it"
                )
            elif options.depth_topic == GROUND_TRUTH_DEPTH and values.nan_sky():
                _echo(
                    f"note: {values.nan_share():.1%} of {options.depth_topic}'s pixels in "
                    f"{log.name} are NaN and none +inf (first {len(shares)} images): an earlier "
                    "`pcainterp synth` wrote the sky so; learn fills them from the nearest pixel "
                    "with a depth, as SGBM's holes, so the sky is learned as the surface nearest "
                    "it; synthesize the log again (sky +inf, disparity 0) to learn the sky"
                )
            return info[0]
        reason = (
            f"no depth image with camera infos found in {log} on {options.depth_topic}; check "
            "the topic options (pcainterp info LOG)"
        )
    else:
        with open_log(log) as reader:
            paired = log_pairing(reader, pairing)
            _require_topics(reader, paired.required_topics(), "stereo pair")
            _check_topic_types(reader, _pairing_types(paired))
            said: list[str] = []

            def hear(line: str) -> None:
                said.append(line)
                if say is not None:
                    say(line)

            pairer = StereoPairer(paired, echo=hear)
            for frame in iter_stereo_frames(reader, pairer=pairer):
                # raw images are estimated in the box of their rectified view both cameras see
                rectifier = pairer.rectification()
                width, height = rectifier.calibration.left.image_size() if rectifier else (0, 0)
                images = (height, width) if rectifier else None
                decision = said[0] if said else None
                return MapSource(
                    frame.camera.image_size, frame.camera.focal_baseline, images, decision
                )
            reason = no_pair_message(log, paired, pairer.stats, reader.damage)
    if why is not None:
        why.append(reason)
    return None


def one_camera(logs: list[Path], options: MapOptions, pairing: PairingConfig) -> MapSource:
    """Return the camera of the first map the logs give, each log's first map checked.

    A log whose f*b differs from the first's by more than :data:`FOCAL_BASELINE_NOTE` is
    named in a note (its maps are scaled: :func:`scaled_to`), one whose maps differ in size
    by at most :data:`SIZE_TOLERANCE` a side in another (they are resampled:
    :func:`resized_to`), and a log that gives no map in a third (it adds none).

    Raises:
        LogReadError: no log gives a map (the first log's reason).
        PcaInterpError: two logs' maps differ in size by more (before any map is learned).
    """
    why: list[str] = []

    def say(log: Path) -> Callable[[str], None]:  # the rectify decision, as densify prints it
        return _echo if len(logs) == 1 else lambda line: _echo(f"{log.name}: {line}")

    cameras = [(log, log_camera(log, options, pairing, why, say=say(log))) for log in logs]
    found = [(log, camera) for log, camera in cameras if camera is not None]
    if not found:
        raise LogReadError(why[0])
    decisions = tuple((str(log), c.rectify) for log, c in found if c.rectify is not None)
    for reason in why:
        _echo(f"note: {reason}; learning from the other logs")
    first_log, camera = found[0]
    for log, other in found[1:]:
        if other.image_size != camera.image_size:
            if not close_sizes(other.image_size, camera.image_size):
                raise PcaInterpError(
                    f"{log} gives {other.describe_maps()} but {first_log} gives "
                    f"{camera.describe_maps()}; learn one basis per camera"
                )
            height, width = camera.image_size
            _echo(
                f"note: {log.name} gives {other.describe_maps()} and {first_log.name} "
                f"{camera.describe_maps()}: sides within {SIZE_TOLERANCE:.0%}, as one "
                f"camera's rectified box may differ, so its maps are resampled to "
                f"{width}x{height} (as densify maps a basis onto another image size)"
            )
        ratio = _ratio(camera, other)
        if abs(ratio - 1.0) > FOCAL_BASELINE_NOTE:
            _echo(
                f"note: {log.name}'s camera has f*b {other.focal_baseline:.2f} px*m, "
                f"{first_log.name}'s {camera.focal_baseline:.2f}: its maps are scaled by "
                f"{ratio:.3g} to {first_log.name}'s (at one depth the disparity is "
                "proportional to f*b)"
            )
    return dataclasses.replace(camera, decisions=decisions)


def _ratio(camera: MapSource, other: MapSource) -> float:
    """Return f*b of ``camera`` over ``other``'s (1 when either is unknown)."""
    if camera.focal_baseline > 0 and other.focal_baseline > 0:
        return camera.focal_baseline / other.focal_baseline
    return 1.0


def check_fit_logs(
    fit_logs: tuple[Path, ...], logs: list[Path], options: MapOptions, pairing: PairingConfig
) -> None:
    """Refuse ``--fit-logs`` logs whose stereo images differ in size from the training logs'.

    Sizes within :data:`SIZE_TOLERANCE` a side are one camera (the fit maps the basis onto
    each frame's size, as ``densify`` does).

    The prior is fitted on their stereo pairs (GFTT + SGBM, as ``densify`` measures), so
    their camera is compared with the first training log's stereo camera (a training log
    of a depth topic with one camera: its depth maps' camera, review 58c C8); an f*b that
    differs is mapped as every camera is (``fitting.fit_frame``), and named in a note.

    Raises:
        LogReadError: a fit log has no stereo pair.
        PcaInterpError: a fit log's images differ in size.
    """
    why: list[str] = []
    training = None
    try:
        training = log_camera(logs[0], options, pairing, why, stereo=True)
    except TopicNotFoundError:
        if not options.depth_topic:
            raise  # a depth topic's log may have one camera: its fit logs are the stereo
        training = log_camera(logs[0], options, pairing, why)  # its depth maps' camera
    for log in fit_logs:
        camera = log_camera(log, options, pairing, why, stereo=True)
        if camera is None:
            raise LogReadError(why[-1])
        if training is None:
            continue  # a training log that gives no map: nothing to compare
        if not close_sizes(camera.image_size, training.image_size):
            raise PcaInterpError(
                f"--fit-logs {log.name} has {camera.describe()} but the training log "
                f"{logs[0].name} has {training.describe()}; fit on logs of the training "
                "camera (or drop --fit-logs to fit on a held-out share of the training logs)"
            )
        ratio = _ratio(training, camera)
        if abs(ratio - 1.0) > FOCAL_BASELINE_NOTE:
            _echo(
                f"note: --fit-logs {log.name}'s camera has f*b {camera.focal_baseline:.2f} "
                f"px*m, {logs[0].name}'s {training.focal_baseline:.2f}: its disparities are "
                f"scaled by {ratio:.3g} for the fit"
            )


def check_logs_once(logs: list[Path]) -> None:
    """Refuse two logs that read one file, whose maps would count twice.

    A log given twice, or a rosbag2 folder and its own storage file
    (:func:`~pcainterp_stream.io.logreader.log_files`).

    Raises:
        PcaInterpError: "s05_r2/s05_r2.mcap is a storage file of the rosbag2 folder s05_r2,
            given too: its maps would count twice; pass each log once (the folder or its file)".
    """
    read: list[tuple[Path, Path]] = []  # (file, the log that reads it)
    for log in logs:
        files = log_files(log)
        for path, owner in read:
            if not any(_same_file(path, file) for file in files):
                continue
            if files == [log] and owner.is_dir():
                what = f"is a storage file of the rosbag2 folder {owner}, given too"
            elif log.is_dir() and not owner.is_dir():
                what = f"is the rosbag2 folder of {owner}, given too"
            else:
                what = f"is {owner} again"
            raise PcaInterpError(
                f"{log} {what}: its maps would count twice; pass each log once"
                + (" (the folder or its file)" if log.is_dir() != owner.is_dir() else "")
            )
        read.extend((file, log) for file in files)


def _same_file(first: Path, second: Path) -> bool:
    """Return whether two paths name one file: one inode where both exist, else one path."""
    try:
        return os.path.samefile(first, second)
    except OSError:
        return first.resolve() == second.resolve()
