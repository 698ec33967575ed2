"""The ``learn`` job: a PCA basis from the depth or SGBM maps of logs, and the fitted prior."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import itertools
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import BasisError, PcaInterpError
from pcainterp_stream.estimate.adapt import ROUGH_KERNEL
from pcainterp_stream.estimate.basis import (
    BUILT_IN_INDOOR,
    BUILTIN_LABELS,
    Basis,
    grid_size_for,
)
from pcainterp_stream.estimate.finetune import (
    BuiltinFit,
    builtin_fits,
    camera_mismatch,
    disparity_scale,
    finetune_basis,
)
from pcainterp_stream.estimate.learning import DEFAULT_BOX_SIZE, learn_basis, preprocess_disparity
from pcainterp_stream.estimate.prior import LocalPrior
from pcainterp_stream.estimate.solve import DEFAULT_SIGMA
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.frontend.stereo import GfttConfig, SgbmConfig
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.output_paths import make_partial_file, saved_elsewhere, write_advice
from pcainterp_stream.pipeline.blas_threads import restoring_blas_threads
from pcainterp_stream.pipeline.common import (
    _bar,
    _check_output_folder,
    _echo,
    _expected_frames,
    count_readable,
)
from pcainterp_stream.pipeline.held_out import FIT_SEQUENCE_FRAMES, choose_kernel

# re-exported: the cluster's learner (pipeline/distributed.py) imports them from here
from pcainterp_stream.pipeline.held_out import HeldOutFrame as HeldOutFrame
from pcainterp_stream.pipeline.held_out import measure_held_out as measure_held_out
from pcainterp_stream.pipeline.learn_check import (
    BuiltinScore,
    by_fit,
    compare_learned,
    measure,
    score_builtins,
)
from pcainterp_stream.pipeline.learn_maps import (
    MapSource,
    check_fit_logs,
    check_logs_once,
    close_sizes,
    depth_maps,
    one_camera,
    resized_to,
    sgbm_maps,
)
from pcainterp_stream.pipeline.learn_maps import log_pairing as log_pairing

# re-exported: the cluster's learner imports them from here
from pcainterp_stream.pipeline.map_checks import BLANK_MAPS as BLANK_MAPS
from pcainterp_stream.pipeline.map_checks import FLAT_FIX as FLAT_FIX
from pcainterp_stream.pipeline.map_checks import FLAT_MAPS as FLAT_MAPS
from pcainterp_stream.pipeline.map_checks import ViewCount, far_cut_counts, warn_far_cut
from pcainterp_stream.pipeline.map_checks import check_flat as check_flat
from pcainterp_stream.pipeline.map_checks import is_flat as is_flat
from pcainterp_stream.pipeline.map_checks import note_blank as note_blank
from pcainterp_stream.pipeline.map_checks import shows_surface as shows_surface
from pcainterp_stream.pipeline.processor import ProcessorConfig


@dataclass(frozen=True)
class LearnOptions:
    """Options of ``pcainterp learn``.

    Attributes:
        n_components: components to keep (the most, with ``variance``).
        variance: keep the fewest components reaching this explained-variance ratio.
        grid_scale: basis grid pixels per image pixel.
        depth_topic: learn from this depth topic (32FC1 m, 16UC1 mm, compressedDepth)
            instead of SGBM maps.
        every: use every N-th frame.
        sgbm: matcher options for SGBM maps (and the fitting frames' lookups).
        fit_prior: fit the hybrid prior, the noise level and the temporal process noise by
            the evidence on frames the basis does not see (``fitting.py``); the default.
            False learns the paper's model (basis and eigenvalues only).
        holdout: with ``fit_prior`` and no ``fit_logs``: the share of each log's frames,
            at its end, kept out of the basis for the fit.
        fit_logs: fit on these logs (all frames) instead of a held-out share.
        gftt: corner options of the fitting frames' measurements.
        with_synthetic: fine-tune instead of learning from scratch: merge the maps into
            ``prior_basis`` counted as this many maps (``estimate/finetune.py``); the
            result lives on that basis's grid and camera, and the fit keeps its local
            kernel. ``"auto"`` (the command line's default): as :func:`plan_synthetic`
            decides (:data:`AUTO_PRIOR_MAPS` when the logs give fewer than
            :data:`AUTO_MAX_MAPS` maps of a camera like the basis's). None or 0: learn
            from the maps alone (None is this API's default).
        prior_basis: the basis fine-tuned with ``with_synthetic``; None: the built-in one.
    """

    n_components: int = 500
    variance: float | None = None
    grid_scale: float = 0.25
    depth_topic: str | None = None
    every: int = 1
    sgbm: SgbmConfig = dataclasses.field(default_factory=SgbmConfig)
    fit_prior: bool = True
    holdout: float = 0.2
    fit_logs: tuple[Path, ...] = ()
    gftt: GfttConfig = dataclasses.field(default_factory=GfttConfig)
    with_synthetic: int | Literal["auto"] | None = None
    prior_basis: Basis | None = None


AUTO = "auto"
"""``LearnOptions.with_synthetic`` (``learn --with-synthetic auto``): decide by the logs."""

AUTO_MAX_MAPS = 1000
"""``auto`` fine-tunes when the logs give fewer training maps than this: measured better at
40 and 86 real maps and 240 and 800 synthetic ones (docs/bases.md, "How `learn`'s default
was chosen"); from AUTO_PRIOR_MAPS maps on, the user's maps carry most of the weight."""

AUTO_PRIOR_MAPS = 1000
"""The maps ``auto`` counts the built-in basis for: of 250, 1000, 4000 and 6000, the best
mean over the two real KITTI clips, each learned and the other densified (docs/bases.md,
"How `learn`'s default was chosen")."""


def learn_pairing(
    logs: list[Path], pairing: PairingConfig, depth_topic: str | None = None
) -> PairingConfig:
    r"""Return the pairing ``learn`` reads the logs with, the pair of each found and printed.

    Each log's pair is found in it (:func:`log_pairing`), before any work, so a log without
    one is refused first. When every log has the same topics that pairing is returned; when
    they differ, ``pairing`` itself, and each log is read with its own
    (:func:`log_pairing` again where it is opened).

    Args:
        logs: the logs to read (to learn from and to fit on).
        pairing: the pairing the options ask for (named image topics are kept, each
            with its own camera info unless an info topic was named).
        depth_topic: the depth topic learned from instead of SGBM maps, if any.

    Raises:
        TopicNotFoundError: no stereo pair in a log (and no ``depth_topic``), or two
            equally good ones.
    """
    found: list[PairingConfig] = []
    for log in dict.fromkeys(logs):  # a log given twice is read once
        with open_log(log) as reader:
            echo = _echo if len(logs) == 1 else _prefixed(f"{log.name}: ")
            found.append(log_pairing(reader, pairing, depth_topic, echo))
    topics = {(p.left_topic, p.right_topic, p.left_info_topic, p.right_info_topic) for p in found}
    return found[0] if len(topics) == 1 else pairing


def _prefixed(prefix: str) -> Callable[[str], None]:
    """Return an echo that starts each line with ``prefix`` (the log's name)."""
    return lambda line: _echo(prefix + line)


def _source_topic(log: Path, options: LearnOptions, pairing: PairingConfig) -> str:
    """Return the topic a log's maps are counted on: the depth topic or its left images."""
    return _source_topics(log, options, pairing)[0]


def _source_topics(
    log: Path, options: LearnOptions, pairing: PairingConfig
) -> tuple[str, list[str]]:
    """Return the topic a log's maps are counted on, and every topic they are read from."""
    if options.depth_topic:
        return options.depth_topic, [pairing.left_info_topic, pairing.right_info_topic]
    if pairing.discover:
        with contextlib.suppress(PcaInterpError), open_log(log) as reader:
            pairing = log_pairing(reader, pairing)
    # unreadable, or no pair: said when the log is read
    return pairing.left_topic, list(pairing.required_topics())


def source_meta(logs: list[Path], options: LearnOptions) -> dict[str, Any]:
    """``meta["source"]`` of a learned basis: the logs, what maps, SGBM settings, ``every``."""
    sgbm = dataclasses.asdict(options.sgbm)
    sgbm["mode"] = options.sgbm.mode.name
    return {
        "logs": [str(log) for log in logs],
        "maps": f"depth topic {options.depth_topic}" if options.depth_topic else "SGBM",
        "sgbm": None if options.depth_topic else sgbm,
        "every": options.every,
    }


@dataclass(frozen=True)
class SyntheticPlan:
    """What ``learn`` does with the built-in basis's synthetic maps.

    Attributes:
        prior_basis: the basis to fine-tune, or None to learn from the maps alone.
        n_prior: the maps it counts for (0 with no prior basis).
        rule: why, as ``meta["source"]["with_synthetic_rule"]`` records it.
        note: the line printed for the user, or None.
        label: which built-in basis ``prior_basis`` is (``built-in``, ``built-in-indoor``),
            None: none or one given by the caller.
    """

    prior_basis: Basis | None
    n_prior: int
    rule: str
    note: str | None = None
    label: str | None = None


BUILTIN_WORLDS = {
    "street": ("KITTI-like", "synthetic streets"),
    "indoor": ("VI-sensor-like", "synthetic rooms, corridors and halls"),
}
"""Each built-in basis's camera and world, as ``learn``'s notes name them."""


def _camera_of(fit: BuiltinFit) -> str:
    """Name a built-in basis's camera: "the indoor basis's VI-sensor-like 752x480"."""
    height, width = fit.basis.image_size
    return f"the {fit.kind} basis's {BUILTIN_WORLDS[fit.kind][0]} {width}x{height}"


def plan_synthetic(
    options: LearnOptions,
    n_maps: int | None,
    camera: tuple[tuple[int, int], float],
    scores: Sequence[BuiltinScore] = (),
) -> SyntheticPlan:
    """Decide whether ``learn`` fine-tunes a built-in basis (``--with-synthetic``), and which.

    The built-in basis whose camera is like the logs' (:func:`finetune.builtin_fits`: the
    street basis for a KITTI-like camera, the indoor one for a 752x480 VI-sensor-like one)
    or, with ``--with-synthetic N`` and no such one, the closest; ``options.prior_basis``
    when given.

    Args:
        options: the learning options (``with_synthetic``, ``prior_basis``).
        n_maps: the training maps the logs give (after the held-out share), None: unknown.
        camera: ((height, width) px, f*b px*m) of the logs' camera.
        scores: the built-in bases scored on the held-out frames, the best first
            (:func:`learn_check.score_builtins`): ``auto`` merges the one that fits them
            best, also into a camera like no built-in basis's when it beats linear
            interpolation there (:func:`learn_check.by_fit`; bug hunt 16D F2, F7).

    Returns:
        The :class:`SyntheticPlan`. ``auto`` fine-tunes with :data:`AUTO_PRIOR_MAPS` when
        ``n_maps`` < :data:`AUTO_MAX_MAPS` and :func:`camera_mismatch` finds nothing; it
        learns from the maps alone, with a note, when the camera is like no built-in
        basis's, ``grid_scale`` asks for another grid than the basis's, or no built-in
        basis is installed.
    """
    requested = options.with_synthetic
    if requested is None or requested == 0:
        return SyntheticPlan(None, 0, "off: --with-synthetic 0" if requested == 0 else "off")
    image_size, focal_baseline = camera
    count = "an unknown number of" if n_maps is None else str(n_maps)
    if requested == AUTO and n_maps is not None and n_maps >= AUTO_MAX_MAPS:
        return SyntheticPlan(None, 0, f"auto: {n_maps} maps, not fewer than {AUTO_MAX_MAPS}")
    if options.prior_basis is not None:
        mismatch = camera_mismatch(options.prior_basis, image_size, focal_baseline)
        fits = [BuiltinFit("given", options.prior_basis, mismatch, 0.0)]
    elif requested != AUTO:
        fits = builtin_fits(image_size, focal_baseline)  # none installed: the error says so
    else:
        try:
            fits = builtin_fits(image_size, focal_baseline)
        except BasisError as err:
            rule = f"auto: the built-in basis is not installed ({err})"
            note = f"note: {rule}; learning from your {count} maps alone"
            return SyntheticPlan(None, 0, rule, note)
    chosen = fits[0]
    given = options.prior_basis is not None
    why = ""
    if requested == AUTO and not given:
        better, why = by_fit(chosen.kind, chosen.mismatch is not None, scores)
        if better is not None:  # chosen by fit on the held-out frames: merged, whatever the camera
            fit = next(fit for fit in fits if fit.kind == better.kind)
            chosen = dataclasses.replace(fit, mismatch=None)
    label = None if given else BUILTIN_LABELS[chosen.kind]
    name = "the basis" if given else f"the built-in {chosen.kind} basis"
    if requested != AUTO:
        rule = f"--with-synthetic {requested}"
        if given:
            return SyntheticPlan(chosen.basis, int(requested), rule)
        unlike = "" if chosen.mismatch is None else f", the closest ({chosen.mismatch})"
        note = (
            f"note: merging your {count} maps with {name}'s {BUILTIN_WORLDS[chosen.kind][1]} "
            f"(counted as {requested} maps{unlike})"
        )
        return SyntheticPlan(chosen.basis, int(requested), rule, note, label)
    if chosen.mismatch is not None:
        rule = f"auto: the camera differs from {name}'s ({chosen.mismatch})"
        unlike = (
            f"your camera is not like the given basis's ({chosen.mismatch})"
            if given
            else "your camera is like none of theirs: "
            + "; ".join(f"{_camera_of(fit)} ({fit.mismatch})" for fit in fits)
        )
        return SyntheticPlan(
            None,
            0,
            rule,
            f"note: not merging {'the basis' if given else 'the built-in bases'}' synthetic "
            f"maps into your {count} maps: {unlike}; --with-synthetic N merges them anyway",
        )
    prior_basis = chosen.basis
    preprocessing = prior_basis.meta.get("preprocessing", {})
    grid_scale = float(
        preprocessing.get("grid_scale", prior_basis.grid_size[1] / prior_basis.image_size[1])
    )
    if not np.isclose(options.grid_scale, grid_scale, rtol=0.01):
        rule = (
            f"auto: --grid-scale {options.grid_scale:g} asks for another grid than "
            f"{name}'s {grid_scale:g}"
        )
        return SyntheticPlan(None, 0, rule, f"note: {rule}; learning from your {count} maps alone")
    kind = "" if given else f" {chosen.kind}"
    rule = f"auto: {count} maps, fewer than {AUTO_MAX_MAPS}, and a camera like the{kind} basis's"
    if why:
        rule = f"auto: {count} maps, fewer than {AUTO_MAX_MAPS}, and {why}"
    world = "" if given else f"{BUILTIN_WORLDS[chosen.kind][1]}, "
    if not options.fit_prior:  # learn_basis fits no prior: no kernel to keep
        kernel = ", keeping no local kernel (--no-fit-prior: no fitted prior)"
    elif kept_kernel(prior_basis) is None:
        kernel = ""
    else:
        kernel = " and keeping its local kernel"
    return SyntheticPlan(
        prior_basis,
        AUTO_PRIOR_MAPS,
        rule,
        f"note: {count} maps of your own are few (< {AUTO_MAX_MAPS}): merging them with "
        f"{name}'s synthetic statistics ({world}counted as {AUTO_PRIOR_MAPS} maps)"
        f"{kernel}{f' ({why})' if why else ''}; --with-synthetic 0 learns from your maps alone",
        label,
    )


def kept_kernel(basis: Basis) -> LocalPrior | None:
    """Return the local kernel of a basis's fitted prior (kept when fine-tuning), or None."""
    fitted = basis.meta.get("prior")
    local = fitted.get("local") if isinstance(fitted, dict) else None
    return LocalPrior.from_meta(local) if isinstance(local, dict) else None


def expected_maps(logs: list[Path], options: LearnOptions, pairing: PairingConfig) -> int | None:
    """Return the maps the logs' summaries promise (every N-th frame); None: unknown."""
    totals = [
        _expected_frames(log, _source_topic(log, options, pairing), options.every) for log in logs
    ]
    return None if None in totals else sum(total for total in totals if total is not None)


@dataclass(frozen=True)
class GridTarget:
    """Where ``learn`` puts every map before its statistics are taken.

    Attributes:
        grid_size: (gh, gw) of the basis grid.
        disparity_scale: factor on the maps' disparities (the built-in basis's f*b over the
            logs' when fine-tuning, else 1).
        box_size: side of the box filter (px).
        finetune: the maps go into a fine-tuned basis (invalid pixels are made NaN before
            the scale, as :func:`~pcainterp_stream.estimate.finetune.finetune_basis` does).
        focal_baseline: f*b (px*m) every map is put in as it is read, before
            ``disparity_scale`` (the first log's: :func:`learn_maps.scaled_to`); None: each
            chunk's first map's.
        image_size: (H, W) every map is resampled to when its size is close
            (:func:`learn_maps.resized_to`; the first log's); None: each chunk's first map's.
    """

    grid_size: tuple[int, int]
    disparity_scale: float = 1.0
    box_size: int = DEFAULT_BOX_SIZE
    finetune: bool = False
    focal_baseline: float | None = None
    image_size: tuple[int, int] | None = None


def to_grid(disparity: npt.NDArray[np.float32], target: GridTarget) -> npt.NDArray[np.float32]:
    """Preprocess one map onto the grid as the local learner does; (s,) float32 (px).

    Raises:
        ValueError: the map has no valid pixel.
    """
    if target.finetune:
        with np.errstate(invalid="ignore"):
            valid = np.isfinite(disparity) & (disparity >= 0.0)
        scaled = np.where(valid, disparity * np.float32(target.disparity_scale), np.nan)
        grid = preprocess_disparity(
            scaled.astype(np.float32), target.grid_size, box_size=target.box_size
        )
    else:
        grid = preprocess_disparity(disparity, target.grid_size, box_size=target.box_size)
    return grid.reshape(-1)


@dataclass(frozen=True)
class MapPlan:
    """Which maps ``learn`` takes from which log and what it does with them.

    The same on one machine and on a cluster: only the way the maps' statistics are
    gathered differs (:func:`learn`).

    Attributes:
        logs: the input logs, as given.
        counts: maps each log promises (every N-th frame), None: unknown.
        kept: maps of each log that go into the basis (the rest is held out for the
            prior's fit), None: all.
        total: maps the basis is learned from, None: unknown.
        camera: image size and f*b of the first log's camera: every map is put in its f*b.
        synthetic: what happens with the built-in basis's statistics.
        target: the grid and the units of the maps.
        measured: the held-out frames of each source (:meth:`held_out`), measured while
            planning; None: not measured yet (or no prior is fitted).
        scores: the built-in bases scored on them (:func:`learn_check.score_builtins`).
    """

    logs: tuple[Path, ...]
    counts: tuple[int | None, ...]
    kept: tuple[int | None, ...]
    total: int | None
    camera: MapSource
    synthetic: SyntheticPlan
    target: GridTarget
    measured: tuple[list[HeldOutFrame], ...] | None = None
    scores: tuple[BuiltinScore, ...] = ()

    def held_out(self, options: LearnOptions) -> list[tuple[Path, int]]:
        """Return (log, first pair index) of the frames the prior is fitted on."""
        return held_out_sources(self.logs, self.kept, options)


def held_out_sources(
    logs: Sequence[Path], kept: Sequence[int | None], options: LearnOptions
) -> list[tuple[Path, int]]:
    """Return (log, first pair index) of the frames the prior is fitted on."""
    if options.fit_logs:
        return [(log, 0) for log in options.fit_logs]
    return [(log, (keep or 0) * options.every) for log, keep in zip(logs, kept, strict=True)]


def _smaller_every(options: LearnOptions) -> str:
    """Return "a smaller --every (--every 50 keeps 1 frame in 50), " when it would help."""
    every = options.every
    return f"a smaller --every (--every {every} keeps 1 frame in {every}), " if every > 1 else ""


def _one_pair(logs: list[Path], options: LearnOptions) -> str:
    """Return "fish.mcap has one stereo pair, whose map the basis learns" (or the logs)."""
    named = logs[0].name if len(logs) == 1 else f"each of the {len(logs)} logs"
    kept = f" kept (--every {options.every})" if options.every > 1 else ""
    return f"{named} has one stereo pair{kept}, whose map the basis learns"


def plan_maps(
    logs: list[Path],
    output: Path,
    options: LearnOptions,
    pairing: PairingConfig,
    cluster: Cluster | None = None,
    *,
    score: bool = True,
) -> MapPlan:
    """Check the options and decide what ``learn`` does with the logs' maps.

    Counts the maps (from the logs' summaries, else by reading them), holds the last
    ``options.holdout`` share of each log out for the prior's fit, reads the camera of each
    log's first frame (and of each ``fit_logs`` log) and decides about the built-in basis
    (:func:`plan_synthetic`, its note printed). The maps of a log whose camera's f*b differs
    from the first log's are scaled to it (:func:`learn_maps.one_camera` says so). With a
    fitted prior (and ``score``), the held-out frames are measured here (on ``cluster`` when
    given) and the built-in bases scored on them, for the merge's choice and the learned
    basis's comparison (:mod:`~.learn_check`).

    Raises:
        PcaInterpError: bad options, an output that is an input or in a missing folder, a
            log given twice (:func:`learn_maps.check_logs_once`), no map in the logs, logs
            of two image sizes, or ``fit_logs`` of another size.
    """
    if options.every < 1:
        raise PcaInterpError(f"--every must be at least 1, got {options.every}")
    requested = options.with_synthetic
    if (isinstance(requested, str) and requested != AUTO) or (
        isinstance(requested, int) and (requested < 0 or requested == 1)
    ):
        raise PcaInterpError(
            f"--with-synthetic must be at least 2 maps (0: off; or auto), got {requested}"
        )
    for log in logs:
        if log.resolve() == output.resolve():
            raise PcaInterpError(f"output {output} is one of the input logs; choose another -o")
    check_logs_once(logs)
    _check_output_folder(output)
    topics = [_source_topics(log, options, pairing) for log in logs]
    counts: list[int | None] = [
        count_readable(log, topic, options.every, read)
        for log, (topic, read) in zip(logs, topics, strict=True)
    ]
    total = None if None in counts else sum(t for t in counts if t is not None)
    holding_out = options.fit_prior and not options.fit_logs
    if holding_out and not 0 < options.holdout < 1:
        raise PcaInterpError(f"--holdout must be in (0, 1), got {options.holdout}")
    kept: list[int | None] = [None] * len(logs)
    if holding_out:
        for index, count in enumerate(counts):
            assert count is not None  # read
            kept[index] = max(1, int(count * (1.0 - options.holdout)))
        total = sum(k for k in kept if k is not None)
        if 1 in counts and all(count is not None and count <= 1 for count in counts):
            # one pair each: its map is learned, none is left to hold out (bug hunt 15C F5)
            every = _smaller_every(options)
            raise PcaInterpError(
                f"no held-out stereo pair to fit the prior on: {_one_pair(logs, options)}; "
                + (f"use more frames, {every}" if every else "use more frames, ")
                + "--fit-logs LOG (no --holdout leaves both a map and a pair to fit on), or "
                "--no-fit-prior (a basis with no fitted prior)"
            )
    camera = one_camera(logs, options, pairing)
    if holding_out and camera.single is not None:
        raise PcaInterpError(
            f"the prior is fitted on held-out stereo pairs, and {logs[0].name} has one camera "
            f"({camera.single}): pass --no-fit-prior, or --fit-logs STEREO_LOG of this camera"
        )
    if options.fit_prior and options.fit_logs:
        check_fit_logs(options.fit_logs, logs, options, pairing)
    measured: tuple[list[HeldOutFrame], ...] | None = None
    scores: tuple[BuiltinScore, ...] = ()
    if options.fit_prior and score:
        with _bar(None, "measure held-out frames") as bar:
            held = held_out_sources(logs, kept, options)
            measured = tuple(measure(held, options, pairing, lambda: bar.update(1), cluster))
        robust = ProcessorConfig().robust
        scores = tuple(score_builtins([f for fs in measured for f in fs], robust))
    plan = plan_synthetic(options, total, (camera.image_size, camera.focal_baseline), scores)
    if plan.note is not None:
        _echo(plan.note)
    if plan.prior_basis is None:
        target = GridTarget(
            grid_size_for(camera.image_size, options.grid_scale),
            focal_baseline=camera.focal_baseline,
            image_size=camera.image_size,
        )
    else:
        preprocessing = plan.prior_basis.meta.get("preprocessing", {})
        target = GridTarget(
            plan.prior_basis.grid_size,
            disparity_scale(plan.prior_basis, camera.focal_baseline),
            int(preprocessing.get("box_size", DEFAULT_BOX_SIZE)),
            finetune=True,
            focal_baseline=camera.focal_baseline,
            image_size=camera.image_size,
        )
    return MapPlan(
        tuple(logs), tuple(counts), tuple(kept), total, camera, plan, target, measured, scores
    )


class Cluster(Protocol):
    """Where ``learn`` gathers the maps' statistics instead of this process.

    A Dask cluster: :class:`pcainterp_stream.pipeline.distributed.DaskLearner`.
    """

    def learn_basis(
        self, plan: MapPlan, options: LearnOptions, pairing: PairingConfig, meta: dict[str, Any]
    ) -> Basis:
        """Return the basis of a plan's maps (not saved), ``meta`` in its ``meta``."""
        ...

    def measure_held_out(
        self, sources: list[tuple[Path, int]], options: LearnOptions, pairing: PairingConfig
    ) -> list[list[HeldOutFrame]]:
        """Return :func:`measure_held_out` of each (log, first pair index), in order."""
        ...


@restoring_blas_threads
def learn(
    logs: list[Path],
    output: Path,
    options: LearnOptions,
    pairing: PairingConfig,
    *,
    cluster: Cluster | None = None,
) -> Basis:
    """Learn a basis from the disparity maps of logs (``pcainterp learn``).

    The basis from the maps alone, or, as :func:`plan_synthetic` decides from
    ``options.with_synthetic``, the built-in basis (``options.prior_basis``) fine-tuned
    with them; then, by default, the prior fitted on the held-out share of each log (or on
    ``options.fit_logs``), a fine-tuned basis keeping the built-in basis's local kernel.
    The basis is saved to ``output`` and returned.

    With a ``cluster`` (``learn --workers/--scheduler``:
    :func:`pcainterp_stream.pipeline.distributed.learn_distributed`) the same plan
    (:func:`plan_maps`: the same maps, the same hold-out, the same merge with the built-in
    basis) runs there: the workers match and summarise chunks of maps and measure the
    held-out frames. While the maps fit :data:`ONE_STEP_BYTES` (:func:`fits_one_step`) the
    summaries are exact and merged in one step: the result is this function's without a
    cluster up to float rounding, the same file every run; beyond, they are truncated and
    tree-merged in chunk order (a sketch keeps the leading eigenpairs, the last ones near l
    less exactly: docs/estimator.md, "Exact on a cluster").

    Args:
        logs: the input logs (on a cluster: paths the workers can read).
        output: the basis file (.npz).
        options: the learning options.
        pairing: the topics of the stereo pairs.
        cluster: where to gather the maps' statistics; None: this process.
    """
    plan = plan_maps(logs, output, options, pairing, cluster)
    source = source_meta(logs, options)
    source["with_synthetic"] = plan.synthetic.n_prior
    source["with_synthetic_rule"] = plan.synthetic.rule
    if plan.synthetic.label is not None:
        source["with_synthetic_basis"] = plan.synthetic.label
    if plan.camera.decisions:  # what densify prints too (--rectify)
        source["rectify"] = {"option": pairing.rectify, "decisions": dict(plan.camera.decisions)}
    meta: dict[str, Any] = {"source": source}
    try:
        if cluster is None:
            basis = _learn_here(plan, options, pairing, meta)
        else:
            basis = cluster.learn_basis(plan, options, pairing, meta)
    except ValueError as err:
        raise PcaInterpError(f"cannot learn a basis from {len(logs)} log(s): {err}") from err
    if options.fit_prior:
        # a fine-tuned basis keeps the built-in basis's kernel (chosen on real streets; the
        # evidence of a few held-out frames picks a worse one: docs/bases.md); the indoor
        # one's, or densify's rougher one, whichever errs less on the held-out frames
        prior_basis = plan.synthetic.prior_basis
        local = None if prior_basis is None else kept_kernel(prior_basis)
        rougher = None
        if plan.synthetic.label == BUILT_IN_INDOOR and local not in (None, ROUGH_KERNEL):
            rougher = ROUGH_KERNEL
        sources = plan.held_out(options)
        measured = None if plan.measured is None else list(plan.measured)
        fitted = fit_prior(
            basis, sources, options, pairing, local, rougher, cluster=cluster, measured=measured
        )
        if local is not None and "local_kept_from" not in fitted:
            fitted["local_kept_from"] = "the fine-tuned basis (learn --with-synthetic)"
        if measured is not None:  # never worse than a built-in basis silently (16D F7)
            frames = [frame for log_frames in measured for frame in log_frames]
            robust = ProcessorConfig().robust
            record, warning = compare_learned(basis, frames, fitted, plan.scores, output, robust)
            if record:
                fitted["held_out_check"] = record
            if warning is not None:
                _echo(warning)
        basis = dataclasses.replace(basis, meta={**basis.meta, "prior": fitted})
    try:  # owner-named temporary within the name limit (bug hunt 9C F3, F4)
        basis.save(output, partial_file=make_partial_file)
    except BasisError as err:  # the fix; on a full disk the basis is kept in TMPDIR (9C F8)
        cause = err.__cause__
        advice = f"; {write_advice(cause)}" if isinstance(cause, OSError) else ""
        raise BasisError(f"{err}{advice}{saved_elsewhere(output, err, basis.save)}") from err
    return basis


ONE_STEP_BYTES = 1 << 30
"""A fine-tune merges the maps in one step while they (float32, with the float64 copy of the
merge) take at most this many bytes on the grid: 1,000 maps on the 1/4 KITTI grid take 0.35 GB."""


def fits_one_step(plan: MapPlan) -> bool:
    """Whether a plan's maps fit :data:`ONE_STEP_BYTES` on its grid (a known number of them).

    Then a fine-tune here, and any learning on a cluster, merges them in one exact step.
    """
    n_pixels = plan.target.grid_size[0] * plan.target.grid_size[1]
    return plan.total is not None and plan.total * n_pixels * 12 <= ONE_STEP_BYTES


def _learn_here(
    plan: MapPlan,
    options: LearnOptions,
    pairing: PairingConfig,
    meta: dict[str, Any],
) -> Basis:
    """Learn the basis of a plan in this process, streaming the maps."""
    image_size, fb = plan.camera.image_size, plan.camera.focal_baseline
    info: list[MapSource] = []
    first: list[Path] = []  # the log of the first map
    blank = used = flat = far = valid = 0
    cut = DEFAULT_SIGMA / plan.target.disparity_scale  # the far cut with no fitted prior
    views = ViewCount()

    def maps() -> Iterator[npt.NDArray[np.float32]]:
        nonlocal blank, used, flat, far, valid
        for log, keep in zip(plan.logs, plan.kept, strict=True):
            if options.depth_topic:
                produced = depth_maps(log, options, pairing, info, focal_baseline=fb)
            else:
                see = functools.partial(views.see, log)
                produced = sgbm_maps(log, options, pairing, info, focal_baseline=fb, seen=see)
            for disparity in itertools.islice(produced, keep):
                if not first:
                    first.append(log)
                if disparity.shape != image_size and close_sizes(disparity.shape, image_size):
                    disparity = resized_to(disparity, image_size)  # one_camera's note said so
                if disparity.shape != image_size:
                    whose = "its first maps" if log == first[0] else f"{first[0].name}'s"
                    raise PcaInterpError(
                        f"{log} gives a {disparity.shape[1]}x{disparity.shape[0]} map (its "
                        f"images, or their rectified box) but {whose} are "
                        f"{image_size[1]}x{image_size[0]}; learn one basis per camera"
                    )
                if not shows_surface(disparity):
                    blank += 1
                    continue
                used += 1
                if not options.depth_topic and is_flat(disparity):
                    flat += 1
                if not options.fit_prior:
                    counted = far_cut_counts(disparity, cut)
                    far, valid = far + counted[0], valid + counted[1]
                yield disparity
        note_blank(plan.logs, blank, used)
        check_flat(plan.logs, flat, used)
        warn_far_cut(far, valid, cut, fb)
        views.check()

    with _bar(plan.total, "learn") as bar:
        progress = lambda done: bar.update(done - bar.n)  # noqa: E731
        if plan.synthetic.prior_basis is not None:
            # maps that fit the budget are merged in one step: the pooled scatter exactly,
            # then its top l + 20 (in batches of 64 the last eigenvalues near l
            # came out up to 4.6 % low at l = 100 on 480 maps: docs/cluster.md)
            one_step = fits_one_step(plan)
            return finetune_basis(
                plan.synthetic.prior_basis,
                maps(),
                n_prior=plan.synthetic.n_prior,
                n_components=options.n_components,
                variance=options.variance,
                focal_baseline=plan.camera.focal_baseline,
                batch_size=max(plan.total or 0, 1) if one_step else 64,
                progress=progress,
                meta=meta,
            )
        return learn_basis(
            maps(),
            n_components=options.n_components,
            variance=options.variance,
            grid_scale=options.grid_scale,
            focal_baseline=plan.camera.focal_baseline,
            progress=progress,
            meta=meta,
        )


FIT_MAX_FRAMES = 16
"""Frames used by the evidence fit of the local prior (evenly spread over the fit frames)."""


def fit_prior(
    basis: Basis,
    sources: list[tuple[Path, int]],
    options: LearnOptions,
    pairing: PairingConfig,
    local: LocalPrior | None = None,
    rougher: LocalPrior | None = None,
    *,
    cluster: Cluster | None = None,
    measured: list[list[HeldOutFrame]] | None = None,
) -> dict[str, Any]:
    """Fit the hybrid prior, sigma and the process noise on frames outside the basis.

    Args:
        basis: the learned basis.
        sources: (log, first pair index) to measure: GFTT + SGBM lookups of every pair from
            that index on, as ``densify`` measures them (:func:`measure_held_out`).
        options: the learning options (SGBM and GFTT settings).
        pairing: topics of the stereo pairs.
        local: a fixed local kernel: only sigma, the process noise and the std scale are
            fitted (:func:`estimate.fitting.fit_prior`).
        rougher: another fixed kernel (with ``local``: the built-in indoor basis's and
            :data:`~.adapt.ROUGH_KERNEL`, densify's fit check's): fitted as ``local`` is,
            and the one whose prior errs less at the held-out frames' SGBM pixels
            (:func:`held_out.score_fit`) is kept, the choice printed and recorded
            (``local_choice``).
        cluster: measure the logs there (a Dask cluster: one task per log, the same
            frames, the same measurements); None: here.
        measured: the frames of ``sources``, measured already (:func:`plan_maps`).

    Returns:
        The JSON-ready ``meta["prior"]`` of the basis.
    """
    from pcainterp_stream.estimate import fitting

    started = time.perf_counter()
    if measured is None and cluster is None:
        with _bar(None, "fit prior (measure held-out frames)") as bar:
            measured = [
                measure_held_out(
                    log,
                    first,
                    options,
                    pairing,
                    lambda: bar.update(1),
                    sample_check=local is not None and rougher is not None,
                )
                for log, first in sources
            ]
    elif measured is None and cluster is not None:
        measured = cluster.measure_held_out(sources, options, pairing)
    assert measured is not None
    sequences: list[list[fitting.FitFrame]] = []
    calibration: list[fitting.CalibrationFrame] = []
    for frames in measured:
        sequences.append(
            [
                fitting.fit_frame(
                    basis,
                    frame.pixels,
                    frame.disparities,
                    image_size=frame.image_size,
                    focal_baseline=frame.focal_baseline,
                )
                for frame in frames
            ]
        )
        calibration.extend(
            fitting.CalibrationFrame(
                frame.pixels,
                frame.disparities,
                frame.image_size,
                frame.focal_baseline,
                frame.reference,
            )
            for frame in frames
            if frame.reference is not None
        )
    if not any(frame.residual.size for sequence in sequences for frame in sequence):
        raise PcaInterpError(
            "no held-out stereo pair with measurements to fit the prior on; use more frames, "
            f"{_smaller_every(options)}a larger --holdout or --fit-logs LOG"
        )
    fit_on = "the --fit-logs logs' frames" if options.fit_logs else "the held-out frames"
    counted = sum(len(sequence) for sequence in sequences)
    usable = sum(1 for sequence in sequences for frame in sequence if frame.residual.size)
    if usable < counted:  # said, never silent (bug hunt 16D F9: fitted on 1 of 6)
        fit_on = fit_on.replace("the ", f"{usable} of the {counted} ", 1) + (
            f" ({counted - usable} without measurements: blank, dark or textureless)"
        )
    _echo(f"fitting the prior by the evidence on {fit_on}")
    robust = ProcessorConfig().robust

    def fit(kernel: LocalPrior | None) -> dict[str, Any]:
        return fitting.fit_prior(
            basis,
            sequences,
            calibration,
            max_frames=FIT_MAX_FRAMES,
            sequence_frames=FIT_SEQUENCE_FRAMES,
            robust=robust,
            local=kernel,
        )

    fitted = fit(local)
    if local is not None and rougher is not None:
        frames = [frame for log_frames in measured for frame in log_frames]
        fitted = choose_kernel(basis, frames, fitted, lambda: fit(rougher), robust)
    # no wall time in the basis: the same inputs give the same file, byte for byte
    fitted.update(
        {
            "std_scale_reference": "SGBM maps of the held-out frames",
            "measured_frames": counted,
            "measured_frames_used": usable,
            "fit_logs": [str(log) for log, _ in sources],
        }
    )
    _echo(f"fitted the prior in {time.perf_counter() - started:.1f} s")
    return fitted
