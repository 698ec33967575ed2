"""The log's own bases that give way mid-log: their files, the record naming them, the lines
(review 57a F1, F5-F7)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from pcainterp_stream import cli
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.frontend.pairing_stats import PairingStats
from pcainterp_stream.frontend.sgbm_resolution import by_camera
from pcainterp_stream.frontend.stereo import SgbmConfig
from pcainterp_stream.io.outputs import (
    BASIS_FINGERPRINT_KEY,
    BASIS_KEY,
    recorded_bases,
    recorded_metadata,
)
from pcainterp_stream.pipeline.adaptation import Adaptation, AdaptFrame
from pcainterp_stream.pipeline.densify import densify, final_basis_path, own_basis_path
from pcainterp_stream.pipeline.jobs import evaluation_basis, synth
from pcainterp_stream.pipeline.processor import FrameProcessor, ProcessorConfig
from pcainterp_stream.records import StereoCamera, StereoFrame, SynthFrame
from pcainterp_stream.synth import SynthConfig, generate
from pcainterp_stream.synth.indoor import camera_options
from pcainterp_stream.synth.log import write_synthetic_log

_VI = camera_options("752x480")
_ROOM = SynthConfig(seed=3, frames=20, scale=0.25, scene="indoor")  # adapts (310x94)


def _parts(*configs: SynthConfig) -> Iterator[SynthFrame]:
    """The configs' frames one after the other, numbered and stamped as one log."""
    index, stamp, step = 0, 0, 100_000_000
    for config in configs:
        for frame in generate(config):
            yield frame._replace(index=index, stamp_ns=stamp)
            index, stamp = index + 1, stamp + step


def _as_stereo(frames: Iterator[SynthFrame]) -> list[StereoFrame]:
    return [
        StereoFrame(f.index, f.stamp_ns, f.stamp_ns, "left", f.left, f.right, f.camera)
        for f in frames
    ]


def _files_match_the_record(out: Path) -> list[str]:
    """Return the names the record gives; assert each file it names is beside the output."""
    names = []
    for entry in recorded_bases(out):
        names.append(entry.basis)
        if entry.basis.endswith(".npz"):
            saved = out.parent / entry.basis
            assert saved.is_file(), f"{entry.basis} (frames from {entry.first_frame}) not written"
            assert Basis.load(saved).fingerprint == entry.fingerprint
    return names


def test_an_own_basis_that_gave_way_is_saved_as_the_output_names_it(tmp_path: Path) -> None:
    """A room that adapts, then another camera: OUTPUT.basis.npz was no longer written (nor
    the "adapted basis:" line), though the channels and the record named it for the room's
    frames: evaluate could not find it."""
    log, out = tmp_path / "two.mcap", tmp_path / "two_dense.mcap"
    write_synthetic_log(_parts(_ROOM, SynthConfig(seed=1, frames=4, scale=0.25, **_VI)), log)
    summary = densify(log, out)
    channel = recorded_metadata(out)
    assert channel[BASIS_KEY] == own_basis_path(out).name
    first = Basis.load(own_basis_path(out))
    assert first.fingerprint == channel[BASIS_FINGERPRINT_KEY]
    names = _files_match_the_record(out)
    assert names[0] == own_basis_path(out).name
    assert final_basis_path(out).name in names  # its relearned one, in force until frame 20
    assert names[-1] == "built-in"
    assert summary.basis_written == own_basis_path(out)
    lines = summary.prior_lines
    assert any(
        line.startswith("adapted basis: ")
        and line.endswith("when it gave way at frame 20 (1 update while streaming)")
        for line in lines
    ), lines
    written = summary.written_lines()
    assert written[0].startswith(f"wrote {own_basis_path(out)}: ")
    assert any("last in force on frames 16-19" in line for line in written), written
    # F6: the log ended 4 frames into the new camera's re-check: said, with the basis kept
    assert (
        "prior: the log ended before the basis choice was made again (on 4 frames of other "
        "views of the 8 it is made on): the built-in street basis kept to the end"
    ) in lines
    basis, note = evaluation_basis(out)
    assert basis == own_basis_path(out), note


