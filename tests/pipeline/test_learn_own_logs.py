"""``learn`` on a user's own logs: the rectify decision, one-camera depth logs, the kernel kept."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pcainterp_stream.errors import PcaInterpError, TopicNotFoundError
from pcainterp_stream.estimate.adapt import ROUGH_KERNEL, FitCheck, HeldOut
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import LogFormat, open_writer
from pcainterp_stream.pipeline import held_out, jobs
from pcainterp_stream.pipeline.learn import learn_pairing

RIGHT = ("/stereo/right/image_rect", "/stereo/right/camera_info")


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("learn_own")
    jobs.synth(folder / "lidar.mcap", frames=4, seed=15, scale=0.25, fmt="mcap", lidar=True)
    jobs.synth_raw(folder / "raw.bag", frames=3, seed=18, scale=0.25, fmt=None, model="plumb_bob")
    with (
        open_log(folder / "lidar.mcap") as reader,
        open_writer(folder / "one.mcap", LogFormat.MCAP) as writer,
    ):
        for raw in reader.messages():
            if raw.topic not in RIGHT:  # a one-camera log with its depth (an RGB-D camera)
                writer.add_message(raw.topic, reader.decode(raw), raw.log_time_ns)
    return folder


def test_learn_prints_and_records_the_rectify_decision(
    folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # before: nothing said, nothing recorded, whatever --rectify was (bug hunt 11A F2)
    options = jobs.LearnOptions(n_components=2, fit_prior=False, with_synthetic=0)
    for rectify, said in (("auto", "rectify auto: remapping the raw images"), ("never", None)):
        pairing = PairingConfig(discover=True, rectify=rectify)
        basis = jobs.learn([folder / "raw.bag"], folder / f"r_{rectify}.npz", options, pairing)
        out = capsys.readouterr().out
        line = next(line for line in out.splitlines() if line.startswith(f"rectify {rectify}"))
        assert said is None or line.startswith(said)
        recorded = basis.meta["source"]["rectify"]
        assert recorded["option"] == rectify
        assert recorded["decisions"] == {str(folder / "raw.bag"): line}


def test_learn_takes_a_one_camera_depth_log_with_its_baseline(folder: Path) -> None:
    # before: "set --right-info-topic", then "no depth image with camera infos" (11A F3)
    one = folder / "one.mcap"
    options = jobs.LearnOptions(
        n_components=2, depth_topic="/ground_truth/depth", fit_prior=False, with_synthetic=0
    )
    with pytest.raises(PcaInterpError, match=r"one camera info .*pass --baseline METRES"):
        jobs.learn([one], folder / "one.npz", options, PairingConfig())
    basis = jobs.learn([one], folder / "one.npz", options, PairingConfig(baseline=0.25))
    with open_log(one) as reader:
        info = next(reader.decode(r) for r in reader.messages(["/stereo/left/camera_info"]))
    assert basis.focal_baseline == pytest.approx(float(np.asarray(info.p)[0]) * 0.25)
    stereo = jobs.learn(
        [folder / "lidar.mcap"], folder / "two.npz", options, PairingConfig(baseline=0.25)
    )
    assert np.allclose(basis.mean, stereo.mean, atol=1e-4)  # the same depth, the same maps
    fitted = jobs.LearnOptions(n_components=2, depth_topic="/ground_truth/depth")
    with pytest.raises(PcaInterpError, match=r"one camera .*pass --no-fit-prior, or --fit-logs"):
        jobs.learn([one], folder / "one.npz", fitted, PairingConfig(baseline=0.25))


def test_fit_logs_are_compared_with_a_one_camera_depth_logs_camera(folder: Path) -> None:
    """Review 58c C8: with a one-camera depth training log, every --fit-logs log skipped the
    size refusal (no stereo camera to compare with): the depth maps' camera is compared."""
    from pcainterp_stream.pipeline.learn_maps import check_fit_logs

    other = folder / "bigger.mcap"  # a stereo log of another camera, 2x the size
    jobs.synth(other, frames=2, seed=16, scale=0.5, fmt="mcap")
    options = jobs.LearnOptions(n_components=2, depth_topic="/ground_truth/depth")
    pairing = PairingConfig(baseline=0.25)
    with pytest.raises(PcaInterpError, match=r"--fit-logs bigger\.mcap has .* but the training"):
        check_fit_logs((other,), [folder / "one.mcap"], options, pairing)
    check_fit_logs((folder / "lidar.mcap",), [folder / "one.mcap"], options, pairing)  # same


