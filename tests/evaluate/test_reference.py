"""``evaluate --reference-topic``: any depth or disparity image as the truth, dense or sparse;
the stereo baselines (sgbm, sgbm_nn) and the coverage split by SGBM's holes."""

from __future__ import annotations

import dataclasses
import itertools
import json
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from hypothesis_profiles import examples

from pcainterp_stream import cli
from pcainterp_stream.errors import LogReadError, PcaInterpError
from pcainterp_stream.evaluate.metrics import (
    CalibrationStats,
    MethodStats,
    Mode,
    ReferenceKind,
    ReferenceView,
    disparity_from_depth,
    disparity_from_reference,
    fill_nearest,
    reference_view,
    relative_transform,
    stereo_transform,
)
from pcainterp_stream.evaluate.reference import (
    ReferenceTopic,
    disparity_image_valid,
    reference_disparity,
)
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log, summary_table
from pcainterp_stream.evaluate.results import PCA_ON_SGBM, SGBM, SGBM_NN, Evaluation
from pcainterp_stream.evaluate.tables import results_markdown
from pcainterp_stream.frontend.stereo import SgbmConfig, compute_disparity
from pcainterp_stream.io import depth_codec, rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.io.outputs import OutputTopics
from pcainterp_stream.pipeline import jobs
from pcainterp_stream.records import StereoCamera
from pcainterp_stream.synth import SynthConfig, generate
from pcainterp_stream.synth.lidar import LIDAR_DEPTH, LidarConfig
from pcainterp_stream.synth.log import (
    DEPTH,
    LEFT_FRAME,
    LEFT_IMAGE,
    POSE,
    RIGHT_IMAGE,
    RIGHT_INFO,
    write_synthetic_log,
)

CONFIG = SynthConfig(seed=31, frames=4, scale=0.25)
CAMERA = CONFIG.camera
FOCAL_BASELINE = CAMERA.focal_baseline
MS = 1_000_000
DISPARITY, STD, INFO = "/pcainterp/disparity", "/pcainterp/disparity_std", "/pcainterp/camera_info"
OWN_DISPARITY = "/ref/densify_disparity"


# ----------------------------------------------------------------------------- maths


def test_reference_values_without_truth_are_nan() -> None:
    depth = np.array([[2.0, np.nan, np.inf, 0.0, -1.0, -np.inf]])
    np.testing.assert_array_equal(
        disparity_from_reference(depth, kind=ReferenceKind.DEPTH, focal_baseline=30.0),
        [[15.0, np.nan, 0.0, np.nan, np.nan, np.nan]],  # +inf depth: farther than measurable
    )
    disparity = np.array([[3.0, np.nan, np.inf, 0.0, -1.0]])
    np.testing.assert_array_equal(
        disparity_from_reference(disparity, kind=ReferenceKind.DISPARITY, focal_baseline=30.0),
        [[3.0, np.nan, np.nan, np.nan, np.nan]],
    )
    with pytest.raises(ValueError, match="Expected `kind` depth or disparity"):
        disparity_from_reference(depth, kind=ReferenceKind.AUTO, focal_baseline=30.0)


@settings(max_examples=examples(40), deadline=None)
@given(
    values=hnp.arrays(np.float64, (5, 6), elements=st.floats(0.5, 60.0)),
    holes=hnp.arrays(np.bool_, (5, 6)),
)
def test_fill_nearest_takes_a_nearest_valid_value(values: np.ndarray, holes: np.ndarray) -> None:
    disparity = np.where(holes, np.nan, values)
    filled = fill_nearest(disparity)
    if holes.all():
        assert filled is None
        return
    assert filled is not None
    np.testing.assert_array_equal(filled[~holes], disparity[~holes].astype(np.float32))
    valid_rows, valid_columns = np.nonzero(~holes)
    for row, column in zip(*np.nonzero(holes), strict=True):
        distance = np.hypot(valid_rows - row, valid_columns - column)
        nearest = distance == distance.min()  # any of equally near valid pixels will do
        candidates = disparity[valid_rows[nearest], valid_columns[nearest]].astype(np.float32)
        assert filled[row, column] in candidates


@settings(max_examples=examples(30), deadline=None)
@given(seed=st.integers(0, 10_000))
def test_coverage_split_adds_up(seed: int) -> None:
    rng = np.random.default_rng(seed)
    shape = (12, 16)
    reference = rng.uniform(0.0, 30.0, shape)
    reference[rng.random(shape) < 0.3] = np.nan  # sparse truth
    view = ReferenceView(
        counted=np.isfinite(reference),
        u=np.zeros(shape),
        v=np.zeros(shape),
        disparity=reference,
        depth=30.0 / reference,
        diagonal=20.0,
    )
    estimate = np.nan_to_num(reference) + rng.normal(0.0, 2.0, shape)
    std = rng.uniform(0.5, 3.0, shape)
    sgbm_valid = rng.random(shape) < 0.7
    stats = CalibrationStats()
    for _ in range(2):
        stats.add(estimate, std, view, np.zeros(shape), sgbm_valid=sgbm_valid)
    holes, valid = stats.by_sgbm["holes"], stats.by_sgbm["valid"]
    for key in ("n", "inside_1", "inside_2"):
        assert holes[key] + valid[key] == stats.sums[key]
    assert holes["n"] == 2 * np.count_nonzero(view.counted & ~sgbm_valid)
    summary = stats.summary()
    with np.errstate(invalid="ignore"):
        inside = (np.abs(estimate - reference) / std <= 2.0) & view.counted
    expected = np.count_nonzero(inside & sgbm_valid) / max(
        np.count_nonzero(view.counted & sgbm_valid), 1
    )
    assert summary["coverage_2sigma_sgbm_valid"] == pytest.approx(expected)