def test_a_second_adoption_is_saved_apart_from_the_first(tmp_path: Path) -> None:
    """Camera A adapts, B, then A again adapts again: OUTPUT.basis.npz held the second
    adoption's basis while the record called the first "(not saved)" and the channels
    named OUTPUT.basis.npz for the first frames."""
    log, out = tmp_path / "aba.mcap", tmp_path / "aba_dense.mcap"
    again = SynthConfig(seed=3, frames=12, scale=0.25, scene="indoor")  # A's room again
    write_synthetic_log(_parts(_ROOM, SynthConfig(seed=1, frames=4, scale=0.25, **_VI), again), log)
    summary = densify(log, out)
    names = _files_match_the_record(out)
    bases = recorded_bases(out)
    assert (bases[0].basis, bases[0].first_frame) == (own_basis_path(out).name, 0)
    assert recorded_metadata(out)[BASIS_FINGERPRINT_KEY] == bases[0].fingerprint
    assert own_basis_path(out, 2).name in names, names
    second = next(entry for entry in bases if entry.basis == own_basis_path(out, 2).name)
    assert second.first_frame >= 24 + 8  # adopted by the check made again on A's return
    lines = summary.prior_lines
    # F7: the camera coming back is no "new camera"
    assert any("a camera seen before in the log" in line for line in lines), lines
    assert (
        "prior: the basis choice made again on the first 8 frames of this camera since frame 24"
    ) in lines
    assert not any("new camera's first" in line for line in lines)
    assert any(line.startswith("adapted basis 2: ") for line in lines), lines
    assert [path for path, _ in summary.bases_saved][:1] == [own_basis_path(out)]


def test_a_recheck_names_the_frames_it_learned_from() -> None:
    """The re-check's warning said "learned from its first 8 frames" of frames 20-27."""
    adaptation = Adaptation(
        mode="auto", may_replace=True, warmup_frames=8, robust="none", calibrate=False
    )
    frames = [
        AdaptFrame(_empty(), _empty(), None, None, (94, 310), 96.5, index=index)
        for index in range(20, 28)
    ]
    assert adaptation._their(frames, 8) == "its first 8 frames"  # the warm-up
    adaptation.checked = True
    assert adaptation._their(frames, 8) == "8 frames from frame 20 to 27"


def _empty() -> object:
    import numpy as np

    return np.zeros((0, 2), np.float32)


def test_a_stream_of_two_cameras_notes_the_recheck_that_never_ends() -> None:
    """The same at the processor: the re-check's line, and no line once it is made."""
    frames = _as_stereo(_parts(_ROOM, SynthConfig(seed=1, frames=4, scale=0.25, **_VI)))
    with FrameProcessor(None, ProcessorConfig()) as engine:
        list(engine.process(frames))
        assert engine.adaptation.end_line() is not None
    with FrameProcessor(None, ProcessorConfig()) as engine:
        list(engine.process(frames[:20]))
        assert engine.adaptation.end_line() is None  # checked and done


def test_a_later_camera_matched_at_the_first_cameras_resolution_is_said() -> None:
    """--stereo-downscale auto chose on the first camera and kept it for the second (f*b 24,
    matched at half resolution), while the line stated the first's rule only."""
    from pcainterp_stream.pipeline.own_bases import matched_alone

    street = StereoCamera(
        width=620, height=188, fx=359.428, fy=359.428, cx=310, cy=94, baseline=0.5372
    )
    vi = StereoCamera(width=376, height=240, fx=218.0, fy=218.0, cx=188, cy=120, baseline=0.11)
    given = SgbmConfig(by_camera=True)
    chosen, phrase = by_camera(given, street.focal_baseline, street.width, street.height)
    stats = PairingStats()
    stats.camera, stats.camera_source, stats.camera_changes = street, "P", 1
    stats.camera_frames = {street: (20, "P"), vi: (4, "P")}
    stats.matching = phrase
    stats.matched_alone = matched_alone(stats, given, chosen)
    note = stats.camera_note()
    assert note is not None
    head, first, second = note.splitlines()
    assert head.endswith(
        "SGBM at half resolution (--stereo-downscale auto: f*b 193 >= 90 px*m), chosen on "
        "the first camera for all):"
    )
    assert second.endswith(
        "f*b 23.98 px*m: 4 pairs; matched at the first camera's resolution, where on its own "
        "--stereo-downscale auto would choose full resolution (f*b 24 < 90 px*m)"
    )
    assert "matched at" not in first


