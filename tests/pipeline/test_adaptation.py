"""The fit check and self-supervised basis on real indoor stereo (EuRoC, MyntEye fisheye)."""

from __future__ import annotations

import dataclasses
import importlib.util
import io
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from pcainterp_stream import synth as synth_module
from pcainterp_stream.estimate import adapt, rougher
from pcainterp_stream.estimate.basis import BUILT_IN, BUILT_IN_INDOOR, Basis
from pcainterp_stream.frontend.motion import Motion
from pcainterp_stream.frontend.pairing import PairingConfig, iter_stereo_frames
from pcainterp_stream.frontend.sgbm_resolution import by_camera
from pcainterp_stream.frontend.stereo import StereoFrontEnd
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import LogFormat, open_writer
from pcainterp_stream.io.outputs import (
    BASIS_FINGERPRINT_KEY,
    BASIS_KEY,
    BASIS_SCOPE,
    BASIS_SCOPE_KEY,
    recorded_bases,
    recorded_metadata,
)
from pcainterp_stream.pipeline import adaptation as adaptation_module
from pcainterp_stream.pipeline.densify import (
    RELEARNED,
    densify,
    final_basis_path,
    own_basis_path,
)
from pcainterp_stream.pipeline.jobs import evaluation_basis, synth
from pcainterp_stream.pipeline.processor import (
    FrameProcessor,
    MeasurementSource,
    ProcessorConfig,
    resolve_settings,
)
from pcainterp_stream.records import StereoCamera, StereoFrame
from pcainterp_stream.synth import SynthConfig, generate
from pcainterp_stream.synth.indoor import camera_options
from pcainterp_stream.synth.log import write_synthetic_log

ROOT = Path(__file__).resolve().parents[2]
REALDATA = ROOT.parent / "shared" / "realdata"
EUROC = REALDATA / "euroc_machine_hall"
FISHEYE = REALDATA / "mynteye_fisheye"


def _stereo_frames(config: SynthConfig) -> list[StereoFrame]:
    """The rendered drive's pairs as the pairer gives them (the left image's stamp twice)."""
    return [
        StereoFrame(f.index, f.stamp_ns, f.stamp_ns, "left", f.left, f.right, f.camera)
        for f in generate(config)
    ]


def _rectify_tool() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "realdata_rectify", ROOT / "tools" / "realdata_rectify.py"
    )
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _rectified(folder: Path, out: Path) -> Path:
    if not folder.is_dir():
        pytest.skip(f"real indoor stereo not found at {folder}")
    assert _rectify_tool().main([str(folder), str(out)]) == 0
    return out


def _errors(log: Path, config: ProcessorConfig) -> tuple[adapt.FitCheck, FrameProcessor]:
    """Densify every pair of ``log``; score the maps against SGBM of the same pairs."""
    with open_log(log) as reader:
        frames = list(iter_stereo_frames(reader, PairingConfig()))
    front_end = StereoFrontEnd(config.gftt, config.sgbm)
    checks = []
    with FrameProcessor(None, config) as engine:
        for result in engine.process(frames):
            sgbm = front_end.measure(result.frame.left, result.frame.right).disparity_map
            reference = np.where(sgbm > 0, sgbm, np.nan).astype(np.float32)
            checks.append(
                adapt.check_frame(result.disparity, reference, result.pixels, result.disparities)
            )
    return adapt.FitCheck.combine(checks), engine


@pytest.mark.realdata
def test_euroc_machine_hall_keeps_the_indoor_basis_with_no_options(tmp_path: Path) -> None:
    log = _rectified(EUROC, tmp_path / "euroc.mcap")
    street, engine = _errors(log, ProcessorConfig(adapt="check", builtin="street"))
    assert not street.fits  # the street basis loses to linear interpolation indoors
    assert "worse than linear" in engine.adaptation.lines[-1]
    # the built-in bases only: the check picks the indoor one, better than nearest here
    indoor, engine = _errors(log, ProcessorConfig(adapt="check"))
    assert engine.basis is Basis.indoor()
    assert indoor.prior < street.prior
    assert indoor.prior < indoor.nearest
    # the default: two pairs are too few to check the log's own basis on a pair apart from
    # the ones it learns (each would learn the other, its neighbour): the indoor basis kept
    default, engine = _errors(log, ProcessorConfig())
    assert not engine.adaptation.adapted
    assert engine.adaptation.own_check is None
    assert engine.basis is Basis.indoor()
    assert default == indoor


@pytest.mark.realdata
def test_a_one_pair_log_keeps_a_built_in_basis_whose_std_is_calibrated(tmp_path: Path) -> None:
    """One pair: no pair left out to calibrate the std of a basis learned from it (bug hunt
    8C F2: calibrated on its own pair, +-2 sigma held 67 % of the fisheye's SGBM pixels)."""
    log = _rectified(FISHEYE, tmp_path / "fisheye.mcap")
    out = tmp_path / "fisheye_dense.mcap"
    summary = densify(log, out)
    assert not any(line.startswith("adapted:") for line in summary.prior_lines)
    assert (
        "prior: kept the built-in indoor basis with the street basis's kernel; this log's own "
        "basis is not learned from one frame: no other frame to calibrate its std on"
    ) in summary.prior_lines
    assert summary.basis_written is None
    assert not own_basis_path(out).exists()


def _indoor_frames(frames: int, seed: int = 4) -> list[StereoFrame]:
    config = SynthConfig(
        seed=seed, frames=frames, scale=0.25, scene="indoor", **camera_options("752x480")
    )
    return _stereo_frames(config)


