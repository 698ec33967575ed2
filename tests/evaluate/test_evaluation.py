"""Evaluation maths (paper section IV-B projection errors, calibration, oracle) and the report."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples
from mcap_copy import McapCopy

from pcainterp_stream import cli
from pcainterp_stream.errors import LogReadError
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.estimate.learning import preprocess_disparity
from pcainterp_stream.evaluate.figures import write_figures
from pcainterp_stream.evaluate.metrics import (
    CalibrationStats,
    MethodStats,
    Mode,
    calibration_sums,
    depth_errors,
    disparity_from_depth,
    oracle_disparity,
    projection_errors,
    reference_view,
    relative_transform,
    stereo_transform,
)
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
from pcainterp_stream.evaluate.results import PCA_ON_SGBM, SGBM, SGBM_NN, Evaluation
from pcainterp_stream.evaluate.tables import results_markdown, summary_table
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.io.outputs import OutputTopics
from pcainterp_stream.pipeline import jobs
from pcainterp_stream.records import StereoCamera

CAMERA = StereoCamera(width=80, height=40, fx=60.0, fy=60.0, cx=39.5, cy=19.5, baseline=0.5)


def _scene(seed: int) -> np.ndarray:
    """A (40, 80) disparity map: a slanted ground, a box, sky (0) in the top rows."""
    rng = np.random.default_rng(seed)
    rows = np.arange(40, dtype=np.float64)[:, None]
    disparity = np.clip((rows - 12.0) * 0.8, 0.0, None) * np.ones((1, 80))
    x0 = int(rng.integers(5, 60))
    disparity[15:30, x0 : x0 + 12] = rng.uniform(5.0, 15.0)
    return disparity


# ----------------------------------------------------------------------------- maths


@settings(max_examples=examples(20), deadline=None)
@given(seed=st.integers(0, 1000), forward=st.floats(0.0, 1.5), yaw=st.floats(-0.05, 0.05))
def test_delta_2d_is_zero_when_estimate_is_reference(seed: int, forward: float, yaw: float) -> None:
    reference = _scene(seed)
    pose_b = np.eye(4)
    pose_b[:3, :3] = [[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]]
    pose_b[2, 3] = forward
    for transform in (stereo_transform(CAMERA), relative_transform(np.eye(4), pose_b)):
        view = reference_view(reference, CAMERA, transform)
        delta_2d, delta_3d = projection_errors(reference, view, CAMERA, transform)
        assert view.counted.sum() > 0.5 * reference.size
        assert np.nanmax(delta_2d) < 1e-9
        assert np.nanmax(delta_3d) < 1e-9
        assert np.all(np.isnan(delta_2d) == ~view.counted)


@pytest.mark.parametrize("offset", [0.5, 1.0, 3.0])
def test_constant_disparity_offset_is_its_projection_error_in_stereo_mode(offset: float) -> None:
    # in the right camera u_R = u - d, so a disparity error of c moves the projection by c
    reference = _scene(1) + 2.0  # no sky: every point finite
    transform = stereo_transform(CAMERA)
    view = reference_view(reference, CAMERA, transform)
    delta_2d, _ = projection_errors(reference + offset, view, CAMERA, transform)
    np.testing.assert_allclose(delta_2d[view.counted], offset, atol=1e-9)
    # pixels whose reference lands left of the right image do not count
    assert not view.counted[:, 0].any()
    assert view.counted[:, -1].all()


def test_sky_lands_by_rotation_alone_and_has_no_delta_3d() -> None:
    reference = np.zeros((40, 80))  # all sky
    pose_b = np.eye(4)
    pose_b[2, 3] = 5.0  # driving forward does not move points at infinity
    transform = relative_transform(np.eye(4), pose_b)
    view = reference_view(reference, CAMERA, transform)
    assert view.counted.all()
    np.testing.assert_allclose(view.u, np.arange(80)[None, :] * np.ones((40, 1)), atol=1e-9)
    delta_2d, delta_3d = projection_errors(np.full((40, 80), 10.0), view, CAMERA, transform)
    assert np.all(np.isnan(delta_3d))
    assert np.nanmin(delta_2d) > 0.0


def test_delta_3d_is_the_distance_of_the_points() -> None:
    reference = np.full((40, 80), 10.0)  # depth f*b/d = 3 m
    transform = stereo_transform(CAMERA)
    view = reference_view(reference, CAMERA, transform)
    _, delta_3d = projection_errors(np.full((40, 80), 15.0), view, CAMERA, transform)  # 2 m
    centre = delta_3d[19:21, 39:41]  # rays almost along the optical axis
    np.testing.assert_allclose(centre, 1.0, rtol=1e-3)


def test_disparity_from_depth_maps_no_surface_to_zero() -> None:
    depth = np.array([[2.0, np.nan, np.inf, 0.0, -1.0]])
    np.testing.assert_allclose(disparity_from_depth(depth, 30.0), [[15.0, 0, 0, 0, 0]])


def test_calibration_coverage_of_a_gaussian_sample() -> None:
    rng = np.random.default_rng(0)
    std = rng.uniform(0.5, 3.0, (200, 200))
    reference = rng.uniform(0.0, 50.0, (200, 200))
    estimate = reference + rng.normal(0.0, 1.0, std.shape) * std
    sums = calibration_sums(estimate, std, reference, np.ones(std.shape, dtype=bool))
    assert sums["inside_1"] / sums["n"] == pytest.approx(0.683, abs=0.01)
    assert sums["inside_2"] / sums["n"] == pytest.approx(0.954, abs=0.01)
    expected_nll = np.mean(0.5 * np.log(2 * np.pi * std**2)) + 0.5
    assert sums["nll"] / sums["n"] == pytest.approx(expected_nll, abs=0.02)
    # an overconfident std (half the true one) covers much less
    narrow = calibration_sums(estimate, std / 2, reference, np.ones(std.shape, dtype=bool))
    assert narrow["inside_2"] / narrow["n"] == pytest.approx(0.683, abs=0.01)


def test_calibration_leaves_pixels_without_a_std_out_of_the_nll() -> None:
    """A std of 0 (a basis that never varies there) is counted apart and left out of the
    NLL, which stays finite; coverage counts it outside. No std (NaN: no estimate there, or
    a 0 stored in a compact log) claims nothing: left out of coverage and NLL alike."""
    std = np.full((10, 10), 1.0)
    std[0, :5] = 0.0  # e.g. pixels that were sky in every training map
    std[1, :3] = np.nan
    reference = np.zeros((10, 10))
    estimate = np.full((10, 10), 0.5)
    estimate[0, 0] = 0.0  # exactly right where the std is 0: inside
    sums = calibration_sums(estimate, std, reference, np.ones(std.shape, dtype=bool))
    assert sums["certain"] == 5
    assert sums["no_std"] == 3
    assert sums["n"] == 97
    per_pixel = 0.5 * np.log(2 * np.pi) + 0.5 * 0.25
    assert sums["nll"] == pytest.approx(92 * per_pixel)
    assert sums["inside_1"] == 93
    stats = CalibrationStats()
    stats.sums = {key: stats.sums[key] + sums[key] for key in stats.sums}
    assert stats.summary()["nll"] == pytest.approx(per_pixel)
    assert stats.summary()["certain"] == pytest.approx(5 / 97)
    assert stats.summary()["no_std"] == pytest.approx(0.03)
    assert stats.summary()["coverage_1sigma"] == pytest.approx(93 / 97)
    nothing = calibration_sums(estimate, np.zeros((10, 10)), reference, np.ones((10, 10), bool))
    assert nothing["nll"] == 0.0
    assert nothing["certain"] == 100


def test_depth_errors_of_a_known_offset() -> None:
    reference = np.full((4, 4), 10.0)  # 3 m with f*b = 30
    estimate = np.full((4, 4), 15.0)  # 2 m
    sums = depth_errors(estimate, reference, np.ones((4, 4), dtype=bool), focal_baseline=30.0)
    assert sums["n"] == 16
    assert sums["abs"] / 16 == pytest.approx(1.0)
    assert np.sqrt(sums["isq"] / 16) == pytest.approx(1000 * (1 / 2 - 1 / 3))
    # beyond max_depth nothing counts
    far = depth_errors(estimate, np.full((4, 4), 0.1), np.ones((4, 4), bool), focal_baseline=30.0)
    assert far["n"] == 0


def test_method_stats_means_and_bins() -> None:
    reference = _scene(3) + 2.0
    transform = stereo_transform(CAMERA)
    view = reference_view(reference, CAMERA, transform)
    stats = MethodStats()
    stats.add(reference + 1.0, view, CAMERA, transform)
    stats.add(reference + 3.0, view, CAMERA, transform)
    summary = stats.summary()
    assert summary["delta_2d_mean"] == pytest.approx(2.0)
    assert summary["disparity_mae"] == pytest.approx(2.0)
    assert sum(stats.delta_2d_hist) == stats.pixels
    assert sum(stats.by_depth_count) == stats.pixels
    calibration = CalibrationStats()
    delta, _ = projection_errors(reference + 1.0, view, CAMERA, transform)
    calibration.add(reference + 1.0, np.full(reference.shape, 0.75), view, delta)
    assert calibration.summary()["coverage_1sigma"] == 0.0
    assert calibration.summary()["coverage_2sigma"] == 1.0


def test_undefined_ratios_print_a_dash_and_figures_do_not_warn(tmp_path: Path) -> None:
    # black images: no measurement, so nearest neighbour is "far" everywhere, as is SGBM's
    # reference: nearest scores 0 px and PCA-MAP / nearest is undefined (it printed
    # 30376721943148.96); no reference depth is within 80 m, so no depth metric either
    def stats(delta_2d_sum: float) -> MethodStats:
        return MethodStats(pixels=100.0, delta_2d_sum=delta_2d_sum, seconds=0.1, frames=2)

    result = Evaluation(log="blank.mcap", mode="stereo", reference="SGBM", frames=2)
    result.methods = {"pca_map": stats(3000.0), "nearest": stats(0.0), "linear": stats(5.0)}
    result.sweep = {10: dict(result.methods)}
    result.sweep_frames, result.sweep_reached, result.sweep_corners = 1, {10: 1}, [12]
    result.calibration = {"stored": CalibrationStats()}
    table = summary_table(result)
    row = next(line for line in table.splitlines() if line.startswith("pca_map"))
    assert row.split() == ["pca_map", "30.000", "-", "-", "-", "-", "-", "-", "50"]
    markdown = results_markdown(result, [])
    assert "nearest neighbour mean Delta_2D = - (target" in markdown
    assert "undefined, nearest neighbour's mean Delta_2D is 0." in markdown
    assert "| 10 | 1 | 30.000 | 0.000 | 0.050 | - |" in markdown
    assert "e+" not in markdown
    write_figures(result, [], tmp_path, None)  # warnings are errors: no log scale of zeros
    result.methods["nearest"] = stats(10000.0)
    assert result.ratio() == pytest.approx(0.3)
    assert " 0.30 " in summary_table(result)


def test_oracle_reproduces_a_map_in_the_basis_span() -> None:
    rng = np.random.default_rng(5)
    grid_size = (10, 20)
    q, _ = np.linalg.qr(rng.normal(size=(200, 3)))
    basis = Basis(
        mean=np.full(grid_size, 8.0, dtype=np.float32),
        components=q.T.reshape(3, *grid_size).astype(np.float32),
        eigenvalues=np.array([30.0, 10.0, 1.0]),
        total_variance=np.float64(45.0),
        image_size=(40, 80),
        focal_baseline=30.0,
        n_train=10,
        meta={},
    )
    reference = _scene(2)
    oracle = oracle_disparity(basis, reference)
    grid = preprocess_disparity(reference, grid_size).reshape(-1)
    projected = basis.pixel_major @ (basis.component_rows @ (grid - basis.mean_flat))
    # the oracle is the least-squares fit: its grid residual is orthogonal to the basis
    residual = grid - basis.mean_flat - projected
    assert np.abs(basis.component_rows @ residual).max() < 1e-3
    assert oracle.shape == reference.shape


# ----------------------------------------------------------------------------- on logs


@pytest.fixture(scope="session")
def dense_logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("evaluation")
    train, test = folder / "train.mcap", folder / "test.mcap"
    jobs.synth(train, frames=20, seed=21, scale=0.25, fmt="mcap")
    jobs.synth(test, frames=4, seed=22, scale=0.25, fmt="mcap")
    basis = folder / "basis.npz"
    options = jobs.LearnOptions(n_components=10, fit_prior=False)
    jobs.learn([train], basis, options, PairingConfig())
    dense = folder / "dense.mcap"
    # float32 channels: re-densifying must reproduce the stored estimate at every pixel (a
    # compact log reads disparities below min_disparity as 0, REP 118's +inf depth)
    jobs.densify(test, dense, basis, topics=OutputTopics())
    compact = folder / "compact.mcap"
    jobs.densify(test, compact, basis)
    return {"basis": basis, "dense": dense, "test": test, "folder": folder, "compact": compact}


def test_evaluate_writes_report_with_every_section(dense_logs: dict[str, Path]) -> None:
    out = dense_logs["folder"] / "report"
    folder, table = jobs.evaluate(
        dense_logs["dense"], out, basis=dense_logs["basis"], sweep_every=2
    )
    assert folder == out
    report = json.loads((out / "results.json").read_text())
    assert report["mode"] == "temporal"
    assert report["reference"] == "ground truth"
    assert report["frames"] == 3  # temporal: the last frame has no successor
    assert set(report["methods"]) == {"pca_map", "nearest", "linear", "oracle"}
    # the stereo baselines beside them, and the coverage split by SGBM's holes
    assert set(report["stereo_baselines"]) == {"sgbm", "sgbm_nn", "pca_map@sgbm"}
    stored_split = report["calibration"]["stored"]["mean"]
    parts = stored_split["pixels_sgbm_holes"] + stored_split["pixels_sgbm_valid"]
    assert parts == stored_split["pixels"]
    assert report["reference_label"] == "ground truth (dense, 100.0 % of pixels)"
    assert set(report["calibration"]) == {"stored", "paper", "exact", "exact+residual"}
    # adding the variance the basis leaves out widens the band
    widened = report["calibration"]["exact+residual"]["mean"]["coverage_2sigma"]
    assert widened >= report["calibration"]["exact"]["mean"]["coverage_2sigma"]
    # only the counts the sweep's frames had corners for (a 80x40 px frame has few)
    reached = {
        str(points) for points in (50, 100, 200, 400, 800) if points <= max(report["sweep_corners"])
    }
    assert set(report["sweep"]) == set(report["sweep_frames_reached"]) == reached
    # the log was densified with exact uncertainty: re-densifying reproduces its calibration
    stored = report["calibration"]["stored"]["mean"]["coverage_2sigma"]
    assert report["calibration"]["exact"]["mean"]["coverage_2sigma"] == pytest.approx(
        stored, abs=0.01
    )
    # the oracle is the best the basis can do (on average, with the same reference)
    means = {name: m["mean"]["delta_2d_mean"] for name, m in report["methods"].items()}
    assert means["oracle"] < means["pca_map"]
    figures = ["errors.png", "uncertainty.png", "examples.png", "basis.png"]
    figures += ["sweep.png"] if reached else []  # no row: no curve
    for name in figures:
        assert (out / name).stat().st_size > 1000
        assert f"({name})" in (out / "results.md").read_text()
    assert "pca_map" in table
    assert "Targets" in (out / "results.md").read_text()


def test_a_basis_of_another_camera_is_named_and_has_no_oracle_row(
    dense_logs: dict[str, Path],
) -> None:
    """As densify warns of it; the oracle would read many times nearest (bug hunt 11A F7)."""
    basis = Basis.load(dense_logs["basis"])
    other = dense_logs["folder"] / "depth_camera.npz"  # a 320x240 depth camera's, f*b 9.6
    dataclasses.replace(basis, image_size=(240, 320), focal_baseline=9.6).save(other)
    out = dense_logs["folder"] / "other_camera_report"
    _, table = jobs.evaluate(dense_logs["dense"], out, basis=other, sweep_every=0)
    report = json.loads((out / "results.json").read_text())
    assert set(report["methods"]) == {"pca_map", "nearest", "linear"}
    note = (
        f"the basis {other} was learned for another camera (320x240 px, f*b 9.6 px*m; this "
        "log's 310x94 px"
    )
    assert sum(note in line for line in report["notes"]) == 1
    assert "the oracle row, its best fit to the truth, is left out" in table
    assert note in (out / "results.md").read_text()


def test_stereo_mode_with_an_sgbm_reference(
    dense_logs: dict[str, Path],
) -> None:
    result, examples = evaluate_log(
        dense_logs["dense"], EvaluateOptions(mode=None, sweep_every=0, examples=1)
    )
    assert result.mode == "temporal"
    stereo, _ = evaluate_log(
        dense_logs["dense"], EvaluateOptions(mode=Mode.STEREO, sgbm_reference=True, sweep_every=0)
    )
    assert stereo.mode == "stereo"
    assert stereo.reference == "SGBM"
    assert stereo.frames == 4
    # SGBM leaves holes: fewer pixels count than with the ground truth
    truth, _ = evaluate_log(dense_logs["dense"], EvaluateOptions(mode=Mode.STEREO, sweep_every=0))
    assert stereo.methods["pca_map"].pixels < truth.methods["pca_map"].pixels
    assert stereo.calibration.keys() == {"stored"}
    assert stereo.stereo == {}  # SGBM against itself would be trivially perfect
    assert len(examples) == 1


def test_evaluate_cli_prints_table(
    dense_logs: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    out = dense_logs["folder"] / "cli_report"
    code = cli.main(["evaluate", str(dense_logs["dense"]), "-o", str(out), "--sweep-every", "0"])
    assert code == 0
    text = capsys.readouterr().out
    assert "nearest" in text
    assert (out / "results.md").is_file()


def test_evaluate_refuses_a_log_without_densified_channels(dense_logs: dict[str, Path]) -> None:
    with pytest.raises(
        LogReadError, match=r"has no /pcainterp/disparity or /pcainterp/depth, .*pcainterp densify"
    ):
        evaluate_log(dense_logs["test"])


def test_evaluate_names_the_prefix_a_log_has(dense_logs: dict[str, Path]) -> None:
    # it named /nope/disparity alone and did not say the log has them under /pcainterp
    with pytest.raises(LogReadError) as caught:
        evaluate_log(dense_logs["dense"], topics=OutputTopics.with_prefix("/nope"))
    assert str(caught.value) == (
        f"{dense_logs['dense']} has no /nope/disparity or /nope/depth, /nope/disparity_std, "
        "/nope/features, /nope/camera_info; it has densified channels under /pcainterp: "
        "pass --output-prefix /pcainterp"
    )


def test_evaluate_cli_one_line_errors(
    dense_logs: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main(["evaluate", str(dense_logs["dense"]), "--sweep-every", "-1"]) == 2
    assert "--sweep-every must be >= 0" in capsys.readouterr().err
    missing = dense_logs["folder"] / "nope.npz"
    assert cli.main(["evaluate", str(dense_logs["dense"]), "--basis", str(missing)]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert cli.main(["evaluate", str(dense_logs["dense"]), "--output-prefix", "/a b"]) == 2
    assert "--output-prefix '/a b' is not a ROS 2 topic name" in capsys.readouterr().err


def test_evaluate_refuses_a_file_as_report_folder_up_front(
    dense_logs: dict[str, Path],
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from pcainterp_stream.evaluate import report

    def never(*args: object, **kwargs: object) -> None:
        raise AssertionError("the log was evaluated before the output was checked")

    monkeypatch.setattr(report, "evaluate_log", never)
    target = dense_logs["folder"] / "a_file"
    target.write_text("kept")
    args = ["evaluate", str(dense_logs["dense"]), "-o", str(target), "--no-basis"]
    assert cli.main(args) == 2
    err = capsys.readouterr().err
    assert f"cannot write the report to {target}: it is a file" in err
    assert len(err.splitlines()) == 1
    assert target.read_text() == "kept"


def test_evaluate_help_has_examples(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["evaluate", "--help"])
    assert exit_info.value.code == 0
    assert "pcainterp evaluate" in capsys.readouterr().out.split("examples:")[1]


def test_evaluate_reads_a_compact_log(dense_logs: dict[str, Path]) -> None:
    """The default (compressedDepth) log gives the report of the float32 one.

    Away from REP 118's "too far" pixels (read as disparity 0 from a compact log) the
    estimate is the same to 1/64 of its std and the std to 1 %.
    """
    reports = {}
    for name in ("dense", "compact"):
        out = dense_logs["folder"] / f"report_{name}"
        jobs.evaluate(dense_logs[name], out, basis=dense_logs["basis"], sweep_every=0)
        reports[name] = json.loads((out / "results.json").read_text())
    full, compact = reports["dense"], reports["compact"]
    assert compact["frames"] == full["frames"]
    assert set(compact["methods"]) == set(full["methods"])
    assert compact["measurements"] == full["measurements"]
    # the baselines read the features only: the same but for f*b's last digits
    for method in ("nearest", "linear"):
        means = {
            name: {
                k: v for k, v in reports[name]["methods"][method]["mean"].items() if "ms" not in k
            }
            for name in reports
        }
        assert means["compact"] == pytest.approx(means["dense"], rel=1e-6)


def _outputs_delayed(source: Path, target: Path, frames: int) -> None:
    """Copy an MCAP with every ``/pcainterp/*`` message written ``frames`` frames later."""
    held: list[tuple[int, Any, Any]] = []
    with McapCopy(source, target) as copy:
        lefts = 0
        for topic, channel_id, message in copy.messages():
            if topic.startswith("/pcainterp/"):
                held.append((lefts + frames, channel_id, message))
                continue
            if topic == "/stereo/left/image_rect":
                lefts += 1
            while held and held[0][0] <= lefts:
                _, late_id, late = held.pop(0)
                copy.add(late_id, late.log_time, late.data, late.publish_time)
            copy.add(channel_id, message.log_time, message.data, message.publish_time)
        for _, late_id, late in held:
            copy.add(late_id, late.log_time, late.data, late.publish_time)


def test_outputs_written_well_after_their_input_are_still_found(tmp_path: Path) -> None:
    """densify writes a frame's outputs up to ~20 frames after its input images (look-ahead,
    the fit check's warm-up, the encoders): evaluate pairs every frame with its right image."""
    log = tmp_path / "in.mcap"
    jobs.synth(log, frames=30, seed=23, scale=0.25, fmt="mcap")
    dense = tmp_path / "dense.mcap"
    jobs.densify(log, dense)
    late = tmp_path / "late.mcap"
    _outputs_delayed(dense, late, 24)
    options = EvaluateOptions(mode=Mode.STEREO, sgbm_reference=True, sweep_every=0)
    on_time, _ = evaluate_log(dense, options)
    delayed, _ = evaluate_log(late, options)
    assert delayed.frames == on_time.frames == 30
    for method in ("pca_map", "nearest"):
        assert delayed.methods[method].pixels == on_time.methods[method].pixels
        assert delayed.methods[method].delta_2d_sum == on_time.methods[method].delta_2d_sum


def _rewritten(source: Path, target: Path, *, right_later_ns: int = 0, drop_key: str = "") -> Path:
    """Copy an MCAP: the right images stamped ``right_later_ns`` later, ``drop_key`` left out
    of every channel's metadata (a log densified before the key was recorded)."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    from pcainterp_stream.io import rosmsg
    from pcainterp_stream.io.logreader import open_log
    from pcainterp_stream.io.logwriter import open_writer

    if right_later_ns:
        with open_log(source) as reader, open_writer(target, "mcap") as writer:
            for raw in reader.messages():
                message = reader.decode(raw)
                if raw.topic == "/stereo/right/image_rect":
                    stamp = rosmsg.stamp_ns(message) + right_later_ns
                    message.header = rosmsg.header(stamp, message.header.frame_id)
                writer.add_message(raw.topic, message, raw.log_time_ns)
        return target
    with source.open("rb") as stream, target.open("wb") as out:
        writer = Writer(out)
        writer.start()
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in make_reader(stream).iter_messages(log_time_order=False):
            if channel.id not in channels:
                if schema is not None and schema.id not in schemas:
                    schemas[schema.id] = writer.register_schema(
                        schema.name, schema.encoding, schema.data
                    )
                metadata = {k: v for k, v in channel.metadata.items() if k != drop_key}
                channels[channel.id] = writer.register_channel(
                    channel.topic,
                    channel.message_encoding,
                    schemas.get(schema.id, 0) if schema is not None else 0,
                    metadata,
                )
            writer.add_message(
                channels[channel.id], message.log_time, message.data, message.publish_time
            )
        writer.finish()
    return target


def test_evaluate_pairs_the_right_images_within_densifys_tolerance(
    dense_logs: dict[str, Path], tmp_path: Path
) -> None:
    from pcainterp_stream.io.outputs import STAMP_TOLERANCE_KEY, recorded_metadata

    # the right images stamped 3 ms after their left ones: densify pairs them within 5 ms
    offset = _rewritten(dense_logs["test"], tmp_path / "offset.mcap", right_later_ns=3_000_000)
    dense = tmp_path / "dense.mcap"
    jobs.densify(offset, dense, dense_logs["basis"], pairing=PairingConfig(tolerance_ns=5_000_000))
    assert recorded_metadata(dense)[STAMP_TOLERANCE_KEY] == "5000000"
    options = EvaluateOptions(mode=Mode.STEREO, sgbm_reference=True, sweep_every=0)
    result, _ = evaluate_log(dense, options)
    assert result.frames == 4
    # a tighter one given is used, and said
    with pytest.raises(
        LogReadError,
        match=r"^frame 0 has no /ground_truth/depth and the right images of "
        r"/stereo/right/image_rect did not pair with it within 2 ms \(--stamp-tolerance-ms; "
        r"the nearest is 3\.00 ms away\), so there is no SGBM reference; pass "
        r"--stamp-tolerance-ms 3$",
    ):
        evaluate_log(dense, dataclasses.replace(options, stamp_tolerance_ns=2_000_000))
    # a log densified before the tolerance was recorded: 1 ms, and the fix
    old = _rewritten(dense, tmp_path / "old.mcap", drop_key=STAMP_TOLERANCE_KEY)
    with pytest.raises(
        LogReadError,
        match=r"within 1 ms \(the default: the log records none; the nearest is 3\.00 ms "
        r"away\), so there is no SGBM reference; pass --stamp-tolerance-ms 3 \(as densify "
        r"was given\)$",
    ):
        evaluate_log(old, options)
    given, _ = evaluate_log(old, dataclasses.replace(options, stamp_tolerance_ns=3_000_000))
    assert given.frames == 4
    assert given.methods["pca_map"].delta_2d_sum == result.methods["pca_map"].delta_2d_sum


def _recorded_by_a_driver(
    source: Path, target: Path, right_later_ns: int, fmt: str, *, png: bool = False
) -> Path:
    """Copy a synthetic log as a stereo driver records it: the right image and its camera
    info logged ``right_later_ns`` after the left one (same stamps), written as ``fmt``;
    with ``png`` both images as PNG ``CompressedImage`` (lossless: the same pixels)."""
    import cv2

    from pcainterp_stream.io import rosmsg
    from pcainterp_stream.io.logreader import open_log
    from pcainterp_stream.io.logwriter import open_writer
    from pcainterp_stream.io.outputs import image_of

    with open_log(source) as reader, open_writer(target, fmt) as writer:
        for raw in reader.messages():
            message = reader.decode(raw)
            log_time_ns = raw.log_time_ns
            if raw.topic.startswith("/stereo/right/"):
                log_time_ns += right_later_ns
            if png and raw.topic.endswith("/image_rect"):
                ok, data = cv2.imencode(".png", image_of(message))
                assert ok
                stamp, frame_id = rosmsg.stamp_ns(message), message.header.frame_id
                message = rosmsg.compressed_image_message(data.tobytes(), "png", stamp, frame_id)
            writer.add_message(raw.topic, message, log_time_ns)
    return target


def _scores(result: Evaluation) -> dict[str, dict[str, Any]]:
    """Every row's accumulated errors, without its timing."""
    rows = {**result.methods, **{f"stereo {k}": v for k, v in result.stereo.items()}}
    return {
        name: {k: v for k, v in dataclasses.asdict(stats).items() if k != "seconds"}
        for name, stats in rows.items()
    }


@pytest.fixture(scope="module")
def driver_logs(dense_logs: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Any:
    """Return a function: (right log delay ns, format, png) -> that log densified."""
    folder = tmp_path_factory.mktemp("driver_logs")
    made: dict[tuple[int, str, bool], Path] = {}

    def densified(right_later_ns: int, fmt: str = "mcap", png: bool = False) -> Path:
        key = (right_later_ns, fmt, png)
        if key not in made:
            name = f"r{right_later_ns}_{fmt}{'_png' if png else ''}"
            suffix = {"mcap": ".mcap", "ros1": ".bag"}.get(fmt, "")
            log = _recorded_by_a_driver(
                dense_logs["test"], folder / f"{name}{suffix}", right_later_ns, fmt, png=png
            )
            made[key] = folder / f"{name}_dense.mcap"
            jobs.densify(log, made[key], dense_logs["basis"], topics=OutputTopics())
        return made[key]

    return densified


@pytest.mark.parametrize(
    ("right_later_ns", "fmt", "png"),
    [
        (1_000_000, "mcap", False),
        (30_000_000, "mcap", False),
        (1_000_000, "ros1", False),
        (30_000_000, "rosbag2-sqlite3", False),
        (30_000_000, "mcap", True),
        (250_000_000, "mcap", False),  # 2.5 frames: 30 ms at 80 Hz
        (-1_000_000, "mcap", False),
    ],
)
def test_a_right_image_logged_after_the_left_is_found(
    driver_logs: Any, right_later_ns: int, fmt: str, png: bool
) -> None:
    """A driver's right image is received (logged) apart from the left by jitter, mostly
    after it, while densify writes the outputs at the left's log time: evaluate scores the
    SGBM rows and takes the SGBM reference as it does with equal log times."""
    same, later = driver_logs(0, fmt, png), driver_logs(right_later_ns, fmt, png)
    truth = EvaluateOptions(mode=Mode.STEREO, sweep_every=0)
    expected, _ = evaluate_log(same, truth)
    assert expected.stereo.keys() == {SGBM, SGBM_NN, PCA_ON_SGBM}
    result, _ = evaluate_log(later, truth)
    assert result.stereo_note == expected.stereo_note == ""
    assert _scores(result) == _scores(expected)
    sgbm = EvaluateOptions(mode=Mode.STEREO, sgbm_reference=True, sweep_every=0)
    expected, _ = evaluate_log(same, sgbm)
    result, _ = evaluate_log(later, sgbm)
    assert result.frames == expected.frames == 4
    assert _scores(result) == _scores(expected)


def test_a_frame_whose_right_image_never_comes_is_evaluated_without_it(
    driver_logs: Any, tmp_path: Path
) -> None:
    """Frame 1's right image was dropped (right images logged 30 ms after the left): the
    frames after it find theirs, it has no SGBM rows, and with the SGBM reference it is the
    error it is with equal log times."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    source = driver_logs(30_000_000)
    dropped = tmp_path / "dropped.mcap"
    rights = 0
    with source.open("rb") as stream, dropped.open("wb") as out:
        writer = Writer(out)
        writer.start()
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in make_reader(stream).iter_messages():
            if channel.topic == "/stereo/right/image_rect":
                rights += 1
                if rights == 2:
                    continue
            if channel.id not in channels:
                if schema is not None and schema.id not in schemas:
                    schemas[schema.id] = writer.register_schema(
                        schema.name, schema.encoding, schema.data
                    )
                channels[channel.id] = writer.register_channel(
                    channel.topic,
                    channel.message_encoding,
                    schemas.get(schema.id, 0) if schema is not None else 0,
                    dict(channel.metadata),
                )
            writer.add_message(
                channels[channel.id], message.log_time, message.data, message.publish_time
            )
        writer.finish()
    truth = EvaluateOptions(mode=Mode.STEREO, sweep_every=0)
    full, _ = evaluate_log(source, truth)
    result, _ = evaluate_log(dropped, truth)
    assert result.frames == full.frames == 4
    assert result.stereo[SGBM].frames == 3
    assert full.stereo[SGBM].frames == 4
    assert _scores(result)["pca_map"] == _scores(full)["pca_map"]
    with pytest.raises(
        LogReadError,
        match=r"^frame 1 has no /ground_truth/depth and the right images of "
        r"/stereo/right/image_rect did not pair with it within 1 ms .*the nearest is 100\.00 ms",
    ):
        evaluate_log(dropped, EvaluateOptions(mode=Mode.STEREO, sgbm_reference=True))


def test_a_frame_waits_a_bounded_number_of_frames_for_its_right_image(
    dense_logs: dict[str, Path], tmp_path: Path
) -> None:
    """Right images logged 1.5 s (15 frames) late, densified with a pairing window that
    long: the first frames do not wait for them (memory stays bounded) and go on without
    one; the last ones still find theirs."""
    from pcainterp_stream.evaluate.log_frames import RIGHT_WAIT_FRAMES, read_frames

    log = tmp_path / "in.mcap"
    jobs.synth(log, frames=12, seed=24, scale=0.25, fmt="mcap")
    late = _recorded_by_a_driver(log, tmp_path / "late.mcap", 1_500_000_000, "mcap")
    dense = tmp_path / "dense.mcap"
    window = PairingConfig(window=16)
    jobs.densify(late, dense, dense_logs["basis"], topics=OutputTopics(), pairing=window)
    frames = list(read_frames(dense, OutputTopics(), None))
    alone = 12 - RIGHT_WAIT_FRAMES
    assert [frame.right is None for frame in frames] == [True] * alone + [False] * (12 - alone)
    assert [frame.index for frame in frames] == list(range(12))
    assert frames[0].right_gap_ns is None  # no right image was read yet


def _boxed(source: Path, target: Path, box: tuple[int, int, int, int]) -> Path:
    """Copy a float32 densified log with its estimate and std NaN outside ``box`` (x, y,
    width, height), as densify writes a raw or black-bordered pair."""
    from pcainterp_stream.io import rosmsg
    from pcainterp_stream.io.logreader import open_log
    from pcainterp_stream.io.logwriter import open_writer

    x, y, width, height = box

    def cut(image: Any) -> Any:
        values = rosmsg.image_array(image).astype(np.float32)
        outside = np.ones(values.shape, dtype=bool)
        outside[y : y + height, x : x + width] = False
        values[outside] = np.nan
        return rosmsg.image_message(values, rosmsg.stamp_ns(image), image.header.frame_id)

    with open_log(source) as reader, open_writer(target, "mcap") as writer:
        for raw in reader.messages():
            message = reader.decode(raw)
            if raw.topic.startswith("/pcainterp/") and str(message.__msgtype__) in (
                rosmsg.DISPARITY_IMAGE,
                rosmsg.IMAGE,
            ):
                if str(message.__msgtype__) == rosmsg.DISPARITY_IMAGE:
                    message.image = cut(message.image)
                elif message.encoding == "32FC1":
                    message = cut(message)
            writer.channel_metadata.setdefault(raw.topic, dict(raw.channel_metadata))
            writer.add_message(raw.topic, message, raw.log_time_ns)
    return target


def test_pixels_without_an_estimate_are_left_out_of_every_method(
    dense_logs: dict[str, Path],
) -> None:
    # before: NaN (no estimate, outside the rectified box) was scored as disparity 0 (far)
    # for pca_map only, and its NaN std as a miss of the stored uncertainty
    options = EvaluateOptions(mode=Mode.STEREO, basis=dense_logs["basis"], sweep_every=1)
    whole, _ = evaluate_log(dense_logs["dense"], options)
    height, width = whole.image_size
    box = (6, 3, width - 14, height - 12)  # cut more at the bottom: the near ground
    log = _boxed(dense_logs["dense"], dense_logs["folder"] / "boxed.mcap", box)
    boxed, _ = evaluate_log(log, options)
    assert boxed.frames == whole.frames
    for name in ("pca_map", "nearest", "oracle"):
        mean, before = (r.methods[name].summary()["delta_2d_mean"] for r in (boxed, whole))
        assert mean < 1.5 * before, name
    stored = boxed.calibration["stored"].summary()["coverage_2sigma"]
    assert stored > whole.calibration["stored"].summary()["coverage_2sigma"] - 0.05
    assert 0 < boxed.no_estimate < whole.methods["pca_map"].pixels
    counted = {name: stats.pixels for name, stats in boxed.methods.items()}
    assert set(counted.values()) == {whole.methods["pca_map"].pixels - boxed.no_estimate}
    for name, stats in boxed.calibration.items():
        assert stats.sums["no_std"] == 0, name
        assert stats.sums["n"] == counted["pca_map"], name
    # the re-densified rows estimate in the box, as densify did: as good as on the whole
    for name in ("paper", "exact"):
        coverage = (r.calibration[name].summary()["coverage_2sigma"] for r in (boxed, whole))
        assert next(coverage) > next(coverage) - 0.1, name
    share = f"{100 * boxed.no_estimate_fraction:.1f} % of the reference pixels have no estimate"
    assert share in summary_table(boxed)
    assert share in results_markdown(boxed, [])
    assert boxed.summary()["left_out_no_estimate"] == pytest.approx(boxed.no_estimate_fraction)
    assert "no estimate" not in summary_table(whole)
    assert whole.summary()["left_out_no_estimate"] == 0.0


def test_the_box_of_an_estimate_is_recovered_from_its_nan() -> None:
    from pcainterp_stream.evaluate.box import estimate_box

    has_estimate = np.zeros((40, 80), dtype=bool)
    assert estimate_box(has_estimate) is None  # no estimate at all
    has_estimate[3:31, 6:72] = True
    assert estimate_box(has_estimate) == (6, 3, 66, 28)
    has_estimate[10, 10] = False  # NaN inside: no box densify used, the basis rows skip it
    assert estimate_box(has_estimate) is None
    assert estimate_box(np.ones((40, 80), dtype=bool)) == (0, 0, 80, 40)
