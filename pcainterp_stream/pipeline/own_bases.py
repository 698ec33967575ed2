"""The bases of a log's own that densified an output: their files, names and lines.

A basis a fit check adopted is saved beside the output as ``OUTPUT.basis.npz`` (the first
check's; the output's channels name it when it densified the first frames),
``OUTPUT.basis-2.npz`` (a check made again after a camera change or a basis that stopped
fitting, :mod:`~pcainterp_stream.pipeline.refit`)...; the last one relearned from each while
streaming as ``OUTPUT.final.basis.npz`` (``OUTPUT.final.basis-2.npz``...), also when it was
relearned at the last frame of its camera or the log and densified no frame. The output's
``pcainterp.basis`` record names each that densified frames by that file, so ``evaluate``
finds them.
"""

from __future__ import annotations

import errno
from dataclasses import dataclass, replace
from pathlib import Path
from typing import IO

from pcainterp_stream.errors import BasisError
from pcainterp_stream.estimate.basis import Basis, builtin_kind
from pcainterp_stream.frontend.pairing_stats import PairingStats
from pcainterp_stream.frontend.sgbm_resolution import by_camera
from pcainterp_stream.frontend.stereo import SgbmConfig
from pcainterp_stream.io.output_paths import make_partial_file, write_advice
from pcainterp_stream.io.outputs import BASES_RECORD
from pcainterp_stream.io.path_text import path_text
from pcainterp_stream.pipeline.adaptation import Adaptation
from pcainterp_stream.pipeline.wording import count as _count
from pcainterp_stream.records import StereoCamera

RELEARNED = "self-supervised, relearned while streaming (not saved)"
"""How the :data:`~.outputs.BASES_RECORD` record names a relearned basis no file holds."""


@dataclass(frozen=True)
class OwnBasis:
    """A basis of the log's own that densified frames of the output (or was relearned last).

    Attributes:
        basis: the basis.
        adoption: which check adopted it or the basis it was relearned from (1: the first;
            a check made again after a camera change or a basis that stopped fitting: 2...).
        relearned: relearned while streaming (else adopted by the check).
        first: the first frame densified with it (not ``densified``: the frame whose map
            completed it).
        until: the first frame densified with another basis after it (None: the log's end;
            not ``densified``: where its adoption gave way).
        name: how the output's record names it.
        path: the file it is saved as, beside the output (None: not saved).
        opening: it densified the first frames (the output's channels name it).
        densified: it densified frames (else it was relearned at the last frame of its
            camera or of the log: saved, and named by no entry of the record).
        seen: the maps its adoption saw to the log's end (distinct views; 0: not known),
            of which a basis relearned while streaming learned those up to the last
            doubling (:meth:`~.adaptation.Adaptation.update`).
        stopped: the frame at which its adoption's basis stopped fitting this log
            (:mod:`~.refit`), None: it did not. Such a basis is not advised for other logs
            of the camera: on two other rooms of the camera whose log stopped one, it gave
            4.5x and 5.5x the default's error (bug hunt 16D F1).
    """

    basis: Basis
    adoption: int
    relearned: bool
    first: int
    until: int | None
    name: str
    path: Path | None
    opening: bool = False
    densified: bool = True
    seen: int = 0
    stopped: int | None = None

    def reuse(self) -> str:
        """Return the advice on other logs: reuse it, or not, when it stopped fitting."""
        if self.stopped is None:
            return "densify --basis with it for other logs of this camera"
        return (
            f"it stopped fitting this log at frame {self.stopped}: kept for inspection only, "
            "not for other logs of this camera; plain densify or pcainterp learn for those"
        )

    def frames(self) -> str:
        """Return "frames 16-23" or "frames 16 to the end"."""
        if self.until is None:
            return f"frames {self.first} to the end"
        return (
            f"frames {self.first}-{self.until - 1}"
            if self.until - 1 > self.first
            else (f"frame {self.first}")
        )

    def described(self, owns: list[OwnBasis]) -> str:
        """Return what the "wrote" line says of it (``owns``: every one of the log's)."""
        channels = self.opening  # the output channels name it
        more = any(o.adoption == self.adoption and o.relearned for o in owns)
        again = self.adoption > 1
        if not self.relearned:
            where = (
                "the output names it; evaluate re-densifies with it"
                if channels
                else f"the output's {BASES_RECORD} record names it for {self.frames()}"
            )
            what = (
                "the basis learned from this log's first frames"
                if channels
                else "the basis learned from this log's own SGBM maps by the "
                + ("check made again" if again else "fit check")
            )
            tail = "" if more and self.stopped is None else f"; {self.reuse()}"
            return f"{what} ({where}{tail})"
        if self.until is None and not again:
            # relearned each time the maps double: the last doubling's, not all of them
            learned = self.basis.n_train
            maps = (
                f"{learned} of the {self.seen} maps this log's own basis saw, when they last "
                "doubled"
                if self.seen > learned
                else "all of this log's maps"
            )
            return f"the basis relearned from {maps} ({self.reuse()})"
        if not self.densified:
            return (
                f"the basis relearned from the maps up to frame {self.first}, the last of its "
                f"camera there: it densified no frame ({self.reuse()})"
            )
        return (
            f"the basis relearned while streaming, last in force on {self.frames()} (the "
            f"output's {BASES_RECORD} record names it; {self.reuse()})"
        )


