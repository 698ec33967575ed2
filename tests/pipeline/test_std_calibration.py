"""The written std is calibrated honestly (bug hunt 8C F1, F2, F3 and the std-scale guard)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from pcainterp_stream.estimate import adapt
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.pipeline import adaptation as adaptation_module
from pcainterp_stream.pipeline.adaptation import Adaptation, Candidate
from pcainterp_stream.pipeline.processor import (
    FrameProcessor,
    MeasurementSource,
    ProcessorConfig,
    resolve_settings,
)
from pcainterp_stream.records import StereoFrame
from pcainterp_stream.synth import SynthConfig, generate
from pcainterp_stream.synth.indoor import camera_options


def _basis(prior: dict[str, Any]) -> Basis:
    height, width = 20, 30
    component = np.zeros((1, height, width), dtype=np.float32)
    component[0].flat[0] = 1.0
    return Basis(
        mean=np.full((height, width), 20.0, dtype=np.float32),
        components=component,
        eigenvalues=np.array([1.0]),
        total_variance=1.0,
        image_size=(height, width),
        focal_baseline=100.0,
        n_train=4,
        meta={"prior": prior},
    )


PAPER_FIT = {"local": None, "sigma": 0.1, "plain_sigma": 0.1, "std_scale": 37.4}
"""A basis whose evidence chose the paper's prior (the flat wall's own basis: F3)."""


@pytest.mark.parametrize(
    "config",
    [
        ProcessorConfig(),
        ProcessorConfig(measurements="dense"),
        ProcessorConfig(source=MeasurementSource.FEATURES),
    ],
    ids=["sparse", "dense", "features"],
)
def test_a_paper_prior_fit_applies_its_fitted_std_scale(config: ProcessorConfig) -> None:
    """Its scale (37.4) was dropped: 4 % of a flat wall's pixels inside +-2 std (8C F3)."""
    settings = resolve_settings(_basis(PAPER_FIT), config)
    assert settings.local_prior is None
    assert settings.std_scale == 37.4
    assert not settings.scale_by_innovation
    assert settings.densify_options()["std_scale"] == 37.4
    # --no-calibrate reports the posterior std itself
    plain = resolve_settings(_basis(PAPER_FIT), dataclasses.replace(config, calibrate=False))
    assert plain.std_scale == 1.0
    # learn's fit: the per-frame scale fitted with the paper's prior applies with it too
    learned = _basis({**PAPER_FIT, "innovation_std_scale": 2.5})
    settings = resolve_settings(learned, config)
    assert (settings.std_scale, settings.scale_by_innovation) == (2.5, True)


def test_a_hybrid_fit_scale_does_not_apply_to_the_paper_prior() -> None:
    hybrid = {**PAPER_FIT, "local": {"variance": 2.0, "length_scale": 8.0, "kernel": "laplace"}}
    assert resolve_settings(_basis(hybrid), ProcessorConfig()).std_scale == 37.4
    assert resolve_settings(_basis(hybrid), ProcessorConfig(prior="paper")).std_scale == 1.0


def test_an_absurd_fitted_std_scale_is_warned_once() -> None:
    """2.94e7 (two EuRoC maps on dense mode's lattice): the std rests on that one factor."""
    absurd = _basis({**PAPER_FIT, "std_scale": 2.94e7})
    with FrameProcessor(absurd, ProcessorConfig(adapt="off")) as engine:
        warnings = [line for line in engine.adaptation.lines if line.startswith("warning:")]
    assert warnings == [
        "warning: the basis has a fitted std scale of 2.94e+07: its own posterior std is about "
        "0 (a basis learned from too few maps), so the std written rests on that one factor; "
        "learn a basis from more frames of this camera (pcainterp learn LOG [LOG ...] -o "
        "BASIS.npz) or densify without --basis"
    ]
    engine.adaptation.warn_std_scale(2.94e7)  # a relearned basis as absurd: no second line
    assert len(engine.adaptation.lines) == 1
    with FrameProcessor(_basis(PAPER_FIT), ProcessorConfig(adapt="off")) as engine:
        assert engine.adaptation.lines == []  # 37.4 is a usable own basis's scale


