"""The incremental frame processor: stereo pairs in, densified frames out.

Per pair: GFTT corners on the left image, SGBM disparity, disparity lookups at the corners
(or the points of a sparse feature stream instead), then MAP densification with the basis.
Stereo matching of the next frames runs in worker threads, the densification of the
matched frames batch after batch in a thread of its own, and the calling thread does the
caller's I/O (OpenCV, BLAS, zlib and zstd release the GIL).

Threads (measured in docs/stages.md, "Stereo front end", "Threads"): on a few cores the pipeline
is fastest when no library spawns threads of its own, so that every thread is one unit of
work the OS can place: each stereo worker runs OpenCV on one thread
(``cv2.setNumThreads(1)``), BLAS runs on one thread (threadpoolctl), and two stereo workers
keep both cores busy while the calling thread waits for I/O. A two-thread OpenBLAS next to
running SGBM threads spins and is several times slower. Both settings are process-wide; the
processor restores the previous values in :meth:`FrameProcessor.close`.

The threads of a ``densify`` job, all of them (docs/benchmarks.md "Throughput" and "The
densify thread and a lean SGBM-alone reference"; docs/speed_levers.md): the calling thread
(read, pair, hand frames on); this processor's ``stereo_workers`` threads running GFTT,
SGBM, the lookups and the odometry of the carried points; its ``densify`` thread, in
stream order (the set-up with scipy's imports, the fit check, the carried points and the
adaptation: state that moves frame by frame), handing each batch with its final
measurements to the ``estimate_workers`` threads (the solves, the std, the images; several
batches at once, unless the temporal prior carries a state from frame to frame, when the
densify thread estimates in turn); the job's two encoder threads building the output
messages; and the log writer's own thread (``open_writer(..., threaded=True)``: CDR
serialization, MCAP chunks, zstd, file writes), fed through a bounded queue. Memory is
bounded by the look-ahead and the densify queue here and by the encoders' and writer's
queues there.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import os
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from pcainterp_stream import defaults
from pcainterp_stream.allocator import Releases
from pcainterp_stream.estimate import adapt, fitting
from pcainterp_stream.estimate.basis import (
    BUILTIN_KINDS,
    Basis,
    builtin_basis,
    builtin_basis_installed,
    builtin_kind,
)
from pcainterp_stream.estimate.cells import Seeding
from pcainterp_stream.estimate.dense import (
    DenseModel,
    field_options,
    find_holes,
    fuse_dense,
)
from pcainterp_stream.estimate.estimator import DensifyResult, densify_batch
from pcainterp_stream.estimate.prior import LocalPrior, Robust, TemporalPrior
from pcainterp_stream.estimate.variance import prior_std_map
from pcainterp_stream.frontend.features import features_to_measurements
from pcainterp_stream.frontend.motion import CarriedPoints, CarryConfig, estimate_motion
from pcainterp_stream.frontend.near import NearConfig, extend_near, lookups_only
from pcainterp_stream.frontend.stereo import (
    GfttConfig,
    SgbmConfig,
    StereoFrontEnd,
    to_grey8,
)
from pcainterp_stream.interrupt import signalled
from pcainterp_stream.pipeline.adaptation import FITS_BELOW, OWN_ABOVE_STREET, Candidate
from pcainterp_stream.pipeline.held_out import clipped_pixels
from pcainterp_stream.pipeline.measured import Measured, cells_on_grid, sgbm_maps
from pcainterp_stream.pipeline.prepare import prepare as _prepare  # tools/thread_cpu.py times it
from pcainterp_stream.pipeline.refit import Camera, Refitting, adapt_frame
from pcainterp_stream.pipeline.threads import ThreadLimits, finished, gathered, lower_priority
from pcainterp_stream.records import DensifiedFrame, SparseFeatures, StereoFrame


class MeasurementSource(enum.Enum):
    """Where the sparse measurements of a frame come from."""

    STEREO = "stereo"
    """GFTT corners on the left image, disparities looked up in an SGBM map."""
    FEATURES = "features"
    """The points of a sparse feature stream (``/features``) with the frame's stamp."""


CHECK_LEAD_BATCHES = 3
"""Batches the stereo workers match ahead while the densify thread runs the fit check.

The check and the first batch take the densify thread ~0.4-0.6 s on a KITTI log (two
built-in bases checked), as long as matching ~12-18 frames on the other core: with one
batch ahead the workers stopped and a core sat idle (measured in docs/speed_levers.md).
Each frame held costs its pair and SGBM map (~3-5 MB at KITTI size)."""