def own_bases(
    adaptation: Adaptation, given: Basis, output: Path | IO[bytes] | None
) -> list[OwnBasis]:
    """Return the bases of the log's own that densified frames, in stream order, named.

    A basis a check adopted is ``OUTPUT.basis.npz`` (the first check's; the output's
    channels name it when it densified the first frames), ``OUTPUT.basis-2.npz`` (a check
    made again, after a camera change or a basis that stopped fitting)...; the last basis
    relearned from each is ``OUTPUT.final.basis.npz`` (``OUTPUT.final.basis-2.npz``...);
    the relearned ones between are not saved (:data:`RELEARNED`). The last relearned from
    an adoption at the last frame of its camera (or of the log) densified no frame: it comes
    after its adoption's others (``densified`` False), saved, and the one before it is not.
    Without a file output none is saved: the first is named ``self-supervised``.
    """
    starts = adaptation.in_force
    adopted = {id(own): number for number, own in enumerate(adaptation.own_bases, 1)}
    owns: list[OwnBasis] = []
    adoption = 0
    for at, start in enumerate(starts):
        used = start.basis
        if builtin_kind(used) is not None or used is given:
            continue
        relearned = id(used) not in adopted
        adoption = adoption if relearned else adopted[id(used)]
        following = starts[at + 1] if at + 1 < len(starts) else None
        until = following.frame.index if following is not None else None
        # the last relearned one of its adoption: the next basis is not relearned from it
        last = (
            following is None
            or id(following.basis) in adopted
            or (builtin_kind(following.basis) is not None or following.basis is given)
        )
        path: Path | None = None
        if isinstance(output, Path) and (not relearned or last):
            path = (final_basis_path if relearned else own_basis_path)(output, adoption)
        if path is not None:
            name = path.name
        elif relearned:
            name = RELEARNED
        else:
            name = own_basis_label(output) if adoption == 1 else "self-supervised (not saved)"
        owns.append(
            OwnBasis(used, adoption, relearned, start.frame.index, until, name, path, at == 0)
        )
    if owns and owns[-1].until is None and owns[-1].adoption == len(adaptation.own_bases):
        owns[-1] = replace(owns[-1], seen=adaptation.maps_seen)  # the last adoption's, to the end
    for number, (newest, frame) in adaptation.relearned.items():
        run = [at for at, own in enumerate(owns) if own.adoption == number]
        if not run or any(owns[at].basis is newest for at in run):
            continue  # densified frames (or its adoption none: not one of the log's)
        end = run[-1]
        if owns[end].relearned:  # the one it was relearned from: one of those between now
            owns[end] = replace(owns[end], name=RELEARNED, path=None)
        path = final_basis_path(output, number) if isinstance(output, Path) else None
        name = path.name if path is not None else RELEARNED
        unused = OwnBasis(newest, number, True, frame, owns[end].until, name, path, False, False)
        owns.insert(end + 1, unused)
    stops = adaptation.stopped
    return [replace(own, stopped=stops.get(own.adoption)) for own in owns]


