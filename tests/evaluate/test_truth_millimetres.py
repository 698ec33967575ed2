"""``/ground_truth/depth`` in 16UC1 millimetres (REP 118) is read as millimetres (bug hunt 16B F7).

evaluate read the truth's raw values whatever the encoding, so a 16UC1 truth was taken as
metres (pca_map D2D 23.4 px instead of 1.6, exit 0); it is now read by the rule of
``--reference-topic`` (32FC1 metres, 16UC1 / mono16 millimetres, 0: no value).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap_copy import McapCopy
from rosbags.typesys import Stores, get_typestore

from pcainterp_stream.errors import LogReadError
from pcainterp_stream.evaluate.metrics import Mode, compare_with_ground_truth
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.stereo_log import DEPTH as TRUTH
from pcainterp_stream.pipeline import jobs

OPTIONS = EvaluateOptions(mode=Mode.STEREO, sweep_every=0, linear=False)
STORE = get_typestore(Stores.ROS2_HUMBLE)


def _rewrite_truth(source: Path, target: Path, encoding: str) -> None:
    """Copy a densified log with its truth as 16UC1 millimetres (or mono8, a camera image)."""
    with McapCopy(source, target) as copy:
        for topic, channel_id, message in copy.messages():
            data = message.data
            if topic == TRUTH:
                image = STORE.deserialize_cdr(data, rosmsg.IMAGE)
                metres = rosmsg.image_array(image).astype(np.float64)
                if encoding == "16UC1":
                    values = np.where(np.isfinite(metres), np.clip(metres * 1000, 0, 65535), 0)
                    raw, step = values.astype("<u2"), image.width * 2
                else:
                    raw, step = np.zeros(metres.shape, np.uint8), image.width
                image.data = np.frombuffer(raw.tobytes(), np.uint8)
                image.encoding, image.step, image.is_bigendian = encoding, step, 0
                data = STORE.serialize_cdr(image, rosmsg.IMAGE)
            copy.add(channel_id, message.log_time, bytes(data))


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("truth_mm")
    jobs.synth(folder / "synth.mcap", frames=3, seed=43, scale=0.25, fmt="mcap")
    jobs.densify(folder / "synth.mcap", folder / "dense.mcap")
    _rewrite_truth(folder / "dense.mcap", folder / "mm.mcap", "16UC1")
    _rewrite_truth(folder / "dense.mcap", folder / "mono8.mcap", "mono8")
    return folder


def _d2d(path: Path) -> float:
    result, _ = evaluate_log(path, OPTIONS)
    stats = result.methods["pca_map"]
    return stats.delta_2d_sum / stats.pixels


def test_a_millimetre_truth_scores_as_the_metre_one(folder: Path) -> None:
    metres, millimetres = _d2d(folder / "dense.mcap"), _d2d(folder / "mm.mcap")
    assert millimetres == pytest.approx(metres, rel=0.2)  # mm rounding, the sky unknown


def test_compare_with_ground_truth_reads_millimetres(folder: Path) -> None:
    metres = compare_with_ground_truth(folder / "dense.mcap").mean_abs_error("pca_map")
    millimetres = compare_with_ground_truth(folder / "mm.mcap").mean_abs_error("pca_map")
    assert millimetres == pytest.approx(metres, rel=0.2)


def test_a_camera_image_as_truth_is_refused_in_one_line(folder: Path) -> None:
    with pytest.raises(LogReadError, match=r"/ground_truth/depth: mono8 is a camera image"):
        evaluate_log(folder / "mono8.mcap", OPTIONS)
