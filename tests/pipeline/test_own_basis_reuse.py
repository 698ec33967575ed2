"""A log's own basis that stopped fitting is not advised for other logs (bug hunt 16D F1)."""

from __future__ import annotations

from pathlib import Path

from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.pipeline.own_bases import adoption_lines, own_bases
from pcainterp_stream.pipeline.processor import FrameProcessor, ProcessorConfig
from pcainterp_stream.records import StereoFrame
from pcainterp_stream.synth import SynthConfig, generate


def _room() -> list[StereoFrame]:
    config = SynthConfig(seed=3, frames=24, scale=0.25, scene="indoor")  # a KITTI-like camera
    return [
        StereoFrame(f.index, f.stamp_ns, f.stamp_ns, "left", f.left, f.right, f.camera)
        for f in generate(config)
    ]


def test_a_basis_that_stopped_fitting_is_not_advised_for_other_logs() -> None:
    """The run that stopped its own basis at frame 23 (2.20x linear) still wrote "densify
    --basis with it for other logs of this camera" for OUTPUT.final.basis.npz: on two other
    rooms of the camera it gave 18.0 and 13.8 px against the default's 4.0 and 2.5."""
    with FrameProcessor(None, ProcessorConfig()) as engine:
        list(engine.process(_room()))
        adaptation = engine.adaptation
    assert any("stopped fitting at frame 23" in line for line in adaptation.lines)
    assert adaptation.stopped == {1: 23}
    owns = own_bases(adaptation, Basis.default(), Path("out.mcap"))
    said = [own.described(owns) for own in owns if own.path is not None]
    assert [own.path.name for own in owns if own.path is not None] == [
        "out.basis.npz",
        "out.final.basis.npz",
    ]
    for line in said:
        assert "for other logs of this camera" in line
        assert "densify --basis with it" not in line
        assert "it stopped fitting this log at frame 23: kept for inspection only" in line
    assert adoption_lines(owns)[0].endswith(
        "when it stopped fitting at frame 23 (1 update while streaming)"
    )
