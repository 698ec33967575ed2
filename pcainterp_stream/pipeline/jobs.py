"""The jobs behind the ``pcainterp`` commands: plain functions over paths and configs.

``learn``/``fit_prior`` live in :mod:`~pcainterp_stream.pipeline.learn` and ``densify`` in
:mod:`~pcainterp_stream.pipeline.densify`; this module holds the others and exports all.

Each job streams (one frame, or a small look-ahead of frames, in memory), shows a progress
bar on a terminal, writes its output atomically (temporary file beside the target, renamed
when complete) and raises only :class:`~pcainterp_stream.errors.PcaInterpError` subclasses
on bad input, which the command line prints as one line.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import time
from pathlib import Path

from pcainterp_stream.errors import (
    BasisError,
    PcaInterpError,
)
from pcainterp_stream.estimate.basis import (
    BUILT_IN,
    BUILT_IN_INDOOR,
    BUILTIN_KINDS,
    BUILTIN_LABELS,
    IN_MEMORY,
    Basis,
    builtin_basis,
    builtin_basis_installed,
    builtin_kind,
    check_basis_file,
    default_basis_path,
    default_basis_recipe,
    indoor_basis_path,
)
from pcainterp_stream.frontend.pairing import (
    PairingConfig,
)
from pcainterp_stream.io.densify_record import DENSIFY_RECORD, OUTPUT_PREFIX_KEY
from pcainterp_stream.io.logwriter import WriteSummary
from pcainterp_stream.io.outputs import (
    BASES_RECORD,
    BASIS_FINGERPRINT_KEY,
    BASIS_KEY,
    BasisInForce,
    OutputTopics,
    recorded_bases_of,
    recorded_metadata,
)
from pcainterp_stream.pipeline.blas_threads import restoring_blas_threads
from pcainterp_stream.pipeline.common import _bar, _echo
from pcainterp_stream.pipeline.densify import DensifySummary, densify
from pcainterp_stream.pipeline.learn import LearnOptions, fit_prior, learn
from pcainterp_stream.pipeline.learn_check import check_lines
from pcainterp_stream.pipeline.processor import ProcessorConfig

__all__ = [
    "DensifySummary",
    "LearnOptions",
    "demo",
    "densify",
    "describe_basis",
    "evaluate",
    "fit_prior",
    "import_kitti",
    "info",
    "learn",
    "synth",
]


def synth(
    out: Path,
    *,
    frames: int,
    seed: int,
    scale: float,
    fmt: str | None,
    lidar: bool = False,
    scene: str = "street",
    camera: str = "kitti",
    platform: str = "auto",
) -> WriteSummary:
    """Render a synthetic drive and write it as a log (``pcainterp synth``).

    ``lidar`` also writes the LiDAR-like sparse truth ``/ground_truth/lidar_depth``;
    ``scene``, ``camera`` and ``platform`` choose the world (:mod:`~pcainterp_stream.synth.indoor`).
    """
    from pcainterp_stream.synth import LidarConfig, SynthConfig, generate
    from pcainterp_stream.synth.indoor import camera_options
    from pcainterp_stream.synth.log import write_synthetic_log

    if frames < 1:
        raise PcaInterpError(f"--frames must be at least 1, got {frames}")
    if not 0.05 <= scale <= 4.0:  # also refuses nan
        raise PcaInterpError(f"--scale must be in [0.05, 4], got {scale}")
    if platform != "auto" and scene == "street":
        raise PcaInterpError(
            f"--platform {platform} carries the camera of an indoor scene; a street drive's "
            "camera is on a car: add --scene indoor or drop --platform"
        )
    config = SynthConfig(
        seed=seed,
        frames=frames,
        scale=scale,
        scene=scene,
        platform=platform,
        **camera_options(camera),
    )
    with _bar(frames, f"synth {out.name}") as bar:
        return write_synthetic_log(
            generate(config),
            out,
            format=fmt,
            total=frames,
            progress=lambda done, total: bar.update(done - bar.n),
            lidar=LidarConfig(seed=seed) if lidar else None,
        )


def synth_raw(
    out: Path, *, frames: int, seed: int, scale: float, fmt: str | None, model: str
) -> WriteSummary:
    """Render a synthetic drive recorded raw, as a driver does (``pcainterp synth --raw``)."""
    from pcainterp_stream.synth import SynthConfig
    from pcainterp_stream.synth.raw import write_raw_log

    if frames < 1:
        raise PcaInterpError(f"--frames must be at least 1, got {frames}")
    if not 0.05 <= scale <= 4.0:  # also refuses nan
        raise PcaInterpError(f"--scale must be in [0.05, 4], got {scale}")
    config = SynthConfig(seed=seed, frames=frames, scale=scale)
    with _bar(frames, f"synth --raw {out.name}") as bar:
        return write_raw_log(
            config,
            out,
            model=model,
            format=fmt,
            progress=lambda done, total: bar.update(done - bar.n),
        )


def import_kitti(
    folder: Path, out: Path, *, max_frames: int | None, colour: bool = False
) -> WriteSummary:
    """Convert a KITTI folder into an MCAP log (``pcainterp import-kitti``).

    ``colour``: the colour pair even where the grey one is there (default: the grey pair,
    the colour one in a folder without it).
    """
    from pcainterp_stream.io.kitti import KittiPair, open_kitti
    from pcainterp_stream.io.kitti import import_kitti as convert
    from pcainterp_stream.io.stereo_log import LEFT_IMAGE, LIDAR_DEPTH

    if max_frames is not None and max_frames < 1:
        raise PcaInterpError(f"--max-frames must be at least 1, got {max_frames}")
    with _bar(None, f"import {folder.name}") as bar:

        def progress(done: int, total: int | None) -> None:
            bar.total = total
            bar.update(done - bar.n)

        sequence = open_kitti(folder, pair=KittiPair.COLOUR if colour else None)
        summary = convert(sequence, out, max_frames=max_frames, progress=progress)
    for warning in sequence.warnings:  # on standard error, as cli.common.warn
        print(f"warning: {warning}", file=sys.stderr, flush=True)
    if sequence.lens is not None:
        lefts, rights = sequence.unpaired
        left_out = (
            f"; {lefts} left and {rights} right images with no partner near their stamp left out"
            if lefts or rights
            else ""
        )
        _echo(
            f"unrectified drive ({sequence.camera.width}x{sequence.camera.height}, the raw size "
            "of the calibration file): written as a raw log, /camera/{left,right}/image_raw with "
            f"the raw cameras' camera_info (K, D, R_rect, P_rect); densify rectifies it{left_out}"
        )
    truths = summary.topic_counts.get(LIDAR_DEPTH, 0)
    if truths:
        _echo(
            f"depth truth: {truths} of {summary.topic_counts.get(LEFT_IMAGE, 0)} frames on "
            f"{LIDAR_DEPTH} (from {sequence.truth_folder}); evaluate scores against it"
        )
    elif sequence.unused_truth is not None:
        _echo(
            f"note: the depth truth in {sequence.unused_truth} belongs to the colour camera 2 "
            "and was left out with the grey pair; add --colour to import it"
        )
    return summary


@restoring_blas_threads
def evaluate(
    input_path: Path,
    output: Path | None,
    *,
    basis: Path | Basis | None = None,
    mode: str | None = None,
    sigma: float = 2.0,
    sweep_every: int = 10,
    max_frames: int | None = None,
    topics: OutputTopics | None = None,
    linear: bool = True,
    basis_rows: bool = True,
    reference_topic: str | None = None,
    reference_kind: str = "auto",
    pairing: PairingConfig | None = None,
    stamp_tolerance_ms: float | None = None,
) -> tuple[Path, str]:
    """Evaluate a densified log into a report folder (``pcainterp evaluate``).

    Args:
        input_path: a log written by ``pcainterp densify``.
        output: the report folder; None: ``<log stem>_report`` beside the log.
        basis: the basis for the rows that re-densify (oracle, uncertainty kinds, points
            sweep); None: the one the log records (:func:`evaluation_basis`).
        mode: ``stereo``, ``temporal`` or None (automatic).
        sigma: noise std (px) of the re-densification.
        sweep_every: points sweep on every N-th frame, 0 = off.
        max_frames: evaluate at most this many frames.
        topics: the log's output topics.
        linear: also evaluate linear interpolation (~0.5 s per KITTI-size frame).
        basis_rows: False skips the rows that re-densify with a basis.
        reference_topic: score against this ground-truth image topic of the log.
        reference_kind: ``auto``, ``depth`` or ``disparity`` (what the topic holds).
        pairing: the input pair's topics and rectification (raw images are rectified as
            densify did); None: the synthetic logs' topics.
        stamp_tolerance_ms: a frame's right image, truth, pose and reference message are
            the ones stamped nearest it within this; None: the tolerance the log records
            densify paired with (1 ms if it records none), and for the reference message
            under half the frame interval.

    Returns:
        The report folder and the summary table text.
    """
    from pcainterp_stream.evaluate.log_frames import frame_count
    from pcainterp_stream.evaluate.metrics import Mode, ReferenceKind
    from pcainterp_stream.evaluate.report import EvaluateOptions, summary_table, write_report

    if not 0 < sigma < float("inf"):
        raise PcaInterpError(f"--sigma must be > 0 px, got {sigma}")
    if sweep_every < 0:
        raise PcaInterpError(f"--sweep-every must be >= 0, got {sweep_every}")
    if max_frames is not None and max_frames < 1:
        raise PcaInterpError(f"--max-frames must be at least 1, got {max_frames}")
    if isinstance(basis, Path):
        check_basis_file(basis)
    folder = output or input_path.with_name(input_path.stem + "_report")
    if not basis_rows:
        chosen, note = None, "none, those rows are skipped"
    elif basis is None:
        chosen, note = evaluation_basis(input_path, topics)
    else:
        chosen, note = basis, f"{_basis_name(basis)} (given)"
    options = EvaluateOptions(
        basis=chosen,
        basis_note=note,
        linear=linear,
        mode=Mode(mode) if mode is not None else None,
        sigma=sigma,
        sweep_every=sweep_every,
        max_frames=max_frames,
        reference_topic=reference_topic,
        reference_kind=ReferenceKind(reference_kind),
        pairing=pairing,
        stamp_tolerance_ns=None if stamp_tolerance_ms is None else round(stamp_tolerance_ms * 1e6),
    )
    total = frame_count(input_path, topics or OutputTopics(), max_frames)  # "k/N frames"
    with _bar(total, f"evaluate {input_path.name}") as bar:
        result = write_report(
            input_path,
            folder,
            options,
            topics=topics,
            progress=lambda done: bar.update(done - bar.n),
        )
    return folder, summary_table(result)


def _basis_name(basis: Path | Basis) -> str:
    if isinstance(basis, Path):
        return str(basis)
    kind = builtin_kind(basis)
    return BUILTIN_LABELS[kind] if kind is not None else IN_MEMORY


def evaluation_basis(
    input_path: Path, topics: OutputTopics | None = None
) -> tuple[Basis | Path | None, str]:
    """Choose the basis ``evaluate`` re-densifies with when none is given.

    The one the densified log records in its channel metadata (``io/outputs``), if a file
    of the same content (fingerprint) is where the log records it (relative to the log's
    folder), beside the log or in the working folder (:func:`_recorded_basis_file`); for a
    log that records none (densified by an older version), the built-in basis. Otherwise
    none: the rows that need a basis are skipped, and the note says why.

    Args:
        input_path: a log written by ``pcainterp densify``.
        topics: its output topics.

    Returns:
        The basis (a built-in one loaded, a file as its path, or None) and a note on how it
        was chosen.
    """
    try:
        recorded = recorded_metadata(input_path, topics)
    except PcaInterpError:
        return None, "none (the log cannot be read; the error follows)"
    label = recorded.get(BASIS_KEY)
    fingerprint = recorded.get(BASIS_FINGERPRINT_KEY)
    skipped = "the rows that re-densify with a basis are skipped; pass --basis BASIS.npz"
    if label is None or label in (BUILT_IN, BUILT_IN_INDOOR):
        why = "recorded in the log" if label else "the log records no basis"
        label = label or BUILT_IN
        try:
            basis = builtin_basis("indoor" if label == BUILT_IN_INDOOR else "street")
        except BasisError:
            return None, f"none (the {label} basis is not installed; {skipped})"
        if fingerprint is not None and fingerprint != basis.fingerprint:
            return None, (
                f"none (the log was densified with another {label} basis, fingerprint "
                f"{fingerprint}, not this installation's {basis.fingerprint}; {skipped})"
            )
        return basis, f"{label} ({why})"
    if label == IN_MEMORY:
        return None, f"none (the log was densified with a basis object, no file; {skipped})"
    return _recorded_basis_file(input_path, label, fingerprint, skipped)


def _recorded_basis_file(
    log: Path, label: str, fingerprint: str | None, skipped: str
) -> tuple[Path | None, str]:
    """Find the basis file a log records (``label``) whose content is ``fingerprint``'s.

    Where densify recorded it: the path relative to the log's folder (``densify.basis_label``;
    an absolute path, from older versions, as it is); then a file of its name beside the
    log; then the path, and the name, in the working folder (older versions recorded the
    path as densify was given it, or the name only). The first of those whose fingerprint
    is the log's is the one; a file there with another fingerprint is not used, and the
    note says whether the recorded file changed or another file has its name.
    """
    name = Path(label).name
    recorded = log.parent / label
    places = [recorded, log.parent / name, Path(label), Path(name)]
    seen: set[Path] = set()
    other: tuple[Path, str] | None = None  # the first file there of another fingerprint
    error: BasisError | None = None
    for place in places:
        if not place.is_file() or place.resolve() in seen:
            continue
        seen.add(place.resolve())
        try:
            found = Basis.load(place).fingerprint
        except BasisError as err:
            error = error or err
            continue
        if fingerprint is None or found == fingerprint:
            # the file, not the basis loaded to check it: the report names the file it
            # re-densified with
            return _tidy(place), f"{_tidy(place)} (recorded in the log)"
        other = other or (place, found)
    was = f"the log was densified with {label}, fingerprint {fingerprint}"
    if other is not None:
        place, found = other
        if place.resolve() == recorded.resolve():
            why = f"{_shown(place)} changed since {was}: its fingerprint is now {found}"
        else:
            why = (
                f"{_shown(place)} is another basis of that name (fingerprint {found}), not the "
                f"one the log was densified with ({label}, fingerprint {fingerprint})"
            )
        return None, f"none ({why}; {skipped})"
    if error is not None:
        return None, f"none ({error}; {skipped})"
    if Path(label) == Path(name):
        looked = "beside the log nor in the working folder"
    else:
        looked = f"at {os.path.normpath(recorded)}, nor as {name} beside the log"
        looked += " or in the working folder"
    return None, f"none ({was}, not found {looked}; {skipped})"


def _shown(path: Path) -> str:
    """Return how a note names a file: ``./my.npz`` in the working folder, else its path."""
    return f"./{path}" if len(path.parts) == 1 else str(_tidy(path))


def _tidy(path: Path) -> Path:
    """Return ``path`` without ``..`` parts when that is the same file (``out/../b.npz``)."""
    tidy = Path(os.path.normpath(path))
    try:
        return tidy if tidy != path and os.path.samefile(tidy, path) else path
    except OSError:
        return path


def describe_basis(path: Path | None = None, *, builtin: str = "street") -> str:
    """Return a text description of a basis file (None: the built-in ``builtin`` basis)."""
    basis = Basis.load(path) if path is not None else builtin_basis(builtin)
    height, width = basis.image_size
    grid_height, grid_width = basis.grid_size
    ratio = basis.explained_variance_ratio
    meta = basis.meta if isinstance(basis.meta, dict) else {}
    learning = meta.get("learning", {}) if isinstance(meta.get("learning"), dict) else {}
    source = meta.get("source", {}) if isinstance(meta.get("source"), dict) else {}
    title = f"{path}: pcainterp basis" if path is not None else _built_in_title(builtin)
    tuned, rule = meta.get("finetune"), source.get("with_synthetic_rule")
    tuned = tuned if isinstance(tuned, dict) else None
    lines = [
        title,
        f"  image size       {width}x{height} px"
        + (" (the basis learn merged into: its grid and camera)" if tuned else ""),
        f"  grid             {grid_width}x{grid_height} ({grid_width * grid_height} pixels)",
        f"  components       {basis.n_components}",
        f"  variance         {100 * ratio:.2f} % of the training variance explained",
        f"  first eigenvalue {basis.eigenvalues[0]:.4g} px^2",
        f"  focal*baseline   {basis.focal_baseline:.4g} px*m",
        f"  training maps    {basis.n_train}"
        + (f" ({source['maps']})" if isinstance(source.get("maps"), str) else ""),
    ]
    logs, drives, seeds = source.get("logs"), source.get("drives"), source.get("seeds")
    if isinstance(logs, list) and logs:
        lines.append(f"  drives           {len(logs)} log(s): {', '.join(map(str, logs[:4]))}")
    elif isinstance(drives, int):
        span = f" (seeds {seeds[0]}-{seeds[-1]})" if isinstance(seeds, list) and seeds else ""
        lines.append(f"  drives           {drives} synthetic drives{span}")
    walks, walk_seeds = source.get("indoor_walks"), source.get("indoor_seeds")
    if isinstance(walks, int) and walks > 0:
        span = (
            f" (seeds {walk_seeds[0]}-{walk_seeds[-1]})"
            if isinstance(walk_seeds, list) and walk_seeds
            else ""
        )
        lines.append(
            f"  indoor walks     {walks} synthetic rooms, corridors and halls{span}: "
            "hand-held, drone and ground-robot heights and pitches"
        )
    cameras = source.get("cameras")
    if isinstance(cameras, list) and cameras:
        lines.append(
            f"  cameras          {', '.join(map(str, cameras))} (each view stretched onto "
            f"{width}x{height}, disparity in its f*b)"
        )
    lines.append(f"  method           {learning.get('method', '?')}")
    if tuned is not None:
        into = {BUILT_IN: "the built-in street basis", BUILT_IN_INDOOR: "the built-in indoor basis"}
        merged = into.get(str(source.get("with_synthetic_basis")), "a basis")
        prior = tuned.get("prior_basis")
        if isinstance(prior, dict) and "fingerprint" in prior:
            merged += (
                f" (fingerprint {prior['fingerprint']}, {prior.get('n_components', '?')} "
                f"components, {prior.get('n_train', '?')} maps)"
            )
        lines.append(
            f"  fine-tuned       {tuned.get('n_maps', '?')} maps merged into {merged} counted "
            f"as {tuned.get('n_prior', '?')} maps (learn --with-synthetic"
            + (f"; {rule})" if isinstance(rule, str) else ")")
        )
        lines += _maps_camera(tuned, basis)
    elif isinstance(rule, str) and rule != "off":
        lines.append(f"  synthetic maps   not merged ({rule})")
    fitted = meta.get("prior")
    if isinstance(fitted, dict):
        local = fitted.get("local")
        kernel = (
            f"{local.get('kernel', 'laplace')} kernel, {local['length_scale']:g} px, "
            f"{local['variance']:.3g} px^2"
            if isinstance(local, dict)
            else "none (the paper's prior had the best evidence)"
        )
        lines += [
            f"  fitted prior     {kernel}"
            + (" (kept)" if "local_kept_from" in fitted else "")
            + f"; sigma {fitted.get('sigma', float('nan')):.3g} px; "
            f"process noise {fitted.get('process_noise', float('nan')):g}; "
            f"std scale {fitted.get('std_scale', 1.0):.3g}"
            + (
                f" ({fitted['innovation_std_scale']:.3g} with the per-frame covariance scale)"
                if "innovation_std_scale" in fitted
                else ""
            ),
        ]
        lines += check_lines(fitted)  # learn's held-out figures
    else:
        lines.append("  fitted prior     none (the paper's model; learn fits one by default)")
    if path is None and builtin == "indoor":
        lines.append(
            "  learned from     synthetic indoor walks only: rooms, corridors and halls seen "
            "hand-held, from a drone and from a ground robot, by several cameras (densify "
            "chooses it when it fits the first frames of a log better than the street basis; "
            "--basis builtin-indoor forces it)"
        )
        lines += _recipe_lines(builtin)
    elif path is None:
        lines.append(
            "  learned from     synthetic streets only: a forward-looking camera at car height "
            "(densify checks it on the first frames of every log, tries the built-in indoor "
            "basis when it does not fit, and learns one from the log's own stereo when neither "
            "does; --basis builtin-street forces it)"
        )
        lines += _recipe_lines(builtin)
    elif isinstance(meta.get("source"), str):
        lines.append(f"  learned from     {meta['source']}")
    return "\n".join(lines)


def _maps_camera(tuned: dict[str, object], basis: Basis) -> list[str]:
    """Name the camera a fine-tuned basis's own maps came from ([]: not recorded)."""
    size, focal_baseline = tuned.get("maps_image_size"), tuned.get("maps_focal_baseline")
    if not (isinstance(size, list) and len(size) == 2 and isinstance(focal_baseline, float)):
        return []
    height, width = size
    basis_height, basis_width = basis.image_size
    scale = tuned.get("disparity_scale")
    mapped = f", disparity x{scale:.3g}" if isinstance(scale, float) and scale != 1.0 else ""
    return [
        f"  maps' camera     {width}x{height} px, f*b {focal_baseline:.4g} px*m: the camera "
        f"of the logs it learned from, their maps mapped onto {basis_width}x{basis_height}"
        f"{mapped} (densify maps the basis onto each log's camera)"
    ]