def test_the_basis_relearned_at_the_logs_last_frame_is_saved(tmp_path: Path) -> None:
    """Review 57d D1: relearned from all 16 maps at the last frame, it densified no frame:
    OUTPUT.final.basis.npz was not written and the line said "8 maps, 7 components at the
    end (0 updates while streaming)"."""
    log, out = tmp_path / "r16.mcap", tmp_path / "r16_dense.mcap"
    write_synthetic_log(generate(SynthConfig(seed=3, frames=16, scale=0.25, scene="indoor")), log)
    summary = densify(log, out)
    assert (
        "adapted basis: 16 maps, 15 components at the end (1 update while streaming)"
        in summary.prior_lines
    ), summary.prior_lines
    final = final_basis_path(out)
    assert summary.final_basis_written == final
    assert Basis.load(final).n_train == 16
    assert [path for path, _ in summary.bases_saved] == [own_basis_path(out), final]
    written = summary.written_lines()
    assert written[1].startswith(f"wrote {final}: the basis relearned from all of this log's")
    assert "densify --basis" not in written[0]  # the relearned one is the one to reuse
    assert _files_match_the_record(out) == [own_basis_path(out).name]  # no frame used it


def test_the_final_basis_line_says_how_many_maps_it_learned(tmp_path: Path) -> None:
    """Bug hunt 15C F3: relearned at 16 maps (when they doubled) and in force to the end of a
    24-frame room, the final basis was said to be "relearned from all of this log's maps"."""
    log, out = tmp_path / "r24.mcap", tmp_path / "r24_dense.mcap"
    write_synthetic_log(generate(SynthConfig(seed=3, frames=24, scale=0.25, scene="indoor")), log)
    summary = densify(log, out)
    final = final_basis_path(out)
    assert Basis.load(final).n_train == 16
    written = summary.written_lines()
    assert written[1] == (
        f"wrote {final}: the basis relearned from 16 of the 23 maps this log's own basis saw, "
        "when they last doubled (it stopped fitting this log at frame 23: kept for inspection "
        "only, not for other logs of this camera; plain densify or pcainterp learn for those)"
    )  # 23: the own basis stopped fitting at frame 23, before its map was added (16D F1)


def test_the_basis_relearned_at_a_cameras_last_frame_is_saved(tmp_path: Path) -> None:
    """The same at the last frame of a camera the log then leaves (16 room frames, 4 VI)."""
    log, out = tmp_path / "r16vi.mcap", tmp_path / "r16vi_dense.mcap"
    room = SynthConfig(seed=3, frames=16, scale=0.25, scene="indoor")
    write_synthetic_log(_parts(room, SynthConfig(seed=1, frames=4, scale=0.25, **_VI)), log)
    summary = densify(log, out)
    assert any(
        line.startswith("adapted basis: 16 maps, 15 components when it gave way at frame 16 ")
        for line in summary.prior_lines
    ), summary.prior_lines
    final = final_basis_path(out)
    assert Basis.load(final).n_train == 16
    assert any(
        line.startswith(f"wrote {final}: ") and "it densified no frame" in line
        for line in summary.written_lines()
    ), summary.written_lines()
    assert final.name not in _files_match_the_record(out)


