"""The basis choice made again mid-log: another camera, or a log's own basis that stops fitting.

The fit check (:mod:`~pcainterp_stream.pipeline.adaptation`) chooses a basis on the log's
first frames. Two things can make that choice wrong later, and both were silent:

- **the camera changes** (a driver restarted at another resolution or calibration, another
  rig): a basis learned from the first camera's SGBM maps gave the second 44-52 % depth
  error (4 % alone), its std covering 20-24 % of the truth. On a camera change the choice is
  made again on the new camera's first frames, as at the start; a log's own basis of
  another camera is not used on it meanwhile (the basis given at the start is).
- **the scene changes** under a log's own basis (a robot leaving a building): a basis learned
  indoors put the street 4-5x too near, its std covering 6-19 %. :class:`FitWatch` scores
  the basis in use on the held-out SGBM pixels of every :data:`WATCH_EVERY`-th frame (the
  pixels and plain interpolation the fit check scores; one solve without std, before the
  frame's map is learned) and, when it stops beating linear interpolation, the built-in basis
  the check that adopted it chose or the basis given at the start, whichever does better on
  the frames it failed on, takes over and the choice is made again on the next frames.
  A built-in basis kept is not watched: it is the same basis the check chose and costs
  nothing more (a street basis on an indoor part degraded the depth, but its std covered
  it: 99 %).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

from pcainterp_stream.estimate import adapt
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.estimator import densify_batch
from pcainterp_stream.frontend.near import lookups_only
from pcainterp_stream.pipeline.adapt_frames import AdaptFrame
from pcainterp_stream.pipeline.adaptation import Adaptation, Candidate
from pcainterp_stream.pipeline.held_out import clipped_pixels
from pcainterp_stream.pipeline.measured import Measured, check_cells, sgbm_maps
from pcainterp_stream.records import StereoFrame

WATCH_EVERY = 4
"""A log's own basis is scored on every this-many-th frame it densifies (one solve, no std)."""

WATCH_FRAMES = 3
"""The scores pooled: the last this many frames scored (pixel-weighted; fewer at first)."""

WATCH_LINEAR = 2.0
"""The basis stops fitting when its pooled error is at least this times linear
interpolation's, and :data:`WATCH_ABOVE` times the ratio it was adopted at (its leave-one-out
figure). On synthetic rooms that keep their own basis (188x120, 33 frames, seeds 1 and 3)
single frames scored 0.35-1.43x linear and three pooled up to 1.35x: the noise of a few
frames, not another scene; the street after a room scored 15x."""

WATCH_ABOVE = 2.0
"""See :data:`WATCH_LINEAR`: an own basis adopted at 1.1x linear is given up above 2.2x."""

Camera = tuple[tuple[int, int], float]
"""(image size (height, width), f*b px*m): what tells one camera from another."""


def camera_of(frame: AdaptFrame) -> Camera:
    """Return the frame's camera as the adaptation tells cameras apart."""
    return frame.image_size, frame.focal_baseline


def describe_camera(camera: Camera) -> str:
    """Return "376x240 px, f*b 24.0 px*m"."""
    (height, width), focal_baseline = camera
    return f"{width}x{height} px, f*b {focal_baseline:.1f} px*m"