@dataclass(frozen=True)
class ProcessorConfig:
    """Options of the frame processor.

    Attributes:
        gftt: corner detector options.
        sgbm: stereo matcher options (by default at the resolution ``densify`` chooses for
            the camera, :mod:`~pcainterp_stream.frontend.sgbm_resolution`; half resolution,
            :data:`~pcainterp_stream.defaults.STEREO_DOWNSCALE`, until chosen).
        sigma: measurement noise std (px) of the MAP estimate, "evidence" (fitted per
            frame) or "auto" (the basis's fitted sigma when it has one, else 2 px).
        uncertainty: "exact-coarse" (default: the exact std on the variance grid, resampled),
            "exact" (exact at every pixel), "paper" or "none".
        prior: "auto" (hybrid when the basis has a fitted local prior, else the paper's),
            "paper" or "hybrid" (needs a basis whose prior ``learn`` fitted, its default).
        robust: IRLS loss on the measurements: "none", "huber" or "cauchy".
        temporal: carry each frame's posterior into the next frame's prior.
        process_noise: the temporal prior's process noise (fraction of the eigenvalues);
            None: the basis's fitted value, else 0.1.
        carry: carrying the measurements of earlier frames into each frame, moved by the
            estimated ego-motion (:mod:`motion`); ``frames=0`` is off.
        calibrate: calibrate the std as the basis's fit did (with the hybrid prior it was
            fitted with): its factor, and per frame sqrt(a) of the covariance scale fitted
            from the frame's innovation (``prior.covariance_scale``) when the fit has that
            factor (``innovation_std_scale``); False reports the posterior std itself.
        source: measurement source.
        max_features: most points of a feature stream's cloud measured per frame (thinned:
            :func:`~pcainterp_stream.frontend.features.thin_measurements`).
        measurements: ``"sparse"`` (the paper's: a few hundred GFTT corners looked up in the
            SGBM map, the default) or ``"dense"`` (that estimate then fused, pixel by pixel,
            with the whole SGBM map: :mod:`~pcainterp_stream.estimate.dense`; stereo
            source only; ``densify --measurements dense`` pairs it with
            ``sgbm=frontend.matchers.REFINED_DENSE_SGBM`` and
            ``gftt=frontend.matchers.dense_points()``).
        dense: the noise model of dense mode.
        batch_size: frames densified together (matrix-matrix products).
        lookahead: frames queued for stereo matching ahead of densification; at least
            ``stereo_workers`` keeps every worker busy.
        stereo_workers: threads running the stereo front end (each has its own matcher).
        estimate_workers: threads estimating batches whose measurements are final (the
            solves, the std, the images), several batches at once; without the temporal
            prior no state runs from one batch's estimate to the next, so the results do
            not depend on it. None: 2, and 1 in dense mode (its full-resolution matching
            keeps both cores busy alone; a second thread only held ~30 MB more frames).
        opencv_threads: ``cv2.setNumThreads`` while the processor is open (stereo source
            only); None leaves OpenCV's setting alone.
        blas_threads: BLAS threads while the processor is open (stereo source only, via
            threadpoolctl when installed); None leaves BLAS alone.
        worker_niceness: nice value added to the stereo worker threads (Linux), so the
            calling thread, the pipeline's serial part, wins a contended core; 0 = off.
        keep_freed_memory: tune glibc's malloc (process-wide, for the rest of the process)
            so the many full-size temporaries per frame reuse freed heap memory instead of
            page-faulting fresh ``mmap`` regions: ~15 % less CPU per frame end to end; cap
            its arenas at one per core (each keeps its high-water mark); and give the free
            pages back now and then (:class:`~pcainterp_stream.allocator.Releases`), so
            memory creeps less on long logs.
        adapt: the fit check and self-supervised adaptation: ``"auto"`` checks the basis
            on the first frames against linear interpolation on held-out SGBM pixels; when
            it is a built-in one that does not fit well, the other built-in one is checked
            too (``builtin``) and, when neither fits well, a basis learned from the log's
            own SGBM maps replaces it if it does better (not in dense mode), and keeps
            learning as frames come; ``"check"`` checks (and may pick between the built-in
            bases) but never learns; ``"off"``. A feature stream (no SGBM maps) is
            checked on left-out measurements (every 5th) and never adapted.
        warmup_frames: frames of the check (and of the first self-supervised basis).
        builtin: which built-in basis a processor given a built-in one (or None) uses:
            ``"auto"`` starts with the street basis and, when it does not fit the first
            frames well (``adapt`` not ``"off"``), checks the indoor one on the same held-out
            pixels and uses whichever fits better; ``"street"`` or ``"indoor"``: that one.
        edge_aware: sparse stereo mode partitions each frame along its SGBM map (beside
            SGBM) for an edge-aware local prior (:mod:`~pcainterp_stream.estimate.cells`),
            used when the basis's local prior has a cell weight (the built-in street
            basis); False: the stationary kernel.
        near: sparse stereo mode also matches at quarter resolution (twice SGBM's
            range) on frames whose map nears the range's end, and measures the surfaces
            nearer than the range there (:mod:`~pcainterp_stream.frontend.near`; its
            ``match_range`` is set from ``sgbm``); None: off. Dense mode and feature
            streams do not use it.
        depth_std: sparse mode converts each frame's disparity std to a depth std; False
            leaves the results' ``depth_std`` unknown (NaN), for a caller that does not
            use it (:func:`~pcainterp_stream.pipeline.densify.densify` when no written
            channel, viewer or callback takes it): ~0.6 ms less per KITTI-size frame.
    """

    gftt: GfttConfig = field(default_factory=GfttConfig)
    sgbm: SgbmConfig = field(
        default_factory=lambda: SgbmConfig(downscale=defaults.STEREO_DOWNSCALE, by_camera=True)
    )
    sigma: float | str = "auto"
    uncertainty: str = "exact-coarse"
    prior: str = "auto"
    robust: str = defaults.ROBUST
    temporal: bool = defaults.TEMPORAL
    process_noise: float | None = None
    carry: CarryConfig = field(
        default_factory=lambda: CarryConfig(
            frames=defaults.CARRY_FRAMES,
            gap=defaults.CARRY_GAP,
            age_std=defaults.CARRY_AGE_STD,
        )
    )
    calibrate: bool = True
    source: MeasurementSource = MeasurementSource.STEREO
    max_features: int = defaults.MAX_FEATURES
    measurements: str = "sparse"
    dense: DenseModel = field(default_factory=DenseModel)
    batch_size: int = 4
    lookahead: int = 4
    stereo_workers: int = 2
    estimate_workers: int | None = None
    opencv_threads: int | None = 1
    blas_threads: int | None = 1
    worker_niceness: int = 0
    keep_freed_memory: bool = True
    adapt: str = "auto"
    warmup_frames: int = 8
    builtin: str = "auto"
    edge_aware: bool = True
    near: NearConfig | None = field(default_factory=NearConfig)
    depth_std: bool = True

    def __post_init__(self) -> None:
        if self.adapt not in ("auto", "check", "off"):
            raise ValueError(f'Expected adapt "auto", "check" or "off", got {self.adapt!r}')
        if self.builtin not in ("auto", *BUILTIN_KINDS):
            raise ValueError(f'Expected builtin "auto", "street" or "indoor", got {self.builtin!r}')
        if self.warmup_frames < 1:
            raise ValueError(f"warmup_frames must be >= 1, got {self.warmup_frames}")
        if self.measurements not in ("sparse", "dense"):
            raise ValueError(
                f'Expected measurements "sparse" or "dense", got {self.measurements!r}'
            )
        if self.measurements == "dense" and self.source is not MeasurementSource.STEREO:
            raise ValueError("dense measurements come from the stereo pair, not a feature stream")
        if self.batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {self.batch_size}")
        if self.lookahead < 0:
            raise ValueError(f"lookahead must be >= 0, got {self.lookahead}")
        if self.stereo_workers < 1:
            raise ValueError(f"stereo_workers must be >= 1, got {self.stereo_workers}")
        if self.estimate_workers is not None and self.estimate_workers < 1:
            raise ValueError(f"estimate_workers must be >= 1, got {self.estimate_workers}")
        for name in ("opencv_threads", "blas_threads"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ValueError(f"{name} must be >= 1 or None, got {value}")


@dataclass(frozen=True)
class EstimateSettings:
    """The estimate's settings once the basis's fitted values are filled in.

    Attributes:
        sigma: noise std (px) or "evidence".
        local_prior: the local kernel of the hybrid prior, or None.
        process_noise: the temporal prior's process noise.
        std_scale: calibration factor on the reported std (1: the posterior std).
        scale_by_innovation: also scale each frame's std by its covariance scale.
        match_range: SGBM's largest disparity (px; sparse stereo mode), near which the std
            is widened (:func:`~pcainterp_stream.estimate.variance.widen_near_range`).
        robust_start: "trimmed" for a feature stream, else "plain" (``prior.RobustStart``).
    """

    sigma: float | str
    local_prior: LocalPrior | None
    process_noise: float
    std_scale: float = 1.0
    scale_by_innovation: bool = False
    match_range: float | None = None
    robust_start: str = "plain"

    def densify_options(self) -> dict[str, Any]:
        """Return the keyword arguments of :func:`~estimator.densify` these settings fill.

        The fields and ``zero_is_match`` (SGBM's 0 is a match), ``process_noise`` aside:
        for tools densifying as the command does.
        """
        fields = (f.name for f in dataclasses.fields(self) if f.name != "process_noise")
        return {name: getattr(self, name) for name in fields} | {"zero_is_match": True}


def resolve_settings(basis: Basis, config: ProcessorConfig) -> EstimateSettings:
    """Fill the "auto" settings of a configuration from the basis's fitted prior.

    Args:
        basis: the basis; ``basis.meta["prior"]`` holds what ``learn`` fitted (by default).
        config: the processor options.

    Returns:
        The :class:`EstimateSettings`.

    Raises:
        ValueError: ``prior="hybrid"`` with a basis that has no fitted local prior, or an
            unknown option value.
    """
    fitted = basis.meta.get("prior") if isinstance(basis.meta, dict) else None
    fitted = fitted if isinstance(fitted, dict) else {}
    if config.prior not in ("auto", "paper", "hybrid"):
        raise ValueError(f'Expected prior "auto", "paper" or "hybrid", got {config.prior!r}')
    local = None
    if config.prior != "paper" and fitted.get("local"):
        local = LocalPrior.from_meta(fitted["local"])
    if config.prior == "hybrid" and local is None:
        raise ValueError(
            "the basis has no fitted local prior (learned with --no-fit-prior, or the fit "
            "preferred the paper's prior); learn one with `pcainterp learn` (it fits the prior "
            "by default) or pass --prior paper"
        )
    sigma: float | str = config.sigma
    if sigma == "auto":
        key = "sigma" if local is not None else "plain_sigma"
        sigma = float(fitted[key]) if key in fitted else 2.0
    process_noise = config.process_noise
    if process_noise is None:
        process_noise = float(fitted.get("process_noise", 0.1))
    # a paper's-prior fit's scale too, not only a kernel fit's
    calibrated = fitting.fitted_std_scale(fitted, local is not None) if config.calibrate else None
    std_scale, scale_by_innovation = calibrated or (1.0, False)
    stereo = config.source is MeasurementSource.STEREO and config.measurements == "sparse"
    return EstimateSettings(
        sigma=sigma,
        local_prior=local,
        process_noise=process_noise,
        std_scale=std_scale,
        scale_by_innovation=scale_by_innovation,
        # the largest disparity SGBM returns, in the images' px
        match_range=config.sgbm.matched().band * config.sgbm.downscale if stereo else None,
        robust_start="trimmed" if config.source is MeasurementSource.FEATURES else "plain",
    )


class FrameProcessor:
    """Densify a stream of stereo pairs, pipelined; use as a context manager.

    ``submit`` takes frames in order and returns the frames finished so far, in order;
    ``finish`` returns the rest. ``process`` wraps both for a plain iterable. While open,
    the processor sets the process-wide OpenCV and BLAS thread counts of its configuration
    (stereo source only) and restores them in :meth:`close`.

    Args:
        basis: the PCA basis; None: the built-in one (:meth:`Basis.default`).
        config: processor options.
    """

    def __init__(self, basis: Basis | None = None, config: ProcessorConfig | None = None) -> None:
        self.config = config or ProcessorConfig()
        basis = self._builtin(basis)
        self.basis = basis
        std = prior_std_map(basis) if self.config.gftt.fill_placement == "prior_std" else None
        self.front_end = StereoFrontEnd(self.config.gftt, self.config.sgbm, prior_std=std)
        if self.config.keep_freed_memory:
            # the synthetic renderer's allocator tuning; same temporaries problem here
            from pcainterp_stream.allocator import keep_freed_memory, limit_arenas

            keep_freed_memory()
            # one arena per core: each keeps its threads' high-water mark (allocator.py)
            limit_arenas(os.cpu_count() or 2)
        stereo = self.config.source is MeasurementSource.STEREO
        self._executor = ThreadPoolExecutor(
            max_workers=self.config.stereo_workers if stereo else 1,
            thread_name_prefix="stereo",
            initializer=lower_priority,
            initargs=(self.config.worker_niceness,),
        )
        self._limits = ThreadLimits(
            self.config.opencv_threads if stereo else None,
            self.config.blas_threads if stereo else None,
        )
        self._pending: deque[Future[Measured]] = deque()
        self._ready: list[Measured] = []
        # the densification (the fit check, the solves, the images), sequential by nature
        # (temporal prior, carried points, adaptation), runs batch after batch in a thread
        # of its own, so the calling thread keeps reading and feeding the stereo workers
        self._lane = ThreadPoolExecutor(max_workers=1, thread_name_prefix="densify")
        # each batch's estimate once its measurements are final: several at once if stateless
        estimate_workers = self.config.estimate_workers or (
            1 if self.config.measurements == "dense" else 2
        )
        self._estimators = ThreadPoolExecutor(estimate_workers, thread_name_prefix="estimate")
        self._densifying: deque[tuple[int, Future[Future[list[DensifiedFrame]]]]] = deque()
        self._densified_any = False
        self.frames_done = 0
        self.settings = resolve_settings(basis, self.config)
        near, reach = self.config.near, self.settings.match_range  # None unless sparse stereo
        self.near = (
            None if near is None or reach is None else dataclasses.replace(near, match_range=reach)
        )
        noise = self.settings.process_noise
        self.temporal = TemporalPrior(process_noise=noise) if self.config.temporal else None
        self.dense = self.config.measurements == "dense"
        # --robust applies to the SGBM pixels of dense mode too
        self._dense_model = dataclasses.replace(
            self.config.dense, robust=Robust(self.config.robust)
        )
        self.carried = CarriedPoints(self.config.carry) if self.config.carry.frames else None
        self._previous_frame: StereoFrame | None = None
        self._submitted = 0
        self._releases = Releases()  # the heap's free pages given back now and then
        # a feature stream has no SGBM maps: checked by left-out points, never adapted;
        # dense mode is checked and chooses a built-in basis but learns none (docs/bases.md)
        kind = builtin_kind(basis)
        self.adaptation = Refitting(
            mode="check" if self.config.adapt == "auto" and not stereo else self.config.adapt,
            may_replace=kind is not None,
            may_learn=not self.dense,
            warmup_frames=self.config.warmup_frames,
            robust=self.config.robust,
            calibrate=self.config.calibrate,
            name=f"the built-in {kind} basis" if kind is not None else "the basis",
            alternatives=self._alternatives(kind),
            advisory=self._alternatives(kind, warn=True),
            own_above=OWN_ABOVE_STREET if kind == "street" else FITS_BELOW,
            options_of=lambda basis: resolve_settings(basis, self.config).densify_options(),
            cells=self.config.edge_aware and stereo and not self.dense,
        )
        self._camera: Camera | None = None  # the last frame submitted's
        self._changes = 0  # camera changes submitted: their maps are kept (Refitting)
        self._measuring_lock = threading.Lock()  # _changes and _measuring: submit, _measured_for
        self.adaptation.warn_std_scale(self.settings.std_scale)
        # decided here, not from the lane's state: the first batch is the check's frames
        self._warming = self.adaptation.warming
        self._measuring = (basis.grid_size, self.adaptation.wants_maps())  # see _measured_for
        self._lane.submit(_prepare, basis, self.config.uncertainty)

    def _builtin(self, basis: Basis | None) -> Basis:
        """Return the basis to start with: ``config.builtin``'s for None or a built-in one."""
        if basis is not None and builtin_kind(basis) is None:
            return basis
        if self.config.builtin != "auto":
            return builtin_basis(self.config.builtin)
        return Basis.default() if basis is None else basis

    def _alternatives(self, kind: str | None, warn: bool = False) -> list[Callable[[], Candidate]]:
        """Return loaders of the other built-in bases the check may choose, or (``warn``) name.

        Each loaded when first needed. ``warn``: those a basis the user chose (a file, or
        ``builtin`` "street"/"indoor") is compared with when it loses, for its warning only.
        """
        if (kind is None or self.config.builtin != "auto") != warn:
            return []
        return [
            functools.partial(_candidate, other, self.config)
            for other in BUILTIN_KINDS
            if other != kind and builtin_basis_installed(other)
        ]

    def __enter__(self) -> FrameProcessor:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        interrupted = exc_type is not None and (
            issubclass(exc_type, KeyboardInterrupt) or signalled()
        )
        self.close(wait=not interrupted)

    def close(self, *, wait: bool = True) -> None:
        """Stop the worker threads, dropping frames still in flight; restore thread counts.

        Args:
            wait: wait for the task each thread is running (an SGBM match, a batch, the
                one-off set-up with its imports) to end. An interrupted command does not:
                its clean-up must not wait seconds for a loaded machine to finish an import.
        """
        for future in self._pending:
            future.cancel()
        for _, densifying in self._densifying:
            densifying.cancel()
        self._pending.clear()
        self._ready.clear()
        self._densifying.clear()
        self._executor.shutdown(wait=wait, cancel_futures=True)
        self._lane.shutdown(wait=wait, cancel_futures=True)
        self._estimators.shutdown(wait=wait, cancel_futures=True)
        self._limits.restore()

    def _measure(
        self,
        frame: StereoFrame,
        features: SparseFeatures | None,
        previous: StereoFrame | None = None,
        check_frame: bool = True,
    ) -> Measured:
        disparity_map = raw_map = noise = sgbm_map = grid = held_out = holes = partition = None
        basis_grid, keep_maps = self._measuring  # one read: the densify thread may switch
        if self.config.source is MeasurementSource.FEATURES:
            cap = self.config.max_features
            pixels, disparities, counts = features_to_measurements(features, frame.camera, cap)
        else:
            measurements = self.front_end.measure(frame.left, frame.right)
            pixels, disparities = measurements.pixels, measurements.disparities
            counts = dict(measurements.counts)
            if self.near is not None:  # sparse stereo mode only (see __init__)
                pixels, disparities, noise, near = extend_near(
                    frame.left,
                    frame.right,
                    measurements.disparity_map,
                    pixels,
                    disparities,
                    self.near,
                )
                counts.update(near)
            if self.dense:
                disparity_map = measurements.disparity_map
                # the fusion's estimate-free part, in parallel, not in the densify thread
                holes = find_holes(disparity_map, measurements.weak, zero_is_match=True)
            elif self.config.edge_aware:  # an edge-aware local prior's cells, beside SGBM
                size = frame.camera.image_size
                partition = Seeding.along(measurements.disparity_map, pixels, size, basis_grid)
            if keep_maps:
                if check_frame or self.adaptation.adapted:
                    sgbm_map, grid = sgbm_maps(measurements.disparity_map, frame.camera)
                    if check_frame and grid is not None:
                        checked = lookups_only(pixels, disparities, noise)
                        clipped = clipped_pixels(frame.left, frame.right, sgbm_map)
                        held_out = adapt.HeldOut.of(sgbm_map, *checked, clipped)
                else:  # matched ahead while the check runs: needed only if it adapts
                    raw_map = measurements.disparity_map
        motion = None
        if previous is not None and previous.camera == frame.camera:
            # visual odometry beside SGBM in the worker: needs only this frame's points
            motion = estimate_motion(
                to_grey8(previous.left),
                to_grey8(frame.left),
                pixels,
                disparities,
                frame.camera,
                config=self.config.carry,
            )
        return Measured(
            frame,
            pixels,
            disparities,
            counts,
            motion,
            disparity_map,
            sgbm_map,
            grid,
            raw_map,
            held_out,
            holes,
            partition,
            noise,
        )

    def submit(
        self, frame: StereoFrame, features: SparseFeatures | None = None
    ) -> list[DensifiedFrame]:
        """Queue one frame; return the frames finished meanwhile, in stream order."""
        previous = self._previous_frame if self.carried is not None else None
        self._previous_frame = frame
        camera = (frame.camera.image_size, frame.camera.focal_baseline)
        if self._camera not in (None, camera):  # the choice is made again on its maps
            self._camera_changed()
        self._camera = camera
        check_frame = self._submitted < self.adaptation.warmup_frames
        self._submitted += 1
        if self.config.keep_freed_memory:
            self._releases.frame(self._submitted)
        self._pending.append(
            self._executor.submit(self._measure, frame, features, previous, check_frame)
        )
        while len(self._pending) > self.config.lookahead:
            self._ready.append(self._pending.popleft().result())
        wanted = self.adaptation.warmup_frames if self._warming else self.config.batch_size
        if len(self._ready) >= wanted:
            self._hand_over()
        return self._collect(keep=self._lane_frames())

    def finish(self) -> list[DensifiedFrame]:
        """Finish every queued frame and return them in stream order."""
        return [result for batch in self.finish_batches() for result in batch]

    def finish_batches(self) -> Iterator[list[DensifiedFrame]]:
        """Finish every queued frame, yielding the results batch by batch in stream order.

        The last frames are handed to the densify thread in batches as their matching
        ends, and each batch is yielded as soon as it is densified: the caller can pass it
        on while the next is densified, and never holds the images of all of them at once.
        """
        while self._pending:
            self._ready.append(self._pending.popleft().result())
            if not self._warming and len(self._ready) >= self.config.batch_size:
                self._hand_over()
            yield self._collect(keep=self._lane_frames())
        self._hand_over()
        while self._densifying:
            yield self._collect(keep=sum(count for count, _ in self._densifying) - 1)

    def _lane_frames(self) -> int:
        """Frames queued on the densify thread before ``submit`` waits for it.

        While the fit check runs (on the first, largest batch) the stereo workers go on
        matching up to :data:`CHECK_LEAD_BATCHES` batches more, so neither core waits for
        the check; after it, one batch waits while one is densified. Each frame held is
        its pair and measurements.
        """
        if self._densified_any:
            return 2 * self.config.batch_size
        return self.adaptation.warmup_frames + CHECK_LEAD_BATCHES * self.config.batch_size

    def _hand_over(self) -> None:
        """Queue the ready frames, as one batch, on the densify thread."""
        ready, self._ready = self._ready, []
        if not ready:
            return
        warming, self._warming = self._warming, False
        self._densifying.append(
            (len(ready), self._lane.submit(self._densify_batch, ready, warming))
        )

    def _collect(self, keep: int) -> list[DensifiedFrame]:
        """Return the densified batches that are done, in order.

        Waits (for the oldest batch) while more than ``keep`` frames are queued on the
        densify thread.
        """
        results: list[DensifiedFrame] = []
        queued = sum(count for count, _ in self._densifying)
        while self._densifying and (queued > keep or _done(self._densifying[0][1])):
            count, future = self._densifying.popleft()
            batch = future.result().result()
            results += batch
            self.frames_done += len(batch)
            queued -= count
            self._densified_any = True
        return results

    def _densify_batch(self, ready: list[Measured], warming: bool) -> Future[list[DensifiedFrame]]:
        """Densify one batch from the densify thread (after the fit check on the first).

        Returns the future of its frames: the estimate runs in the estimate pool when no
        state runs from frame to frame, else here.
        """
        if warming and self.adaptation.warming:
            ready = self._warm_up(ready)
        return self._densify_ready(ready)

    def _warm_up(self, ready: list[Measured]) -> list[Measured]:
        """Check the basis on the held-back frames; switch to the log's own when it wins."""
        frames = [adapt_frame(item) for item in ready]
        own = self.adaptation.warm_up(self.basis, frames, self.settings.densify_options())
        if own is not None:
            self._use(own)
        self._measured_for()
        # the warm-up maps are in the log's basis now (or not wanted): not added again
        return [
            item._replace(
                partition=cells_on_grid(item, self.basis.grid_size),
                sgbm_map=None,
                grid_map=None,
                raw_map=None,
                held_out=None,
            )
            for item in ready
        ]

    def _measured_for(self) -> None:
        """Set what the stereo workers measure a frame for: the basis's grid, and keep maps.

        One value, set after the densify thread's changes and read once per frame. The maps
        are kept while the basis may still switch, so a frame measured before a switch gets
        its cells again for the new basis (:func:`~.measured.cells_on_grid`).
        """
        with self._measuring_lock:  # else a change submitted meanwhile is lost (review 57d D6)
            wanted = self.adaptation.wants_maps() or self._changes > self.adaptation.changes
            self._measuring = (self.basis.grid_size, wanted)

    def _camera_changed(self) -> None:
        """Count a camera change submitted and keep its maps (the reader's thread)."""
        with self._measuring_lock:
            self._changes, self._measuring = self._changes + 1, (self._measuring[0], True)

    def _use(self, basis: Basis) -> None:
        """Densify from now on with ``basis`` (its fitted prior; the temporal prior restarts).

        The fit check may have tuned it (:meth:`~.adaptation.Adaptation.tuning`: the indoor
        basis with the street basis's kernel).
        """
        self.basis = basis
        settings = resolve_settings(basis, self.config)
        self.settings = dataclasses.replace(settings, **self.adaptation.tuning(basis))  # type: ignore[arg-type]
        self.adaptation.warn_std_scale(self.settings.std_scale, "this log's own basis")
        if self.temporal is not None:
            self.temporal = TemporalPrior(process_noise=self.settings.process_noise)

    def process(
        self, frames: Iterable[StereoFrame | tuple[StereoFrame, SparseFeatures | None]]
    ) -> Iterator[DensifiedFrame]:
        """Densify every frame of an iterable, yielding results in order."""
        for item in frames:
            if isinstance(item, StereoFrame):
                yield from self.submit(item)
            else:
                yield from self.submit(*item)
        for batch in self.finish_batches():
            yield from batch

    def _densify_ready(self, ready: list[Measured]) -> Future[list[DensifiedFrame]]:
        if not ready:
            return finished([])
        if not (self.adaptation.adapted or self.adaptation.deferred):
            # up to a camera change (then the choice is made again, in stream order); each
            # frame's camera is noted once: the changed frame's answer is handed on
            answers = enumerate(self.adaptation.new_camera(item.frame) for item in ready)
            cut, change = next(((at, a) for at, a in answers if a[0]), (len(ready), None))
            if self.temporal is not None:
                parts = [finished(self._estimate_all(self._measurements(ready[:cut])))]
            else:  # frames independent once carried: in the pool, in batch-size parts
                size = self.config.batch_size
                parts = [
                    self._estimators.submit(self._estimate_all, self._measurements(ready[at:end]))
                    for at, end in ((at, min(at + size, cut)) for at in range(0, cut, size))
                ]
            return gathered(parts + ([self._in_order(ready[cut:], change)] if change else []))
        return self._in_order(ready)

    def _in_order(
        self, ready: list[Measured], noted: tuple[bool, Basis | None] | None = None
    ) -> Future[list[DensifiedFrame]]:
        """Densify frame by frame with the adaptation (the log's own basis, a check again).

        ``noted``: the first frame's ``new_camera`` answer, when the caller asked for it.
        """
        # the log's own basis: a frame whose map completes a relearning is densified with the
        # basis of the frames before it, the next frames with the relearned one, so what a
        # frame gets never depends on how frames were batched
        results: list[DensifiedFrame] = []
        start = 0
        for index, item in enumerate(ready):
            _, basis = noted if index == 0 and noted else self.adaptation.new_camera(item.frame)
            if basis is not None:  # another camera: this frame on, another basis
                results += self._estimate_all(self._measurements(ready[start:index]))
                start = index
                self._use(basis)
            relearned = self.adaptation.update([adapt_frame(item)], self.basis)
            if relearned is not None:
                results += self._estimate_all(self._measurements(ready[start : index + 1]))
                start = index + 1
                self._use(relearned)
        results += self._estimate_all(self._measurements(ready[start:]))
        self._measured_for()
        return finished(results)

    def _measurements(self, ready: list[Measured]) -> list[_Estimate]:
        """Return each camera's group of ``ready`` with its final measurements (in order).

        The carried points move from frame to frame, so they are added here, in stream
        order, with the basis and settings of this moment; what is left of each group
        (:meth:`_estimate`) depends on nothing else.
        """
        jobs: list[_Estimate] = []
        # Frames of one camera are densified together; a camera change splits the batch.
        start = 0
        while start < len(ready):
            camera = ready[start].frame.camera
            stop = start
            while stop < len(ready) and ready[stop].frame.camera == camera:
                stop += 1
            group = ready[start:stop]
            pixels: list[npt.NDArray[Any]] = [item.pixels for item in group]
            disparities: list[npt.NDArray[Any]] = [item.disparities for item in group]
            noise_stds: list[npt.NDArray[Any] | None] | None = None
            if any(item.noise is not None for item in group):
                noise_stds = [item.noise for item in group]
            carried = [0] * len(group)
            if self.carried is not None:
                noise_stds = []
                for index, item in enumerate(group):  # in stream order: one motion each
                    resets = self.carried.resets
                    pixels[index], disparities[index], noise, carried[index] = self.carried.carry(
                        None, item.pixels, item.disparities, camera, motion=item.motion
                    )
                    if item.noise is not None:  # this frame's own points come first
                        noise[: item.noise.shape[0]] = item.noise
                    noise_stds.append(noise)
                    item.counts["carry_reset"] = self.carried.resets - resets
            self.adaptation.bind([item.frame for item in group], self.basis)
            jobs.append(
                _Estimate(
                    group,
                    pixels,
                    disparities,
                    noise_stds,
                    carried,
                    self.basis,
                    self.settings.densify_options(),
                    self.temporal,
                    [cells_on_grid(item, self.basis.grid_size) for item in group]
                    if self.config.edge_aware
                    else None,
                )
            )
            start = stop
        return jobs

    def _estimate_all(self, jobs: list[_Estimate]) -> list[DensifiedFrame]:
        return [result for job in jobs for result in self._estimate(job)]

    def _estimate(self, job: _Estimate) -> list[DensifiedFrame]:
        """Estimate one camera's group of frames from its final measurements."""
        camera = job.group[0].frame.camera
        estimates = densify_batch(
            job.basis,
            job.pixels,
            job.disparities,
            uncertainty=self.config.uncertainty,
            image_size=camera.image_size,
            focal_baseline=camera.focal_baseline,
            robust=self.config.robust,
            temporal=job.temporal,
            noise_stds=job.noise_stds,
            with_depth=not self.dense,  # dense mode converts the fused disparity
            with_depth_std=self.config.depth_std,
            partitions=job.partitions,
            **job.options,
            **(field_options(job.basis, self._dense_model) if self.dense else {}),
        )
        return [
            self._result(item, estimate, n_carried)
            for item, estimate, n_carried in zip(job.group, estimates, job.carried, strict=True)
        ]

    def _result(self, item: Measured, estimate: DensifyResult, n_carried: int) -> DensifiedFrame:
        counts = dict(item.counts)
        counts["carried"] = n_carried
        counts["dropped"] = int(estimate.n_dropped)
        counts["temporal_reset"] = int(estimate.temporal == "reset")
        counts["downweighted"] = int(estimate.n_downweighted)
        if item.disparity_map is not None:  # dense mode: the SGBM map, pixel by pixel
            sgbm_map, model = item.disparity_map, self._dense_model  # 0: a match (SGBM's range)
            estimate = fuse_dense(estimate, sgbm_map, model, item.holes, zero_is_match=True)
        unknown = _unknown(estimate.disparity.shape)
        # dense mode: SGBM's matched pixels measure too (a blank pair's map has none)
        mapped = item.holes is not None and item.holes.index.size < estimate.disparity.size
        if not (item.pixels.shape[0] or n_carried or estimate.temporal == "temporal" or mapped):
            estimate = estimate.unknown()  # not one measurement, own or carried: no estimate
        return DensifiedFrame(
            frame=item.frame,
            pixels=item.pixels,
            disparities=item.disparities,
            disparity=estimate.disparity,
            # "none" uncertainty has no std: written as NaN (unknown)
            disparity_std=_or(estimate.disparity_std, unknown),
            depth=_or(estimate.depth, unknown),
            depth_std=_or(estimate.depth_std, unknown),
            measurement_source="dense" if self.dense else self.config.source.value,
            counts=counts,
            min_disparity=estimate.min_disparity,
        )


class _Estimate(NamedTuple):
    """One camera's group of a batch with its final measurements, ready to estimate."""

    group: list[Measured]
    pixels: list[npt.NDArray[Any]]
    disparities: list[npt.NDArray[Any]]
    noise_stds: list[npt.NDArray[Any] | None] | None
    carried: list[int]
    basis: Basis
    options: dict[str, Any]
    temporal: TemporalPrior | None
    partitions: list[Seeding | None] | None = None  # searched in the pool, a batch at once


def _done(future: Future[Future[list[DensifiedFrame]]]) -> bool:
    """Tell whether a batch handed to the densify thread is estimated (both steps done)."""
    return future.done() and (future.exception() is not None or future.result().done())


def _candidate(kind: str, config: ProcessorConfig) -> Candidate:
    """Load the built-in basis ``kind`` with its settings under ``config``."""
    basis = builtin_basis(kind)
    settings = resolve_settings(basis, config).densify_options()
    return Candidate(f"the built-in {kind} basis", basis, settings)


Float32 = npt.NDArray[np.float32]


@functools.lru_cache(maxsize=4)
def _unknown(shape: tuple[int, ...]) -> Float32:
    """Return a shared read-only all-NaN float32 image (the std when uncertainty is "none")."""
    unknown = np.full(shape, np.nan, dtype=np.float32)
    unknown.flags.writeable = False
    return unknown


def _or(array: Float32 | None, default: Float32) -> Float32:
    return default if array is None else array