def test_coverage_split_separates_holes_from_the_rest() -> None:
    reference = np.full((4, 6), 0.4)  # every pixel lands inside the right image
    view = reference_view(reference, CAMERA_SMALL, stereo_transform(CAMERA_SMALL))
    assert view.counted.all()
    sgbm_valid = np.zeros((4, 6), dtype=bool)
    sgbm_valid[:, 3:] = True
    estimate = np.where(sgbm_valid, 0.9, 10.0)  # good where SGBM is valid, bad in the holes
    stats = CalibrationStats()
    stats.add(estimate, np.ones((4, 6)), view, np.zeros((4, 6)), sgbm_valid=sgbm_valid)
    summary = stats.summary()
    assert summary["coverage_2sigma_sgbm_valid"] == 1.0
    assert summary["coverage_2sigma_sgbm_holes"] == 0.0
    assert not CalibrationStats().has_sgbm_split
    assert "coverage_2sigma_sgbm_holes" not in CalibrationStats().summary()


CAMERA_SMALL = StereoCamera(width=6, height=4, fx=5.0, fy=5.0, cx=2.5, cy=1.5, baseline=0.5)


# ----------------------------------------------------------------------------- logs


def _image(array: np.ndarray, stamp: int, encoding: str) -> Any:
    return rosmsg.image_message(array, stamp, LEFT_FRAME, encoding=encoding)


def _compressed_mm(millimetres: np.ndarray, stamp: int) -> Any:
    encoded = depth_codec.encode_16(millimetres)
    return rosmsg.compressed_image_message(encoded.data, encoded.format, stamp, LEFT_FRAME)


