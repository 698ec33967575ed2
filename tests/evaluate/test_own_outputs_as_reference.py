"""densify's own outputs are no reference (bug hunt 16A F2).

``--reference-topic /pcainterp/depth`` scored the estimate against itself (D2D 0.000 px,
exit 0), and the not-found message offered the outputs and the camera images (which it then
refuses) as references. Now refused in one line, and left out of the topics offered.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from pcainterp_stream import cli
from pcainterp_stream.pipeline import jobs


@pytest.fixture(scope="module")
def dense(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("own_outputs")
    jobs.synth(folder / "synth.mcap", frames=2, seed=43, scale=0.25, fmt="mcap")
    jobs.densify(folder / "synth.mcap", folder / "dense.mcap")
    return folder / "dense.mcap"


def _error(capsys: pytest.CaptureFixture[str], dense: Path, topic: str) -> str:
    out = dense.with_name("report")
    args = ["evaluate", str(dense), "-o", str(out), "--no-basis", "--sweep-every", "0"]
    assert cli.main([*args, "--reference-topic", topic]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "Traceback" not in err
    assert not out.exists()
    return err


@pytest.mark.parametrize("topic", ["/pcainterp/depth", "/pcainterp/disparity_std"])
def test_an_output_of_densify_is_refused_as_reference(
    dense: Path, capsys: pytest.CaptureFixture[str], topic: str
) -> None:
    err = _error(capsys, dense, topic)
    assert f"reference topic {topic} is one of densify's own outputs" in err


def test_the_topics_offered_are_the_log_s_own_depth_topics(
    dense: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    err = _error(capsys, dense, "/nope")
    assert "image topics present: /ground_truth/depth;" in err
    assert "/pcainterp/" not in err
    assert "/stereo/left/image_rect" not in err