@dataclass
class FitWatch:
    """The held-out scores of a log's own basis on the frames it densifies.

    Attributes:
        adopted: its ratio to linear interpolation when adopted (leave-one-out).
        scores: the last :data:`WATCH_FRAMES` frames' scores, with their frame indices.
        count: frames seen since it was adopted.
        kept: the frames of the scores (when given: the built-in bases are scored on their
            held-out pixels when the basis stops fitting, :meth:`Refitting._stopped`).
    """

    adopted: float
    scores: list[tuple[int, adapt.FrameCheck]] = field(default_factory=list)
    count: int = 0
    kept: list[AdaptFrame] = field(default_factory=list)

    def due(self) -> bool:
        """Count one frame; return whether it is to be scored."""
        self.count += 1
        return self.count % WATCH_EVERY == 0

    def add(
        self, index: int, score: adapt.FrameCheck, frame: AdaptFrame | None = None
    ) -> adapt.FitCheck | None:
        """Add frame ``index``'s score; return the pooled check when the basis stops fitting."""
        self.scores = [*self.scores, (index, score)][-WATCH_FRAMES:]
        if frame is not None:
            self.kept = [*self.kept, frame][-WATCH_FRAMES:]
        pooled = adapt.FitCheck.combine([check for _, check in self.scores])
        if not pooled.frames or pooled.degenerate or pooled.ratio < self.limit():
            return None
        return pooled

    def limit(self) -> float:
        """Return the ratio to linear interpolation at which the basis stops fitting."""
        return max(WATCH_LINEAR, WATCH_ABOVE * self.adopted)

    def failed(self) -> list[AdaptFrame]:
        """Return the kept frames the basis failed on alone (the newest if none did).

        The pool that stopped it may hold frames of the scene before (a room, then the
        street at frame 12: frames 11 and 15 pooled, the own basis failing on 15 alone).
        """
        limit, kept = self.limit(), {frame.index: frame for frame in self.kept}
        pairs = [(kept[index], check) for index, check in self.scores if index in kept]
        failed = [f for f, check in pairs if check.pixels and check.prior >= limit * check.linear]
        return failed or [frame for frame, _ in pairs][-1:]

    def frames(self) -> str:
        """Return the frames pooled: "15, 19 and 23"."""
        return _names([index for index, _ in self.scores])


def _names(indices: list[int]) -> str:
    """Return "15, 19 and 23"."""
    names = [str(index) for index in indices]
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"


def score(
    basis: Basis,
    frame: AdaptFrame,
    options: dict[str, object],
    robust: str,
    cells: bool = False,
) -> adapt.FrameCheck:
    """Score ``basis`` on one frame's held-out SGBM pixels (a solve without std).

    ``cells``: an edge-aware prior is scored with its cells along SGBM's map
    (:attr:`~.adaptation.Adaptation.cells`).
    """
    assert frame.sgbm_map is not None
    held = frame.held_out
    if held is None:
        held = adapt.HeldOut.of(frame.sgbm_map, frame.pixels, frame.disparities, frame.clipped)
    (estimate,) = densify_batch(
        basis,
        [frame.pixels],
        [frame.disparities],
        uncertainty="none",
        image_size=frame.image_size,
        focal_baseline=frame.focal_baseline,
        robust=robust,
        with_depth=False,
        partitions=[frame.cells(basis.grid_size)] if cells and check_cells(options) else None,
        **options,  # type: ignore[arg-type]
    )
    return held.score(estimate.disparity, estimate.min_disparity)


OptionsOf = Callable[[Basis], dict[str, object]]
"""The estimate's keyword options with a basis (its fitted prior under the run's options)."""


def adapt_frame(item: Measured) -> AdaptFrame:
    """Return what the adaptation needs of one measured frame."""
    camera = item.frame.camera
    sgbm_map, grid = item.sgbm_map, item.grid_map
    if item.raw_map is not None:
        sgbm_map, grid = sgbm_maps(item.raw_map, camera)
    pixels, disparities = lookups_only(item.pixels, item.disparities, item.noise)  # not near's
    size, fb = camera.image_size, camera.focal_baseline
    # a check made on it after the warm-up (a check made again, the watch of the log's own
    # basis) holds its pixels out here: an over-exposed pair's clipped ones left out, as the
    # stereo workers leave them out of the warm-up's (bug hunt 16F F1); ~0.4 ms a KITTI pair
    clipped = None
    if sgbm_map is not None and item.held_out is None:
        clipped = clipped_pixels(item.frame.left, item.frame.right, sgbm_map)
    return AdaptFrame(
        pixels,
        disparities,
        sgbm_map,
        grid,
        size,
        fb,
        item.held_out,
        item.motion,
        camera,
        item.frame.index,
        clipped,
    )


