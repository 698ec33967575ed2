"""End-to-end jobs on small synthetic logs: learn, densify (stereo and features), Rerun, KITTI."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from pcainterp_stream.errors import PcaInterpError
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.estimator import densify
from pcainterp_stream.evaluate.metrics import compare_with_ground_truth
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.io import depth_codec, rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import LogFormat, open_writer
from pcainterp_stream.io.outputs import OutputTopics, display_millimetres, image_of
from pcainterp_stream.pipeline import jobs
from pcainterp_stream.pipeline.learn import learn_pairing
from pcainterp_stream.pipeline.processor import MeasurementSource, ProcessorConfig

REALDATA = Path(__file__).resolve().parents[3] / "shared" / "realdata"
KITTI_RAW = REALDATA / "kitti_raw" / "2011_09_26"


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("jobs")
    train, test = folder / "train.mcap", folder / "test.mcap"
    jobs.synth(train, frames=24, seed=11, scale=0.25, fmt="mcap")
    jobs.synth(test, frames=5, seed=12, scale=0.25, fmt="mcap")
    basis = folder / "basis.npz"
    options = jobs.LearnOptions(n_components=12, fit_prior=False)
    jobs.learn([train], basis, options, PairingConfig())
    return {"train": train, "test": test, "basis": basis, "folder": folder}


def test_learn_from_sgbm_maps_records_camera_and_source(logs: dict[str, Path]) -> None:
    basis = Basis.load(logs["basis"])
    assert basis.image_size == (94, 310)
    assert basis.n_train == 24
    assert basis.n_components == 12
    assert basis.focal_baseline == pytest.approx(718.856 * 0.25 * 0.5372, rel=0.01)
    assert basis.meta["source"]["maps"] == "SGBM"
    # the Python API learns from the maps alone unless asked (the command line: auto)
    assert jobs.LearnOptions().with_synthetic is None
    assert basis.meta["source"]["with_synthetic"] == 0
    assert basis.meta["source"]["with_synthetic_rule"] == "off"
    assert "finetune" not in basis.meta


def test_learn_from_depth_topic_uses_every_nth_frame(logs: dict[str, Path]) -> None:
    out = logs["folder"] / "gt_basis.npz"
    options = jobs.LearnOptions(
        n_components=5, depth_topic="/ground_truth/depth", every=2, fit_prior=False
    )
    basis = jobs.learn([logs["train"]], out, options, PairingConfig())
    assert basis.n_train == 12
    # sky (NaN depth) is disparity 0, so the mean map's top rows are small
    assert float(basis.mean[0].mean()) < float(basis.mean[-1].mean())


def test_learn_reads_millimetres_and_compressed_depth(logs: dict[str, Path]) -> None:
    # the ground truth (to 50 m) as 32FC1 metres, as a 16UC1 millimetre image (pcainterp's
    # depth_mm) and as a 32FC1 compressedDepth one (its compact depth): the same basis
    source = logs["folder"] / "depth_forms.mcap"
    with open_log(logs["train"]) as reader, open_writer(source, LogFormat.MCAP) as writer:
        for raw in reader.messages():
            message = reader.decode(raw)
            writer.add_message(raw.topic, message, raw.log_time_ns)
            if raw.topic != "/ground_truth/depth":
                continue
            depth = rosmsg.image_array(message).astype(np.float32)
            depth[~(depth < 50.0)] = np.nan  # within depth_mm's range (it clips at 60 m)
            stamp = rosmsg.stamp_ns(message)
            near = rosmsg.image_message(depth, stamp, "left")
            writer.add_message("/gt/near", near, raw.log_time_ns)
            millimetres = rosmsg.image_message(
                display_millimetres(depth.copy()), stamp, "left", encoding="16UC1"
            )
            writer.add_message("/gt/depth_mm", millimetres, raw.log_time_ns)
            encoded = depth_codec.encode_depth(depth, quant_a=4000.0)
            compact = rosmsg.compressed_image_message(encoded.data, encoded.format, stamp, "left")
            writer.add_message("/gt/depth", compact, raw.log_time_ns)
    bases = {}
    for topic in ("/gt/near", "/gt/depth_mm", "/gt/depth"):
        options = jobs.LearnOptions(n_components=5, depth_topic=topic, every=2, fit_prior=False)
        out = logs["folder"] / f"forms_{topic.replace('/', '_')}.npz"
        bases[topic] = jobs.learn([source], out, options, PairingConfig())
    metres = bases["/gt/near"].mean
    # before: the 16UC1 millimetres were read as metres, a mean disparity 1000x too small
    np.testing.assert_allclose(bases["/gt/depth_mm"].mean, metres, rtol=0.01, atol=0.05)
    np.testing.assert_allclose(bases["/gt/depth"].mean, metres, rtol=0.01, atol=0.05)


def _renamed(source: Path, target: Path, old: str, new: str) -> Path:
    """Copy a log with every topic starting with ``old`` moved under ``new``."""
    with open_log(source) as reader, open_writer(target, LogFormat.MCAP) as writer:
        for raw in reader.messages():
            topic = new + raw.topic[len(old) :] if raw.topic.startswith(old) else raw.topic
            writer.add_message(topic, reader.decode(raw), raw.log_time_ns)
    return target


def test_learn_finds_each_logs_own_topics(
    logs: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    cam = _renamed(logs["test"], logs["folder"] / "cam.mcap", "/stereo/", "/cam/")
    both = [logs["test"], cam]
    pairing = learn_pairing(both, PairingConfig(discover=True))
    assert pairing.discover  # the topics differ: each log's are found where it is read
    said = capsys.readouterr().out.splitlines()
    assert said[0].startswith("test.mcap: topics: left /stereo/left/image_rect,")
    assert said[1].startswith("cam.mcap: topics: left /cam/left/image_rect, right /cam/right")
    out = logs["folder"] / "both_basis.npz"
    basis = jobs.learn(both, out, jobs.LearnOptions(n_components=3), pairing)
    assert basis.n_train == 8  # 4 of each log's 5 frames; the 5th of each fits the prior
    assert basis.meta["prior"]["fit_logs"] == [str(logs["test"]), str(cam)]
    # logs of one pair of topics: that pair, found once
    same = learn_pairing([logs["test"], logs["train"]], PairingConfig(discover=True))
    assert not same.discover
    assert same.left_topic == "/stereo/left/image_rect"


def test_learn_refuses_logs_of_two_image_sizes_before_learning(
    logs: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    from pcainterp_stream.pipeline import learn as learn_job

    small = logs["folder"] / "small_camera.mcap"
    jobs.synth(small, frames=2, seed=13, scale=0.2, fmt="mcap")
    monkeypatch.setattr(learn_job, "learn_basis", None)  # not reached
    with pytest.raises(
        PcaInterpError, match=r"small_camera.mcap gives 248x75 maps \(its images\) but .*test"
    ):
        jobs.learn(
            [logs["test"], small],
            logs["folder"] / "sizes.npz",
            jobs.LearnOptions(n_components=3),
            PairingConfig(discover=True),
        )


def test_densify_beats_nearest_neighbour_against_ground_truth(logs: dict[str, Path]) -> None:
    out = logs["folder"] / "dense.mcap"
    summary = jobs.densify(logs["test"], out, logs["basis"])
    assert summary.frames == 5
    assert summary.measurements > 5 * 20
    comparison = compare_with_ground_truth(out)
    assert comparison.frames == 5
    assert comparison.mean_abs_error("pca_map") < comparison.mean_abs_error("nearest")
    # the output keeps every input message and adds 6 channels per frame
    with open_log(out) as reader:
        counts = {topic: info.message_count for topic, info in reader.topics().items()}
    assert counts["/stereo/left/image_rect"] == 5
    assert counts["/ground_truth/pose"] == 5
    assert counts["/pcainterp/depth"] == counts["/pcainterp/camera_info"] == 5


def test_densify_output_messages_carry_left_header_and_log_time(logs: dict[str, Path]) -> None:
    out = logs["folder"] / "dense_headers.mcap"
    jobs.densify(logs["test"], out, logs["basis"])
    left: dict[int, tuple[int, str]] = {}
    outputs: list[tuple[int, int, str]] = []
    in_file_order: list[int] = []
    with open_log(out) as reader:
        for raw in reader.messages():
            in_file_order.append(raw.log_time_ns)
            message = reader.decode(raw)
            if raw.topic == "/stereo/left/image_rect":
                left[raw.log_time_ns] = (rosmsg.stamp_ns(message), message.header.frame_id)
            elif raw.topic.startswith("/pcainterp/"):
                stamp = rosmsg.stamp_ns(message)
                outputs.append((raw.log_time_ns, stamp, message.header.frame_id))
    assert len(outputs) == 5 * 5  # the compact default: depth, std, features, info, depth_mm
    for log_time, stamp, frame_id in outputs:
        assert left[log_time] == (stamp, frame_id)
    # the inputs wait for the outputs made frames later: the file reads in log-time order
    assert in_file_order == sorted(in_file_order)


def _add_feature_stream(source: Path, target: Path) -> None:
    """Copy a synthetic log and add /features: true 3-D points at a few hundred pixels."""
    rng = np.random.default_rng(0)
    with open_log(source) as reader, open_writer(target, LogFormat.MCAP) as writer:
        camera_info = None
        for raw in reader.messages():
            writer.add_raw(raw)
            if raw.topic == "/stereo/left/camera_info":
                camera_info = reader.decode(raw)
            if raw.topic != "/ground_truth/depth" or camera_info is None:
                continue
            message = reader.decode(raw)
            depth = rosmsg.image_array(message)
            p = rosmsg.projection_matrix(camera_info)
            v = rng.integers(0, depth.shape[0], 150)
            u = rng.integers(0, depth.shape[1], 150)
            z = depth[v, u]
            keep = np.isfinite(z)
            u, v, z = u[keep], v[keep], z[keep]
            x = (u - p[0, 2]) * z / p[0, 0]
            y = (v - p[1, 2]) * z / p[1, 1]
            cloud = rosmsg.pointcloud2_message(
                {"x": x.astype(np.float32), "y": y.astype(np.float32), "z": z},
                rosmsg.stamp_ns(message),
                "stereo_left_optical",
            )
            writer.add_message("/features", cloud, raw.log_time_ns)


def test_densify_from_a_feature_stream(logs: dict[str, Path]) -> None:
    with_features = logs["folder"] / "features.mcap"
    _add_feature_stream(logs["test"], with_features)
    out = logs["folder"] / "features_dense.mcap"
    summary = jobs.densify(
        with_features,
        out,
        logs["basis"],
        topics=OutputTopics(),  # float32 channels: the by-hand checks read the disparity
        pairing=PairingConfig(features_topic="/features"),
        processor=ProcessorConfig(source=MeasurementSource.FEATURES),
    )
    assert summary.frames == 5
    # no SGBM map: the basis is checked on left-out points, never replaced
    assert summary.prior_lines[0].startswith("prior: the basis ")
    assert "left-out measurements" in summary.prior_lines[0]
    assert summary.basis_written is None
    with open_log(out) as reader:
        clouds = [reader.decode(raw) for raw in reader.messages(["/pcainterp/features"])]
        dense = [reader.decode(raw) for raw in reader.messages(["/pcainterp/disparity"])]
    assert len(clouds) == len(dense) == 5
    fields = rosmsg.pointcloud2_arrays(clouds[0])
    # the measurements used are exactly the stream's points (integer pixels, all inside)
    assert 100 < fields["u"].size <= 150
    np.testing.assert_allclose(fields["u"], np.round(fields["u"]), atol=1e-3)
    # their disparities are f*b / z of the points
    focal_baseline = float(dense[0].f) * float(dense[0].t)
    np.testing.assert_allclose(fields["disparity"], focal_baseline / fields["z"], rtol=1e-5)
    # the MAP estimate is pulled from the prior mean towards its measurements
    rows, cols = np.round(fields["v"]).astype(int), np.round(fields["u"]).astype(int)
    estimate = rosmsg.image_array(dense[0].image)[rows, cols]
    prior = densify(Basis.load(logs["basis"]), np.zeros((0, 2)), np.zeros(0)).disparity
    posterior_misfit = np.median(np.abs(estimate - fields["disparity"]))
    prior_misfit = np.median(np.abs(prior[rows, cols] - fields["disparity"]))
    assert posterior_misfit < 0.7 * prior_misfit


def test_rerun_recording_has_every_frame(logs: dict[str, Path]) -> None:
    import rerun.chunk

    rrd = logs["folder"] / "test.rrd"
    summary_of_job = jobs.densify(
        logs["test"], logs["folder"] / "dense_rrd.mcap", logs["basis"], rrd=rrd
    )
    summary = rerun.chunk.RrdReader(rrd).store().summary()
    rows: dict[str, int] = {}
    for entity, count in re.findall(r"^(\S+) rows=(\d+) static=False", summary, re.MULTILINE):
        rows[entity] = rows.get(entity, 0) + int(count)
    for entity in ("/camera/image", "/camera/depth", "/camera/features", "/depth_std"):
        assert rows[entity] == 5, summary
    assert rows["/camera"] == 1  # the pinhole, logged once for an unchanging camera
    assert not list(logs["folder"].glob(".test.rrd*"))
    assert summary_of_job.rrd_written


def test_a_recording_that_cannot_be_written_is_a_warning_and_never_hangs(
    logs: dict[str, Path], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A full disk under --rrd: Rerun's own file sink would never return from its shutdown."""
    import errno

    from pcainterp_stream.io import rerun_sink

    class FullDisk:
        def write(self, data: bytes) -> int:
            raise OSError(errno.ENOSPC, "No space left on device")

        def close(self) -> None:
            pass

    monkeypatch.setattr(rerun_sink._Pump, "_open_target", lambda self: FullDisk())
    rrd, out = logs["folder"] / "full.rrd", logs["folder"] / "dense_full.mcap"
    summary = jobs.densify(logs["test"], out, logs["basis"], rrd=rrd)
    assert summary.frames == 5
    assert out.is_file()  # the log's own output is whole
    assert not summary.rrd_written
    assert not rrd.exists()
    assert not list(logs["folder"].glob(".full.rrd*"))
    err = capsys.readouterr().err
    assert f"warning: cannot write {rrd}: No space left on device; no recording" in err