def test_densify_refuses_up_front_an_output_whose_second_bases_name_is_too_long(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Review 57d D4: a 238-byte stem passed the check (OUTPUT.final.basis.npz fits), then a
    log that adopted a second basis ran to its end and lost its output to a traceback on
    OUTPUT.final.basis-2.npz (256 bytes)."""
    limit = int(os.pathconf(tmp_path, "PC_NAME_MAX"))
    stem = "s" * (limit - len(".final.basis-2.npz") + 1)
    log = tmp_path / "logs" / "two.mcap"
    log.parent.mkdir()
    synth(log, frames=2, seed=3, scale=0.25, fmt="mcap")
    capsys.readouterr()
    code = cli.main(["densify", str(log), "-o", str(tmp_path / f"{stem}.mcap")])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.splitlines() == [
        f"pcainterp: error: cannot write the adapted basis {stem}.final.basis-2.npz: the file "
        f"name is too long for the file system ({limit + 1} bytes, at most {limit}): choose a "
        "shorter name (a run that adapts its basis writes it beside the output)"
    ]
    assert sorted(os.listdir(tmp_path)) == ["logs"]


def test_a_side_basis_that_cannot_be_written_costs_the_output_nothing(tmp_path: Path) -> None:
    """D4: where a side basis cannot be written (here, by the library, which checks no name
    up front), the output is written and a warning names the missing file and the fix."""
    limit = int(os.pathconf(tmp_path, "PC_NAME_MAX"))
    stem = "s" * (limit - len(".final.basis-2.npz") + 1)
    log, out = tmp_path / "aba.mcap", tmp_path / f"{stem}.mcap"
    write_synthetic_log(_parts(_ROOM, SynthConfig(seed=1, frames=4, scale=0.25, **_VI), _ROOM), log)
    summary = densify(log, out)
    assert out.is_file()
    missing = final_basis_path(out, 2)
    assert [w for w in summary.warnings if "adapted basis" in w] == [
        f"the adapted basis {missing} was not written (the file name is too long for the file "
        "system: choose a shorter name): the output was written without it, though its record "
        f"names it; densify {log} again to write it"
    ]
    assert missing not in [path for path, _ in summary.bases_saved]
    written = [out, own_basis_path(out), final_basis_path(out), own_basis_path(out, 2)]
    assert sorted(os.listdir(tmp_path)) == sorted([log.name, *(path.name for path in written)])


def test_a_full_disk_refusing_a_side_basis_names_the_fix(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Review 57d D2: "cannot write basis X: No space left on device" ended densify with no
    fix (Basis.save no longer gives one); it is a warning now, with the fix, and the output
    and the first basis are written."""
    import errno

    from pcainterp_stream.errors import BasisError

    log, out = tmp_path / "r16.mcap", tmp_path / "r16_dense.mcap"
    write_synthetic_log(generate(SynthConfig(seed=3, frames=16, scale=0.25, scene="indoor")), log)
    save = Basis.save

    def full(basis: Basis, path: Path, **options: object) -> None:
        if Path(path) == final_basis_path(out):
            error = OSError(errno.ENOSPC, "No space left on device")
            raise BasisError(f"cannot write basis {path}: {error.strerror}") from error
        save(basis, path, **options)  # type: ignore[arg-type]

    monkeypatch.setattr(Basis, "save", full)
    summary = densify(log, out)
    assert out.is_file()
    assert own_basis_path(out).is_file()
    assert [w for w in summary.warnings if "adapted basis" in w] == [
        f"the adapted basis {final_basis_path(out)} was not written (No space left on device; "
        "free some space, or write it elsewhere): the output was written without it, though "
        f"its record names it; densify {log} again to write it"
    ]
    assert summary.final_basis_written is None


def test_the_bases_go_when_the_output_then_fails(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Review 57d D3: the bases were saved (committed) before the output was closed; a full
    disk at its close left them beside an output the error said "nothing was written there"."""
    from pcainterp_stream.errors import LogWriteError
    from pcainterp_stream.io.logwriter import LogWriter

    log, out = tmp_path / "logs" / "r16.mcap", tmp_path / "out" / "r16_dense.mcap"
    log.parent.mkdir()
    out.parent.mkdir()
    write_synthetic_log(generate(SynthConfig(seed=3, frames=16, scale=0.25, scene="indoor")), log)

    def full(self: LogWriter) -> None:
        raise LogWriteError(f"writing {self.path} failed: No space left on device")

    monkeypatch.setattr(LogWriter, "_commit", full)
    with pytest.raises(LogWriteError, match="No space left"):
        densify(log, out)
    assert os.listdir(out.parent) == []