def _densified_by(records: list[tuple[str, dict[str, str]]]) -> list[str]:
    """Name the bases a densified MCAP log was made with, from its records ([]: none).

    Per ``pcainterp.densify`` record (one per output prefix), every basis in force from the
    ``pcainterp.basis`` record of its prefix, else the basis of its first outputs, and the
    entries (f*b, min disparity) of its ``pcainterp.cameras`` record (the first 12 of them).
    """
    from pcainterp_stream.evaluate.tuning import describe_tuning, tuning_of
    from pcainterp_stream.io.loginfo import seconds_text
    from pcainterp_stream.io.output_cameras import CAMERAS_RECORD, recorded_cameras_of

    shown = 12  # entries of a pcainterp.cameras record listed (--sigma evidence: up to one a frame)
    densified = [fields for name, fields in records if name == DENSIFY_RECORD]
    in_force = {
        fields.get(OUTPUT_PREFIX_KEY): fields for name, fields in records if name == BASES_RECORD
    }
    cameras = {
        fields.get(OUTPUT_PREFIX_KEY): fields for name, fields in records if name == CAMERAS_RECORD
    }
    lines = []
    for record in densified:
        prefix = record.get(OUTPUT_PREFIX_KEY)
        try:
            bases = recorded_bases_of(in_force[prefix]) if prefix in in_force else []
        except ValueError:
            bases = []
        if not bases and "basis" in record:
            fingerprint = record.get("basis_fingerprint", "unknown")
            bases = [BasisInForce(record["basis"], fingerprint, 0, 0, 0)]
        lines.append(
            "  densified with" + (f" ({prefix})" if prefix and len(densified) > 1 else "") + ":"
        )
        for entry in bases:
            line = f"    {entry.basis} (fingerprint {entry.fingerprint}) from frame "
            line += str(entry.first_frame)
            if entry.tuning:
                try:
                    what = describe_tuning(tuning_of(entry.tuning))
                except ValueError as err:
                    what = str(err)
                line += f", tuned by densify's fit check: {what}"
            lines.append(line)
        if prefix in cameras:  # the camera or min disparity changed mid-log: each frame's own
            try:
                entries = recorded_cameras_of(cameras[prefix])
            except ValueError as err:
                lines.append(f"  cameras: unreadable {CAMERAS_RECORD} record ({err})")
                continue
            lines.append(
                f"  cameras ({len(entries)}, a new one when the camera or the min disparity "
                "changed; compact depth decodes with each one's f*b and min disparity):"
            )
            # the first entries, and every one whose f*b changed (a camera change is never hidden)
            listed = [
                number
                for number, entry in enumerate(entries)
                if number < shown or entry.focal_baseline != entries[number - 1].focal_baseline
            ]
            lines.extend(
                f"    f*b {entries[number].focal_baseline:.6g} px*m, min disparity "
                f"{entries[number].min_disparity:.4g} px from frame {entries[number].first_frame} "
                f"(stamp {seconds_text(entries[number].first_stamp_ns)} s)"
                for number in listed
            )
            kept = set(listed)
            if rest := [entry for number, entry in enumerate(entries) if number not in kept]:
                low = min(entry.min_disparity for entry in rest)
                high = max(entry.min_disparity for entry in rest)
                lines.append(
                    f"    ... {len(rest)} more min disparity changes to frame "
                    f"{rest[-1].first_frame} ({low:.4g}-{high:.4g} px)"
                )
    return lines