def test_info_describes_basis_and_log(logs: dict[str, Path]) -> None:
    text = jobs.info(logs["basis"])
    assert "12" in text
    assert "310x94" in text
    text = jobs.info(logs["test"])
    assert "/stereo/left/image_rect" in text


def test_info_names_the_camera_of_a_fine_tuned_basis(logs: dict[str, Path]) -> None:
    """Its file is on the built-in's grid; info names the maps' camera (bug hunt 11A F6)."""
    out = logs["folder"] / "tuned.npz"
    options = jobs.LearnOptions(n_components=5, fit_prior=False, with_synthetic=100)
    jobs.learn([logs["train"]], out, options, PairingConfig())
    built_in = Basis.default()
    text = jobs.info(out)
    assert "image size       1241x376 px (the basis learn merged into: its grid and camera)" in text
    assert f"the built-in street basis (fingerprint {built_in.fingerprint}, " in text
    assert re.search(
        r"maps' camera     310x94 px, f\*b 96\.\d+ px\*m: the camera of the logs it learned "
        r"from, their maps mapped onto 1241x376, disparity x4",
        text,
    ), text
    assert "maps' camera" not in jobs.info(logs["basis"])  # learned from scratch: its own


def test_info_names_the_basis_a_log_was_densified_with(logs: dict[str, Path]) -> None:
    dense = logs["folder"] / "info_dense.mcap"
    jobs.densify(logs["test"], dense, logs["basis"])
    fingerprint = Basis.load(logs["basis"]).fingerprint
    text = jobs.info(dense)
    assert f"  densified with:\n    basis.npz (fingerprint {fingerprint}) from frame 0" in text
    assert "densified with" not in jobs.info(logs["test"])


