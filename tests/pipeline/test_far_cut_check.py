"""densify's fit check scores its maps as the output writes them: the far cut included.

Bug hunt 16D F8: a basis whose sigma is large for the camera (a ``learn --no-fit-prior``
basis, 2 px, on a camera of f*b 9.6 px*m) writes most of a room as too far (depth +inf);
the check scored the disparity before that cut and said 1.23x nearest where the output
was 3.85x nearest, with no word of the cut.
"""

from __future__ import annotations

import numpy as np

from pcainterp_stream.estimate import adapt
from pcainterp_stream.frontend.stereo import StereoFrontEnd
from pcainterp_stream.pipeline.processor import FrameProcessor, ProcessorConfig
from pcainterp_stream.records import StereoFrame
from pcainterp_stream.synth import SynthConfig, generate
from pcainterp_stream.synth.indoor import camera_options


def test_the_fit_check_scores_the_maps_as_written_with_the_far_cut() -> None:
    """A 640x480 room at half size (f*b 9.6 px*m) with the indoor basis at sigma 10 (2 px in
    this camera): 65 % of the check's pixels are written as too far. Before: the check said
    0.30 px (1.61x nearest) where the written maps erred 1.10 px at the same pixels."""
    config = SynthConfig(seed=11, frames=8, scale=0.5, scene="indoor", **camera_options("640x480"))
    frames = [
        StereoFrame(f.index, f.stamp_ns, f.stamp_ns, "left", f.left, f.right, f.camera)
        for f in generate(config)
    ]
    processor = ProcessorConfig(adapt="check", builtin="indoor", sigma=10.0)
    front_end = StereoFrontEnd(processor.gftt, processor.sgbm)
    written = []
    with FrameProcessor(None, processor) as engine:
        for result in engine.process(frames):
            sgbm = front_end.measure(result.frame.left, result.frame.right).disparity_map
            reference = np.where(sgbm > 0, sgbm, np.nan).astype(np.float32)
            as_written = np.where(np.isposinf(result.depth), 0.0, result.disparity)
            written.append(
                adapt.check_frame(as_written, reference, result.pixels, result.disparities)
            )
            assert result.min_disparity > 1.5
        check = engine.adaptation.check
        lines = engine.adaptation.lines
    assert check is not None
    output = adapt.FitCheck.combine(written)
    assert check.pixels == output.pixels
    assert abs(check.prior - output.prior) < 0.02 * output.prior
    assert check.far > 0.5 * check.pixels
    assert "% of them written as too far and scored so: below 2 px" in lines[0]
    assert not check.fits