def test_the_log_basis_keeps_learning_and_never_depends_on_thread_timing() -> None:
    frames = _indoor_frames(20, seed=1)  # a room the street basis does not fit
    outputs = []
    for workers, lookahead in ((1, 0), (2, 4), (2, 4)):
        # the street basis alone (no indoor alternative): the log's own basis is learned
        config = ProcessorConfig(stereo_workers=workers, lookahead=lookahead, builtin="street")
        with FrameProcessor(None, config) as engine:
            results = list(engine.process(frames))
            assert engine.adaptation.adapted
            assert engine.adaptation.updates >= 1  # relearned as the maps doubled
            assert engine.basis.n_train > 2
            assert engine.adaptation.relearned[1][0] is engine.basis  # OUTPUT.final.basis.npz
        outputs.append(np.stack([result.disparity for result in results]))
    # the same maps and decisions whatever the threads and the look-ahead
    np.testing.assert_array_equal(outputs[0], outputs[1])
    np.testing.assert_array_equal(outputs[1], outputs[2])


def test_an_adapted_basis_without_a_file_output_is_said_unsaved(tmp_path: Path) -> None:
    """densify - -o -: no folder to save OUTPUT.basis.npz in; it was dropped silently."""
    log = tmp_path / "room.mcap"
    synth(log, frames=8, seed=1, scale=0.25, fmt=None, scene="indoor", camera="752x480")
    processor = ProcessorConfig(builtin="street")  # a room the street basis does not fit
    summary = densify(log, io.BytesIO(), processor=processor)
    assert any(line.startswith("adapted:") for line in summary.prior_lines)
    assert summary.basis_written is None
    assert summary.prior_lines[-1] == (
        "note: the adapted basis was not saved: the output is standard output, with no folder "
        "to save it in; densify -o FILE.mcap also writes it, as FILE.basis.npz, for evaluate "
        "and for --basis"
    )
    assert list(tmp_path.iterdir()) == [log]


def test_a_street_log_keeps_the_street_basis() -> None:
    """The street basis fits a street: kept, the indoor one not even tried."""
    config = SynthConfig(seed=9001, frames=8, scale=0.5)
    frames = _stereo_frames(config)
    with FrameProcessor(None, ProcessorConfig()) as engine:
        list(engine.process(frames))
        assert engine.adaptation.check is not None
        assert engine.adaptation.check.ratio < 0.8
        assert engine.adaptation.switched is None
        assert not engine.adaptation.adapted
        assert engine.basis is Basis.default()
        assert not any("indoor" in line for line in engine.adaptation.lines)


