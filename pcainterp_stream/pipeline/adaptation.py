"""The fit check and the self-supervised basis of one densify stream.

:class:`Adaptation` is the frame processor's state for it (:mod:`~pcainterp_stream.estimate.adapt`
has the maths): the first ``warmup_frames`` frames are held back, the basis is checked on
them against linear interpolation on held-out SGBM pixels. When it is the built-in street
basis and it does not fit the log well, the other built-in bases (the indoor one) are
checked on the same pixels, and, in ``auto`` mode, a basis learned from the log's own SGBM
maps is tried too (leave-one-out); the one with the lowest held-out error is used from the
first frame on (the warm-up frames are densified with it too). Warm-up frames that are one
view (their maps, or the ego-motion: a camera that barely moves) teach a basis nothing but
their noise: a built-in basis is kept. A log's own basis is then relearned from all its maps
so far (but copies of the view added last) each time their number doubles. Every decision depends
only on the frames and their order: a log gives the same output however it is read
(file, pipe, live).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from pcainterp_stream.estimate import adapt, fitting, rougher
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.estimator import densify_batch
from pcainterp_stream.frontend.motion import view_shift
from pcainterp_stream.pipeline.adapt_frames import STILL_SHIFT, AdaptFrame, still_links
from pcainterp_stream.pipeline.measured import check_cells
from pcainterp_stream.pipeline.wording import count as _count
from pcainterp_stream.pipeline.wording import figures as _figures
from pcainterp_stream.records import StereoFrame

FITS_BELOW = 0.8
"""A basis at most this times linear interpolation's error is kept without trying the other
built-in bases or the log's own (learning and checking the log's own costs a few seconds)."""

OWN_ABOVE_STREET = 1.0
"""The built-in street basis, when it is the one chosen, is replaced by a try of the log's own
only when it loses to linear interpolation (at least this times its error). On real street
logs (both KITTI clips, KITTI's depth-annotated frames) the log's own basis never beat it,
while with sparse mode's lattice of lookups linear interpolation comes close to it (0.9-0.95x
on the clips): trying the log's own there cost ~3.5 s per log for nothing. On the real indoor
pairs the log's own beat the indoor basis by 4x, so that one keeps :data:`FITS_BELOW`."""

MAX_MAPS = 256
"""Most SGBM maps kept for the log's own basis; past it, every other one is dropped."""

MOVED = "prior: the camera moved: checked again on {} of other views"
"""The line of the check made again after a standing start ("{}": its frames)."""


def unfit_warning(check: adapt.FitCheck, where: str, fix: str) -> str:
    """Return the warning of a prior that fails the fit check, with ``fix`` ("; learn ...").

    When linear interpolation is exact on the held-out points
    (:attr:`~pcainterp_stream.estimate.adapt.FitCheck.degenerate`) the ratio is one over ~0
    and the fix a guess: the warning says what the points are instead.
    """
    if check.degenerate:
        return (
            f"warning: linear interpolation is exact on this log's {where} "
            f"({check.linear:.2g} px): they are constant or exactly planar, as no measured "
            "scene is, so the fit check compares nothing; check what the measurements are"
        )
    return (
        f"warning: the prior is worse than linear interpolation on this log's {where} "
        f"({check.ratio:.2f}x){fix}"
    )


class BasisStart(NamedTuple):
    """A basis the stream was densified with, from its first frame on (until the next one).

    Attributes:
        frame: the first frame densified with it (its index, stamp and log time).
        basis: the basis.
        tuning: the settings the fit check tuned it with (:meth:`Adaptation.tuning`), or None.
    """

    frame: StereoFrame
    basis: Basis
    tuning: dict[str, object] | None = None


@dataclass(frozen=True)
class Candidate:
    """Another built-in basis the check may choose instead of the given one.

    Attributes:
        name: how the summary names it ("the built-in indoor basis").
        basis: the basis.
        settings: the estimate's keyword options with it (its own fitted prior).
        tuned: the estimate's settings that differ from the basis's fitted prior (the
            rougher kernel and its std scale: :meth:`Adaptation.tuning`).
        untuned: the candidate before the tuning (the camera changes: :meth:`Adaptation.untune`).
    """

    name: str
    basis: Basis
    settings: dict[str, object]
    tuned: dict[str, object] = field(default_factory=dict)
    untuned: Candidate | None = None