def test_learn_of_a_one_camera_log_names_depth_topics_not_a_pair(folder: Path) -> None:
    # before: "pass --left-topic and --right-topic", which cannot be followed (11A F4)
    with pytest.raises(TopicNotFoundError) as caught:
        learn_pairing([folder / "one.mcap"], PairingConfig(discover=True))
    message = str(caught.value)
    assert "learn needs a stereo pair (its SGBM maps) or a depth image topic" in message
    assert re.search(r"--depth-topic TOPIC, e\.g\. /ground_truth/\w*depth", message)
    assert "pass --left-topic" not in message


def _frame(reference: np.ndarray, focal_baseline: float = 10.0) -> held_out.HeldOutFrame:
    pixels = np.array([[4.0, 4.0], [20.0, 4.0], [4.0, 20.0], [20.0, 20.0]])
    disparities = np.full(4, 5.0)
    return held_out.HeldOutFrame(
        pixels,
        disparities,
        (24, 24),
        focal_baseline,
        None,
        HeldOut.of(reference, pixels, disparities),
    )


def _fit(local: dict[str, Any]) -> dict[str, Any]:
    return {"local": local, "sigma": 1.0, "plain_sigma": 1.0, "std_scale": 1.0}


@pytest.mark.parametrize(("rough_px", "chosen"), [(0.3, "rough"), (0.5, "indoor"), (0.4, "indoor")])
def test_the_indoor_kernel_or_the_rougher_one_whichever_errs_less_held_out(
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    rough_px: float,
    chosen: str,
) -> None:
    # before: a fine-tuned indoor basis always kept the indoor kernel, and lost to the
    # default's rougher kernel on held-out frames of the same room (11A F5)
    indoor = {"kernel": "gaussian", "length_scale": 32.0, "variance": 2.38}
    kept, rough = _fit(indoor), _fit(ROUGH_KERNEL.to_meta())

    def score(basis: Basis, frames: Any, fitted: dict[str, Any], *, robust: str) -> FitCheck:
        error = rough_px if fitted is rough else 0.4
        return FitCheck(len(frames), 100, error, 0.5, 0.6, first_column=2)

    monkeypatch.setattr(held_out, "score_fit", score)
    frames = [_frame(np.full((24, 24), 5.0, np.float32))]
    result = held_out.choose_kernel(Basis.default(), frames, kept, lambda: rough, "cauchy")
    assert result is (rough if chosen == "rough" else kept)
    record = result["local_choice"]
    assert record["chosen"] == chosen
    assert record["tried"] is True
    assert record["first_column"] == 2  # review 58c C2: the columns scored
    assert record["kernels"]["rough"]["held_out_px"] == rough_px
    assert record["kernels"]["indoor"]["local"] == indoor
    # review 58c C2: worded as densify's line (rougher's helpers)
    out = capsys.readouterr().out
    assert (
        "prior: the fine-tuned indoor basis with the street basis's local kernel (laplace, "
        "64 px, 40 px^2) " in out
    )
    verdict = "taken" if chosen == "rough" else "not taken"
    mine, theirs = ("0.30", "0.40") if rough_px != 0.4 else ("0.4000", "0.4000")
    mine = "0.50" if rough_px == 0.5 else mine
    assert (
        f"; {verdict}: {mine} px against {theirs} with the built-in indoor basis's own kernel "
        "(gaussian, 32 px, 2.38 px^2) on the same held-out SGBM pixels"
    ) in out