def _references(depth: np.ndarray, stamp: int, index: int) -> list[tuple[str, Any, int]]:
    """The extra reference topics of one frame: (topic, message, log time offset ns)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        disparity = (FOCAL_BASELINE / depth).astype(np.float32)  # 0 for the sky: no truth
    millimetres = np.where(np.isfinite(depth) & (depth < 65.0), np.rint(depth * 1000), 0)
    millimetres = millimetres.astype(np.uint16)
    metres_of_mm = np.where(millimetres > 0, millimetres / 1000.0, np.nan).astype(np.float32)
    doubled = rosmsg.disparity_image_message(
        2 * disparity,  # a camera of twice the focal length: f t = 2 f b
        stamp,
        LEFT_FRAME,
        focal=2 * CAMERA.fx,
        baseline=CAMERA.baseline,
        min_disparity=0.0,
        max_disparity=200.0,
    )
    no_sky = np.where(np.isinf(depth), np.nan, depth).astype(np.float32)
    extra = [
        ("/ref/depth_no_sky", _image(no_sky, stamp, "32FC1"), 0),  # sky NaN: no truth
        ("/ref/depth_mm", _image(millimetres, stamp, "16UC1"), 0),
        ("/ref/compressed_mm", _compressed_mm(millimetres, stamp), 0),  # image_transport's
        ("/ref/depth_m_of_mm", _image(metres_of_mm, stamp, "32FC1"), 0),
        ("/ref/disparity_image", doubled, 0),
        ("/ref/disparity_32f", _image(disparity, stamp, "32FC1"), 0),
        ("/ref/small", _image(depth[:-1], stamp, "32FC1"), 0),
        # logged 1.5 frames late: a frame waits for it
        ("/ref/late", _image(depth, stamp, "32FC1"), 150_000_000),
    ]
    if index % 2 == 0:
        extra.append(("/ref/every_other", _image(depth, stamp, "32FC1"), 0))
        # stamped 60 ms on: nearer the next frame (100 ms on) than its own, so the next's
        extra.append(("/ref/between", _image(depth, stamp + 60 * MS, "32FC1"), 60 * MS))
    # a LiDAR scan projected into the camera, stamped with the scan's time 20 ms on
    extra.append(("/ref/lidar_20ms", _image(depth, stamp + 20 * MS, "32FC1"), 20 * MS))
    # two scans per frame: 30 ms before (another depth: a wrong match shows) and 10 ms after
    extra.append(("/ref/two_scans", _image(2 * depth, stamp - 30 * MS, "32FC1"), 0))
    extra.append(("/ref/two_scans", _image(depth, stamp + 10 * MS, "32FC1"), 10 * MS))
    return extra


def _with_references(source: Path, target: Path) -> None:
    """Copy a densified log, adding reference topics made from its ground-truth depth."""
    late: list[tuple[str, Any, int]] = []
    index = 0
    with open_log(source) as reader, open_writer(target) as writer:
        for raw in reader.messages():
            for topic, message, log_time in [item for item in late if item[2] <= raw.log_time_ns]:
                writer.add_message(topic, message, log_time)
            late = [item for item in late if item[2] > raw.log_time_ns]
            if raw.topic == DISPARITY:
                raw = raw._replace(channel_metadata={"pcainterp.measurements": "dense"})
                # a DisparityImage as densify writes it (min_disparity > 0), under a topic of
                # its own: densify's own outputs are refused as a reference (bug hunt 16A F2)
                writer.add_message(OWN_DISPARITY, reader.decode(raw), raw.log_time_ns)
            writer.add_raw(raw)
            if raw.topic != DEPTH:
                continue
            message = reader.decode(raw)
            depth = rosmsg.image_array(message).astype(np.float32)
            stamp = rosmsg.stamp_ns(message)
            for topic, extra, offset in _references(depth, stamp, index):
                if offset:
                    late.append((topic, extra, raw.log_time_ns + offset))
                else:
                    writer.add_message(topic, extra, raw.log_time_ns)
            index += 1
        for topic, message, log_time in late:
            writer.add_message(topic, message, log_time)


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("reference")
    drive = folder / "drive.mcap"
    write_synthetic_log(generate(CONFIG), drive, lidar=LidarConfig(seed=CONFIG.seed))
    dense = folder / "dense.mcap"
    # the built-in basis; float32 channels, which the by-hand checks read
    jobs.densify(drive, dense, topics=OutputTopics())
    references = folder / "references.mcap"
    _with_references(dense, references)
    return {"dense": dense, "references": references, "folder": folder}


def _evaluate(path: Path, topic: str | None, **options: Any) -> Evaluation:
    options.setdefault("mode", Mode.STEREO)
    result, _ = evaluate_log(
        path, EvaluateOptions(reference_topic=topic, sweep_every=0, linear=False, **options)
    )
    return result


def _frames(path: Path) -> list[dict[str, Any]]:
    """Every message of the log, grouped by header stamp, in stamp order."""
    grouped: dict[int, dict[str, Any]] = {}
    topics = [DISPARITY, STD, INFO, DEPTH, LIDAR_DEPTH, POSE, LEFT_IMAGE, RIGHT_IMAGE]
    with open_log(path) as reader:
        for raw in reader.messages(topics):
            message = reader.decode(raw)
            stamp = rosmsg.stamp_ns(message.image if raw.topic == DISPARITY else message)
            grouped.setdefault(stamp, {})[raw.topic] = message
    return [grouped[stamp] for stamp in sorted(grouped)]


def _camera(parts: dict[str, Any]) -> StereoCamera:
    p = rosmsg.projection_matrix(parts[INFO])
    height, width = CAMERA.image_size
    return StereoCamera(width, height, p[0, 0], p[1, 1], p[0, 2], p[1, 2], parts[DISPARITY].t)


@pytest.mark.parametrize("mode", [Mode.STEREO, Mode.TEMPORAL])
def test_sparse_reference_scores_the_dense_truth_on_its_pixels(
    logs: dict[str, Path], mode: Mode
) -> None:
    result = _evaluate(logs["dense"], LIDAR_DEPTH, mode=mode)
    # by hand: the dense /ground_truth/depth, counted only where the LiDAR topic has a value
    pca, stored, sgbm, filled = MethodStats(), CalibrationStats(), MethodStats(), MethodStats()
    frames = _frames(logs["dense"])
    pairs = (
        [(parts, stereo_transform(_camera(parts))) for parts in frames]
        if mode is Mode.STEREO
        else [
            (a, relative_transform(rosmsg.pose_matrix(a[POSE]), rosmsg.pose_matrix(b[POSE])))
            for a, b in itertools.pairwise(frames)
        ]
    )
    dense_pixels = 0
    for parts, transform in pairs:
        camera = _camera(parts)
        estimate = rosmsg.image_array(parts[DISPARITY].image)
        truth = disparity_from_depth(rosmsg.image_array(parts[DEPTH]), camera.focal_baseline)
        view = reference_view(truth, camera, transform)
        dense_pixels += int(view.counted.sum())
        lidar = np.isfinite(rosmsg.image_array(parts[LIDAR_DEPTH]))
        on_lidar = dataclasses.replace(view, counted=view.counted & lidar)
        delta = pca.add(estimate, on_lidar, camera, transform)
        split = compute_disparity(
            rosmsg.image_array(parts[LEFT_IMAGE]),
            rosmsg.image_array(parts[RIGHT_IMAGE]),
            SgbmConfig(),
        )
        stored.add(
            estimate, rosmsg.image_array(parts[STD]), on_lidar, delta, sgbm_valid=np.isfinite(split)
        )
        on_sgbm = dataclasses.replace(on_lidar, counted=on_lidar.counted & np.isfinite(split))
        sgbm.add(split, on_sgbm, camera, transform)
        nearest_filled = fill_nearest(split)
        assert nearest_filled is not None
        filled.add(nearest_filled, on_lidar, camera, transform)
    assert result.frames == len(pairs)
    assert result.methods["pca_map"].pixels == pca.pixels
    assert 0.02 * dense_pixels < pca.pixels < 0.06 * dense_pixels
    for name in ("delta_2d_mean", "delta_3d_mean", "rmse_m", "imae_per_km"):
        assert result.methods["pca_map"].summary()[name] == pytest.approx(pca.summary()[name])
        assert result.stereo[SGBM].summary()[name] == pytest.approx(sgbm.summary()[name])
        assert result.stereo[SGBM_NN].summary()[name] == pytest.approx(filled.summary()[name])
    computed = result.calibration["stored"].summary()
    for name, value in stored.summary().items():
        if name != "ms_per_frame":
            assert computed[name] == pytest.approx(value), name
    assert result.reference == LIDAR_DEPTH
    assert result.reference_kind == "depth"
    assert result.reference_label.startswith(f"{LIDAR_DEPTH} (sparse, ")
    assert 0.03 < result.reference_fraction < 0.05
    assert "oracle" not in result.methods


def test_stereo_baselines_count_their_pixels(logs: dict[str, Path]) -> None:
    result = _evaluate(logs["dense"], None)
    assert result.reference == "ground truth"
    assert result.reference_label == "ground truth (dense, 100.0 % of pixels)"
    assert set(result.stereo) == {SGBM, SGBM_NN, PCA_ON_SGBM}
    pca = result.methods["pca_map"]
    assert result.stereo[SGBM_NN].pixels == pca.pixels  # holes filled: every counted pixel
    assert result.stereo[PCA_ON_SGBM].pixels == result.stereo[SGBM].pixels < pca.pixels
    assert result.sgbm_fill == pytest.approx(result.stereo[SGBM].pixels / pca.pixels)
    assert 0.4 < result.sgbm_fill < 0.95  # the left band of 128 px is a hole at this size
    assert result.stereo[SGBM].seconds > 0
    # SGBM is far better where it has a value than PCA-MAP from a few hundred points
    means = {name: stats.summary()["delta_2d_mean"] for name, stats in result.stereo.items()}
    assert means[SGBM] < means[PCA_ON_SGBM]
    stored = result.calibration["stored"]
    assert stored.by_sgbm["holes"]["n"] + stored.by_sgbm["valid"]["n"] == stored.sums["n"]
    assert stored.by_sgbm["valid"]["n"] == result.stereo[SGBM].pixels
    table = summary_table(result)
    assert "pca_map@sgbm" in table
    assert "in SGBM holes" in table
    # with SGBM as the reference they would be trivially perfect
    sgbm_reference = _evaluate(logs["dense"], None, sgbm_reference=True)
    assert sgbm_reference.stereo == {}
    assert "trivially perfect" in sgbm_reference.stereo_note
    assert "trivially perfect" in summary_table(sgbm_reference)
    assert not sgbm_reference.calibration["stored"].has_sgbm_split
    assert sgbm_reference.reference_label.startswith("SGBM (dense, ")


def test_reference_encodings_give_the_same_scores(logs: dict[str, Path]) -> None:
    path = logs["references"]
    named = _evaluate(path, DEPTH)  # 32FC1 m; its +inf sky is disparity 0 and counts
    default = _evaluate(path, None)  # the same topic unnamed: read by the same rule
    assert named.methods["pca_map"].pixels == default.methods["pca_map"].pixels
    assert named.methods["pca_map"].delta_2d_sum == default.methods["pca_map"].delta_2d_sum
    # a disparity or millimetre reference cannot say "too far": compare them without the sky
    base = _evaluate(path, "/ref/depth_no_sky")
    assert base.methods["pca_map"].pixels < named.methods["pca_map"].pixels
    assert base.measurements == "dense"
    assert "measurements of the densified log: dense" in summary_table(base)

    def means(result: Evaluation) -> dict[str, float]:
        return result.methods["pca_map"].summary() | {
            "stored": result.calibration["stored"].summary()["coverage_2sigma"]
        }

    for topic, kind in (
        ("/ref/disparity_image", ReferenceKind.AUTO),  # rescaled by the log's f*b / its f*t
        ("/ref/disparity_32f", ReferenceKind.DISPARITY),
        ("/ref/late", ReferenceKind.DEPTH),  # logged after its frame: the frame waits
    ):
        result = _evaluate(path, topic, reference_kind=kind)
        expected = named if topic == "/ref/late" else base
        assert result.skipped == 0
        assert result.methods["pca_map"].pixels == expected.methods["pca_map"].pixels, topic
        assert means(result) == pytest.approx(means(expected), rel=1e-5), topic
    assert _evaluate(path, "/ref/disparity_image").reference_kind == "disparity"
    millimetres = _evaluate(path, "/ref/depth_mm")
    metres = _evaluate(path, "/ref/depth_m_of_mm")
    compressed = _evaluate(path, "/ref/compressed_mm")  # 16UC1; compressedDepth png
    assert means(compressed) == means(millimetres)
    assert millimetres.methods["pca_map"].pixels == metres.methods["pca_map"].pixels
    assert means(millimetres) == pytest.approx(means(metres), rel=1e-6)
    assert means(millimetres)["delta_2d_mean"] == pytest.approx(
        means(base)["delta_2d_mean"], rel=0.05
    )


@pytest.mark.parametrize(("mode", "frames"), [(Mode.STEREO, 2), (Mode.TEMPORAL, 2)])
def test_frames_without_a_reference_message_are_skipped(
    logs: dict[str, Path], mode: Mode, frames: int
) -> None:
    result = _evaluate(logs["references"], "/ref/every_other", mode=mode)
    assert result.skipped == 2
    assert result.frames == frames
    assert (
        "2 frames skipped: no /ref/every_other message within the stamp tolerance"
        in summary_table(result)
    )


def test_a_reference_stamped_apart_from_the_frames_is_matched_by_the_nearest_stamp(
    logs: dict[str, Path],
) -> None:
    """A user's projected LiDAR stamped 20 ms after the camera is scored (bug hunt 11A F1)."""
    path = logs["references"]
    exact = _evaluate(path, DEPTH)
    for topic, tolerance in (
        ("/ref/lidar_20ms", None),  # under half the frame interval by default
        ("/ref/lidar_20ms", 25 * MS),
        ("/ref/two_scans", None),  # the nearest of two: 10 ms after, not 30 ms before
    ):
        result = _evaluate(path, topic, stamp_tolerance_ns=tolerance)
        assert result.skipped == 0, topic
        assert result.methods["pca_map"].pixels == exact.methods["pca_map"].pixels, topic
        assert result.methods["pca_map"].summary() == pytest.approx(
            exact.methods["pca_map"].summary(), rel=1e-6
        ), topic
    note = " ".join(_evaluate(path, "/ref/lidar_20ms").notes)
    assert "/ref/lidar_20ms matched to frames by the nearest header stamp within 50 ms" in note
    assert "under half the frame interval of 100 ms" in note
    assert "4 of 4 messages stamped 20.00-20.00 ms from their frame's" in note
    assert not any("matched to frames" in n for n in exact.notes)  # no note at offset 0


