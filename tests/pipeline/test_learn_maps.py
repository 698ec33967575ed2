"""``learn``'s maps and cameras: one f*b, fit logs of the training camera, pairing errors."""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pcainterp_stream.errors import LogReadError, PcaInterpError
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import LogFormat, open_writer
from pcainterp_stream.pipeline import jobs, learn_maps


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("learn_maps")
    jobs.synth(folder / "drive.mcap", frames=6, seed=11, scale=0.25, fmt="mcap")
    return folder


def _rewritten(source: Path, target: Path, *, baseline: float = 1.0, right_ms: int = 0) -> Path:
    """Copy a log, the right camera's baseline times ``baseline``, its images stamped later."""
    with open_log(source) as reader, open_writer(target, LogFormat.MCAP) as writer:
        for raw in reader.messages():
            message = reader.decode(raw)
            if raw.topic == "/stereo/right/camera_info":
                p = np.array(message.p, dtype=np.float64)
                p[3] *= baseline  # P[0, 3] = -fx * baseline
                message = dataclasses.replace(message, p=p)
            elif raw.topic == "/stereo/right/image_rect" and right_ms:
                stamp = message.header.stamp
                shifted = stamp.sec * 10**9 + stamp.nanosec + right_ms * 1_000_000
                time = dataclasses.replace(stamp, sec=shifted // 10**9, nanosec=shifted % 10**9)
                message = dataclasses.replace(
                    message, header=dataclasses.replace(message.header, stamp=time)
                )
            writer.add_message(raw.topic, message, raw.log_time_ns)
    return target


def test_scaled_to_keeps_invalid_pixels_invalid() -> None:
    from pcainterp_stream.pipeline.learn_maps import scaled_to

    disparity = np.array([[2.0, 0.0, -1.0, np.nan]], dtype=np.float32)
    scaled = scaled_to(disparity, 20.0, 10.0)
    np.testing.assert_array_equal(scaled[0, :3], [1.0, 0.0, -0.5])
    assert np.isnan(scaled[0, 3])
    assert scaled.dtype == np.float32
    assert scaled_to(disparity, 10.0, 10.0) is disparity


def test_learn_puts_the_maps_of_two_f_b_in_the_first_logs(
    folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the same depths seen by a rig of twice the baseline: twice the disparities; scaled to
    # the first log's f*b they are the same maps (before: learned as they were, the mean
    # 1.5x the first log's and the basis stamped with its f*b)
    drive = folder / "drive.mcap"
    wide = _rewritten(drive, folder / "wide.mcap", baseline=2.0)
    options = jobs.LearnOptions(n_components=3, depth_topic="/ground_truth/depth", fit_prior=False)
    alone = jobs.learn([drive], folder / "alone.npz", options, PairingConfig())
    capsys.readouterr()
    both = jobs.learn([drive, wide], folder / "both.npz", options, PairingConfig())
    assert both.focal_baseline == pytest.approx(alone.focal_baseline)
    np.testing.assert_allclose(both.mean, alone.mean, rtol=1e-4, atol=1e-4)
    said = capsys.readouterr().out
    assert "wide.mcap's camera has f*b " in said
    assert "its maps are scaled by 0.5 to drive.mcap's" in said
    # the other order: the basis is the wide camera's, the drive's maps doubled
    wide_first = jobs.learn([wide, drive], folder / "wide_first.npz", options, PairingConfig())
    assert wide_first.focal_baseline == pytest.approx(2.0 * alone.focal_baseline)
    np.testing.assert_allclose(wide_first.mean, 2.0 * alone.mean, rtol=1e-4, atol=1e-3)


def test_learn_on_a_cluster_scales_the_maps_too(folder: Path) -> None:
    from pcainterp_stream.pipeline.distributed import summarize_chunk
    from pcainterp_stream.pipeline.learn import GridTarget

    wide = _rewritten(folder / "drive.mcap", folder / "wide_c.mcap", baseline=2.0)
    options = jobs.LearnOptions(depth_topic="/ground_truth/depth")
    own = summarize_chunk(wide, 0, 2, options, PairingConfig(), 4)
    assert own is not None
    target = GridTarget(own.grid_size, focal_baseline=own.focal_baseline / 2.0)
    half = summarize_chunk(wide, 0, 2, options, PairingConfig(), 4, target)
    assert half is not None
    assert half.focal_baseline == pytest.approx(own.focal_baseline / 2.0)
    np.testing.assert_allclose(half.mean, own.mean / 2.0, rtol=1e-4, atol=1e-4)


def test_learn_refuses_fit_logs_of_another_camera(folder: Path) -> None:
    small = folder / "small.mcap"
    jobs.synth(small, frames=2, seed=13, scale=0.2, fmt="mcap")
    options = jobs.LearnOptions(n_components=3, fit_logs=(small,))
    with pytest.raises(
        PcaInterpError,
        match=r"--fit-logs small.mcap has 248x75 images but the training log drive.mcap has "
        r"310x94 images; fit on logs of the training camera",
    ):
        jobs.learn([folder / "drive.mcap"], folder / "fit.npz", options, PairingConfig())
    assert not (folder / "fit.npz").exists()


def test_learn_says_when_it_fits_on_the_fit_logs(
    folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    other = folder / "other.mcap"
    jobs.synth(other, frames=3, seed=14, scale=0.25, fmt="mcap")
    options = jobs.LearnOptions(n_components=3, fit_logs=(other,))
    basis = jobs.learn([folder / "drive.mcap"], folder / "fitted.npz", options, PairingConfig())
    assert basis.meta["prior"]["fit_logs"] == [str(other)]
    assert "fitting the prior by the evidence on the --fit-logs logs' frames" in (
        capsys.readouterr().out
    )


def test_learn_names_the_stamp_gap_and_the_tolerance_that_pairs(folder: Path) -> None:
    late = _rewritten(folder / "drive.mcap", folder / "late.mcap", right_ms=20)
    with pytest.raises(
        LogReadError,
        match=r"no stereo pair found in .*late.mcap \(.*\); all 12 images dropped unpaired had "
        r"an unpaired other-side image 20.00-20.00 ms away, beyond the 1 ms tolerance; pass "
        r"--stamp-tolerance-ms 20 to pair them",
    ):
        jobs.learn([late], folder / "late.npz", jobs.LearnOptions(), PairingConfig())
    tolerant = PairingConfig(tolerance_ns=25_000_000)
    options = jobs.LearnOptions(n_components=3, fit_prior=False)
    assert jobs.learn([late], folder / "late.npz", options, tolerant).n_train == 6


def _right_is_left(source: Path, target: Path) -> Path:
    """Copy a log whose right images are its left ones again, a small patch 1 px off.

    (As a codec's noise leaves a few 1 px matches: the exact copy matches at 0 px
    everywhere, a map refused as blank.)
    """
    with open_log(source) as reader:
        lefts = {
            rosmsg.stamp_ns(message): message
            for raw in reader.messages(["/stereo/left/image_rect"])
            for message in [reader.decode(raw)]
        }
    with open_log(source) as reader, open_writer(target, LogFormat.MCAP) as writer:
        for raw in reader.messages():
            message = reader.decode(raw)
            if raw.topic == "/stereo/right/image_rect":
                left = lefts[rosmsg.stamp_ns(message)]
                image = rosmsg.image_array(left).copy()
                image[60:68, 150:160] = image[60:68, 151:161]
                message = dataclasses.replace(
                    left, header=message.header, data=image.reshape(-1).astype(np.uint8)
                )
            writer.add_message(raw.topic, message, raw.log_time_ns)
    return target


def test_learn_refuses_a_pair_whose_right_image_is_the_left_one(folder: Path) -> None:
    # before: a basis of ~0 px disparity, written without a word (bug hunt 6A F12)
    same = _right_is_left(folder / "drive.mcap", folder / "same.mcap")
    options = jobs.LearnOptions(n_components=3, fit_prior=False)
    # the pairer's row check stops it first; learn's own check is the second line
    with pytest.raises(PcaInterpError, match=r"shows one view twice"):
        jobs.learn([same], folder / "same.npz", options, PairingConfig())
    with pytest.raises(
        PcaInterpError,
        match=r"same.mcap: all of the 6 SGBM maps have almost no disparity .*; the right "
        r"topic may show the left camera again",
    ):
        jobs.learn([same], folder / "same.npz", options, PairingConfig(check_rows=False))
    assert not (folder / "same.npz").exists()


def test_depth_disparity_reads_rep_118() -> None:
    from pcainterp_stream.pipeline.learn_maps import depth_disparity

    # NaN, 0 and negative depth: no value (a hole, NaN); +inf: too far (disparity 0)
    depth = np.array([[2.0, np.inf, np.nan, 0.0, -1.0]], dtype=np.float32)
    disparity = depth_disparity(depth, 10.0)
    assert disparity.dtype == np.float32
    np.testing.assert_array_equal(disparity[0, :2], [5.0, 0.0])
    assert np.isnan(disparity[0, 2:]).all()


@pytest.fixture(scope="module")
def lidar(folder: Path) -> Path:
    lidar = folder / "lidar.mcap"
    jobs.synth(lidar, frames=4, seed=15, scale=0.25, fmt="mcap", lidar=True)
    return lidar


def test_learn_fills_a_sparse_depth_topics_holes(
    lidar: Path, folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # before: a projected LiDAR's holes (NaN) were learned as infinitely far, a basis of mean
    # disparity ~0.7 px where the scene's is ~15 (bug hunt 6A F14); then refused (< 50 %)
    sparse = jobs.LearnOptions(
        n_components=3, depth_topic="/ground_truth/lidar_depth", fit_prior=False
    )
    basis = jobs.learn([lidar], folder / "lidar.npz", sparse, PairingConfig())
    assert re.search(
        r"note: /ground_truth/lidar_depth in lidar.mcap has a depth at \d+% of the pixels of "
        r"its images \(median of the first \d+\); learn fills the others from the nearest pixel",
        capsys.readouterr().out,
    )
    dense = dataclasses.replace(sparse, depth_topic="/ground_truth/depth")
    truth = jobs.learn([lidar], folder / "truth.npz", dense, PairingConfig())
    assert capsys.readouterr().out.count("note: /ground_truth/depth") == 0
    assert float(basis.mean.mean()) > 0.8 * float(truth.mean.mean())
    assert float(np.mean(basis.mean < 1.0)) < 0.1


def test_learn_names_an_earlier_synthetic_logs_nan_sky(
    folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # before: the sky of a log of an earlier synth (NaN, not +inf) was learned as a hole
    # filled from the nearest pixel, silently (review F4); evaluate notes it as no truth
    source, nan_sky = folder / "drive.mcap", folder / "nan_sky.mcap"
    with open_log(source) as reader, open_writer(nan_sky, LogFormat.MCAP) as writer:
        for raw in reader.messages():
            message = reader.decode(raw)
            if raw.topic == "/ground_truth/depth":
                depth = np.frombuffer(bytes(message.data), np.float32)
                sky = np.where(np.isposinf(depth), np.float32(np.nan), depth)
                message = dataclasses.replace(message, data=np.frombuffer(sky.tobytes(), np.uint8))
            writer.add_message(raw.topic, message, raw.log_time_ns)
    options = jobs.LearnOptions(n_components=3, depth_topic="/ground_truth/depth", fit_prior=False)
    jobs.learn([nan_sky], folder / "nan_sky.npz", options, PairingConfig())
    assert re.search(
        r"note: \d+\.\d% of /ground_truth/depth's pixels in nan_sky.mcap are NaN and none \+inf "
        r"\(first \d+ images\): an earlier `pcainterp synth` wrote the sky so; learn fills them",
        capsys.readouterr().out,
    )
    jobs.learn([source], folder / "inf_sky.npz", options, PairingConfig())  # +inf: no note
    assert "NaN" not in capsys.readouterr().out


def test_a_dense_depth_topic_with_a_blank_first_image_is_not_called_sparse(
    lidar: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # a depth camera's start-up image without depth said nothing of the topic (review 54 F1)
    real = learn_maps.depth_maps

    def blank_first(*args: Any, **kwargs: Any) -> Iterator[np.ndarray]:
        maps = real(*args, **kwargs)
        first = next(maps)
        yield np.full_like(first, np.nan)
        yield from maps

    monkeypatch.setattr(learn_maps, "depth_maps", blank_first)
    dense = jobs.LearnOptions(n_components=3, depth_topic="/ground_truth/depth")
    assert learn_maps.log_camera(lidar, dense, PairingConfig()) is not None
    assert "note:" not in capsys.readouterr().out


def test_on_a_cluster_a_sparse_depth_topics_holes_are_filled_too(lidar: Path, folder: Path) -> None:
    from pcainterp_stream.pipeline.distributed import summarize_chunk

    sparse = jobs.LearnOptions(depth_topic="/ground_truth/lidar_depth")
    dense = jobs.LearnOptions(depth_topic="/ground_truth/depth")
    chunk = summarize_chunk(lidar, 0, None, sparse, PairingConfig(), 4)
    truth = summarize_chunk(lidar, 0, None, dense, PairingConfig(), 4)
    assert chunk is not None
    assert truth is not None
    assert float(chunk.mean.mean()) > 0.8 * float(truth.mean.mean())


@pytest.fixture(scope="module")
def rosbag2(folder: Path) -> Path:
    bag = folder / "r2"
    jobs.synth(bag, frames=3, seed=17, scale=0.25, fmt="rosbag2")
    return bag


def test_log_files_are_a_rosbag2_folders_storage_files(rosbag2: Path, folder: Path) -> None:
    from pcainterp_stream.io.logreader import log_files

    assert log_files(rosbag2) == [rosbag2 / "r2.mcap"]
    assert log_files(folder / "drive.mcap") == [folder / "drive.mcap"]


def test_learn_refuses_a_rosbag2_folder_and_its_own_storage_file(rosbag2: Path) -> None:
    # before: "6 maps of your own" from 3 frames (bug hunt 6A F10)
    options = jobs.LearnOptions(n_components=2, fit_prior=False, with_synthetic=0)
    storage = rosbag2 / "r2.mcap"
    output = rosbag2.parent / "twice.npz"
    with pytest.raises(
        PcaInterpError,
        match=r"r2/r2.mcap is a storage file of the rosbag2 folder .*r2, given too: its maps "
        r"would count twice; pass each log once \(the folder or its file\)",
    ):
        jobs.learn([rosbag2, storage], output, options, PairingConfig())
    with pytest.raises(PcaInterpError, match=r"r2 is the rosbag2 folder of .*r2.mcap, given"):
        jobs.learn([storage, rosbag2], output, options, PairingConfig())
    with pytest.raises(PcaInterpError, match=r"r2 is .*r2 again: its maps would count twice"):
        jobs.learn([rosbag2, rosbag2], output, options, PairingConfig())
    assert not output.exists()


@pytest.fixture(scope="module")
def raw_and_rectified(folder: Path) -> tuple[Path, Path]:
    """A raw log (rectified box 310x92) and a rectified one (310x94) of one camera."""
    raw = folder / "raw.bag"
    jobs.synth_raw(raw, frames=3, seed=18, scale=0.25, fmt=None, model="plumb_bob")
    return raw, folder / "drive.mcap"


def test_learn_takes_one_cameras_raw_and_rectified_logs(
    raw_and_rectified: tuple[Path, Path], folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # before: "raw.bag has 310x94 images (rectified box 310x92) but drive.mcap has 310x94
    # images; learn one basis per camera": one camera called two (bug hunt 6A F10)
    raw, rectified = raw_and_rectified
    options = jobs.LearnOptions(n_components=3, fit_prior=False, with_synthetic=0)
    pairing = PairingConfig(discover=True)
    basis = jobs.learn([rectified, raw], folder / "mixed_rr.npz", options, pairing)
    assert basis.image_size == (94, 310)
    assert basis.n_train == 9
    assert re.search(
        r"note: raw.bag gives 310x92 maps \(the rectified box of its 310x94 raw images\) and "
        r"drive.mcap 310x94 maps \(its images\): sides within 3%.* so its maps are resampled "
        r"to 310x94",
        capsys.readouterr().out,
    )
    first_raw = jobs.learn([raw, rectified], folder / "mixed_rr2.npz", options, pairing)
    assert first_raw.image_size == (92, 310)


def test_on_a_cluster_raw_and_rectified_maps_are_resampled_to_the_plans_size(
    raw_and_rectified: tuple[Path, Path],
) -> None:
    from pcainterp_stream.pipeline.distributed import summarize_chunk
    from pcainterp_stream.pipeline.learn import GridTarget

    raw, _ = raw_and_rectified
    options = jobs.LearnOptions(n_components=3)
    target = GridTarget((23, 77), image_size=(94, 310))
    chunk = summarize_chunk(raw, 0, None, options, PairingConfig(discover=True), 4, target)
    assert chunk is not None
    assert chunk.image_size == (94, 310)
    assert chunk.n_maps == 3


def test_learn_still_refuses_two_cameras_naming_their_maps(folder: Path) -> None:
    small = folder / "small3.mcap"
    jobs.synth(small, frames=2, seed=19, scale=0.2, fmt="mcap")
    options = jobs.LearnOptions(n_components=3, fit_prior=False)
    with pytest.raises(
        PcaInterpError,
        match=r"small3.mcap gives 248x75 maps \(its images\) but .*drive.mcap gives 310x94 "
        r"maps \(its images\); learn one basis per camera",
    ):
        jobs.learn([folder / "drive.mcap", small], folder / "two.npz", options, PairingConfig())


def _later(source: Path, writer: Any, offset_ns: int) -> None:
    """Add a log's messages to ``writer``, their header stamps and log times later."""
    with open_log(source) as reader:
        for raw in reader.messages():
            message = reader.decode(raw)
            header = getattr(message, "header", None)
            if header is not None:
                shifted = rosmsg.stamp_ns(message) + offset_ns
                time = dataclasses.replace(
                    header.stamp, sec=shifted // 10**9, nanosec=shifted % 10**9
                )
                message = dataclasses.replace(
                    message, header=dataclasses.replace(header, stamp=time)
                )
            writer.add_message(raw.topic, message, raw.log_time_ns + offset_ns)


def test_a_log_whose_images_change_size_is_named_as_itself(folder: Path) -> None:
    small = folder / "small2.mcap"
    jobs.synth(small, frames=2, seed=16, scale=0.2, fmt="mcap")
    mixed = folder / "mixed.mcap"
    with open_writer(mixed, LogFormat.MCAP) as writer:
        _later(folder / "drive.mcap", writer, 0)
        _later(small, writer, 1000 * 10**9)
    options = jobs.LearnOptions(n_components=3, fit_prior=False)
    # before: "... but the first log's are 310x94" of the one log given
    with pytest.raises(
        PcaInterpError, match=r"mixed.mcap gives a 248x75 map .* but its first maps"
    ):
        jobs.learn([mixed], folder / "mixed.npz", options, PairingConfig())


def test_a_log_without_a_pair_among_others_is_named_in_a_note(
    folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # before: skipped without a word
    late = _rewritten(folder / "drive.mcap", folder / "late2.mcap", right_ms=20)
    options = jobs.LearnOptions(n_components=3, fit_prior=False)
    basis = jobs.learn([folder / "drive.mcap", late], folder / "one.npz", options, PairingConfig())
    assert basis.n_train == 6
    assert re.search(
        r"note: no stereo pair found in .*late2.mcap \(.*\); all 12 images dropped unpaired .*"
        r"pass --stamp-tolerance-ms 20 to pair them; learning from the other logs",
        capsys.readouterr().out,
    )


def test_on_a_cluster_the_flat_maps_are_counted_and_refused(folder: Path) -> None:
    from pcainterp_stream.pipeline.distributed import merge, summarize_chunk
    from pcainterp_stream.pipeline.learn import check_flat

    same = _right_is_left(folder / "drive.mcap", folder / "same_c.mcap")
    options = jobs.LearnOptions(n_components=3)
    unchecked = PairingConfig(check_rows=False)  # the row check would stop it first
    first = summarize_chunk(same, 0, 2, options, unchecked, 4)
    second = summarize_chunk(same, 2, None, options, unchecked, 4)
    total = merge(first, second, 4)
    assert total is not None
    assert (total.n_maps, total.flat_maps) == (6, 6)
    with pytest.raises(PcaInterpError, match=r"same_c.mcap: all of the 6 SGBM maps have almost"):
        check_flat((same,), total.flat_maps, total.n_maps)
    drive = summarize_chunk(folder / "drive.mcap", 0, None, options, PairingConfig(), 4)
    assert drive is not None
    assert drive.flat_maps == 0