@dataclass
class Adaptation:
    """Fit check and self-supervised basis state of one stream.

    Attributes:
        mode: "auto", "check" or "off" (:class:`~.processor.ProcessorConfig` ``adapt``).
        may_replace: the basis may be replaced (it is the built-in one).
        may_learn: in ``auto`` mode the log's own basis may be tried; False (dense mode)
            only chooses between the built-in bases. Measured on 15 logs in dense mode
            (docs/bases.md, "Dense mode: checked, never adapted"): the log's own basis was
            tried on 8 for 0.25-0.8 s of CPU each, changed no result against the truth, and
            where it won (EuRoC) its fitted std scale came out at 3e7.
        warmup_frames: frames held back for the check.
        robust: the robust loss densify uses.
        calibrate: calibrate the std of a learned basis.
        checked: the warm-up check is done.
        adapted: the log's own basis replaced the given one.
        lines: what to print in the run's summary.
        check: the given basis's held-out figure, once checked.
        own_check: the log's own basis's held-out (leave-one-out) figure, when tried.
        own_against: the basis it was compared with, on the frames it was checked on.
        first_basis: the log's own basis adopted first (``OUTPUT.basis.npz``; the output's
            channels name it when it densified the first frames).
        own_bases: every basis of the log's own adopted by a check, in order (a check made
            again may adopt another: ``OUTPUT.basis-2.npz``); relearned ones are not here.
        relearned: by adoption (1, 2...), the last basis relearned from it and the frame whose
            map completed it (``OUTPUT.final.basis.npz``...), densifying a frame or not.
        name: how the summary names the given basis.
        alternatives: loaders of the other built-in bases, checked (and loaded) only when
            the given one does not fit well.
        advisory: loaders of the built-in bases a basis the user chose (a file, or
            ``--basis builtin-street``/``-indoor``) is compared with when it loses to linear
            interpolation: never chosen, only named in the warning when ``--basis builtin``
            would do better (:meth:`_builtin_advice`).
        switched: the alternative chosen instead of the given basis, if any.
        builtin_choice: the built-in basis (with its tuning) the check that adopted the log's
            own basis chose among the built-in ones (None: the given one); when that own basis
            stops fitting, it or the given basis takes over (:mod:`~.refit`).
        own_above: the log's own basis is tried when the given basis (if it stays chosen)
            scores at least this times linear interpolation's error.
        stopped: by adoption (1, 2...), the frame at which the log's own basis it adopted
            (or one relearned from it) stopped fitting (:mod:`~.refit`); such a basis is
            not advised for other logs of the camera (:mod:`~.own_bases`).
        in_force: each basis the frames were densified with, in stream order, from the
            first frame it took over (:meth:`bind`): the output records them.
        cells: score an edge-aware prior with the cells densify draws along SGBM's map
            (sparse stereo mode with ``edge_aware``), as the frames will be densified.
    """

    mode: str
    may_replace: bool
    warmup_frames: int
    robust: str
    calibrate: bool
    name: str = "the basis"
    may_learn: bool = True
    alternatives: list[Callable[[], Candidate]] = field(default_factory=list)
    advisory: list[Callable[[], Candidate]] = field(default_factory=list)
    own_above: float = FITS_BELOW
    switched: Candidate | None = None
    builtin_choice: Candidate | None = None
    checked: bool = False
    adapted: bool = False
    lines: list[str] = field(default_factory=list)
    check: adapt.FitCheck | None = None
    own_check: adapt.FitCheck | None = None
    own_against: adapt.FitCheck | None = None
    first_basis: Basis | None = None
    own_bases: list[Basis] = field(default_factory=list)
    updates: int = 0
    relearned: dict[int, tuple[Basis, int]] = field(default_factory=dict)
    stopped: dict[int, int] = field(default_factory=dict)
    deferred: bool = False
    in_force: list[BasisStart] = field(default_factory=list)
    again: str = MOVED  # the line of a deferred check, "{}": its frames
    cells: bool = False
    _given: Basis | None = None
    _settings: dict[str, object] = field(default_factory=dict)
    _views: list[AdaptFrame] = field(default_factory=list)
    _standing_warning: list[str] = field(default_factory=list)
    _maps: list[npt.NDArray[np.float32]] = field(default_factory=list)
    _recent: list[adapt.Measured] = field(default_factory=list)
    _seen: int = 0
    _next_update: int = 0
    _camera: tuple[tuple[int, int], float] | None = None
    # the newest map added and the ego-motion since its frame (None: unknown)
    _last_map: npt.NDArray[np.float32] | None = None
    _since: npt.NDArray[np.float64] | None = None

    @property
    def active(self) -> bool:
        """Return whether frames are checked at all."""
        return self.mode != "off"

    @property
    def warming(self) -> bool:
        """Return whether frames are still held back for the check."""
        return self.active and not self.checked

    @property
    def maps_seen(self) -> int:
        """Return the maps (distinct views) the log's own basis in force has seen so far."""
        return self._seen

    def wants_maps(self) -> bool:
        """Return whether the stereo workers should keep each frame's SGBM map."""
        return self.warming or self.adapted or self.deferred

    def tuning(self, basis: Basis) -> dict[str, object]:
        """Return the estimate's settings to use with ``basis`` beyond its fitted prior's."""
        chosen = self.switched
        return dict(chosen.tuned) if chosen is not None and chosen.basis is basis else {}

    def untune(self) -> Basis | None:
        """Drop the tuning (fitted on the camera before a change); return its basis, if any."""
        chosen = self.switched
        if chosen is None or chosen.untuned is None:
            return None
        self.switched = chosen.untuned
        return chosen.basis

    def bind(self, frames: list[StereoFrame], basis: Basis) -> None:
        """Note that ``frames``, the next ones in stream order, are densified with ``basis``."""
        last, tuning = self.in_force[-1:], self.tuning(basis)  # a re-check may change only it
        if frames and (not last or last[0].basis is not basis or (last[0].tuning or {}) != tuning):
            self.in_force.append(BasisStart(frames[0], basis, tuning or None))

    def warm_up(
        self, basis: Basis, frames: list[AdaptFrame], settings: dict[str, object]
    ) -> Basis | None:
        """Check ``basis`` on the warm-up frames; return the log's own basis to use, or None.

        Args:
            basis: the basis in use.
            frames: the held-back frames (those with an SGBM map count).
            settings: the estimate's keyword options (sigma, local prior, std scale...).
        """
        # ``checked`` turns True only once the decision is made (``adapted`` set first): the
        # stereo workers measuring ahead keep every map until then (:meth:`wants_maps`),
        # whatever the timing, so the maps a relearned basis sees never depend on it
        self._given, self._settings = basis, settings
        try:
            return self._decide(basis, frames, settings)
        finally:
            self.checked = True

    def _warn_unfit(
        self,
        may_adapt: bool,
        own_frames: int = 0,
        learned: str = "",
        standing: bool = False,
        camera: tuple[tuple[int, int], float] | None = None,
        single: bool = False,
        builtin: tuple[str, bool] = ("", False),
        holes: float | None = None,
        short: bool = False,
    ) -> None:
        """Add a ``warning:`` line when the basis kept loses to linear interpolation.

        ``own_frames``: the log's own basis, learned from that many frames (``learned``
        says which: :meth:`_their`), was tried and did no better (0: not tried).
        ``standing``: it was not learned, the warm-up frames being one view; ``single``: nor
        from a warm-up of one frame.
        ``camera``: (image size, f*b) of the log, named with the basis's when they are not
        alike (:func:`~.adapt.other_camera`). ``builtin``: :meth:`_builtin_advice`'s advice and
        whether the basis it names fits (then no other advice is given). ``holes``: the
        share of the warm-up's pixels SGBM left as holes (dense mode: what the basis fills).
        ``short``: the warm-up is too short for the log's own basis to be checked on frames
        apart from the ones it learns: adapting would not; not advised.
        """
        if self.check is None or not self.check.frames or self.check.fits:
            return
        basis = self._given if self.switched is None else self.switched.basis
        elsewhere = ""
        if camera is not None and basis is not None:
            elsewhere = adapt.other_camera(basis, *camera)  # the likely cause, named first
        advice, enough = builtin
        if standing:
            fix = (
                "; a basis learned from logs of this camera that move may fit: pcainterp "
                "learn LOG -o BASIS.npz, then densify --basis BASIS.npz"
            )
        elif single:
            fix = (
                "; a basis learned from more frames of this camera may fit: pcainterp learn "
                "LOG [LOG ...] -o BASIS.npz, then densify --basis BASIS.npz"
            )
        elif own_frames:
            # what was tried is named, and what differs in the advice: more frames, and
            # learn merges a camera like the built-in one's with the built-in basis's maps
            fix = (
                f", and so is this log's own basis, learned from "
                f"{learned or 'its first ' + _count(own_frames, 'frame')}; a basis learned "
                "from more frames of this camera may fit (learn merges them with the built-in "
                "basis's maps when the camera is like its own): pcainterp learn LOG [LOG ...] "
                "-o BASIS.npz, then densify --basis BASIS.npz"
            )
        elif enough:  # a built-in basis fits where the user's does not
            fix = ""
        elif may_adapt and self.may_learn and not short:
            fix = "; densify without --basis builtin to adapt to this log"
        elif may_adapt and self.may_learn:  # short: a basis of more frames
            fix = (
                "; a basis learned from more frames of this camera may fit: pcainterp learn "
                "LOG [LOG ...] -o BASIS.npz, then densify --basis BASIS.npz"
            )
        elif elsewhere:
            fix = (
                "; learn a basis for this camera: pcainterp learn LOG [LOG ...] -o BASIS.npz, "
                "then densify --basis BASIS.npz"
            )
        elif may_adapt:  # a built-in basis (dense mode learns none of the log's own)
            fix = (
                "; a basis learned from logs of this camera may fit: pcainterp learn LOG "
                "[LOG ...] -o BASIS.npz, then densify --basis BASIS.npz"
            )
        else:  # a basis file of this camera (perhaps learned from this very log)
            fix = (
                "; a basis learned from more frames of this camera may fit: pcainterp learn "
                "LOG [LOG ...] -o BASIS.npz, then densify --basis BASIS.npz"
            )
        if not self.may_learn:  # dense mode: no basis of the log's own, and what it does
            shared = "" if holes is None else f", {holes:.0%} of this log's pixels"
            fix = (
                "; dense mode does not adapt the basis, and uses it mostly to fill SGBM's "
                f"holes{shared} (where SGBM matched, its own value dominates){fix}"
            )
        fix = elsewhere + advice + fix
        self.lines.append(unfit_warning(self.check, "held-out SGBM pixels", fix))

    def _builtin_advice(
        self, check: Callable[[Basis, dict[str, object]], adapt.FitCheck]
    ) -> tuple[str, bool]:
        """Name plain ``densify`` when a built-in basis does better than a user's that loses.

        For a basis the user chose (:attr:`advisory` holds the built-in bases to compare it
        with) that loses to linear interpolation: the built-in bases are checked on the
        same pixels (only on this warning's path) and the one ``--basis builtin`` chooses
        (the street basis when it fits well, else the better one) is named when its error
        is lower. The advice is densify without ``--basis``: it checks that basis too, and
        the indoor basis with the rougher kernel ``--basis builtin`` does not try (bug hunt
        16D F4: 0.195 and 0.250 px against --basis builtin's 0.219 and 0.257). Returns
        (the advice or "", whether the basis named fits).
        """
        if self.check is None or self.check.fits or self.check.degenerate:
            return "", False
        if not self.check.frames:
            return "", False
        checked = []
        for load in self.advisory:
            candidate = load()
            result = check(candidate.basis, candidate.settings)
            if result.frames:
                checked.append((candidate, result))
        if not checked:
            return "", False
        candidate, result = checked[0]  # the street basis first, as --basis builtin checks
        if result.ratio >= FITS_BELOW:
            candidate, result = min(checked, key=lambda pair: pair[1].prior)
        if not result.prior < self.check.prior:
            return "", False
        return (
            f"; {candidate.name} does better ({result.ratio:.2f}x linear): densify without "
            "--basis, which checks it and the built-in bases' other kernels and takes the best",
            result.fits,
        )

    def warn_std_scale(self, scale: float, name: str | None = None) -> None:
        """Warn (once) when the basis in use has an absurd fitted std scale.

        Above :data:`~.fitting.ABSURD_STD_SCALE` its posterior std is degenerate and the
        std written rests on that factor alone. ``name``: how to name the basis (default:
        the given one's :attr:`name`).
        """
        if not scale > fitting.ABSURD_STD_SCALE:
            return
        line = (
            f"warning: {name or self.name} has a fitted std scale of {scale:.3g}: its own "
            "posterior std is about 0 (a basis learned from too few maps), so the std written "
            "rests on that one factor; learn a basis from more frames of this camera "
            "(pcainterp learn LOG [LOG ...] -o BASIS.npz) or densify without --basis"
        )
        if line not in self.lines:
            self.lines.append(line)

    def _chosen_line(self, given: adapt.FitCheck) -> str:
        """Return the line naming the built-in basis chosen over the given one (``given``).

        When the two errors print alike at the figures' precision, the line says it is a
        near-tie, with enough digits to tell them apart (both lines read "1.01 px" on a log
        whose errors were 1.005 and 1.014 px); the choice itself is the same.
        """
        if self.switched is None or self.check is None:
            return ""
        if f"{self.check.prior:.2f}" != f"{given.prior:.2f}":
            return f"prior: {self.switched.name} chosen (fits this log better)"
        chosen, other = _figures(self.check.prior, given.prior)
        return (
            f"prior: {self.switched.name} chosen by a near-tie ({chosen} px against "
            f"{other} for {self.name}); --basis builtin-street or builtin-indoor forces one"
        )

    def _their(self, frames: list[AdaptFrame], count: int) -> str:
        """Name the frames a check is made on: "its first 8 frames" at the warm-up.

        A check made again (a camera change, a basis that stopped fitting, a standing start)
        is made on later frames: "8 frames from frame 20 to 27".
        """
        if not self.checked or not frames:
            return f"its first {_count(count, 'frame')}"
        first, last = frames[0].index, frames[-1].index
        return f"{_count(count, 'frame')} from frame {first} to {last}"

    def end_line(self) -> str | None:
        """Return the line of a log that ended before a check made again, else None.

        The check announced (after a camera change, a basis that stopped fitting, a standing
        start) waits for :attr:`warmup_frames` frames of other views; a log that ends first
        keeps the basis in use to its end.
        """
        if not self.deferred:
            return None
        kept = self.name if self.switched is None else self.switched.name
        return (
            "prior: the log ended before the basis choice was made again (on "
            f"{_count(len(self._views), 'frame')} of other views of the {self.warmup_frames} it "
            f"is made on): {kept} kept to the end"
        )

    def _decide(
        self, basis: Basis, frames: list[AdaptFrame], settings: dict[str, object]
    ) -> Basis | None:
        usable = [f for f in frames if f.sgbm_map is not None and f.grid_map is not None]
        if not usable:  # a feature stream: no dense map to hold pixels out of
            return self._check_left_out(basis, frames, settings)
        size, fb = usable[0].image_size, usable[0].focal_baseline
        usable = [f for f in usable if f.image_size == size and f.focal_baseline == fb]
        usable = adapt.typical_frames(usable, self.lines)  # few measurements: no reference
        measured = [f.measured() for f in usable]
        # the held-out pixels and plain interpolation there: once per frame, for every basis
        held_out = [
            f.held_out
            if f.held_out is not None
            else adapt.HeldOut.of(m.reference, m.pixels, m.disparities, f.clipped)
            for f, m in zip(usable, measured, strict=True)
        ]

        per_frame: dict[int, list[adapt.FrameCheck]] = {}  # each basis's, by id

        def check(candidate: Basis, options: dict[str, object]) -> adapt.FitCheck:
            cells = self.cells and check_cells(options)
            grid = candidate.grid_size
            estimates = densify_batch(
                candidate,
                [f.pixels for f in usable],
                [f.disparities for f in usable],
                uncertainty="none",
                image_size=size,
                focal_baseline=fb,
                robust=self.robust,
                with_depth=False,  # scored on the disparity only
                partitions=[f.cells(grid) for f in usable] if cells else None,
                **options,  # type: ignore[arg-type]
            )
            scores = [
                h.score(e.disparity, e.min_disparity)
                for e, h in zip(estimates, held_out, strict=True)
            ]
            per_frame[id(candidate)] = scores
            return adapt.FitCheck.combine(scores)

        self.check = check(basis, settings)
        self.lines.append(f"prior: {self.name} {self.check.describe()}")
        given = plain = self.check
        if self.may_replace and self.check.frames > 0 and self.check.ratio >= FITS_BELOW:
            # the given built-in basis does not fit well: the other built-in ones, on the
            # same held-out pixels; the lowest error is kept, with no margin for the street
            # basis on a near-tie: tried (2-8 %), it changed no real stereo log and made KITTI
            # with SGBM clouds as features 13 % worse (the indoor basis was right there)
            for load in self.alternatives:
                candidate = load()
                other = check(candidate.basis, candidate.settings)
                self.lines.append(f"prior: {candidate.name} {other.describe()}")
                if other.frames and other.prior < self.check.prior:
                    self.check, self.switched = other, candidate
            # the chosen indoor basis with a rougher kernel (rougher.try_rougher); not in
            # dense mode, where the basis fills SGBM's holes, which no check scores (measured:
            # sparse mode only); the own basis is tried as without it (room 5: 0.28 -> 0.21 px)
            indoor, plain = self.switched, self.check
            tune = self.mode == "auto" and self.may_learn  # `--basis builtin`: as they are
            if indoor is not None and self.check.ratio >= FITS_BELOW and tune:
                scores = per_frame.get(id(indoor.basis), [])
                rough = rougher.try_rougher(
                    basis,
                    (indoor.basis, indoor.name, indoor.settings),
                    lambda options: check(indoor.basis, options),
                    self.check,
                    (measured, size, fb),
                    robust=self.robust,
                    calibrate=self.calibrate,
                )
                self.lines += [rough.line] if rough is not None else []
                if rough is not None and rough.tuned is None:
                    per_frame[id(indoor.basis)] = scores  # the kernel kept's
                elif rough is not None and rough.tuned is not None:
                    name, tuned = f"{indoor.name} with the street basis's kernel", rough.tuned
                    self.check = rough.check
                    both = indoor.settings | tuned
                    self.switched = Candidate(name, indoor.basis, both, tuned, indoor)
        # a built-in basis that fits well is used as it is: the log's own basis is tried
        # only when none does (its leave-one-out figure, scored against the SGBM maps it
        # learns from, flatters it against the truth)
        try_own = (
            self.mode == "auto"
            and self.may_learn
            and self.may_replace
            and plain.frames > 0
            and plain.ratio >= (self.own_above if self.switched is None else FITS_BELOW)
        )
        maps = [f.grid_map for f in usable if f.grid_map is not None]
        # frames that repeat one view (a camera standing still) are one piece of evidence:
        # the log's own basis is checked only on views it did not learn from
        # the ego-motion's views, of the frames in order, for the frames kept
        # (a chain whose first frame is left out, typical_frames or no map: its first kept)
        links, at = still_links(frames), {id(f): k for k, f in enumerate(usable)}
        first_kept: dict[int, int] = {}
        same_as = [
            first_kept.setdefault(links[j], at[id(f)]) for j, f in enumerate(frames) if id(f) in at
        ]
        views = adapt.view_labels(maps, same_as=same_as)
        distinct = int(views.max()) + 1 if views.size else 0
        # too few frames for the gap rule: a left-out frame's basis would learn its
        # neighbours, whose figure flatters it (a 4-frame room: 0.15 px held out, 0.35 px
        # against the truth, its std calibrated there holding 52 % of it)
        short = distinct >= 2 and any(step.near for step in adapt.leave_out_plan(maps, views=views))
        if not try_own:
            if self.switched is not None:
                self.lines.append(self._chosen_line(given))
            holes = None
            if not self.may_learn and not self.check.fits:  # dense mode: its SGBM holes
                sgbm = [f.sgbm_map for f in usable if f.sgbm_map is not None]
                holes = float(np.mean([np.mean(~np.isfinite(m)) for m in sgbm]))
            builtin = self._builtin_advice(check)
            self._warn_unfit(
                self.may_replace, camera=(size, fb), builtin=builtin, holes=holes, short=short
            )
            return None if self.switched is None else self.switched.basis
        kept = f"{self.name} kept" if self.switched is None else f"{self.switched.name} chosen"
        log_goes_on = len(frames) >= self.warmup_frames  # fewer: the log ended in the warm-up
        if len(maps) >= 2 and distinct < 2 and self.check.fits and log_goes_on:
            # one view and more log to come: nothing to check the log's own basis on, and
            # the frames that follow are not that view
            self.lines.append(
                f"prior: {kept}; this log's own basis not tried: "
                f"{self._their(usable, len(maps))} are one view (the camera stood still), none "
                "left to check it on"
            )
            return None if self.switched is None else self.switched.basis
        if distinct < 2:
            # a basis learned from one view spans its noise: its std covered 67 % of the
            # truth on a synthetic street standing still (the built-in one's 97 %), and the
            # frames that follow when the camera moves are views it never saw. From one
            # frame, no frame is left to calibrate its std on: calibrated on the frame it
            # reproduces, it covered 0-67 % of the truth on 7 one-frame synthetic logs (4
            # cameras), the built-in basis kept 92-97 %, its depth 10 % better to 21 % worse
            # per log, 2.5 % worse on average
            best = self.name if self.switched is None else self.switched.name
            again = (
                f" (checked again on the first {_count(self.warmup_frames, 'frame')} of other "
                "views)"
                if log_goes_on
                else ""
            )
            self.lines.append(
                f"prior: the camera barely moves: kept {best}; this log's own basis is not "
                f"learned: {self._their(usable, len(maps))} are one view{again}"
                if len(maps) >= 2
                else f"prior: kept {best}; this log's own basis is not learned from one frame: "
                f"no other frame to calibrate its std on{again}"
            )
            before = len(self.lines)
            self._warn_unfit(
                False, standing=len(maps) >= 2, single=len(maps) < 2, camera=(size, fb)
            )
            self._standing_warning = self.lines[before:]  # dropped if the check runs again
            self.deferred, self._views, self.again = log_goes_on, [], MOVED
            self._camera = (size, fb)
            self._last_map, self._since = maps[-1], np.eye(4)
            return None if self.switched is None else self.switched.basis
        if short:
            # as one pair (above): the built-in basis's std holds the truth, the own one's
            # not (2 full-size frames of a synthetic room: equal error, +-2 sigma 94.7 %
            # against 81.5 %, 6.7 % in SGBM's holes)
            best = self.name if self.switched is None else self.switched.name
            self.lines.append(
                f"prior: kept {best}; this log's own basis is not tried: "
                f"{self._their(usable, len(maps))} are too few to check it on frames apart from "
                f"the ones it learns (a frame's check learns {adapt.LEAVE_OUT_MAPS} maps more "
                f"than {adapt.LEAVE_OUT_GAP} frames away from it)"
            )
            self._warn_unfit(False, single=True, camera=(size, fb))
            self._camera = (size, fb)
            return None if self.switched is None else self.switched.basis
        # one map per view (its first): copies teach a basis their noise, not a direction
        _, firsts = np.unique(views, return_index=True)
        view_maps = [maps[index] for index in firsts]
        # the std is calibrated on the frames left out of the maps (below)
        own = adapt.refit_prior(
            adapt.own_basis(view_maps, size, fb), measured, robust=self.robust, calibrate=False
        )
        prior = own.meta.get("prior", {})
        held = adapt.leave_one_out(
            maps,
            measured,
            prior,
            image_size=size,
            focal_baseline=fb,
            robust=self.robust,
            calibrate=self.calibrate,
            views=views,
            held_out=held_out,
        )
        assert held is not None  # two views or more
        self.own_check = held.check
        if held.std_scale is not None:
            own = adapt.with_prior(own, {**prior, "std_scale": held.std_scale})
        own_error = held.check.prior
        # the basis in use, on the frames and pixels the own one was checked on (it was on
        # all warm-up frames: 0.90 px against linear's 0.89, the own 0.78 against 0.75)
        chosen_basis = basis if self.switched is None else self.switched.basis
        scores = per_frame.get(id(chosen_basis), [])
        same = self.check
        if held.left_out and len(scores) == len(usable):
            same = adapt.FitCheck.combine([scores[index] for index in held.left_out])
        self.own_against = same
        better = own_error < same.prior * (1.0 if not plain.fits else adapt.ADAPT_GAIN)
        if not better:
            if self.check.frames and not self.check.fits and not self.check.degenerate:
                kept += (
                    f" ({self.check.ratio:.2f}x linear: worse than linear interpolation on "
                    "held-out SGBM pixels)"
                )
            if own_error < same.prior:
                # better, but a prior that fits is replaced only below ADAPT_GAIN of its error
                own_px, prior_px = _figures(own_error, same.prior)
                verdict = (
                    f"was better ({own_px} px against {prior_px}) but not by "
                    f"the margin that replaces a prior that fits (an error below "
                    f"{adapt.ADAPT_GAIN:g}x the prior's)"
                )
            elif same is not self.check:  # the figures of the frames both were checked on
                own_px, prior_px = _figures(own_error, same.prior)
                verdict = f"did no better ({own_px} px against {prior_px} on the same frames)"
            else:
                verdict = "did no better"
            self.lines.append(
                f"prior: {kept}; this log's own basis {verdict}: {held.check.describe()}"
            )
            # its own basis was tried: no adapting left to suggest
            self._warn_unfit(
                False,
                own_frames=len(maps),
                learned=self._their(usable, len(maps)),
                camera=(size, fb),
            )
            return None if self.switched is None else self.switched.basis
        chosen = self.name if self.switched is None else self.switched.name
        if not self.check.fits:
            why = (
                "the built-in bases do not fit this camera or scene"
                if self.alternatives
                else f"{self.name} does not fit this camera or scene"
            )
        else:
            own_px, prior_px = _figures(own_error, same.prior)
            why = (
                f"{chosen} fits ({self.check.ratio:.2f}x linear), but this log's own basis did "
                f"better on frames it did not learn ({own_px} px against {prior_px})"
            )
        self.builtin_choice, self.switched = self.switched, None
        self.adapted = True
        self.own_bases.append(own)
        if self.first_basis is None:  # a later adoption is another basis, another file
            self.first_basis = own
        self._camera = (size, fb)
        self._maps = list(view_maps)
        self._recent = measured[-adapt.FIT_FRAMES :]
        self._seen = len(maps)
        self._next_update = 2 * len(maps)
        self._last_map, self._since = maps[-1], np.eye(4)
        how = f"held out: {held.check.describe()}"
        if same is not self.check and not self.check.fits:
            how += f"; {chosen} on the same frames: {same.ratio:.2f}x linear"
        frame_count = _count(len(maps), "frame")
        if distinct < len(maps):
            frame_count += f" of {_count(distinct, 'view')}"
        self.lines.append(
            f"adapted: {why}; learned one from this log's own SGBM maps ({frame_count}, "
            f"{_count(own.n_components, 'component')}; {how}); --basis builtin keeps a "
            "built-in one"
        )
        if not held.check.fits and not held.check.degenerate:
            # the basis used loses to linear interpolation: said as for a built-in one
            self.lines.append(
                unfit_warning(
                    held.check,
                    "held-out SGBM pixels",
                    "; this log's own basis, used for doing better than the built-in ones "
                    "there, loses to it too; a basis learned from more frames of this camera "
                    "may fit: pcainterp learn LOG [LOG ...] -o BASIS.npz, then densify "
                    "--basis BASIS.npz",
                )
            )
        return own

    def _check_left_out(
        self, basis: Basis, frames: list[AdaptFrame], settings: dict[str, object]
    ) -> Basis | None:
        """Check ``basis`` by leaving every 5th measurement out (logs without SGBM maps).

        Returns the other built-in basis to use when the given built-in one does not fit
        well and that one does better on the same left-out measurements, else None.
        """

        def check(candidate: Basis, options: dict[str, object]) -> adapt.FitCheck:
            checks = []
            for frame in frames:
                kept, left_out = adapt.left_out_split(frame.pixels.shape[0])
                if left_out.size == 0 or kept.size < 3:
                    continue
                (estimate,) = densify_batch(
                    candidate,
                    [frame.pixels[kept]],
                    [frame.disparities[kept]],
                    uncertainty="none",
                    image_size=frame.image_size,
                    focal_baseline=frame.focal_baseline,
                    robust=self.robust,
                    with_depth=False,  # scored on the disparity only
                    **options,  # type: ignore[arg-type]
                )
                checks.append(
                    adapt.check_left_out(
                        estimate.disparity,
                        frame.pixels,
                        frame.disparities,
                        kept,
                        left_out,
                        estimate.min_disparity,
                    )
                )
            return adapt.FitCheck.combine(checks)

        where = "left-out measurements"
        self.check = check(basis, settings)
        self.lines.append(f"prior: {self.name} {self.check.describe(where)}")
        given = self.check
        if self.may_replace and self.check.frames > 0 and self.check.ratio >= FITS_BELOW:
            for load in self.alternatives:
                candidate = load()
                other = check(candidate.basis, candidate.settings)
                self.lines.append(f"prior: {candidate.name} {other.describe(where)}")
                if other.frames and other.prior < self.check.prior:
                    self.check, self.switched = other, candidate
        if self.switched is not None:
            self.lines.append(self._chosen_line(given))
        if self.check.frames and not self.check.fits:
            advice, enough = self._builtin_advice(check)
            fix = advice + (
                ""
                if enough
                else "; learn a basis for this camera and scene: pcainterp learn LOG -o "
                "BASIS.npz, then densify --basis BASIS.npz"
            )
            self.lines.append(unfit_warning(self.check, where, fix))
        return None if self.switched is None else self.switched.basis

    def update(self, frames: list[AdaptFrame], current: Basis | None = None) -> Basis | None:
        """Add the frames' maps to the log's own basis; return a relearned basis, or None.

        Relearned each time the number of maps seen doubles; its prior refitted, keeping
        the kernel and process noise of ``current`` (the basis in use) when given. A frame of
        the view last added (the camera standing still) is not added: copies of one view
        teach the basis their noise, and calibrate its std on it.
        """
        if self.deferred:
            return self._revisit(frames, current)
        if not self.adapted or self._camera is None:
            return None
        for frame in frames:
            if frame.grid_map is None or (frame.image_size, frame.focal_baseline) != self._camera:
                self._since = None  # the motions chain frame to frame
                continue
            if self._repeats(frame):
                continue
            self._last_map, self._since = frame.grid_map, np.eye(4)
            self._maps.append(frame.grid_map)
            self._recent.append(frame.measured())
            self._seen += 1
        self._recent = self._recent[-adapt.FIT_FRAMES :]
        if len(self._maps) > MAX_MAPS:
            self._maps = self._maps[::2]
        if self._seen < self._next_update:
            return None
        self._next_update = 2 * self._seen
        self.updates += 1
        size, fb = self._camera
        # the std is calibrated on the recent frames with a basis learned without their
        # maps (the newest ones): their errors are those of frames to come
        older = self._maps[: -len(self._recent)] if self._recent else self._maps
        relearned = adapt.refit_prior(
            adapt.own_basis(self._maps, size, fb),
            self._recent,
            robust=self.robust,
            calibrate=self.calibrate,
            keep=current,
            calibrate_with=adapt.own_basis(older, size, fb) if len(older) >= 2 else None,
        )
        self.relearned[len(self.own_bases)] = (relearned, frames[-1].index if frames else 0)
        return relearned

    def _revisit(self, frames: list[AdaptFrame], current: Basis | None) -> Basis | None:
        """After a one-view warm-up: check again once the camera shows other views.

        The first ``warmup_frames`` frames that are not the view before them (ego-motion or
        map) are checked as the warm-up frames were; returns the basis to use from the next
        frame on when it (or its :meth:`tuning`) is not ``current``'s, else None.
        """
        for frame in frames:
            if frame.grid_map is None or (frame.image_size, frame.focal_baseline) != self._camera:
                self._since = None
                continue
            if self._repeats(frame):
                continue
            # its motion since the view added before it (frames skipped between): _decide
            # tells views apart by the motions of the frames it gets (still_links)
            since, motion = self._since, frame.motion
            chained = None if since is None or motion is None else motion._replace(transform=since)
            frame = replace(frame, motion=chained)
            self._last_map, self._since = frame.grid_map, np.eye(4)
            self._views.append(frame)
        if len(self._views) < self.warmup_frames or self._given is None:
            return None
        tuned = self.tuning(current) if current is not None else {}  # the kernel in use
        views, self._views, self.deferred, self.switched = self._views, [], False, None
        self.lines = [line for line in self.lines if line not in self._standing_warning]
        self.lines.append(self.again.format(_count(len(views), "frame")))
        chosen = self._decide(self._given, views, self._settings)
        target = self._given if chosen is None else chosen
        return None if target is current and self.tuning(target) == tuned else target

    def _repeats(self, frame: AdaptFrame) -> bool:
        """Return whether ``frame`` is the view of the newest map added (ego-motion or map)."""
        if self._since is not None and frame.motion is not None and frame.camera is not None:
            self._since = frame.motion.transform @ self._since
            shift = view_shift(self._since, frame.pixels, frame.disparities, frame.camera)
            if shift < STILL_SHIFT:
                return True
        else:
            self._since = None
        assert frame.grid_map is not None
        last = self._last_map
        return last is not None and adapt.view_distance(frame.grid_map, last) < adapt.SAME_VIEW