def test_a_one_frame_log_keeps_the_built_in_basis_and_its_honest_std() -> None:
    """One frame: no frame left out to calibrate a basis learned from it; calibrated on the
    frame it reproduces, its std covered 0-67 % of the truth (8C F2)."""
    config = SynthConfig(seed=7, frames=1, scale=0.25, scene="indoor", **camera_options("640x480"))
    frames = [
        StereoFrame(f.index, f.stamp_ns, f.stamp_ns, "left", f.left, f.right, f.camera)
        for f in generate(config)
    ]
    # the street basis alone: it does not fit a room, so the log's own basis would be tried
    with FrameProcessor(None, ProcessorConfig(builtin="street")) as engine:
        (result,) = list(engine.process(frames))
        adaptation = engine.adaptation
        assert not adaptation.adapted
        assert engine.basis is Basis.default()
    assert any(
        line.startswith(
            "prior: kept the built-in street basis; this log's own basis is not "
            "learned from one frame: no other frame to calibrate its std on"
        )
        for line in adaptation.lines
    ), adaptation.lines
    assert result.disparity_std is not None


def _left_out(prior: float) -> adapt.FitCheck:
    return adapt.FitCheck(frames=4, pixels=240, prior=prior, linear=1.2, nearest=1.81)


def test_a_near_tie_between_built_in_bases_says_so() -> None:
    """Both lines read 1.01 px, then "fits this log better" (8C F1): a near-tie now."""
    indoor = Candidate("the built-in indoor basis", Basis.indoor(), {})
    adaptation = Adaptation(
        mode="check",
        may_replace=True,
        warmup_frames=8,
        robust="cauchy",
        calibrate=True,
        name="the built-in street basis",
    )
    adaptation.check, adaptation.switched = _left_out(1.0051), indoor
    assert adaptation._chosen_line(_left_out(1.0143)) == (
        "prior: the built-in indoor basis chosen by a near-tie (1.0051 px against 1.0143 for "
        "the built-in street basis); --basis builtin-street or builtin-indoor forces one"
    )
    adaptation.check = _left_out(0.91)
    assert adaptation._chosen_line(_left_out(1.0143)) == (
        "prior: the built-in indoor basis chosen (fits this log better)"
    )


def test_the_own_basis_line_prints_a_near_tie_with_enough_digits(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The own-basis line read "was better (0.30 px against 0.30)" (review 56b R4)."""
    options = camera_options("752x480")
    config = SynthConfig(seed=3, frames=8, scale=0.5, scene="indoor", **options)
    frames = [
        StereoFrame(f.index, f.stamp_ns, f.stamp_ns, "left", f.left, f.right, f.camera)
        for f in generate(config)
    ]
    engine = FrameProcessor(None, ProcessorConfig())

    def near_tie(*args: Any, **kwargs: Any) -> adapt.OwnCheck:
        check = engine.adaptation.check
        assert check is not None  # the own basis a hair better, alike at 2 decimals
        prior = check.prior
        own = (max(round(prior, 2) - 0.005, prior - 0.004) + prior) / 2
        return adapt.OwnCheck(adapt.FitCheck(1, 100, own, check.linear, check.nearest), None)

    monkeypatch.setattr(adapt, "leave_one_out", near_tie)
    with engine:
        list(engine.process(frames))
    (line,) = [line for line in engine.adaptation.lines if "own basis was better (" in line]
    own, given = line.split("was better (")[1].split(")")[0].split(" px against ")
    assert own != given, line
    assert adaptation_module._figures(0.2961, 0.3049) == ("0.2961", "0.3049")
    assert adaptation_module._figures(0.2961, 0.3149) == ("0.30", "0.31")