def _built_in_title(builtin: str) -> str:
    path = indoor_basis_path() if builtin == "indoor" else default_basis_path()
    return f"built-in {builtin} basis ({path}): pcainterp basis"


def _recipe_lines(builtin: str) -> list[str]:
    """Describe a built-in basis's sidecar: its checksum and the recipe that made it."""
    indoor = builtin == "indoor"
    sidecar = default_basis_recipe(indoor)
    path = indoor_basis_path() if indoor else default_basis_path()
    if not sidecar:
        return [f"  recipe           unknown (no {path.stem}.json beside the basis)"]
    lines = []
    expected = sidecar.get("sha256")
    if isinstance(expected, str):
        actual = hashlib.sha256(path.read_bytes()).hexdigest()
        state = "matches the file" if actual == expected else f"MISMATCH: the file is {actual}"
        lines.append(f"  sha256           {expected} ({state})")
    recipe = sidecar.get("recipe")
    if isinstance(recipe, dict) and recipe:
        pairs = [f"{key}={json.dumps(value)}" for key, value in recipe.items()]
        lines.append(f"  recipe           {', '.join(pairs)}")
    command = sidecar.get("command")
    if isinstance(command, str):
        lines.append(f"  made by          {command}")
    return lines


def info(path: Path | None) -> str:
    """Return the ``pcainterp info`` text of a log or a basis file (None: the built-in)."""
    from pcainterp_stream.io.loginfo import describe, format_info

    if path is None:  # the built-in bases, each with what it was learned from
        kinds = [k for k in BUILTIN_KINDS if k == "street" or builtin_basis_installed(k)]
        return "\n\n".join(describe_basis(None, builtin=kind) for kind in kinds)
    from pcainterp_stream.golden.store import describe_golden_file

    golden = describe_golden_file(path)  # a golden file is neither a log nor a basis
    if golden is not None:
        return golden
    if path.suffix == ".npz":
        return describe_basis(path)
    if path.is_file() and _starts_as_zip(path):
        try:
            return describe_basis(path)
        except BasisError:
            if _holds_basis_arrays(path):
                raise  # a damaged basis under another name: its own message, not "not a log"
    described = describe(path)
    records = [(record.name, dict(record.metadata)) for record in described.metadata]
    return "\n".join([format_info(described), *_densified_by(records)])