@dataclass
class Refitting(Adaptation):
    """:class:`~.adaptation.Adaptation` that makes its choice again when it stops holding.

    Attributes:
        options_of: the estimate's options with a basis (to score the one in use).
        changes: camera changes the densify thread has seen, in stream order.
        watch: the held-out scores of the log's own basis in use, if adopted.
    """

    options_of: OptionsOf | None = None
    changes: int = 0
    watch: FitWatch | None = None
    _stereo: bool = False
    _lane_camera: Camera | None = None
    _cameras: list[Camera] = field(default_factory=list)  # every camera seen, in order

    def _decide(
        self, basis: Basis, frames: list[AdaptFrame], settings: dict[str, object]
    ) -> Basis | None:
        usable = [f for f in frames if f.sgbm_map is not None and f.grid_map is not None]
        chosen = super()._decide(basis, frames, settings)
        if usable:  # a stereo log: its choice can be made again
            self._stereo, self._camera = True, camera_of(usable[0])
        own = self.own_check
        self.watch = FitWatch(own.ratio) if self.adapted and own is not None else None
        return chosen

    def new_camera(self, frame: StereoFrame) -> tuple[bool, Basis | None]:
        """Note the camera of the next frame in stream order (the densify thread's).

        Returns whether it is another camera than the frame before it's, and the basis to
        densify it with from this frame on when that changes (else None): on a camera change
        after the fit check, the choice is made again on its first frames, and a log's own
        basis, learned for the camera before, gives way to the basis given meanwhile; so does
        the fit check's tuning of the indoor basis (its kernel and std scale fitted on the
        camera before's SGBM maps): the basis is used as it is until the choice is made again.
        """
        camera, index = (frame.camera.image_size, frame.camera.focal_baseline), frame.index
        before, self._lane_camera = self._lane_camera, camera
        if before is None or camera == before:
            if before is None:
                self._cameras.append(camera)
            return False, None
        seen = camera in self._cameras  # back to a camera of the log's
        if not seen:
            self._cameras.append(camera)
        self.changes += 1
        if not (self.active and self.checked and self._stereo and self._given is not None):
            return True, None
        if camera == self._camera and not self.deferred:
            return True, None  # back to the camera the choice was made for
        adapted, self.adapted, self.watch = self.adapted, False, None
        untuned = None if adapted else self.untune()  # the tuning was fitted on the camera before
        again = ", a camera seen before in the log" if seen else ""
        line = (
            f"prior: the camera changed at frame {index} ({describe_camera(camera)}{again}; "
            f"before: {describe_camera(before)})"
        )
        if adapted:
            line += (
                f": this log's own basis, learned for the camera before, is not used on it; "
                f"{self.name} from there"
            )
        elif untuned is not None and self.switched is not None:
            line += (
                f": the kernel and std scale the check tuned on the camera before are not used "
                f"on it; {self.switched.name} as it is from there"
            )
        which = "next" if seen else "first"
        self.lines.append(
            f"{line}; the basis choice is made again on its {which} {self.warmup_frames} frames"
        )
        self._recheck(
            camera,
            f"prior: the basis choice made again on the first {{}} of this camera since frame "
            f"{index}"
            if seen
            else "prior: the basis choice made again on the new camera's first {}",
        )
        return True, self._given if adapted else untuned

    def update(self, frames: list[AdaptFrame], current: Basis | None = None) -> Basis | None:
        """Watch the log's own basis in use, then add the frames' maps (see the base class).

        When the basis stops fitting the frames (:class:`FitWatch`), returns the built-in
        basis the check that adopted it chose (:attr:`~.adaptation.Adaptation.builtin_choice`,
        with its tuning) or the basis given at the start, whichever scores better on the
        frames it failed on (:meth:`_rescored`), used from the next frame on while the choice
        is made again.
        """
        watch, options_of = self.watch, self.options_of
        if self.adapted and watch is not None and current is not None and options_of:
            for frame in frames:
                if frame.sgbm_map is None or camera_of(frame) != self._camera:
                    continue
                if not watch.due():
                    continue
                check = score(current, frame, options_of(current), self.robust, self.cells)
                stopped = watch.add(frame.index, check, frame)
                if stopped is not None:
                    return self._stopped(stopped, watch, frame.index, current)
        return super().update(frames, current)

    def _stopped(
        self, check: adapt.FitCheck, watch: FitWatch, index: int, current: Basis
    ) -> Basis | None:
        # the built-in basis the check chose (and tuned) when it adopted the own one, not the
        # given one it may have scored worst (the street basis on a room: 1.17-3.68x linear);
        # but the scene changed: both are scored on the watch's frames (:meth:`_rescored`)
        choice, name = self._rescored(watch)
        self.lines.append(
            f"prior: this log's own basis stopped fitting at frame {index}: {check.ratio:.2f}x "
            f"linear on held-out SGBM pixels of frames {watch.frames()} "
            f"({watch.adopted:.2f}x when adopted); {name} from the next frame, the basis "
            f"choice made again on the next {self.warmup_frames} frames"
        )
        self.adapted, self.watch, self.switched = False, None, choice  # its tuning with it
        self.stopped[len(self.own_bases)] = index  # not advised for other logs (16D F1)
        assert self._camera is not None
        self._recheck(
            self._camera, f"prior: the basis choice made again on the {{}} after frame {index}"
        )
        target = self._given if choice is None else choice.basis
        return None if target is current else target

    def _rescored(self, watch: FitWatch) -> tuple[Candidate | None, str]:
        """Return the built-in basis to use after a stop (None: the given one) and its name.

        The check's choice (:attr:`~.adaptation.Adaptation.builtin_choice`) was made on the
        scene before the stop: it and the given basis are scored (with their settings) on
        the held-out SGBM pixels of the watch's frames, and the lower error is taken (a
        room, then the street: the indoor basis 2.15 px against the truth on the street, the
        street basis given at the start 1.24; one or two solves per basis, once per stop).
        """
        choice, given = self.builtin_choice, self._given
        if choice is None:
            return None, self.name
        name = f"{choice.name} (the check's built-in choice"
        frames = [frame for frame in watch.failed() if frame.sgbm_map is not None]
        if given is None or not frames:
            return choice, name + ")"

        def pooled(basis: Basis, options: dict[str, object]) -> adapt.FitCheck:
            return adapt.FitCheck.combine(
                [score(basis, frame, options, self.robust, self.cells) for frame in frames]
            )

        ours, theirs = pooled(choice.basis, choice.settings), pooled(given, self._settings)
        where = f"frame{'s' if len(frames) > 1 else ''} {_names([f.index for f in frames])}"
        # the given basis only when it scored lower, or scored where the choice could not
        given_better = theirs.prior < ours.prior or (
            math.isnan(ours.prior) and not math.isnan(theirs.prior)
        )
        if not given_better:
            return (
                choice,
                f"{name}; on {where} {ours.ratio:.2f}x linear, {self.name} {theirs.ratio:.2f}x)",
            )
        return None, (
            f"{self.name} (given at the start; on {where} {theirs.ratio:.2f}x linear, the "
            f"check's built-in choice ({choice.name}) {ours.ratio:.2f}x)"
        )

    def _recheck(self, camera: Camera, line: str) -> None:
        """Make the choice again on the next frames of ``camera`` (:meth:`_revisit`).

        ``line``: what the summary says then ("{}": "8 frames").
        """
        self.deferred, self._views, self.again = True, [], line
        self._camera, self._last_map, self._since = camera, None, None
