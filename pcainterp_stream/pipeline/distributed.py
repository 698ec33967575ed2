"""Scale-out on Dask (dask.distributed): learn a basis from, and densify, fleets of logs.

Learning gathers summaries of chunks. Each task reads a chunk of frames of one log,
matches them (SGBM) or converts a depth topic, preprocesses them onto the basis grid and
returns a :class:`~pcainterp_stream.pipeline.learn_sketch.ChunkSummary`: the count n, the
mean m, the sum of squared centred norms and U S, the SVD factor of its centred block.
While all the maps fit :data:`~pcainterp_stream.pipeline.learn.ONE_STEP_BYTES` (what one
process merges in one step) the factors are whole and merged here in one exact step
(:func:`~pcainterp_stream.pipeline.learn_sketch.combine`, in chunk order): the result is one
process's up to float rounding, the same file run after run. Beyond that they are truncated
to r = l + oversampling columns and tree-reduced on the workers, pairwise, by the SVD of
[U1 S1 | U2 S2 | sqrt(n1 n2 / n) (m1 - m2)] (the column corrects for the moved mean; the
same step as the local streaming learner), in a tree fixed by the chunks' order, not by
which task finishes first (two runs give the same file). A task holds one chunk and a merge
two (s, r) factors, so worker memory does not grow with the number of frames.

What is learned is decided as on one machine (:func:`pcainterp_stream.pipeline.learn.learn`
with a :class:`DaskLearner` calls :func:`learn_on_cluster`): the same maps of each log (the same
held-out share), the same grid and units (the built-in basis's when its statistics are
merged, the merge done here on the reduced summary), and the held-out frames measured on
the workers, one task per log, for the same fit of the prior.

Densifying many logs (``densify --out-dir``, :func:`densify_many`) is
:mod:`pcainterp_stream.pipeline.densify_fleet`'s, re-exported here.

Tasks return the errors they meet (:class:`TaskFailure`,
:mod:`pcainterp_stream.pipeline.cluster_tasks`) rather than raise them: Dask logs
every exception a task raises as a multi-line "Compute Failed" block on the worker's stderr,
before the caller could say the same in one line. On an interruption (or any error that
leaves :func:`connect`'s block) the local cluster's worker processes are killed at once,
before their clean-up could log or commit anything, and Dask's logging is silenced while
the cluster closes.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import LogReadError, PcaInterpError
from pcainterp_stream.estimate.basis import Basis, grid_size_for
from pcainterp_stream.estimate.finetune import finetune_from_sketch
from pcainterp_stream.estimate.learning import basis_from_fit, fit_from_factor
from pcainterp_stream.estimate.solve import DEFAULT_SIGMA
from pcainterp_stream.pipeline.cluster_tasks import TaskFailure, run_task, task_result
from pcainterp_stream.pipeline.common import (
    _bar,
    _check_topic_types,
    _pairing_types,
    _require_topics,
)
from pcainterp_stream.pipeline.densify_fleet import DensifyOutcome, densify_many, output_path
from pcainterp_stream.pipeline.learn import (
    BLANK_MAPS,
    GridTarget,
    HeldOutFrame,
    MapPlan,
    check_flat,
    fits_one_step,
    is_flat,
    learn,
    log_pairing,
    measure_held_out,
    note_blank,
    shows_surface,
    to_grid,
)
from pcainterp_stream.pipeline.learn_maps import close_sizes, depth_maps, resized_to, scaled_to
from pcainterp_stream.pipeline.learn_sketch import (
    ChunkSummary,
    combine,
    empty,
    merge,
    sketch_of,
    summarize,
)
from pcainterp_stream.pipeline.map_checks import far_cut_counts, warn_far_cut
from pcainterp_stream.pipeline.scheduler import (
    QUIET_TRACKER,
    WorkerPaths,
    checked,
    completed,
    connect,
    running_scheduler,
    stop_local_workers,
)

__all__ = [
    "QUIET_TRACKER",
    "ChunkSummary",
    "DaskLearner",
    "DensifyOutcome",
    "TaskFailure",
    "chunk_specs",
    "cluster_oversampling",
    "combine",
    "connect",
    "densify_many",
    "learn_distributed",
    "learn_on_cluster",
    "measure_on_cluster",
    "merge",
    "output_path",
    "run_task",
    "stop_local_workers",
    "summarize",
    "summarize_chunk",
    "task_result",
]

DEFAULT_CHUNK_FRAMES = 64
"""Frames (after ``every``) one learning task reads, matches and summarises."""

DEFAULT_OVERSAMPLING = 20
"""The fewest columns kept beyond l in every summary (the local streaming learner's)."""


def cluster_oversampling(n_components: int) -> int:
    """Return the columns a cluster's summaries keep beyond l: max(20, l / 2).

    A chunk's summary is merged log2(chunks) times, each merge truncating to r columns, and
    the eigenvalues near l come out low. On 480 maps (0.5-scale synthetic logs, chunks of
    64) the largest error of the l = 100 eigenvalues against the exact ones was 1.8 % at
    r = l + 20, 0.6 % at r = 1.5 l and 0.1 % at r = 2 l (the top 10: < 5e-5 for all), and a
    merge costs about (2 r)^2 s: r = 1.5 l keeps the learned model within 1 % of one
    process's at about twice the merge cost of r = l + 20 (docs/cluster.md). Used only
    for maps beyond :data:`~pcainterp_stream.pipeline.learn.ONE_STEP_BYTES` (fewer are
    merged exactly); a fine-tune keeps at least the built-in basis's rank beyond l
    (:meth:`DaskLearner.learn_basis`).
    """
    return max(DEFAULT_OVERSAMPLING, n_components // 2)


def _chunk_maps(
    log: Path, start: int, stop: int | None, options: Any, pairing: Any, fb: float | None
) -> Iterator[tuple[npt.NDArray[np.float32], tuple[int, int], float]]:
    """Yield (disparity (H, W) px, image size, f*b) of maps start..stop-1 of one log.

    Each map is put in the f*b ``fb`` (:func:`learn_maps.scaled_to`; None: the first map's),
    the f*b yielded.
    """
    from pcainterp_stream.frontend.pairing import iter_stereo_frames
    from pcainterp_stream.frontend.stereo import compute_disparity
    from pcainterp_stream.io.logreader import open_log

    if options.depth_topic:
        info: list[Any] = []
        maps = depth_maps(log, options, pairing, info, focal_baseline=fb)
        for disparity in itertools.islice(maps, start, stop):
            yield disparity, info[0].image_size, info[0].focal_baseline if fb is None else fb
        return
    with open_log(log) as reader:
        pairing = log_pairing(reader, pairing)  # the logs' topics may differ
        _require_topics(reader, pairing.required_topics(), "stereo pair")
        _check_topic_types(reader, _pairing_types(pairing))
        used = 0
        for frame in iter_stereo_frames(reader, pairing):
            if frame.index % options.every:
                continue
            used += 1
            if used <= start:
                continue  # decoded but not matched: the cost of an earlier chunk is small
            if stop is not None and used > stop:
                break
            disparity = compute_disparity(frame.left, frame.right, options.sgbm)
            fb = frame.camera.focal_baseline if fb is None else fb
            scaled = scaled_to(disparity, frame.camera.focal_baseline, fb)
            yield scaled, frame.camera.image_size, fb


def summarize_chunk(
    log: Path,
    start: int,
    stop: int | None,
    options: Any,
    pairing: Any,
    keep: int | None,
    target: GridTarget | None = None,
) -> ChunkSummary | None:
    """Read, match and preprocess maps start..stop-1 of one log and summarise them (a task).

    Args:
        log: the log path (readable by the worker).
        start: index of the first map (after ``options.every``).
        stop: one past the last map, or None for the end of the log.
        options: the :class:`pcainterp_stream.pipeline.learn.LearnOptions`.
        pairing: the :class:`pcainterp_stream.frontend.pairing.PairingConfig`.
        keep: r, the columns kept of the factor; None: all (the summary is exact).
        target: the grid and units of the maps (:func:`learn.to_grid`); None: the grid of
            ``options.grid_scale``, the maps' own units.

    Returns:
        The summary (an empty one counting its blank maps when it has no other), or None
        when the chunk has no map.
    """
    grids: list[npt.NDArray[np.float32]] = []
    image_size: tuple[int, int] | None = None
    focal_baseline = 0.0
    flat = blank = far = valid = 0
    fb_target = None if target is None else target.focal_baseline
    for disparity, size, fb in _chunk_maps(log, start, stop, options, pairing, fb_target):
        if image_size is None:
            image_size, focal_baseline = size, fb
            if target is None:
                target = GridTarget(grid_size_for(size, options.grid_scale))
            image_size = target.image_size or image_size  # the plan's camera
        if disparity.shape != image_size and close_sizes(disparity.shape, image_size):
            disparity = resized_to(disparity, image_size)  # as on one machine
        if disparity.shape != image_size:
            raise PcaInterpError(
                f"{log} has maps of shape {disparity.shape}, expected {image_size}; "
                "learn one basis per camera"
            )
        assert target is not None
        if not shows_surface(disparity):
            blank += 1  # skipped as on one machine (learn.shows_surface), and counted
            continue
        if not options.depth_topic and is_flat(disparity):
            flat += 1
        if not options.fit_prior:  # the far cut of the paper's sigma (as on one machine)
            counted = far_cut_counts(disparity, DEFAULT_SIGMA / target.disparity_scale)
            far, valid = far + counted[0], valid + counted[1]
        try:
            grids.append(to_grid(disparity, target))
        except ValueError as err:
            raise PcaInterpError(f"cannot learn from a map of {log}: {err}") from err
    if target is None or image_size is None:
        return None
    if not grids:
        return empty(target.grid_size, image_size, focal_baseline, blank)
    summary = summarize(
        np.stack(grids),
        keep,
        grid_size=target.grid_size,
        image_size=image_size,
        focal_baseline=focal_baseline,
    )
    return dataclasses.replace(
        summary, flat_maps=flat, blank_maps=blank, far_pixels=far, valid_pixels=valid
    )


def learn_distributed(
    logs: list[Path],
    output: Path,
    options: Any,
    pairing: Any,
    client: Any,
    *,
    chunk_frames: int = DEFAULT_CHUNK_FRAMES,
    oversampling: int | None = None,
) -> Basis:
    """Learn a basis on a Dask cluster (``pcainterp learn --scheduler/--workers``).

    :func:`pcainterp_stream.pipeline.learn.learn` with a :class:`DaskLearner`: the same
    plan, hold-out, merge with the built-in basis and fitted prior as in one process.

    Args:
        logs: input logs (paths readable by the workers).
        output: where to save the basis (.npz).
        options: the :class:`pcainterp_stream.pipeline.learn.LearnOptions`.
        pairing: the :class:`pcainterp_stream.frontend.pairing.PairingConfig`.
        client: a connected ``dask.distributed.Client``.
        chunk_frames: maps per task.
        oversampling: columns kept beyond l in every summary (maps beyond one step); None:
            20 for maps merged in one step, else :func:`cluster_oversampling` (a
            fine-tune's at least the built-in basis's rank).

    Returns:
        The saved :class:`Basis`.

    Raises:
        PcaInterpError: bad options, no maps, or a task failed.
    """
    cluster = DaskLearner(client, chunk_frames=chunk_frames, oversampling=oversampling)
    return learn(logs, output, options, pairing, cluster=cluster)


@dataclass(frozen=True)
class DaskLearner:
    """``learn``'s statistics and held-out measurements gathered on a Dask cluster.

    Attributes:
        client: a connected ``dask.distributed.Client``.
        chunk_frames: maps per task.
        oversampling: columns kept beyond l in every summary (maps beyond one step); None:
            20 for maps merged in one step, else :func:`cluster_oversampling` (a
            fine-tune's at least the built-in basis's rank).
    """

    client: Any
    chunk_frames: int = DEFAULT_CHUNK_FRAMES
    oversampling: int | None = None

    def learn_basis(self, plan: MapPlan, options: Any, pairing: Any, meta: dict[str, Any]) -> Basis:
        """Return the basis of a plan's maps: :func:`learn_on_cluster`."""
        exact = fits_one_step(plan)
        oversampling = self.oversampling
        if oversampling is None and exact:
            oversampling = DEFAULT_OVERSAMPLING  # the final truncation only, as one process
        elif oversampling is None:
            oversampling = cluster_oversampling(options.n_components)
            prior = plan.synthetic.prior_basis
            if prior is not None:  # a merge must keep as many directions as the basis's
                oversampling = max(oversampling, prior.n_components)
        return learn_on_cluster(
            plan,
            options,
            pairing,
            self.client,
            meta,
            chunk_frames=self.chunk_frames,
            oversampling=oversampling,
            exact=exact,
        )

    def measure_held_out(
        self, sources: list[tuple[Path, int]], options: Any, pairing: Any
    ) -> list[list[HeldOutFrame]]:
        """Measure held-out frames on the workers: :func:`measure_on_cluster`."""
        return measure_on_cluster(self.client, sources, options, pairing)


def chunk_specs(plan: MapPlan, chunk_frames: int) -> list[tuple[Path, int, int | None]]:
    """Split a plan's maps into tasks: (log, first map, one past the last or None: the end).

    A log's last chunk ends where the plan's maps of it end (its held-out share starts), or
    at the end of the log when none is held out, so a log holding more maps than its summary
    promised loses none.
    """
    specs: list[tuple[Path, int, int | None]] = []
    for log, count, keep in zip(plan.logs, plan.counts, plan.kept, strict=True):
        limit = count if keep is None else keep
        if limit is None:
            specs.append((log, 0, None))
            continue
        starts = range(0, max(limit, 1), chunk_frames)
        for start in starts:
            last = start == starts[-1]
            stop = keep if last else start + chunk_frames
            specs.append((log, start, stop))
    return specs


def learn_on_cluster(
    plan: MapPlan,
    options: Any,
    pairing: Any,
    client: Any,
    meta: dict[str, Any],
    *,
    chunk_frames: int = DEFAULT_CHUNK_FRAMES,
    oversampling: int = DEFAULT_OVERSAMPLING,
    exact: bool = False,
) -> Basis:
    """Learn the basis of a plan from summaries of its maps computed on the cluster.

    Args:
        plan: what to learn from (:func:`pcainterp_stream.pipeline.learn.plan_maps`).
        options: the :class:`pcainterp_stream.pipeline.learn.LearnOptions`.
        pairing: the :class:`pcainterp_stream.frontend.pairing.PairingConfig`.
        client: a connected ``dask.distributed.Client``.
        meta: entries for the basis's ``meta`` (``source``).
        chunk_frames: maps per task.
        oversampling: columns kept beyond l in every summary (exact: in the result).
        exact: the summaries keep every column and are merged here in one step, in chunk
            order (:func:`combine`); else truncated and tree-reduced on the workers.

    Returns:
        The basis (not saved), fine-tuned from the built-in one when the plan says so.

    Raises:
        PcaInterpError: no maps, or a task failed.
    """
    if chunk_frames < 1:
        raise PcaInterpError(f"chunk size must be at least 1 frame, got {chunk_frames}")
    keep = None if exact else options.n_components + oversampling
    # workers may run in another folder: they get absolute paths, the basis records the given
    specs = [(log.resolve(), start, stop) for log, start, stop in chunk_specs(plan, chunk_frames)]
    with _bar(len(specs), "learn on the cluster", unit="chunk") as bar:
        if keep is None:
            total = combine(_gather(client, specs, options, pairing, plan.target, bar.update))
        else:
            final = _reduce(client, specs, options, pairing, keep, plan.target, bar.update)
            total = task_result(final, "a learning task")
    if total is not None:
        note_blank(plan.logs, total.blank_maps, total.n_maps)  # as one process says
    if total is None or not total.n_maps:
        raise LogReadError(
            f"no {'depth image' if options.depth_topic else 'stereo pair'} with a disparity "
            f"above 0 found in {', '.join(map(str, plan.logs))}; check the topic options "
            f"(pcainterp info LOG) and the images ({BLANK_MAPS} give none)"
        )
    check_flat(plan.logs, total.flat_maps, total.n_maps)
    cut = DEFAULT_SIGMA / plan.target.disparity_scale
    warn_far_cut(total.far_pixels, total.valid_pixels, cut, plan.camera.focal_baseline)
    merged = "in one step" if exact else "tree"
    meta = {
        **meta,
        "distributed": {"chunk_frames": chunk_frames, "tasks": len(specs), "merge": merged},
    }
    prior_basis = plan.synthetic.prior_basis
    if prior_basis is not None:
        return finetune_from_sketch(
            prior_basis,
            sketch_of(total),
            n_prior=plan.synthetic.n_prior,
            maps_image_size=total.image_size,
            n_components=options.n_components,
            variance=options.variance,
            focal_baseline=total.focal_baseline,
            oversampling=oversampling,
            used="finetune, distributed",
            meta=meta,
        )
    if total.n_maps < 2:
        raise PcaInterpError(f"learning needs at least two disparity maps, got {total.n_maps}")
    return basis_from_fit(
        fit_from_factor(total.mean, total.factor, total.squares, total.n_maps),
        grid_size=total.grid_size,
        image_size=total.image_size,
        n_components=options.n_components,
        variance=options.variance,
        grid_scale=options.grid_scale,
        used="distributed",
        requested="distributed",
        focal_baseline=total.focal_baseline,
        box_size=plan.target.box_size,
        batch_size=chunk_frames,
        oversampling=oversampling,
        meta=meta,
    )


def measure_on_cluster(
    client: Any, sources: list[tuple[Path, int]], options: Any, pairing: Any
) -> list[list[HeldOutFrame]]:
    """Measure the held-out frames of each (log, first pair) on the cluster, one task a log.

    Returns:
        Per source, what :func:`pcainterp_stream.pipeline.learn.measure_held_out` returns.

    Raises:
        PcaInterpError: a task failed.
    """
    remote = running_scheduler(client)
    futures = [
        client.submit(
            run_task,
            checked,
            WorkerPaths((log.resolve(),)) if remote else None,
            *(measure_held_out, log.resolve(), first, options, pairing),
            pure=False,
        )
        for log, first in sources
    ]
    from dask.distributed import as_completed

    with _bar(len(futures), "fit prior (measure held-out frames on the cluster)", "log") as bar:
        for done in completed(as_completed(futures), client):  # type: ignore[no-untyped-call]
            task_result(done, "a measuring task")  # the first failure raises at once
            bar.update(1)
    return [task_result(future, "a measuring task") for future in futures]


def _submit_chunk(
    client: Any,
    spec: tuple[Path, int, int | None],
    options: Any,
    pairing: Any,
    keep: int | None,
    target: GridTarget | None,
) -> Any:
    """Submit the task summarising one chunk (:func:`summarize_chunk`); return its future."""
    log, start, stop = spec
    return client.submit(
        run_task,
        checked,
        WorkerPaths((log,)) if running_scheduler(client) else None,
        *(summarize_chunk, log, start, stop, options, pairing, keep, target),
        pure=False,
    )


def _window(client: Any) -> int:
    """Tasks outstanding at most: 2 per worker thread (chunks and merges together)."""
    return max(2, 2 * int(sum(client.nthreads().values())))


def _gather(
    client: Any,
    specs: list[tuple[Path, int, int | None]],
    options: Any,
    pairing: Any,
    target: GridTarget | None = None,
    chunk_done: Callable[[], object] | None = None,
) -> list[ChunkSummary | None]:
    """Run the chunk tasks with exact summaries; return them here, in chunk order.

    At most :func:`_window` tasks are outstanding; each summary comes here as its task
    finishes (the maps fit :data:`~pcainterp_stream.pipeline.learn.ONE_STEP_BYTES`).

    Raises:
        PcaInterpError: a task failed (the first failure to finish).
    """
    from dask.distributed import as_completed

    window = _window(client)
    pending = iter(enumerate(specs))
    running: Any = as_completed()  # type: ignore[no-untyped-call]
    index_of: dict[Any, int] = {}
    summaries: list[ChunkSummary | None] = [None] * len(specs)

    def refill() -> None:
        while running.count() < window:
            item = next(pending, None)
            if item is None:
                return
            future = _submit_chunk(client, item[1], options, pairing, None, target)
            index_of[future.key] = item[0]
            running.add(future)

    refill()
    for future in completed(running, client):
        summaries[index_of[future.key]] = task_result(future, "a learning task")
        if chunk_done is not None:
            chunk_done()
        refill()
    return summaries


def _reduce(
    client: Any,
    specs: list[tuple[Path, int, int | None]],
    options: Any,
    pairing: Any,
    keep: int,
    target: GridTarget | None = None,
    chunk_done: Callable[[], object] | None = None,
) -> Any:
    """Run the chunk tasks and merge their summaries in a tree; return the last future.

    The tree is fixed by the chunks' order (a binary counter: chunks 0+1, 2+3, then (0+1) +
    (2+3)..., the last ones folded from the right), not by the order the tasks finish, so
    two runs merge the same summaries the same way and give the same file. A merge is
    submitted as soon as its two operands are (Dask runs it once both are done). At most
    :func:`_window` tasks are outstanding, so the summaries alive on the cluster, and
    hence worker memory, do not grow with the number of chunks.
    """
    from dask.distributed import as_completed

    window = _window(client)
    running: Any = as_completed()  # type: ignore[no-untyped-call]
    finished = completed(running, client)
    chunks: set[Any] = set()
    stack: list[tuple[int, Any]] = []  # (level, future): merged runs of chunks, in order

    def wait(limit: int) -> None:
        while running.count() > limit:
            future = next(finished)
            if chunk_done is not None and future.key in chunks:
                chunk_done()

    def merged(first: Any, second: Any) -> Any:
        future = client.submit(run_task, merge, first, second, keep, pure=False)
        running.add(future)
        return future

    for spec in specs:
        wait(window - 1)
        future = _submit_chunk(client, spec, options, pairing, keep, target)
        chunks.add(future.key)
        running.add(future)
        stack.append((0, future))
        while len(stack) > 1 and stack[-1][0] == stack[-2][0]:
            (level, second), (_, first) = stack.pop(), stack.pop()
            stack.append((level + 1, merged(first, second)))
    while len(stack) > 1:
        (_, second), (level, first) = stack.pop(), stack.pop()
        stack.append((level, merged(first, second)))
    wait(0)
    return stack[0][1] if stack else None
