"""A densified log passed through a ROS 2 bag tool (rosbags-convert, ``ros2 bag convert``)
loses pcainterp's channel metadata; evaluate reads f*b from the features instead."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.evaluate.log_frames import ReadState, _Complete, _recover_focal_baseline
from pcainterp_stream.evaluate.metrics import Mode
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
from pcainterp_stream.io import rosmsg
from pcainterp_stream.pipeline import jobs

FEATURES = "/pcainterp/features"


@pytest.fixture(scope="module")
def compact(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("converted")
    log, dense = folder / "synth.mcap", folder / "dense.mcap"
    jobs.synth(log, frames=3, seed=43, scale=0.25, fmt="mcap")
    jobs.densify(log, dense)  # compact: the depth needs the recorded f*b
    return dense


def _converted(source: Path, storage: str) -> Path:
    from rosbags.convert import convert

    target = source.parent / f"converted_{storage}"
    convert(
        srcs=[source],
        dst=target,
        dst_storage=storage,
        dst_version=8,
        compress=None,
        compress_mode="file",
        default_typestore=None,
        typestore=None,
        exclude_topics=[],
        include_topics=[],
        exclude_msgtypes=[],
        include_msgtypes=[],
    )
    return target


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_converted_log_scores_as_the_log_densify_wrote(compact: Path, storage: str) -> None:
    options = EvaluateOptions(mode=Mode.STEREO, sweep_every=0, linear=False)
    written, _ = evaluate_log(compact, options)
    converted, _ = evaluate_log(_converted(compact, storage), options)
    assert converted.frames == written.frames == 3
    for name, stats in written.methods.items():
        assert converted.methods[name].pixels == stats.pixels
        assert converted.methods[name].delta_2d_sum == pytest.approx(stats.delta_2d_sum, rel=1e-5)
    assert written.notes == []
    assert len(converted.notes) == 1
    assert "carry no pcainterp metadata, as after a ROS 2 bag tool" in converted.notes[0]
    assert "was read from the features (z * disparity)" in converted.notes[0]


def test_features_without_a_disparity_name_the_conversion_and_the_fix() -> None:
    cloud = rosmsg.pointcloud2_message(
        {name: np.zeros(0, np.float32) for name in ("x", "y", "z", "u", "v", "disparity")},
        0,
        "left",
    )
    state = ReadState(converted=True)
    frame = _Complete(index=2, stamp_ns=0, parts={FEATURES: cloud})
    with pytest.raises(
        LogReadError,
        match=r"frame 2 of the densified log: its channels carry no pcainterp metadata .*"
        r"no point with a disparity to read f\*b from.*--precision full",
    ):
        _recover_focal_baseline(frame, FEATURES, state)