def test_a_kept_basis_worse_than_linear_is_named_and_warned(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Every built-in basis and the log's own lose to linear interpolation: the line names the
    basis kept and says it loses, and a warning line follows (it said "prior: kept;")."""
    real = adaptation_module.densify_batch

    def off_by_five(*args: Any, **kwargs: Any) -> list[Any]:
        return [dataclasses.replace(e, disparity=e.disparity + 5.0) for e in real(*args, **kwargs)]

    def no_better(*args: Any, **kwargs: Any) -> adapt.OwnCheck:
        return adapt.OwnCheck(adapt.FitCheck(2, 100, 50.0, 1.0, 1.0), None)

    monkeypatch.setattr(adaptation_module, "densify_batch", off_by_five)
    monkeypatch.setattr(adapt, "leave_one_out", no_better)
    config = SynthConfig(seed=9001, frames=8, scale=0.25)
    frames = _stereo_frames(config)
    with FrameProcessor(None, ProcessorConfig()) as engine:
        list(engine.process(frames))
        adaptation = engine.adaptation
        assert adaptation.check is not None
        assert not adaptation.check.fits
        assert not adaptation.adapted
        kept, warning = adaptation.lines[-2:]
        name = adaptation.name if adaptation.switched is None else adaptation.switched.name
        assert kept.startswith(
            f"prior: {name} {'kept' if adaptation.switched is None else 'chosen'} "
            f"({adaptation.check.ratio:.2f}x linear: worse than linear interpolation on "
            "held-out SGBM pixels); this log's own basis did no better: 50.00x linear"
        )
        # the log's own basis was just tried: the warning does not ask to learn one as if
        # it had not been (it said "learn a basis for this camera" right after "did no better")
        assert warning == (
            "warning: the prior is worse than linear interpolation on this log's held-out SGBM "
            f"pixels ({adaptation.check.ratio:.2f}x), and so is this log's own basis, learned from "
            "its first 8 frames; a basis learned from more frames of this camera may fit "
            "(learn merges them with the built-in basis's maps when the camera is like its "
            "own): pcainterp learn LOG [LOG ...] -o BASIS.npz, then densify --basis BASIS.npz"
        )


def test_the_unfit_warning_over_exact_linear_interpolation_gives_no_ratio() -> None:
    """Constant held-out disparities: linear's error ~0 made a ratio of ~1e14 (and a fix)."""
    fix = "; learn a basis for this camera: pcainterp learn LOG -o BASIS.npz"
    exact = adapt.FitCheck(3, 300, 1.5, 1e-14, 2.0)
    assert adaptation_module.unfit_warning(exact, "held-out SGBM pixels", fix) == (
        "warning: linear interpolation is exact on this log's held-out SGBM pixels (1e-14 px): "
        "they are constant or exactly planar, as no measured scene is, so the fit check "
        "compares nothing; check what the measurements are"
    )
    worse = adapt.FitCheck(3, 300, 1.5, 1.0, 2.0)
    assert adaptation_module.unfit_warning(worse, "held-out SGBM pixels", fix) == (
        "warning: the prior is worse than linear interpolation on this log's held-out SGBM "
        f"pixels (1.50x){fix}"
    )


def test_an_own_basis_better_but_not_by_the_margin_is_said_so(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The built-in indoor basis fits a synthetic room; the log's own basis errs less on the
    held-out pixels but not below adapt.ADAPT_GAIN of it: the line said it "did no better"."""
    config = SynthConfig(seed=3, frames=8, scale=0.5, scene="indoor", **camera_options("752x480"))
    frames = _stereo_frames(config)
    engine = FrameProcessor(None, ProcessorConfig())

    def better(*args: Any, **kwargs: Any) -> adapt.OwnCheck:
        check = engine.adaptation.check  # the chosen basis's, on every warm-up frame
        assert check is not None
        held = adapt.FitCheck(8, 100, 0.75 * check.prior, check.linear, check.nearest)
        return adapt.OwnCheck(held, None)  # no frames named: compared with that figure

    monkeypatch.setattr(adapt, "leave_one_out", better)
    with engine:
        list(engine.process(frames))
        adaptation = engine.adaptation
        assert adaptation.own_check is not None
        assert adaptation.check is not None
        assert adaptation.check.fits
        assert adaptation.own_against is not None
        own, chosen = adaptation.own_check.prior, adaptation.own_against.prior
        assert adapt.ADAPT_GAIN * chosen <= own < chosen
        assert not adaptation.adapted
        assert adaptation.lines[-1].startswith(
            "prior: the built-in indoor basis chosen; this log's own basis was better "
            f"({own:.2f} px against {chosen:.2f}) but not by the margin that replaces a prior "
            "that fits (an error below 0.5x the prior's): "
        )


def _standing_start(standing: int, moving: int, seed: int = 3) -> list[StereoFrame]:
    """A synthetic room whose first pair is seen ``standing`` times (a camera that has not
    moved yet: each copy with +-1 grey level of noise), then ``moving`` pairs of the walk."""
    config = SynthConfig(
        seed=seed, frames=moving + 1, scale=0.5, scene="indoor", **camera_options("752x480")
    )
    walk = list(generate(config))
    rng = np.random.default_rng(0)

    def noisy(image: np.ndarray) -> np.ndarray:
        noise = rng.integers(-1, 2, image.shape)
        return np.clip(image.astype(np.int16) + noise, 0, 255).astype(image.dtype)

    first = walk[0]
    period = walk[1].stamp_ns - first.stamp_ns
    frames = []
    for index in range(standing + moving):
        source = first if index < standing else walk[index - standing + 1]
        stamp = first.stamp_ns + index * period
        left, right = noisy(source.left), noisy(source.right)
        frames.append(StereoFrame(index, stamp, stamp, "left", left, right, source.camera))
    return frames


def test_a_standing_start_keeps_a_builtin_basis_that_fits() -> None:
    """The first 8 pairs are one view: the log's own basis reproduced its copies, and its
    leave-one-out figure replaced a built-in basis that fits (on a real KITTI drive, 1.36x
    nearest neighbour instead of 0.83x). Copies are one view now, and none is left to check
    the log's own basis on."""
    frames = _standing_start(standing=8, moving=4)  # the warm-up: the 8 standing frames
    with FrameProcessor(None, ProcessorConfig()) as engine:
        list(engine.process(frames))
        adaptation = engine.adaptation
        assert adaptation.check is not None
        assert adaptation.check.fits
        assert not adaptation.adapted
        assert adaptation.own_check is None
        assert adaptation.lines[-1].endswith(
            "; this log's own basis not tried: its first 8 frames are one view (the camera "
            "stood still), none left to check it on"
        )


def test_a_standing_start_no_builtin_fits_keeps_the_builtin_basis() -> None:
    """The first 6 pairs are one view and the street basis alone is offered, which does not
    fit the room: the log's own basis was learned from the first copy (a one-map basis with
    the street basis's prior) and its std covered what the copies agree on, not the scene
    (on a synthetic street standing still: 67 % of the truth inside +-2 sigma; the built-in
    basis's 97 %). Now the built-in basis is kept, and the line says why."""
    frames = _standing_start(standing=6, moving=1)[:6]  # the log ends in the warm-up
    with FrameProcessor(None, ProcessorConfig(builtin="street")) as engine:
        list(engine.process(frames))
        adaptation = engine.adaptation
        assert not adaptation.adapted
        assert adaptation.own_check is None
        assert engine.basis is Basis.default()
        kept, warning = adaptation.lines[-2:]
        assert kept == (
            "prior: the camera barely moves: kept the built-in street basis; this log's own "
            "basis is not learned: its first 6 frames are one view"
        )
        assert warning.startswith("warning: the prior is worse than linear interpolation")
        assert warning.endswith(
            "; a basis learned from logs of this camera that move may fit: pcainterp learn "
            "LOG -o BASIS.npz, then densify --basis BASIS.npz"
        )


def _standing_street(frames: int, monkeypatch: pytest.MonkeyPatch) -> list[StereoFrame]:
    """The synthetic street of seed 7 at half size seen from one pose (facing a facade, where
    neither built-in basis fits), with fresh sensor noise in every pair: a car at a light."""
    first_pose = synth_module.camera_pose

    def standing(world: Any, config: SynthConfig, index: int) -> np.ndarray:
        return first_pose(world, config, 0)

    monkeypatch.setattr(synth_module, "camera_pose", standing)
    config = SynthConfig(seed=7, frames=frames, scale=0.5, speed=0.01)
    return _stereo_frames(config)


def test_a_camera_standing_with_fresh_noise_keeps_a_builtin_basis(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A car waiting at a light: 9 pairs of one pose with fresh sensor noise, where no
    built-in basis fits. The log's own basis was learned from the copies (its std covered 67 %
    of the truth; the built-in indoor basis's 97 %); the ego-motion (0.00-0.02 px) and the maps
    say one view, and the built-in basis is kept."""
    with FrameProcessor(None, ProcessorConfig()) as engine:
        list(engine.process(_standing_street(9, monkeypatch)))
        adaptation = engine.adaptation
        assert adaptation.check is not None
        assert not adaptation.check.fits
        assert not adaptation.adapted
        assert adaptation.switched is not None
        assert engine.basis is adaptation.switched.basis
        assert (
            "prior: the camera barely moves: kept the built-in indoor basis; this log's own "
            "basis is not learned: its first 9 frames are one view (checked again on the "
            "first 8 frames of other views)"  # the warm-up: all 9
        ) in adaptation.lines
        assert adaptation.deferred  # the camera never moved: nothing checked again


def test_a_standing_start_is_checked_again_once_the_camera_moves(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """9 pairs standing at a facade (no built-in basis fits: the indoor one is kept), then
    the street drive: the choice made on the standing view was kept for the whole log (on 10
    standing + 30 driving: 4.51 px, where the street basis gives 3.26). The first 8 frames of
    other views are checked as the warm-up's were, and the street basis, which fits them, is
    used from there on."""
    first_pose = synth_module.camera_pose
    facade = SynthConfig(seed=7, frames=1, scale=0.5, speed=0.01)
    stand = 9

    def pose(world: Any, config: SynthConfig, index: int) -> np.ndarray:
        if index < stand:
            return first_pose(world, facade, 0)
        return first_pose(world, config, index - stand + 1)

    monkeypatch.setattr(synth_module, "camera_pose", pose)
    config = SynthConfig(seed=7, frames=stand + 10, scale=0.5)
    frames = _stereo_frames(config)
    with FrameProcessor(None, ProcessorConfig()) as engine:
        list(engine.process(frames))
        adaptation = engine.adaptation
        assert not adaptation.deferred
        assert "prior: the camera moved: checked again on 8 frames of other views" in (
            adaptation.lines
        )
        assert engine.basis is Basis.default()  # the street basis, from the 18th frame on
        assert not any(line.startswith("warning:") for line in adaptation.lines)


def test_a_basis_replaced_mid_log_is_recorded_with_its_first_frame(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """The standing start above, densified to a file: its channels' metadata, fixed at the
    first outputs, named the built-in indoor basis of the standing frames only, and nothing
    said the street basis made the rest. The metadata record pcainterp.basis lists both."""
    first_pose = synth_module.camera_pose
    facade = SynthConfig(seed=7, frames=1, scale=0.5, speed=0.01)
    stand = 9

    def pose(world: Any, config: SynthConfig, index: int) -> np.ndarray:
        if index < stand:
            return first_pose(world, facade, 0)
        return first_pose(world, config, index - stand + 1)

    monkeypatch.setattr(synth_module, "camera_pose", pose)
    log, out = tmp_path / "stand_then_drive.mcap", tmp_path / "dense.mcap"
    write_synthetic_log(generate(SynthConfig(seed=7, frames=stand + 10, scale=0.5)), log)
    densify(log, out)
    channel = recorded_metadata(out)
    assert channel[BASIS_KEY] == BUILT_IN_INDOOR  # the basis of the first outputs
    assert channel[BASIS_SCOPE_KEY] == BASIS_SCOPE
    indoor, street = recorded_bases(out)
    assert (indoor.basis, indoor.fingerprint) == (BUILT_IN_INDOOR, Basis.indoor().fingerprint)
    assert indoor.fingerprint == channel[BASIS_FINGERPRINT_KEY]
    assert (street.basis, street.fingerprint) == (BUILT_IN, Basis.default().fingerprint)
    assert indoor.first_frame == 0
    assert street.first_frame == stand + 8  # checked again on frames 9-16, used from 17 on
    with open_log(out) as reader:
        depth_times = [raw.log_time_ns for raw in reader.messages(["/pcainterp/depth"])]
    assert indoor.first_log_time_ns == depth_times[0]
    assert street.first_log_time_ns == depth_times[street.first_frame]


def test_a_relearned_basis_is_recorded_each_time_it_changes(tmp_path: Path) -> None:
    """A room the street basis does not fit, adapted at the warm-up and relearned as the maps
    double: the record names the log's own basis file from frame 0, each relearned one from
    the frame it took over, the last by its file; a log with one basis records that one."""
    log, out = tmp_path / "room.mcap", tmp_path / "room_dense.mcap"
    synth(log, frames=40, seed=1, scale=0.25, fmt=None, scene="indoor", camera="752x480")
    summary = densify(log, out, processor=ProcessorConfig(builtin="street"))
    assert summary.final_basis_written == final_basis_path(out)
    bases = recorded_bases(out)
    assert len(bases) >= 2  # the first, then relearned at 16 maps (the last, its file)
    first, *between, last = bases
    assert (first.basis, first.first_frame) == (own_basis_path(out).name, 0)
    assert first.fingerprint == Basis.load(own_basis_path(out)).fingerprint
    assert first.fingerprint == recorded_metadata(out)[BASIS_FINGERPRINT_KEY]
    assert last.basis == final_basis_path(out).name
    assert last.fingerprint == Basis.load(final_basis_path(out)).fingerprint
    assert all(entry.basis == RELEARNED for entry in between)
    frames = [entry.first_frame for entry in bases]
    assert frames == sorted(set(frames))
    assert len({entry.fingerprint for entry in bases}) == len(bases)
    kept = tmp_path / "room_kept.mcap"  # --basis builtin: checked, never replaced
    densify(log, kept, processor=ProcessorConfig(builtin="street", adapt="check"))
    (only,) = recorded_bases(kept)
    assert (only.basis, only.fingerprint, only.first_frame) == (
        BUILT_IN,
        Basis.default().fingerprint,
        0,
    )


def test_the_streaming_update_adds_no_copy_of_the_view_it_just_added() -> None:
    """After adapting, every frame's map was added: a camera that stops (at a light) filled the
    log's own basis with copies of one view, and their noise became its components."""
    size, camera = (48, 64), StereoCamera(64, 48, 50.0, 50.0, 32.0, 24.0, 1.0)
    adaptation = adaptation_module.Adaptation("auto", True, 2, "cauchy", False)
    rng = np.random.default_rng(5)
    base = np.full((12, 16), 10.0, np.float32)
    adaptation.adapted, adaptation._camera = True, (size, camera.focal_baseline)
    adaptation._maps, adaptation._last_map, adaptation._since = [base], base, np.eye(4)
    adaptation._seen, adaptation._next_update = 1, 100
    pixels = rng.uniform([2, 2], [61, 45], (40, 2)).astype(np.float32)
    disparities = np.full(40, 10.0, np.float32)

    def frame(grid: np.ndarray, step: float) -> adaptation_module.AdaptFrame:
        moved = np.eye(4)
        moved[0, 3] = step  # m sideways: 10 px of image motion per 1 m here
        reference = np.full(size, 10.0, np.float32)
        motion = Motion(moved, 40, 40)
        return adaptation_module.AdaptFrame(
            pixels, disparities, reference, grid, size, 50.0, None, motion, camera
        )

    for _ in range(3):  # standing: 0.001 m, maps 0.14 px apart (fresh noise)
        noisy = (base + rng.normal(0.0, 0.15, base.shape)).astype(np.float32)
        assert adaptation.update([frame(noisy, 0.001)]) is None
    assert len(adaptation._maps) == 1
    assert adaptation._seen == 1
    adaptation.update([frame(base + 1.0, 0.5)])  # moving again: 5 px
    assert len(adaptation._maps) == 2


def test_an_own_basis_that_beats_a_basis_that_fits_says_it_fits(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The built-in indoor basis fits the room and the log's own basis does far better on
    the frames it did not learn: the line said "the built-in bases do not fit"."""

    def far_better(*args: Any, **kwargs: Any) -> adapt.OwnCheck:
        return adapt.OwnCheck(adapt.FitCheck(2, 100, 0.01, 1.0, 1.0), None)

    monkeypatch.setattr(adapt, "leave_one_out", far_better)
    config = SynthConfig(seed=3, frames=8, scale=0.5, scene="indoor", **camera_options("752x480"))
    frames = _stereo_frames(config)
    with FrameProcessor(None, ProcessorConfig()) as engine:
        list(engine.process(frames))
        adaptation = engine.adaptation
        assert adaptation.adapted
        assert adaptation.check is not None
        assert adaptation.check.fits
        line = next(line for line in adaptation.lines if line.startswith("adapted:"))
        assert line.startswith(
            f"adapted: the built-in indoor basis fits ({adaptation.check.ratio:.2f}x linear), "
            "but this log's own basis did better on frames it did not learn (0.01 px against "
            f"{adaptation.check.prior:.2f}); learned one from this log's own SGBM maps "
            "(8 frames, "
        )
        assert "do not fit" not in line


def test_builtin_indoor_is_recorded_and_evaluate_finds_it(tmp_path: Path) -> None:
    """--basis builtin-indoor (ProcessorConfig.builtin): the output names the indoor basis and
    evaluate re-densifies with it; --basis builtin-street keeps the street one."""
    log = tmp_path / "room.mcap"
    synth(log, frames=3, seed=2, scale=0.25, fmt=None, scene="indoor", camera="752x480")
    out = tmp_path / "room_dense.mcap"
    summary = densify(log, out, processor=ProcessorConfig(builtin="indoor", adapt="check"))
    assert summary.prior_lines[0].startswith("prior: the built-in indoor basis ")
    assert recorded_metadata(out)[BASIS_KEY] == BUILT_IN_INDOOR
    basis, note = evaluation_basis(out)
    assert basis is Basis.indoor()
    assert note.startswith(BUILT_IN_INDOOR)
    street = tmp_path / "room_street.mcap"
    summary = densify(log, street, processor=ProcessorConfig(builtin="street", adapt="check"))
    assert summary.prior_lines[0].startswith("prior: the built-in street basis ")
    # not chosen from: only its warning names the indoor basis, as what plain densify picks
    lines = summary.prior_lines
    assert not any(line.startswith("prior:") and "indoor" in line for line in lines)
    assert all("densify without --basis, which" in line for line in lines if "indoor" in line)
    assert recorded_metadata(street)[BASIS_KEY] == BUILT_IN
    with pytest.raises(ValueError, match="builtin"):
        ProcessorConfig(builtin="forest")


def test_dense_mode_checks_and_chooses_the_built_in_basis_but_learns_none(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """densify --measurements dense checked nothing: no "prior:" line, and the street basis
    on an indoor log. It is checked and picks between the built-in bases as sparse mode
    does, but never learns the log's own (measured: docs/bases.md, "Dense mode")."""

    def never(*args: object, **kwargs: object) -> None:
        raise AssertionError("dense mode learned the log's own basis")

    monkeypatch.setattr(adapt, "own_basis", never)
    log = tmp_path / "room.mcap"
    synth(log, frames=4, seed=2, scale=0.5, fmt=None, scene="indoor", camera="752x480")
    out = tmp_path / "room_dense.mcap"
    summary = densify(log, out, processor=ProcessorConfig(measurements="dense"))
    lines = summary.prior_lines
    assert lines[0].startswith("prior: the built-in street basis ")
    assert lines[1].startswith("prior: the built-in indoor basis ")
    assert lines[2] == "prior: the built-in indoor basis chosen (fits this log better)"
    # nor is it scored with the street basis's kernel: it fills SGBM's holes, never checked
    assert not any("kernel" in line for line in lines)
    assert summary.basis_written is None
    assert recorded_metadata(out)[BASIS_KEY] == BUILT_IN_INDOOR
    # a built-in basis that loses to linear: the warning does not offer to adapt
    adaptation = adaptation_module.Adaptation("auto", True, 2, "cauchy", False, may_learn=False)
    adaptation.check = adapt.FitCheck(2, 100, 2.1, 1.9, 2.0)
    adaptation._warn_unfit(adaptation.may_replace)
    assert "to adapt to this log" not in adaptation.lines[-1]
    assert (
        "; dense mode does not adapt the basis, and uses it mostly to fill SGBM's holes"
        in (adaptation.lines[-1])
    )
    # --basis builtin-street on the room: the indoor basis, which does better, is named (it
    # said only "learn one for this camera": review 56b R3)
    forced = densify(
        log,
        tmp_path / "street.mcap",
        processor=ProcessorConfig(measurements="dense", adapt="check", builtin="street"),
    )
    (warning,) = [line for line in forced.warnings + forced.prior_lines if "linear interp" in line]
    assert "; the built-in indoor basis does better (" in warning
    assert (
        "x linear): densify without --basis, which checks it and the built-in bases' other "
        "kernels and takes the best; dense mode"
    ) in warning
    assert recorded_metadata(tmp_path / "street.mcap")[BASIS_KEY] == BUILT_IN


def _named(name: str) -> Any:
    return lambda: adaptation_module.Candidate(name, Basis.default(), {"name": name})


def test_a_learned_basis_that_loses_is_not_told_to_learn_one_again() -> None:
    """EuRoC, dense mode: the warning said "learn one for this camera"; the basis so learned
    (--basis FILE) scored 1.20x linear, the built-in indoor one 1.12x, and the warning said
    "learn a basis for this camera" again (review 56b R3)."""
    street, indoor = "the built-in street basis", "the built-in indoor basis"
    scores = {
        street: adapt.FitCheck(2, 100, 3.2, 2.0, 2.1),
        indoor: adapt.FitCheck(2, 100, 2.24, 2.0, 2.1),
    }

    def check(basis: Basis, settings: dict[str, object]) -> adapt.FitCheck:
        return scores[str(settings["name"])]

    advisory = [_named(street), _named(indoor)]
    given = adaptation_module.Adaptation(
        "check", False, 2, "cauchy", False, may_learn=False, advisory=advisory
    )
    given.check = adapt.FitCheck(2, 100, 2.4, 2.0, 2.1)
    given._warn_unfit(False, builtin=given._builtin_advice(check), holes=0.13)
    assert given.lines[-1] == (
        "warning: the prior is worse than linear interpolation on this log's held-out SGBM "
        "pixels (1.20x); the built-in indoor basis does better (1.12x linear): densify without "
        "--basis, which checks it and the built-in bases' other kernels and takes the best; "
        "dense mode does not adapt the basis, and uses it mostly to fill SGBM's holes, 13% of "
        "this log's pixels (where SGBM matched, its own "
        "value dominates); a basis learned from more frames of this camera may fit: pcainterp "
        "learn LOG [LOG ...] -o BASIS.npz, then densify --basis BASIS.npz"
    )
    # one that fits: named, and no basis to learn
    scores[indoor] = adapt.FitCheck(2, 100, 1.7, 2.0, 2.1)
    given._warn_unfit(False, builtin=given._builtin_advice(check))
    assert given.lines[-1].endswith(
        "the built-in indoor basis does better (0.85x linear): densify without --basis, "
        "which checks it and the built-in bases' other kernels and takes the best; dense mode "
        "does not adapt the basis, and uses it mostly to fill "
        "SGBM's holes (where SGBM matched, its own value dominates)"
    )
    # a built-in basis does no better: not named; sparse mode: no dense clause
    scores[indoor] = adapt.FitCheck(2, 100, 2.6, 2.0, 2.1)
    sparse = adaptation_module.Adaptation("auto", False, 2, "cauchy", False, advisory=advisory)
    sparse.check = given.check
    sparse._warn_unfit(False, builtin=sparse._builtin_advice(check))
    assert sparse.lines[-1] == (
        "warning: the prior is worse than linear interpolation on this log's held-out SGBM "
        "pixels (1.20x); a basis learned from more frames of this camera may fit: pcainterp "
        "learn LOG [LOG ...] -o BASIS.npz, then densify --basis BASIS.npz"
    )
    # the default (a built-in basis chosen among them): nothing to compare, learning advised
    default = adaptation_module.Adaptation("auto", True, 2, "cauchy", False, may_learn=False)
    default.check = adapt.FitCheck(2, 100, 2.24, 2.0, 2.1)
    default._warn_unfit(True, builtin=default._builtin_advice(check))
    assert default.lines[-1].endswith(
        "(where SGBM matched, its own value dominates); a basis learned from logs of this "
        "camera may fit: pcainterp learn LOG [LOG ...] -o BASIS.npz, then densify --basis "
        "BASIS.npz"
    )


def test_an_indoor_feature_stream_picks_the_indoor_basis_on_left_out_points(
    tmp_path: Path,
) -> None:
    """No SGBM maps to learn from: the check scores both built-in bases on left-out points."""
    log = tmp_path / "room.mcap"
    synth(log, frames=8, seed=4, scale=0.5, fmt=None, scene="indoor", camera="752x480")
    with_features = tmp_path / "room_features.mcap"
    rng = np.random.default_rng(0)
    with open_log(log) as reader, open_writer(with_features, LogFormat.MCAP) as writer:
        camera_info = None
        for raw in reader.messages():
            writer.add_raw(raw)
            if raw.topic == "/stereo/left/camera_info":
                camera_info = reader.decode(raw)
            if raw.topic != "/ground_truth/depth" or camera_info is None:
                continue
            message = reader.decode(raw)
            depth = rosmsg.image_array(message)
            p = rosmsg.projection_matrix(camera_info)
            v = rng.integers(0, depth.shape[0], 300)
            u = rng.integers(0, depth.shape[1], 300)
            z = depth[v, u]
            x = (u - p[0, 2]) * z / p[0, 0]
            y = (v - p[1, 2]) * z / p[1, 1]
            cloud = rosmsg.pointcloud2_message(
                {"x": x.astype(np.float32), "y": y.astype(np.float32), "z": z},
                rosmsg.stamp_ns(message),
                "stereo_left_optical",
            )
            writer.add_message("/features", cloud, raw.log_time_ns)
    summary = densify(
        with_features,
        tmp_path / "room_dense.mcap",
        pairing=PairingConfig(features_topic="/features"),
        processor=ProcessorConfig(source=MeasurementSource.FEATURES),
    )
    lines = summary.prior_lines
    assert lines[0].startswith("prior: the built-in street basis ")
    assert "left-out measurements" in lines[1]
    assert "the built-in indoor basis chosen" in lines[2]
    assert summary.basis_written is None  # nothing learned
    assert recorded_metadata(tmp_path / "room_dense.mcap")[BASIS_KEY] == BUILT_IN_INDOOR


def test_a_real_street_log_that_linear_comes_close_to_keeps_the_street_basis(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """With the lattice of lookups linear interpolation comes close to the street basis on
    real KITTI (0.9-0.95x): the street basis still fits (below 1.0x), so the log's own basis
    is not even learned (it never won on a street, and costs seconds per log)."""
    from pcainterp_stream.io.kitti import iter_frames, open_kitti

    sequence_folder = REALDATA / "kitti_odometry_clip" / "sequences" / "a"
    if not sequence_folder.is_dir():
        pytest.skip(f"the real KITTI odometry clip not found at {sequence_folder}")

    def never(*args: object, **kwargs: object) -> None:
        raise AssertionError("the log's own basis was learned on a street the street basis fits")

    monkeypatch.setattr(adapt, "own_basis", never)
    sequence = open_kitti(sequence_folder)
    frames = [
        StereoFrame(f.frame_index, f.stamp_ns, f.stamp_ns, "left", f.left, f.right, sequence.camera)
        for f in iter_frames(sequence, max_frames=10)
    ]
    with FrameProcessor(None, ProcessorConfig()) as engine:
        list(engine.process(frames))
        assert engine.adaptation.check is not None
        assert engine.adaptation.check.ratio < 1.0
        assert not engine.adaptation.adapted
        assert engine.basis is Basis.default()


def test_the_unfit_warning_names_a_basis_of_another_camera(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # before: "worse than linear interpolation (10.65x); learn a basis for this camera",
    # nothing saying the basis's camera (320x240, f*b 9.6) was not the log's (bug hunt 6A F10)
    real = adaptation_module.densify_batch

    def off_by_five(*args: Any, **kwargs: Any) -> list[Any]:
        return [dataclasses.replace(e, disparity=e.disparity + 5.0) for e in real(*args, **kwargs)]

    monkeypatch.setattr(adaptation_module, "densify_batch", off_by_five)
    # a basis of the indoor camera that is not the built-in one (densify --basis FILE)
    indoor = dataclasses.replace(Basis.indoor(), mean=Basis.indoor().mean + np.float32(0.01))
    frames = _stereo_frames(SynthConfig(seed=9002, frames=6, scale=0.25))
    with FrameProcessor(indoor, ProcessorConfig()) as engine:
        list(engine.process(frames))
        warning = engine.adaptation.lines[-1]
    height, width = indoor.image_size
    fb = frames[0].camera.focal_baseline
    assert warning.startswith(
        "warning: the prior is worse than linear interpolation on this log's held-out SGBM pixels"
    )
    assert (
        f"; the basis was learned for another camera ({width}x{height} px, f*b "
        f"{indoor.focal_baseline:.1f} px*m; this log's 310x94 px, f*b {fb:.1f} px*m: aspect "
        "ratio 3.30 against "
    ) in warning
    assert warning.endswith(
        "; learn a basis for this camera: pcainterp learn LOG [LOG ...] -o BASIS.npz, then "
        "densify --basis BASIS.npz"
    )
    # a basis of a camera like the log's: nothing said about cameras
    street = Basis.default()
    assert adapt.other_camera(street, (94, 310), street.focal_baseline / 4) == ""


def _truth_errors(config: SynthConfig, engine: FrameProcessor) -> tuple[float, float]:
    """Densify the synthetic log; return the mean |error| against the truth and the share
    of it inside +-2 sigma of the std written."""
    truth = [f.camera.focal_baseline / f.depth for f in generate(config)]
    errors, inside = [], []
    with engine:
        for result, disparity in zip(engine.process(_stereo_frames(config)), truth, strict=True):
            valid = np.isfinite(disparity) & np.isfinite(result.disparity)
            error = np.abs(result.disparity - disparity)[valid]
            errors.append(error)
            inside.append(error <= 2.0 * result.disparity_std[valid])
    return float(np.concatenate(errors).mean()), float(np.concatenate(inside).mean())


def _full_width(config: SynthConfig, adapt_mode: str = "auto") -> ProcessorConfig:
    """``densify``'s SGBM for the synthetic camera (full resolution and width indoors)."""
    processor = ProcessorConfig(adapt=adapt_mode)  # "check": the built-in bases as they are
    camera = config.camera
    sgbm, _ = by_camera(processor.sgbm, camera.focal_baseline, camera.width, camera.height)
    return dataclasses.replace(processor, sgbm=sgbm)


def test_the_indoor_basis_that_misfits_takes_the_street_basis_s_kernel(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """bughunt10B Q3: a room where the built-in indoor basis is chosen at >= 0.8x linear
    (seed 5 at 376x240: 0.98x) takes the street basis's rougher kernel, which the check
    scores lower (0.23 px against 0.25), and errs less against the truth (0.216 -> 0.188 px
    over every pixel); its std, refitted on the warm-up's SGBM, holds ~95 % of the truth."""
    config = SynthConfig(seed=5, frames=8, scale=0.5, scene="indoor", **camera_options("752x480"))
    engine = FrameProcessor(None, _full_width(config))
    error, inside = _truth_errors(config, engine)
    adaptation = engine.adaptation
    assert adaptation.switched is not None
    assert adaptation.switched.name == "the built-in indoor basis with the street basis's kernel"
    assert engine.basis is Basis.indoor()
    kernel = engine.settings.local_prior
    assert kernel is not None
    assert (kernel.kernel, kernel.length_scale, kernel.variance) == ("laplace", 64.0, 40.0)
    assert engine.settings.scale_by_innovation  # the indoor basis's rule (review58b R7)
    assert engine.settings.std_scale == adaptation.switched.tuned["std_scale"]
    line = next(line for line in adaptation.lines if "street basis's local kernel" in line)
    assert "; taken: " in line
    # the same log with the indoor kernel (the candidate never scored)
    monkeypatch.setattr(rougher, "try_rougher", lambda *args, **kwargs: None)
    indoor = FrameProcessor(None, _full_width(config))
    indoor_error, _ = _truth_errors(config, indoor)
    assert indoor.adaptation.switched is not None
    assert indoor.adaptation.switched.name == "the built-in indoor basis"
    assert indoor.adaptation.check is not None
    assert indoor.adaptation.check.ratio >= adaptation_module.FITS_BELOW
    assert indoor.settings.scale_by_innovation  # the indoor basis's own std scale
    assert error < 0.95 * indoor_error
    assert 0.93 < inside < 0.98


def test_builtin_keeps_the_built_in_bases_as_they_are() -> None:
    """review58b R4: ``--basis builtin`` (``adapt="check"``, "the built-in bases as they
    are") chooses the indoor basis on the room the default run tunes (seed 5 at 376x240),
    and does not try the rougher kernel on it: its own kernel and std scale."""
    config = SynthConfig(seed=5, frames=8, scale=0.5, scene="indoor", **camera_options("752x480"))
    engine = FrameProcessor(None, _full_width(config, "check"))
    with engine:
        list(engine.process(_stereo_frames(config)))
    adaptation = engine.adaptation
    assert adaptation.switched is not None
    assert adaptation.switched.name == "the built-in indoor basis"
    assert adaptation.tuning(engine.basis) == {}
    assert not any("local kernel" in line for line in adaptation.lines)
    assert engine.settings == resolve_settings(Basis.indoor(), engine.config)


@pytest.mark.parametrize("edge_aware", [True, False])
def test_the_fit_check_scores_an_edge_aware_prior_with_its_cells(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, edge_aware: bool
) -> None:
    """The check scored the street basis without the cells densify draws along SGBM's map:
    on a raw KITTI drive a 0.7 % near-tie then took the indoor basis, 7 % worse against the
    reference (1.313 px against 1.220 with the street basis)."""
    real = adaptation_module.densify_batch
    seen: list[tuple[bool, bool]] = []  # (the prior is edge-aware, cells were passed)

    def spy(*args: Any, **kwargs: Any) -> Any:
        local = kwargs.get("local_prior")
        partitions = kwargs.get("partitions")
        seen.append((bool(getattr(local, "edge_aware", False)), partitions is not None))
        return real(*args, **kwargs)

    monkeypatch.setattr(adaptation_module, "densify_batch", spy)
    log = tmp_path / "drive.mcap"
    synth(log, frames=4, seed=3, scale=0.5, fmt=None)
    densify(log, tmp_path / "out.mcap", processor=ProcessorConfig(edge_aware=edge_aware))
    assert any(aware for aware, _ in seen), "the street basis's prior is edge-aware"
    assert all(cells == (aware and edge_aware) for aware, cells in seen)