def _holds_basis_arrays(path: Path) -> bool:
    """Return whether a zip archive holds a basis file's arrays (``mean.npy``, ``meta.npy``...)."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
    except (OSError, zipfile.BadZipFile):
        return False
    return bool({"mean.npy", "components.npy", "meta.npy"} & names)


def _starts_as_zip(path: Path) -> bool:
    """Return whether a file starts as a zip archive (an ``.npz`` basis under another name).

    False when it cannot be read: the log reader then says so in one line, as densify does
    (a failing disk, /proc/self/mem: EIO).
    """
    try:
        with path.open("rb") as handle:
            return handle.read(4) == b"PK\x03\x04"
    except OSError:
        return False


@restoring_blas_threads
def demo(out: Path, *, spawn_viewer: bool = False, learn_basis: bool = False) -> str:
    """Show the product on a generated drive and return a summary (``pcainterp demo``).

    By default (about a minute on 2 cores): render a held-out synthetic drive (seed
    :data:`DEMO_SEED`, which the built-in basis never saw), densify it with the built-in
    basis, evaluate it against the ground truth (PCA-MAP against nearest neighbour and the
    coverage of the std densify wrote; the slower rows of ``pcainterp evaluate`` are
    skipped). With ``learn_basis`` the whole job instead (about 3 minutes): render training
    drives, learn a basis and fit its prior, densify and evaluate a held-out drive.

    Args:
        out: the folder for the logs, the report and the Rerun recording (created).
        spawn_viewer: stream the densified drive to a Rerun viewer.
        learn_basis: learn a basis from rendered training drives first.

    Returns:
        The summary text.
    """
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:  # a file of that name, a file on the way, a read-only folder
        raise PcaInterpError(
            f"cannot create the demo folder {out}: {err.strerror}; pass --out a folder path"
        ) from err
    if learn_basis:
        return _demo_learn(out, spawn_viewer=spawn_viewer)
    started = time.perf_counter()
    test_log, dense_log = out / "heldout.mcap", out / "heldout_dense.mcap"
    rrd, report_dir = out / "heldout.rrd", out / "report"
    basis = Basis.default()
    _echo(
        f"1/3 rendering a {DEMO_FRAMES}-frame synthetic drive (seed {DEMO_SEED}, never seen by "
        f"the built-in basis) -> {test_log}"
    )
    synth(test_log, frames=DEMO_FRAMES, seed=DEMO_SEED, scale=DEMO_SCALE, fmt="mcap")
    _echo(f"2/3 densifying it with the built-in basis -> {dense_log}, {rrd}")
    summary = densify(test_log, dense_log, None, rrd=rrd, spawn_viewer=spawn_viewer)
    _echo(f"3/3 evaluating the densified drive against ground truth -> {report_dir}/results.md")
    _, table = evaluate(dense_log, report_dir, linear=False, basis_rows=False)
    height, width = basis.image_size
    recipe = default_basis_recipe().get("recipe")
    maps = basis.meta.get("source", {}).get("maps", "") if isinstance(basis.meta, dict) else ""
    described = (
        f"built-in: {basis.n_components} components from {basis.n_train} synthetic "
        f"{'depth ' if 'depth' in str(maps) else ''}maps "
        f"({100 * basis.explained_variance_ratio:.1f} % variance), {width}x{height} px"
        + (" (pcainterp info describes it)" if recipe else "")
    )
    return _demo_summary(
        out, started, described, basis, summary, report_dir, table, dense_log, rrd
    ) + (
        f"\n\nlinear interpolation and the rows that re-densify are left out for speed: "
        f"pcainterp evaluate {dense_log} has them all; pcainterp demo --learn learns a "
        "basis of its own first."
    )


def _demo_learn(out: Path, *, spawn_viewer: bool) -> str:
    """``pcainterp demo --learn``: learn a basis from rendered drives, then as the demo."""
    started = time.perf_counter()
    train_logs = [out / f"train_{seed}.mcap" for seed in DEMO_TRAIN_SEEDS]
    test_log = out / "heldout.mcap"
    basis_path, dense_log, rrd = out / "basis.npz", out / "heldout_dense.mcap", out / "heldout.rrd"
    _echo(
        f"1/5 rendering {len(train_logs)} training drives of {DEMO_TRAIN_FRAMES} frames "
        f"-> {out}/train_*.mcap"
    )
    for seed, train_log in zip(DEMO_TRAIN_SEEDS, train_logs, strict=True):
        synth(train_log, frames=DEMO_TRAIN_FRAMES, seed=seed, scale=DEMO_SCALE, fmt="mcap")
    # the plain demo's drive: its figures and the built-in basis's are compared as they are
    _echo(
        f"2/5 rendering the plain demo's {DEMO_FRAMES}-frame held-out drive (seed {DEMO_SEED}, "
        f"which `pcainterp demo` scores the built-in basis on) -> {test_log}"
    )
    synth(test_log, frames=DEMO_FRAMES, seed=DEMO_SEED, scale=DEMO_SCALE, fmt="mcap")
    # Like the paper's Virtual KITTI experiment, the synthetic basis is learned from the
    # true depth; on real logs `pcainterp learn` uses SGBM maps (docs/results.md has both).
    _echo(
        f"3/5 learning a basis from the training drives' true depth, fitting the hybrid prior "
        f"on the last {100 * DEMO_HOLDOUT:.0f} % of each drive -> {basis_path}"
    )
    basis = learn(
        train_logs,
        basis_path,
        LearnOptions(
            n_components=DEMO_COMPONENTS,
            grid_scale=0.25,
            depth_topic="/ground_truth/depth",
            fit_prior=True,
            holdout=DEMO_HOLDOUT,
        ),
        PairingConfig(),
    )
    _echo(f"4/5 densifying the held-out drive -> {dense_log}, {rrd}")
    summary = densify(test_log, dense_log, basis, rrd=rrd, spawn_viewer=spawn_viewer)
    report_dir = out / "report"
    _echo(f"5/5 evaluating the densified drive against ground truth -> {report_dir}/results.md")
    _, table = evaluate(dense_log, report_dir, basis=basis_path, sweep_every=DEMO_SWEEP_EVERY)
    height, width = basis.image_size
    described = (
        f"{basis_path}: {basis.n_components} components from {basis.n_train} depth maps"
        f" ({100 * basis.explained_variance_ratio:.1f} % variance), {width}x{height} px"
    )
    return _demo_summary(
        out, started, described, basis, summary, report_dir, table, dense_log, rrd
    ) + (
        f"\n\nthe drive is the plain demo's (seed {DEMO_SEED}): `pcainterp demo` prints the "
        "built-in basis's figures on it."
    )


def _demo_summary(
    out: Path,
    started: float,
    described: str,
    basis: Basis,
    summary: DensifySummary,
    report_dir: Path,
    table: str,
    dense_log: Path,
    rrd: Path,
) -> str:
    """Return the demo's closing summary, read from the report's ``results.json``."""
    report = json.loads((report_dir / "results.json").read_text())
    means = {name: m["mean"]["delta_2d_mean"] for name, m in report["methods"].items()}
    # "stored": the std densify wrote (the default estimate's calibrated posterior std)
    coverage = report["calibration"].get("stored", {}).get("mean", {}).get("coverage_2sigma")
    elapsed = time.perf_counter() - started
    lines = [
        "",
        f"demo finished in {elapsed:.0f} s; everything is in {out}/",
        f"  basis            {described}",
        f"  estimate         {_estimate_line(basis)}",
        f"  densified        {summary.frames} frames at {summary.pace},"
        f" {summary.measurements / max(summary.frames, 1):.0f} points per frame",
        f"  mean Delta_2D ({report['mode']} mode, paper IV-B), same sparse points:",
        f"    PCA-MAP           {means['pca_map']:.3f} px",
        f"    nearest neighbour {means['nearest']:.3f} px  (PCA-MAP / NN ="
        f" {means['pca_map'] / max(means['nearest'], 1e-12):.2f}; paper 0.61-0.63)",
    ]
    if "linear" in means:
        lines.append(f"    linear            {means['linear']:.3f} px")
    lines += [
        "  truth inside +-2 sigma (the std densify wrote): "
        + (f"{100 * coverage:.1f} %" if coverage is not None else "n/a"),
        f"  report           {report_dir}/results.md (figures, results.json)",
        f"  view it: rerun {rrd}   (or open {dense_log} in Foxglove)",
        "",
        table,
    ]
    return "\n".join(lines)


def _estimate_line(basis: Basis) -> str:
    """Describe the estimate densify uses by default with this basis."""
    from pcainterp_stream.pipeline.processor import resolve_settings

    settings = resolve_settings(basis, ProcessorConfig())  # what densify does by default
    parts = []
    if settings.local_prior is not None:
        local = settings.local_prior
        edges = (
            f", cut along SGBM's depth edges (w {local.cell_weight:g})"
            if local.edge_aware and ProcessorConfig().edge_aware
            else ""
        )
        parts.append(
            f"hybrid prior ({local.kernel.value} kernel, {local.length_scale:g} px, "
            f"{local.variance:.2g} px^2, fitted by evidence{edges})"
        )
    else:
        parts.append("paper's prior")
    sigma = settings.sigma
    parts.append(f"sigma {sigma:.2f} px" if isinstance(sigma, float) else f"sigma {sigma}")
    config = ProcessorConfig()
    parts.append(f"robust {config.robust}")
    parts.append("temporal prior" if config.temporal else "no temporal prior")
    if config.carry.frames:
        parts.append(f"points carried from the {config.carry.frames} previous frames")
    if config.near is not None:
        parts.append("points beyond SGBM's range from a quarter-resolution match")
    if settings.scale_by_innovation:
        parts.append(f"std x {settings.std_scale:.3g} x per-frame covariance scale")
    elif settings.std_scale != 1.0:
        parts.append(f"std x {settings.std_scale:.3g}")
    if settings.match_range is not None:
        parts.append(f"std widened near SGBM's {settings.match_range:g} px range")
    return ", ".join(parts)


DEMO_SCALE = 1.0


DEMO_SEED = 9001
"""Seed of the demo's drive (``--learn``'s too): a world no basis of the demo learns from."""


DEMO_FRAMES = 40
"""Frames of the demo's drive (sized so the plain demo takes about a minute)."""


DEMO_TRAIN_SEEDS = (1, 3, 4, 5)


DEMO_TRAIN_FRAMES = 200


DEMO_COMPONENTS = 300


DEMO_HOLDOUT = 0.2


DEMO_SWEEP_EVERY = 10