def test_learn_keeps_the_indoor_kernel_where_sgbm_left_its_band_unchecked(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Review 58c C2: densify's guard. learn's held-out frames are matched without the left
    band (columns >= 128 scored): on a camera densify matches at half resolution (f*b 386
    px*m), its band empty, the rougher kernel would extrapolate there unchecked, so it is
    neither fitted nor taken, though it errs less on the columns scored."""
    indoor = {"kernel": "gaussian", "length_scale": 32.0, "variance": 2.38}
    kept = _fit(indoor)

    def score(basis: Basis, frames: Any, fitted: dict[str, Any], *, robust: str) -> FitCheck:
        assert fitted is kept
        return FitCheck(len(frames), 100, 0.4, 0.5, 0.6, first_column=128)

    def fit_rough() -> dict[str, Any]:
        raise AssertionError("fitted")

    monkeypatch.setattr(held_out, "score_fit", score)
    frames = [_frame(np.full((24, 24), 5.0, np.float32), focal_baseline=386.0)]
    result = held_out.choose_kernel(Basis.default(), frames, kept, fit_rough, "cauchy")
    assert result is kept
    record = result["local_choice"]
    assert (record["chosen"], record["tried"], record["first_column"]) == ("indoor", False, 128)
    assert set(record["kernels"]) == {"indoor"}
    assert (
        "prior: the fine-tuned indoor basis with the street basis's local kernel (laplace, 64 px, "
        "40 px^2): not tried: the held-out pixels cover columns >= 128 only"
    ) in capsys.readouterr().out


def test_learn_tries_the_rougher_kernel_where_densify_will_match_the_band(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """On a camera densify matches at full resolution with its left band (f*b below 90
    px*m), the band holds points when the basis is used: the guard does not apply, though
    learn's own held-out pixels start at column 128 (with it, a room learned from 30 frames
    kept the indoor kernel: 0.066 px on its next 10 frames against 0.062 with the rougher)."""
    kept = _fit({"kernel": "gaussian", "length_scale": 32.0, "variance": 2.38})
    rough = _fit(ROUGH_KERNEL.to_meta())

    def score(basis: Basis, frames: Any, fitted: dict[str, Any], *, robust: str) -> FitCheck:
        return FitCheck(
            len(frames), 100, 0.3 if fitted is rough else 0.4, 0.5, 0.6, first_column=128
        )

    monkeypatch.setattr(held_out, "score_fit", score)
    monkeypatch.setattr(held_out, "rough_std_scales", lambda *a, **k: {})
    frames = [_frame(np.full((24, 24), 5.0, np.float32), focal_baseline=48.0)]
    result = held_out.choose_kernel(Basis.default(), frames, kept, lambda: rough, "cauchy")
    assert result is rough
    assert (result["local_choice"]["tried"], result["local_choice"]["first_column"]) == (True, 128)


def test_the_rough_fit_gets_densifys_std_scale_rule() -> None:
    """Review 58c C2: the rough kernel's std scales are densify's (rougher.sgbm_std_scale:
    the larger of the 95.4 % band's and the likelihood's), not the band's alone."""
    from pcainterp_stream.estimate import adapt, rougher

    rng = np.random.default_rng(3)
    frames = []
    for index in range(3):
        reference = (5.0 + rng.normal(0.0, 0.8, (24, 24))).astype(np.float32)
        pixels = rng.uniform(1.0, 23.0, (12, 2))
        disparities = reference[pixels[:, 1].astype(int), pixels[:, 0].astype(int)]
        frames.append(
            held_out.HeldOutFrame(
                pixels, disparities, (24, 24), 10.0, reference if index < 2 else None
            )
        )
    fitted = _fit(ROUGH_KERNEL.to_meta())
    scales = held_out.rough_std_scales(Basis.default(), frames, fitted, robust="cauchy")
    measured = [adapt.Measured(f.pixels, f.disparities, f.reference) for f in frames[:2]]  # type: ignore[arg-type]
    options = {"local_prior": ROUGH_KERNEL, "sigma": 1.0}
    camera = {"image_size": (24, 24), "focal_baseline": 10.0, "robust": "cauchy"}
    for name, per_frame in (("std_scale", False), ("innovation_std_scale", True)):
        same = rougher.sgbm_std_scale(
            Basis.default(), measured, options, per_frame=per_frame, **camera
        )  # type: ignore[arg-type]
        band = rougher.sgbm_std_scale(
            Basis.default(),
            measured,
            options,
            per_frame=per_frame,
            likelihood=False,
            **camera,  # type: ignore[arg-type]
        )
        assert scales[name] == same >= band


def test_score_fit_scores_held_out_sgbm_pixels() -> None:
    flat = _frame(np.full((24, 24), 5.0, np.float32))
    check = held_out.score_fit(Basis.default(), [flat], _fit(ROUGH_KERNEL.to_meta()), robust="none")
    assert check.frames == 1
    assert check.pixels > 0
    assert check.linear == pytest.approx(0.0, abs=1e-9)  # the measurements are the plane


@pytest.mark.parametrize("rougher", [None, ROUGH_KERNEL])
def test_the_held_out_check_is_sampled_only_for_the_kernel_choice(
    folder: Path, monkeypatch: pytest.MonkeyPatch, rougher: Any
) -> None:
    """Review 58c C4: every learn sampled 20 000 held-out SGBM pixels per held-out frame
    (and interpolated there), though only a merge into the indoor basis scores them."""
    from pcainterp_stream.estimate.prior import LocalPrior
    from pcainterp_stream.pipeline import learn as learn_module

    asked: list[bool] = []

    def measure(*args: Any, sample_check: bool = True, **kwargs: Any) -> list[Any]:
        asked.append(sample_check)
        raise StopIteration  # enough: what it was asked

    monkeypatch.setattr(learn_module, "measure_held_out", measure)
    indoor = LocalPrior(2.38, 32.0, "gaussian")
    with pytest.raises(StopIteration):
        learn_module.fit_prior(
            Basis.default(),
            [(folder / "lidar.mcap", 0)],
            jobs.LearnOptions(),
            PairingConfig(),
            indoor,
            rougher,
        )
    assert asked == [rougher is not None]
    frames = held_out.measure_held_out(
        folder / "lidar.mcap", 0, jobs.LearnOptions(), PairingConfig(), sample_check=False
    )
    assert frames
    assert all(frame.check is None for frame in frames)