def save_own_bases(owns: list[OwnBasis], log: Path) -> tuple[list[OwnBasis], list[str]]:
    """Save each of ``owns`` that has a file beside the output; never fail the run for one.

    Returns:
        Those saved, and a warning for each that could not be (a full disk, a name too
        long): the output is written all the same, and its record still names the file,
        which densifying ``log`` again where it can be written makes.
    """
    saved, warnings = [], []
    for own in owns:
        if own.path is None:
            continue
        try:
            own.basis.save(own.path, partial_file=make_partial_file)  # 9C F3, F4
        except BasisError as err:
            cause = err.__cause__
            why = (  # "No space left on device; free some space, or write it elsewhere"
                f"{cause.strerror}; {write_advice(cause)}"
                if isinstance(cause, OSError) and cause.errno != errno.ENAMETOOLONG
                else write_advice(cause)
                if isinstance(cause, OSError)
                else str(err)
            )
            warnings.append(
                f"the adapted basis {own.path} was not written ({why}): the output was "
                f"written without it, though its record names it; densify {log} again to "
                "write it"
            )
        else:
            saved.append(own)
    return saved, warnings


def adoption_lines(owns: list[OwnBasis]) -> list[str]:
    """Return the "adapted basis:" line of each basis of the log's own adopted.

    Its last relearned basis's maps and components, and whether it was in force at the end
    or gave way (a camera change, or it stopped fitting) at a frame.
    """
    lines = []
    for own in owns:
        if own.relearned:
            continue
        run = [o for o in owns if o.adoption == own.adoption]
        last, updates = run[-1], sum(o.relearned for o in run)
        when = "at the end" if last.until is None else f"when it gave way at frame {last.until}"
        if last.stopped is not None and last.until is None:  # stopped at the log's last frame
            when = f"when it stopped fitting at frame {last.stopped}"
        which = "adapted basis" if own.adoption == 1 else f"adapted basis {own.adoption}"
        lines.append(
            f"{which}: {_count(last.basis.n_train, 'map')}, "
            f"{_count(last.basis.n_components, 'component')} {when} "
            f"({updates} update{'s' if updates != 1 else ''} while streaming)"
        )
    return lines


def matched_alone(
    stats: PairingStats, given: SgbmConfig, chosen: SgbmConfig
) -> dict[StereoCamera, str]:
    """Return the later cameras ``auto`` would match at another resolution, with it.

    ``--stereo-downscale auto`` chooses SGBM's resolution on the first pair's camera, for the
    whole log: a camera that follows is matched at that resolution. Returns, for each
    camera after the first that the same rule (``given``, still ``by_camera``) would match
    at another resolution than ``chosen``'s alone, that choice ("full resolution (f*b 24 <
    90 px*m)"), for the ``cameras:`` line.
    """
    notes: dict[StereoCamera, str] = {}
    for seen in list(stats.camera_frames)[1:]:
        alone, phrase = by_camera(given, seen.focal_baseline, seen.width, seen.height)
        if phrase is None or alone.downscale == chosen.downscale:
            continue
        resolution = "full" if alone.downscale == 1 else "half"
        why = phrase.partition("auto: ")[2].removesuffix(")")  # "f*b 24 < 90 px*m"
        notes[seen] = f"{resolution} resolution" + (f" ({why})" if why else "")
    return notes


def own_basis_path(output: Path, adoption: int = 1) -> Path:
    """Return where a run that adapted saves its basis: ``OUTPUT.basis.npz`` beside it.

    ``adoption``: a basis adopted by a check made again later in the log (2, 3...) is saved
    as ``OUTPUT.basis-2.npz``...
    """
    suffix = "" if adoption == 1 else f"-{adoption}"
    return output.with_name(f"{output.stem}.basis{suffix}.npz")


def final_basis_path(output: Path, adoption: int = 1) -> Path:
    """Return where a run that relearned its basis saves the last: ``OUTPUT.final.basis.npz``.

    ``adoption``: as :func:`own_basis_path` (``OUTPUT.final.basis-2.npz``).
    """
    suffix = "" if adoption == 1 else f"-{adoption}"
    return output.with_name(f"{output.stem}.final.basis{suffix}.npz")


def own_basis_label(output: Path | IO[bytes] | None) -> str:
    """Return how the output's channels name a basis learned from the log itself."""
    if isinstance(output, Path):
        return path_text(own_basis_path(output).name)  # metadata is UTF-8: bytes escaped
    return "self-supervised"