def test_demo_learn_runs_small(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(jobs, "DEMO_SCALE", 0.25)
    monkeypatch.setattr(jobs, "DEMO_TRAIN_SEEDS", (1, 3))
    monkeypatch.setattr(jobs, "DEMO_TRAIN_FRAMES", 8)
    monkeypatch.setattr(jobs, "DEMO_FRAMES", 3)
    monkeypatch.setattr(jobs, "DEMO_COMPONENTS", 8)
    text = jobs.demo(tmp_path / "demo", learn_basis=True)
    assert "PCA-MAP" in text
    assert "nearest neighbour" in text
    assert "linear  " in text
    for name in ("train_1.mcap", "train_3.mcap", "heldout.mcap", "basis.npz", "heldout.rrd"):
        assert (tmp_path / "demo" / name).is_file()


def test_demo_learn_scores_the_plain_demos_drive(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Bug hunt 15E F5: --learn scored another drive (seed 2, 50 frames), where its basis
    looked better than the built-in one on the plain demo's; the figures compare now."""
    rendered: dict[str, tuple[int, int]] = {}

    class Rendered(Exception):
        pass

    def fake_synth(path: Path, *, frames: int, seed: int, **options: object) -> None:
        rendered[path.name] = (seed, frames)
        if path.name == "heldout.mcap":
            raise Rendered

    monkeypatch.setattr(jobs, "synth", fake_synth)
    for learn_basis in (False, True):
        with pytest.raises(Rendered):
            jobs.demo(tmp_path / str(learn_basis), learn_basis=learn_basis)
        assert rendered.pop("heldout.mcap") == (jobs.DEMO_SEED, jobs.DEMO_FRAMES)
    assert jobs.DEMO_SEED not in {seed for seed, _ in rendered.values()}  # the training drives


def test_demo_with_the_built_in_basis_runs_small(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(jobs, "DEMO_SCALE", 0.25)  # the basis maps onto the smaller camera
    monkeypatch.setattr(jobs, "DEMO_FRAMES", 3)
    text = jobs.demo(tmp_path / "demo")
    assert "basis            built-in:" in text
    assert "PCA-MAP" in text
    assert "nearest neighbour" in text
    assert "truth inside +-2 sigma" in text
    for name in ("heldout.mcap", "heldout_dense.mcap", "heldout.rrd", "report/results.json"):
        assert (tmp_path / "demo" / name).is_file()
    assert not (tmp_path / "demo" / "basis.npz").exists()  # nothing learned


def test_demo_drive_is_not_in_the_built_in_recipe() -> None:
    from pcainterp_stream.estimate.basis import default_basis_recipe

    def seeds(value: object, named: bool = False) -> set[int]:
        """Every integer under a key that names seeds, at any depth of the recipe."""
        if isinstance(value, dict):
            return set().union(*(seeds(v, named or "seed" in str(k)) for k, v in value.items()))
        if isinstance(value, list | tuple):
            return set().union(*(seeds(v, named) for v in value))
        return {value} if named and isinstance(value, int) else set()

    recipe = default_basis_recipe().get("recipe", {})
    used = seeds(recipe)
    if isinstance(recipe.get("first_seed"), int) and isinstance(recipe.get("drives"), int):
        used |= set(range(recipe["first_seed"], recipe["first_seed"] + recipe["drives"]))
    assert jobs.DEMO_SEED not in used


@pytest.mark.skipif(not KITTI_RAW.is_dir(), reason="needs ../shared/realdata/kitti_raw")
def test_real_kitti_drive_end_to_end(tmp_path: Path) -> None:
    log = tmp_path / "kitti.mcap"
    jobs.import_kitti(KITTI_RAW, log, max_frames=6)
    basis = tmp_path / "kitti_basis.npz"
    options = jobs.LearnOptions(n_components=4, grid_scale=0.125, fit_prior=False)
    jobs.learn([log], basis, options, PairingConfig())
    summary = jobs.densify(log, tmp_path / "kitti_dense.mcap", basis)
    assert summary.frames == 6
    assert summary.measurements / summary.frames > 150
    with open_log(tmp_path / "kitti_dense.mcap") as reader:
        depth = [reader.decode(raw) for raw in reader.messages(["/pcainterp/depth"])]
    image = image_of(depth[0])
    assert image.shape == (375, 1242)
    finite = image[np.isfinite(image)]
    assert finite.size > 0.9 * image.size
    assert 2.0 < float(np.median(finite)) < 80.0


def test_cli_half_resolution_stereo_option(logs: dict[str, Path]) -> None:
    from pcainterp_stream.cli import main

    out = logs["folder"] / "half.mcap"
    args = ["densify", str(logs["test"]), "-o", str(out), "--basis", str(logs["basis"])]
    assert main([*args, "--stereo-downscale", "2"]) == 0
    with open_log(out) as reader:
        assert reader.topics()["/pcainterp/depth"].message_count == 5


def test_the_estimate_line_names_the_std_widened_near_sgbms_range() -> None:
    line = jobs._estimate_line(Basis.default())
    assert "std widened near SGBM's 128 px range" in line
    assert "per-frame covariance scale" in line  # the calibration is named beside it
    assert "points beyond SGBM's range from a quarter-resolution match" in line


def test_inputs_held_for_log_time_order_are_bounded() -> None:
    from pcainterp_stream.io.log_time_hold import LogTimeHold
    from pcainterp_stream.records import RawMessage

    written: list[int] = []

    class Writer:
        def add_raw(self, raw: RawMessage) -> None:
            written.append(raw.log_time_ns)

    def raw(t: int) -> RawMessage:
        return RawMessage(
            "/t", "std_msgs/msg/String", "s", "ros2msg", b"", "cdr", {}, b"x" * 10, t, t, 0
        )

    held = LogTimeHold(Writer().add_raw, limit=35, overhead=0)
    for t in (1, 2, 5, 3):
        held.add(raw(t))
    assert written == [1]  # 40 bytes held: the oldest goes out, in input order
    held.release(2)
    assert written == [1, 2]
    held.release(4)  # 5 came before 3 in the input: its order is kept
    assert written == [1, 2]
    held.release()
    assert written == [1, 2, 5, 3]
