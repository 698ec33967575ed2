"""What ``pcainterp evaluate`` writes: the frames it scores, the report folder, results.json."""

from __future__ import annotations

from pathlib import Path

import pytest

from pcainterp_stream.evaluate.metrics import Mode
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
from pcainterp_stream.evaluate.tables import results_markdown, summary_table
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import decode_image, open_log
from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.pipeline import jobs

LEFT, RIGHT = "/stereo/left/image_rect", "/stereo/right/image_rect"


def _blanked(source: Path, target: Path, frames: set[int]) -> Path:
    """Copy a log with the stereo images of ``frames`` (counted from 0) all black."""
    seen: dict[str, int] = {}
    with open_log(source) as reader, open_writer(target, "mcap") as writer:
        for raw in reader.messages():
            message = reader.decode(raw)
            if raw.topic in (LEFT, RIGHT):
                index = seen[raw.topic] = seen.get(raw.topic, -1) + 1
                if index in frames:
                    black = decode_image(message) * 0
                    message = rosmsg.image_message(
                        black,
                        rosmsg.stamp_ns(message),
                        message.header.frame_id,
                        encoding=message.encoding,
                    )
            writer.add_message(raw.topic, message, raw.log_time_ns)
    return target


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("report_output")
    log = folder / "drive.mcap"
    jobs.synth(log, frames=6, seed=31, scale=0.25, fmt="mcap")
    dense, blank_dense = folder / "dense.mcap", folder / "blank_dense.mcap"
    jobs.densify(log, dense)
    jobs.densify(_blanked(log, folder / "blank.mcap", {1, 2}), blank_dense)
    return {"folder": folder, "log": log, "dense": dense, "blank_dense": blank_dense}


def test_frames_without_a_measurement_are_left_out_of_every_method(
    logs: dict[str, Path],
) -> None:
    # before: nearest and linear (NaN there) were charged huge errors on the black frames,
    # so PCA-MAP / nearest fell (0.66 -> 0.38 on a bug hunt log) and the report was silent
    options = EvaluateOptions(mode=Mode.STEREO, sweep_every=0, linear=True)
    blank, _ = evaluate_log(logs["blank_dense"], options)
    assert blank.no_measurement == [1, 2]
    assert blank.frames == 4
    for name in ("pca_map", "nearest", "linear"):
        stats = blank.methods[name]
        assert stats.pixels > 0
        assert stats.summary()["delta_2d_mean"] < 20.0  # no NaN estimate charged as far
    # every method on the same frames: the same counted pixels
    pixels = {name: stats.pixels for name, stats in blank.methods.items() if name != "oracle"}
    assert len(set(pixels.values())) == 1
    note = "2 frames left out of every method: no measurement there"
    assert note in summary_table(blank)
    assert "(frames 1, 2, counted from 0)" in summary_table(blank)
    assert note in results_markdown(blank, [])
    assert blank.summary()["left_out_no_measurement"] == [1, 2]
    full, _ = evaluate_log(logs["dense"], options)
    assert full.no_measurement == []
    assert "left out" not in summary_table(full)


def test_a_log_without_any_measurement_cannot_be_evaluated(tmp_path: Path) -> None:
    from pcainterp_stream.errors import LogReadError

    log = tmp_path / "drive.mcap"
    jobs.synth(log, frames=2, seed=32, scale=0.25, fmt="mcap")
    dense = tmp_path / "dense.mcap"
    jobs.densify(_blanked(log, tmp_path / "black.mcap", {0, 1}), dense)
    with pytest.raises(LogReadError, match=r"\(2 densified frames read, 2 without a measurement;"):
        evaluate_log(dense, EvaluateOptions(mode=Mode.STEREO, sweep_every=0, linear=False))