@pytest.mark.parametrize("tolerance", [None, 100 * MS])
def test_each_reference_message_goes_to_the_frame_stamped_nearest_it(
    logs: dict[str, Path], tolerance: int | None
) -> None:
    """Stamped 60 ms after frames 0 and 2: frames 1 and 3 (40 ms away) take them, once each."""
    result = _evaluate(logs["references"], "/ref/between", stamp_tolerance_ns=tolerance)
    assert (result.frames, result.skipped) == (2, 2)


def test_a_reference_beyond_the_tolerance_names_its_offset_and_the_option(
    logs: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    path, out = logs["references"], logs["folder"] / "no_report"
    args = ("--reference-topic", "/ref/lidar_20ms", "--stamp-tolerance-ms", "10")
    err = _error(capsys, path, "-o", out, *args)
    assert "4 without a /ref/lidar_20ms message within 10 ms of their stamp" in err
    assert "4 had one 20.00-20.00 ms away: pass --stamp-tolerance-ms 20 to take it" in err
    assert not out.exists()


def _error(capsys: pytest.CaptureFixture[str], *args: str | Path) -> str:
    assert cli.main(["evaluate", *map(str, args), "--no-basis", "--sweep-every", "0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "Traceback" not in err
    return err


def test_reference_errors_are_one_line(
    logs: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    path, out = logs["references"], logs["folder"] / "no_report"
    err = _error(capsys, path, "-o", out, "--reference-topic", "/lidar/points")
    assert "reference topic /lidar/points not found" in err
    assert f"image topics present: {DEPTH}, {LIDAR_DEPTH}, " in err
    assert "/ref/disparity_image" in err
    err = _error(capsys, path, "-o", out, "--reference-topic", "/ref/small")
    assert "reference topic /ref/small has 310x93 images but the estimate is 310x94" in err
    err = _error(capsys, path, "-o", out, "--reference-topic", POSE)
    assert f"{POSE} in {path} is a geometry_msgs/msg/PoseStamped, not a depth" in err
    err = _error(
        capsys,
        path,
        "-o",
        out,
        "--reference-topic",
        "/ref/disparity_image",
        "--reference-kind",
        "depth",
    )
    assert "holds disparity; drop --reference-kind depth" in err
    err = _error(
        capsys,
        path,
        "-o",
        out,
        "--reference-topic",
        "/ref/depth_mm",
        "--reference-kind",
        "disparity",
    )
    assert "has 16UC1 images; a disparity reference must be 32FC1" in err
    err = _error(capsys, path, "-o", out, "--reference-kind", "depth")
    assert "--reference-kind needs --reference-topic" in err
    assert not out.exists()


def test_a_damaged_compressed_depth_reference_is_a_log_read_error() -> None:
    """An RVL header of 100000 x 100000 px: evaluate's one-line error, not a MemoryError."""
    payload = struct.pack("<iff", 0, 100.0, 0.0) + struct.pack("<II", 100_000, 100_000)
    message = rosmsg.compressed_image_message(
        payload + bytes(64), "32FC1; compressedDepth rvl", 5, LEFT_FRAME
    )
    reference = ReferenceTopic("/ref/rvl", rosmsg.COMPRESSED_IMAGE, ReferenceKind.DEPTH)
    with pytest.raises(
        LogReadError, match=r"^reference topic /ref/rvl: RVL header says 100000x100000 px"
    ):
        reference_disparity(
            message, reference, focal_baseline=FOCAL_BASELINE, image_size=CAMERA.image_size
        )


def test_a_disparity_image_is_truth_only_where_it_says_its_values_are_valid() -> None:
    """stereo_msgs' DisparityImage: "any disparity less than min_disparity is invalid" (a
    stereo driver writes OpenCV's invalid match as min_disparity - 1, here 3 px), a value
    above max_disparity was not searched, and a pixel outside valid_window is invalid."""
    height, width = CAMERA.image_size
    values = np.full((height, width), 10.0, dtype=np.float32)
    values[:, :8] = 3.0  # the driver's invalid code in SGBM's empty left band
    values[0, 20] = 3.99  # below min_disparity: invalid
    values[1, 20] = 4.0  # at min_disparity: valid
    values[2, 20] = 60.0  # above max_disparity: not searched
    message = rosmsg.disparity_image_message(
        values,
        5,
        LEFT_FRAME,
        focal=CAMERA.fx,
        baseline=CAMERA.baseline,
        min_disparity=4.0,
        max_disparity=50.0,
    )
    message.valid_window.x_offset, message.valid_window.width = 8, width - 8
    message.valid_window.y_offset, message.valid_window.height = 0, height - 1  # not the last row
    reference = ReferenceTopic("/ref/disparity", rosmsg.DISPARITY_IMAGE, ReferenceKind.DISPARITY)
    truth = reference_disparity(
        message, reference, focal_baseline=FOCAL_BASELINE, image_size=CAMERA.image_size
    )
    expected = np.full((height, width), 10.0)
    expected[:, :8] = np.nan
    expected[-1, :] = np.nan
    expected[0, 20], expected[1, 20], expected[2, 20] = np.nan, 4.0, np.nan
    np.testing.assert_allclose(truth, expected)  # f t = f b: no rescaling; NaN where NaN
    # an unset window (all 0: the whole image) and max_disparity 0 (no bound) keep the rest
    message.valid_window.x_offset = message.valid_window.y_offset = 0
    message.valid_window.width = message.valid_window.height = 0
    message.max_disparity = 0.0
    truth = reference_disparity(
        message, reference, focal_baseline=FOCAL_BASELINE, image_size=CAMERA.image_size
    )
    assert np.isnan(truth[:, :8]).all()  # the invalid code is below min_disparity anyway
    assert truth[2, 20] == 60.0
    assert np.isnan(truth[0, 20])
    assert np.isfinite(truth[:, 8:]).sum() == height * (width - 8) - 1


def test_disparity_image_bounds_apply_to_the_matchers_disparity() -> None:
    """stereo_image_proc shifts its values by -(cx_l - cx_r), its bounds not: its invalid
    code is min_disparity - 1 - (cx_l - cx_r), 1 px with min 0 and cx_r - cx_l = 2."""
    values = np.array([[1.0, 1.9, 2.0, 10.0, 129.0, 129.5]])
    message = rosmsg.disparity_image_message(
        values.astype(np.float32),
        5,
        LEFT_FRAME,
        focal=5.0,
        baseline=1.0,
        min_disparity=0.0,
        max_disparity=127.0,
    )
    message.valid_window.width = message.valid_window.height = 0
    assert disparity_image_valid(message, values).tolist() == [[True] * 4 + [False] * 2]
    # cx_l - cx_r = -2: the matcher's disparity is value - 2, searched in [0, 127]
    assert disparity_image_valid(message, values, -2.0).tolist() == [
        [False, False, True, True, True, False]
    ]
    # cx_l - cx_r = +2: value + 2
    assert disparity_image_valid(message, values, 2.0).tolist() == [[True] * 4 + [False] * 2]


def _with_disparity_image(
    source: Path, target: Path, band: float, right_cx: float, min_disparity: float = 0.0
) -> None:
    """Copy a densified log: the right camera info's P cx moved by ``right_cx`` px, and
    /ref/dimage, true disparity but ``band`` in the 8 left columns."""
    with open_log(source) as reader, open_writer(target) as writer:
        for raw in reader.messages():
            if raw.topic == RIGHT_INFO and right_cx:
                message = reader.decode(raw)
                p = message.p.copy()
                p[2] += right_cx
                message.p = p
                writer.add_message(raw.topic, message, raw.log_time_ns)
                continue
            writer.add_raw(raw)
            if raw.topic != DEPTH:
                continue
            message = reader.decode(raw)
            depth = rosmsg.image_array(message).astype(np.float64)
            with np.errstate(divide="ignore"):
                values = np.where(np.isinf(depth), 0.0, FOCAL_BASELINE / depth)
            values[:, :8] = band
            reference = rosmsg.disparity_image_message(
                values.astype(np.float32),
                rosmsg.stamp_ns(message),
                LEFT_FRAME,
                focal=CAMERA.fx,
                baseline=CAMERA.baseline,
                min_disparity=min_disparity,
                max_disparity=min_disparity + 127.0,
            )
            writer.add_message("/ref/dimage", reference, raw.log_time_ns)


def test_a_disparity_image_of_a_pair_whose_cx_differ_drops_its_shifted_code(
    logs: dict[str, Path],
) -> None:
    # review 15d R1: the code 1 px (min 0, cx_r - cx_l = 2) was scored as truth
    folder = logs["folder"]
    runs = {}
    for name, band, right_cx in (("code", 1.0, 2.0), ("nan", np.nan, 2.0), ("equal", 1.0, 0.0)):
        log = folder / f"dimage_{name}.mcap"
        _with_disparity_image(logs["dense"], log, band, right_cx)
        runs[name] = _evaluate(log, "/ref/dimage")
    code, nan, equal = (runs[name].methods["pca_map"] for name in ("code", "nan", "equal"))
    assert equal.pixels > nan.pixels  # cx equal: the band's 1 px is a disparity, scored
    assert code.pixels <= nan.pixels  # the band is the code, not truth (nor are v < 2 px)
    assert code.pixels > 0.9 * nan.pixels
    assert any("value + (cx_l - cx_r)" in note for note in runs["code"].notes)
    assert not any("cx_l - cx_r" in note for note in runs["equal"].notes)


def _truth_out_of_reach(source: Path, target: Path) -> None:
    """Copy a densified log with /ref/reach: the depth, but frame 1's truth only in columns
    40-47, where its estimate is NaN, and frame 2's only in the 3 left columns, at 1 m (its
    disparity carries it out of the right view)."""
    index = {DISPARITY: 0, DEPTH: 0}
    with open_log(source) as reader, open_writer(target) as writer:
        for raw in reader.messages():
            if raw.topic not in index:
                writer.add_raw(raw)
                continue
            message = reader.decode(raw)
            frame = index[raw.topic]
            index[raw.topic] += 1
            if raw.topic == DISPARITY:
                if frame == 1:
                    values = rosmsg.image_array(message.image).astype(np.float32)
                    values[:, 40:48] = np.nan
                    message.image.data = np.frombuffer(values.tobytes(), np.uint8)
                writer.add_message(raw.topic, message, raw.log_time_ns)
                continue
            writer.add_raw(raw)
            depth = rosmsg.image_array(message).astype(np.float32)
            if frame == 1:
                depth[:, :40], depth[:, 48:] = np.nan, np.nan
            elif frame == 2:
                depth[:, :3], depth[:, 3:] = 1.0, np.nan
            image = _image(depth, rosmsg.stamp_ns(message), "32FC1")
            writer.add_message("/ref/reach", image, raw.log_time_ns)


def test_frames_whose_truth_cannot_be_scored_are_left_out_and_say_why(
    logs: dict[str, Path],
) -> None:
    # review 15d R6: truth only where the estimate is NaN was counted with 0 px, unnamed;
    # R2: the note said "NaN, 0 or < 0" for every cause
    log = logs["folder"] / "reach.mcap"
    _truth_out_of_reach(logs["dense"], log)
    result = _evaluate(log, "/ref/reach")
    assert result.frames == 2
    assert result.no_truth == [1, 2]
    note = result.no_truth_note
    assert "frame 1: its truth lies only where the estimate is NaN" in note
    assert "frame 2: its 282 px of truth all leave the view of the right camera" in note
    assert "NaN, 0 or < 0" not in note
    assert "frames 1, 2" not in summary_table(result)  # each named with its own cause


def test_a_disparity_image_out_of_its_own_bounds_says_so(logs: dict[str, Path]) -> None:
    # review 15d R2: "every pixel is NaN, 0 or < 0" of values of 10-60 px
    log = logs["folder"] / "dimage_below.mcap"
    _with_disparity_image(logs["dense"], log, 1.0, 0.0, min_disparity=500.0)
    with pytest.raises(LogReadError) as raised:
        _evaluate(log, "/ref/dimage")
    message = str(raised.value)
    assert "below its min_disparity 500 px" in message
    assert "likewise frames 1, 2, 3" in message
    assert "NaN, 0 or < 0" not in message
    assert "\n" not in message


def test_densifys_own_disparity_as_reference_cannot_say_too_far(logs: dict[str, Path]) -> None:
    # review 15d R3: its values below min_disparity are no truth, so "too far" printed
    # "reference 0.0 % (0.0 % found)", 0 of 0
    result = _evaluate(logs["references"], OWN_DISPARITY)
    assert result.ranges.counted > 0
    assert result.ranges.blind
    (line,) = [line for line in summary_table(result).splitlines() if line.startswith("too far")]
    assert 'the reference cannot say "too far"' in line
    assert "found" not in line
    truth = _evaluate(logs["references"], "/ref/disparity_32f")  # 0 < d < min can be far
    assert not truth.ranges.blind


def test_a_dense_log_does_not_grade_the_papers_sparse_target(logs: dict[str, Path]) -> None:
    # bug hunt 15D F3: a dense log's /pcainterp/features are the prior's points, not the
    # SGBM pixels its map fused: "PCA-MAP / nearest neighbour = 0.28 (target <= 0.65): met"
    # compared the map with an interpolation of other points
    def target_line(result: Evaluation) -> str:
        markdown = results_markdown(result, [])
        (line,) = [n for n in markdown.splitlines() if "PCA-MAP / nearest neighbour mean" in n]
        return line

    dense = _evaluate(logs["references"], "/ref/depth_no_sky")
    assert dense.measurements == "dense"
    line = target_line(dense)
    assert "not graded: in a dense log nearest neighbour interpolates the points that " in line
    assert not line.endswith(": met.")
    assert "missed" not in line
    sparse = _evaluate(logs["dense"], None)
    assert sparse.measurements != "dense"
    assert "not graded" not in target_line(sparse)
    assert ": met." in target_line(sparse) or ": missed by" in target_line(sparse)


def test_cli_report_names_a_sparse_reference(
    logs: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    out = logs["folder"] / "lidar_report"
    args = ["evaluate", str(logs["dense"]), "-o", str(out), "--reference-topic", LIDAR_DEPTH]
    assert cli.main([*args, "--sweep-every", "2"]) == 0  # temporal, the built-in basis
    printed = capsys.readouterr().out
    assert f"reference: {LIDAR_DEPTH} (sparse, " in printed
    markdown = (out / "results.md").read_text()
    assert f"reference: {LIDAR_DEPTH} (sparse, " in markdown
    assert "- dense mode:" not in markdown  # its targets only for --measurements dense
    report = json.loads((out / "results.json").read_text())
    assert report["reference"] == LIDAR_DEPTH
    assert report["mode"] == "temporal"
    assert 0.03 < report["reference_fraction"] < 0.05
    assert set(report["stereo_baselines"]) == {SGBM, SGBM_NN, PCA_ON_SGBM}
    assert "oracle" not in report["methods"]  # a sparse reference is no map to fit the basis to
    # rows only for the point counts the sweep's frames had corners for
    reached = [p for p in (50, 100, 200, 400, 800) if p <= max(report["sweep_corners"])]
    assert set(report["sweep"]) == {str(p) for p in reached}
    # the coverage target grades the std the log carries, not evaluate's re-densification
    stored = report["calibration"]["stored"]["mean"]["coverage_2sigma"]
    assert f"- the log's stored uncertainty: +-2 sigma coverage = {100 * stored:.1f} %" in markdown
    sigma = "--sigma 2 px of the basis's camera, 0.5 px in the log's"  # quarter-scale log
    assert f"re-densification ({sigma}, no calibration) +-2 sigma" in markdown
    assert "for the paper's model, not graded." in markdown
    split = report["calibration"]["exact"]["mean"]
    assert split["pixels_sgbm_holes"] + split["pixels_sgbm_valid"] == split["pixels"]
    for name in ("errors.png", "uncertainty.png", "sweep.png", "examples.png"):
        assert (out / name).stat().st_size > 1000


def test_sparse_truth_alone_is_the_default_reference(logs: dict[str, Path]) -> None:
    # a log with /ground_truth/lidar_depth but no dense truth, as import-kitti writes KITTI's
    sparse_only = logs["folder"] / "sparse_only.mcap"
    with open_log(logs["dense"]) as reader, open_writer(sparse_only) as writer:
        for raw in reader.messages():
            if raw.topic != DEPTH:
                writer.add_raw(raw)
    default = _evaluate(sparse_only, None)
    assert default.reference == LIDAR_DEPTH
    named = _evaluate(logs["dense"], LIDAR_DEPTH)
    assert default.methods["pca_map"].summary() == named.methods["pca_map"].summary()
    assert _evaluate(logs["dense"], None).reference == "ground truth"  # the dense one first
    assert _evaluate(sparse_only, None, sgbm_reference=True).reference == "SGBM"


def test_a_default_lidar_topic_that_is_no_image_falls_back_to_sgbm(
    logs: dict[str, Path],
) -> None:
    # before: a /ground_truth/lidar_depth of another type (a point cloud under that natural
    # name) made evaluate fail as if the user had named it, where it used to compare to SGBM
    cloud = logs["folder"] / "cloud_lidar.mcap"
    with open_log(logs["dense"]) as reader, open_writer(cloud) as writer:
        for raw in reader.messages():
            if raw.topic == LIDAR_DEPTH:
                points = {axis: np.zeros(3, np.float32) for axis in "xyz"}
                stamp = rosmsg.stamp_ns(reader.decode(raw))
                writer.add_message(
                    raw.topic, rosmsg.pointcloud2_message(points, stamp, "lidar"), raw.log_time_ns
                )
            elif raw.topic != DEPTH:
                writer.add_raw(raw)
    assert _evaluate(cloud, None).reference == "SGBM"
    with pytest.raises(PcaInterpError, match="is a sensor_msgs/msg/PointCloud2"):
        _evaluate(cloud, LIDAR_DEPTH)  # named by the user: still refused
