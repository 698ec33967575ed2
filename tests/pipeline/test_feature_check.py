"""densify with a feature stream names the stream's problems, not the images'."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from pcainterp_stream import cli
from pcainterp_stream.errors import PcaInterpError
from pcainterp_stream.frontend.motion import CarryConfig
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.frontend.pairing_stats import PairingStats
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import LogFormat, open_writer
from pcainterp_stream.io.outputs import image_of
from pcainterp_stream.pipeline import jobs
from pcainterp_stream.pipeline.densify import DensifySummary
from pcainterp_stream.pipeline.feature_check import FeatureStreamCheck
from pcainterp_stream.pipeline.processor import MeasurementSource, ProcessorConfig
from pcainterp_stream.records import SparseFeatures, StereoCamera, StereoFrame

FRAMES = 4
MS = 1_000_000
FEATURES = ["--features-topic", "/features"]
Points = npt.NDArray[np.floating[Any]]
# (frame number, stamp, frame_id, points) -> the cloud written (or clouds), or None for none
Cloud = tuple[int, str, Points]
Damage = Callable[[int, int, str, Points], Cloud | list[Cloud] | None]


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("features") / "drive.mcap"
    jobs.synth(path, frames=FRAMES, seed=12, scale=0.25, fmt="mcap")
    return path


def with_features(
    source: Path, target: Path, damage: Damage | None = None, names: str = "xyz"
) -> Path:
    """Copy a synthetic log adding /features: true 3-D points (left optical, m), damaged.

    ``names`` are the clouds' three field names (``xyw``: a cloud without z).
    """
    rng = np.random.default_rng(0)
    index = 0
    with open_log(source) as reader, open_writer(target, LogFormat.MCAP) as writer:
        camera_info = None
        for raw in reader.messages():
            writer.add_raw(raw)
            if raw.topic == "/stereo/left/camera_info":
                camera_info = reader.decode(raw)
            if raw.topic != "/ground_truth/depth" or camera_info is None:
                continue
            depth = rosmsg.image_array(reader.decode(raw))
            p = rosmsg.projection_matrix(camera_info)
            v = rng.integers(0, depth.shape[0], 150)
            u = rng.integers(0, depth.shape[1], 150)
            z = depth[v, u]
            keep = np.isfinite(z)
            u, v, z = u[keep], v[keep], z[keep]
            x = (u - p[0, 2]) * z / p[0, 0]
            y = (v - p[1, 2]) * z / p[1, 1]
            points = np.stack([x, y, z], axis=1).astype(np.float32)
            stamp = rosmsg.stamp_ns(reader.decode(raw))
            cloud: Cloud | list[Cloud] | None = (stamp, "stereo_left_optical", points)
            if damage is not None:
                cloud = damage(index, stamp, "stereo_left_optical", points)
            index += 1
            for stamp, frame_id, points in [] if cloud is None else _listed(cloud):
                points = points.astype(np.float32)
                fields = {name: points[:, i] for i, name in enumerate(names)}
                message = rosmsg.pointcloud2_message(fields, stamp, frame_id)
                writer.add_message("/features", message, raw.log_time_ns)
    return target


def _listed(cloud: Cloud | list[Cloud]) -> list[Cloud]:
    return cloud if isinstance(cloud, list) else [cloud]


def densify(
    source: Path, output: Path, max_features: int = 500, tolerance_ms: int = 1, **options: Any
) -> DensifySummary:
    return jobs.densify(
        source,
        output,
        pairing=PairingConfig(features_topic="/features", tolerance_ns=tolerance_ms * MS),
        processor=ProcessorConfig(
            source=MeasurementSource.FEATURES, max_features=max_features, **options
        ),
    )


def test_a_sound_stream_says_what_it_gave_and_warns_of_nothing(log: Path, tmp_path: Path) -> None:
    summary = densify(with_features(log, tmp_path / "f.mcap"), tmp_path / "out.mcap")
    assert summary.feature_line is not None
    found = re.fullmatch(
        r"features: (\d+) points of /features in 4 of 4 frames, (\d+) used; 0 behind the "
        r"camera, 0 outside the 310x94 image(?:; (\d+) left out on a pixel already holding a "
        r"nearer point)?",
        summary.feature_line,
    )
    assert found is not None
    points, used, shared = (int(n or 0) for n in found.groups())
    assert used + shared == points  # the random pixels repeat a few: one point each
    assert shared < 0.02 * points
    assert summary.warnings == []


def _later(ms: int) -> Damage:
    return lambda i, stamp, frame_id, points: (stamp + ms * MS, frame_id, points)


@pytest.mark.parametrize(
    ("damage", "cause"),
    [
        (
            _later(3),
            r"4 had no cloud within the 1 ms stamp tolerance \(the nearest cloud was "
            r"3 ms from an image's stamp; pass --stamp-tolerance-ms 3 if",
        ),
        (_later(-3), r"4 had no cloud .*the nearest cloud was 3 ms .* --stamp-tolerance-ms 3 "),
        (lambda i, s, f, p: (s, f, p[:0]), r"4 had an empty cloud \(no point with finite"),
        (
            lambda i, s, f, p: (s, f, -p),
            r"4 had every point of their cloud behind the camera "
            r"\(z <= 0, \d+ points\): are the clouds in the left camera's optical frame",
        ),
        (
            lambda i, s, f, p: (s, f, p + p[:, 2:] * [5, 0, 0]),
            r"4 had every point of their "
            r"cloud outside the 310x94 image \(\d+ points\)",
        ),
    ],
    ids=["3ms-late", "3ms-early", "empty", "behind", "outside"],
)
def test_a_stream_that_gives_no_frame_a_point_is_refused_naming_why(
    log: Path, tmp_path: Path, damage: Damage, cause: str
) -> None:
    source = with_features(log, tmp_path / "f.mcap", damage)
    output = tmp_path / "out.mcap"
    with pytest.raises(
        PcaInterpError,
        match=rf"^{source}: --features-topic /features gave no usable point in any of the 4 "
        rf"frames: {cause}",
    ):
        densify(source, output)
    assert sorted(path.name for path in tmp_path.iterdir()) == ["f.mcap"]  # nothing written


def test_clouds_that_cannot_be_read_are_named(log: Path, tmp_path: Path) -> None:
    source = with_features(log, tmp_path / "f.mcap", names="xyw")
    with pytest.raises(
        PcaInterpError,
        match=r"in any of the 4 frames: 4 had no cloud: none could be read \(/features: "
        r"point cloud has no field z \(fields: x, y, w\)\)$",
    ):
        densify(source, tmp_path / "out.mcap")


def test_frames_without_a_cloud_are_blamed_on_the_stream(log: Path, tmp_path: Path) -> None:
    # a SLAM front end publishing at keyframes only: every other frame has no cloud
    source = with_features(
        log, tmp_path / "f.mcap", lambda i, s, f, p: None if i % 2 else (s, f, p)
    )
    summary = densify(source, tmp_path / "out.mcap")
    assert summary.frames == 4
    (line,) = summary.warnings
    assert line.startswith(
        "2 of 4 frames got no point from --features-topic /features, so they have no estimate "
        "(depth NaN): "
    )
    with open_log(tmp_path / "out.mcap") as reader:
        depths = [image_of(reader.decode(raw)) for raw in reader.messages(["/pcainterp/depth"])]
    assert [bool(np.isnan(depth).all()) for depth in depths] == [False, True, False, True]
    assert line.endswith(": 2 had no cloud within the 1 ms stamp tolerance")  # no near miss
    assert "textureless" not in line
    assert summary.feature_line is not None
    assert " in 2 of 4 frames" in summary.feature_line


def test_frames_whose_points_all_fall_outside_are_blamed_on_the_stream(
    log: Path, tmp_path: Path
) -> None:
    source = with_features(
        log, tmp_path / "f.mcap", lambda i, s, f, p: (s, f, p + p[:, 2:] * [5, 0, 0] * (i % 2))
    )
    (line,) = densify(source, tmp_path / "out.mcap").warnings
    assert re.search(
        r"^2 of 4 frames got no point .*: 2 had every point of their cloud outside the "
        r"310x94 image \(\d+ points\)",
        line,
    )


def test_points_mostly_dropped_are_a_warning(log: Path, tmp_path: Path) -> None:
    def shift_most(i: int, stamp: int, frame_id: str, points: Points) -> tuple[int, str, Points]:
        moved = points.copy()
        moved[len(points) // 4 :, 0] += moved[len(points) // 4 :, 2] * 5
        return stamp, frame_id, moved

    summary = densify(with_features(log, tmp_path / "f.mcap", shift_most), tmp_path / "o.mcap")
    (line,) = summary.warnings
    assert re.fullmatch(
        r"(\d+) of the \d+ points of /features were dropped \(0 behind the camera, \1 "
        r"outside the 310x94 image\): are the clouds in the left camera's optical frame .*",
        line,
    )


def test_clouds_in_another_frame_are_a_warning(log: Path, tmp_path: Path) -> None:
    # camera_link may be a renamed optical frame: warned of, densified
    source = with_features(log, tmp_path / "f.mcap", lambda i, s, f, p: (s, "camera_link", p))
    assert densify(source, tmp_path / "out.mcap").warnings == [
        "the clouds of /features are in frame 'camera_link', the left image in "
        "'stereo_left_optical': their points were used as if in the left optical frame "
        "(transform them there before densifying)"
    ]
    # a ROS 1 frame_id's leading slash names the same frame
    slash = with_features(log, tmp_path / "g.mcap", lambda i, s, f, p: (s, "/" + f, p))
    assert densify(slash, tmp_path / "out2.mcap").warnings == []


@pytest.mark.parametrize("frame_id", ["map", "odom", "/world", "earth"])
def test_clouds_in_a_world_frame_are_refused(log: Path, tmp_path: Path, frame_id: str) -> None:
    # ORB-SLAM's map points: warned of only, and densified worse than without the stream
    source = with_features(log, tmp_path / "f.mcap", lambda i, s, f, p: (s, frame_id, p + 20))
    with pytest.raises(
        PcaInterpError,
        match=rf"^{re.escape(str(source))}: the clouds of --features-topic /features are in "
        rf"frame '{frame_id}', a world frame \(REP 105\): a map's points, not the left "
        r"camera's; transform them into the left optical frame 'stereo_left_optical' \(with "
        r"the camera's pose at each stamp\) before densifying$",
    ):
        densify(source, tmp_path / "out.mcap")
    assert sorted(path.name for path in tmp_path.iterdir()) == ["f.mcap"]  # nothing written


def _moved_to(depth: float) -> Damage:
    """Move each cloud's first point along its ray to ``depth`` m: a triangulation failure."""

    def moved(i: int, stamp: int, frame_id: str, points: Points) -> Cloud:
        bad = points.copy()
        bad[0] *= depth / bad[0, 2]
        return stamp, frame_id, bad

    return moved


def _disparities(path: Path) -> npt.NDArray[np.float64]:
    with open_log(path) as reader:
        depths = [image_of(reader.decode(raw)) for raw in reader.messages(["/pcainterp/depth"])]
    return 1.0 / np.stack(depths).astype(np.float64)  # f*b aside


def test_points_nearer_than_the_pair_sees_are_dropped_and_counted(
    log: Path, tmp_path: Path
) -> None:
    # one point per frame at 1 cm (a disparity of ~5,000 px on the 310 px image) made the
    # map 3-9x worse; now it is left out, as if the cloud had not had it
    summary = densify(with_features(log, tmp_path / "f.mcap", _moved_to(0.01)), tmp_path / "o")
    assert summary.feature_line is not None
    assert re.search(
        r"; 0 behind the camera, 0 outside the 310x94 image, 4 nearer than the stereo pair "
        r"sees \(disparity over the 310 px width: z < 0.\d+ m; triangulation failures\?\)",
        summary.feature_line,
    )
    assert summary.warnings == []
    without = with_features(log, tmp_path / "w.mcap", lambda i, s, f, p: (s, f, p[1:]))
    densify(without, tmp_path / "w_out")
    assert _depths(tmp_path / "o") == _depths(tmp_path / "w_out")


def test_one_wrong_point_per_frame_is_left_out_by_the_robust_start(
    log: Path, tmp_path: Path
) -> None:
    # one point of ~150 per frame at 1 m (a disparity the pair can see) pulled the map by
    # tens of px around it: the Cauchy weight of the plain start still trusted it
    summary = densify(with_features(log, tmp_path / "f.mcap", _moved_to(1.0)), tmp_path / "o")
    assert summary.feature_line is not None
    assert "stereo pair" not in summary.feature_line
    without = with_features(log, tmp_path / "w.mcap", lambda i, s, f, p: (s, f, p[1:]))
    densify(without, tmp_path / "w_out")
    error = np.abs(_disparities(tmp_path / "o") - _disparities(tmp_path / "w_out"))
    assert np.nanmax(error) < 0.01  # 1/m: ~1 px of disparity (f*b ~97 px*m)


def test_millimetre_coordinates_are_a_warning(log: Path, tmp_path: Path) -> None:
    source = with_features(log, tmp_path / "f.mcap", lambda i, s, f, p: (s, f, p * 1000))
    warnings = densify(source, tmp_path / "out.mcap").warnings
    (line,) = [w for w in warnings if "median depth" in w]
    assert re.fullmatch(
        r"the points of /features have a median depth of [\d,]+ m \([\d.]+ m if the "
        r"coordinates are millimetres\): ROS point clouds are in metres \(REP 103\); .*",
        line,
    )


def test_the_command_line_prints_the_stream_and_refuses_in_one_line(
    log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sound = with_features(log, tmp_path / "f.mcap")
    assert cli.main(["densify", str(sound), "-o", str(tmp_path / "out.mcap"), *FEATURES]) == 0
    assert re.search(
        r"^features: \d+ points of /features in 4 of 4 frames", capsys.readouterr().out, re.M
    )
    late = with_features(log, tmp_path / "late.mcap", _later(3))
    target = tmp_path / "late_out.mcap"
    assert cli.main(["densify", str(late), "-o", str(target), *FEATURES]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"pcainterp: error: {late}: --features-topic /features gave no usable")
    assert err.count("\n") == 1
    assert "Traceback" not in err
    assert "--stamp-tolerance-ms 3" in err
    assert not [p.name for p in tmp_path.iterdir() if "late_out" in p.name]  # nor a temporary
    ok = ["densify", str(late), "-o", str(target), *FEATURES, "--stamp-tolerance-ms", "3"]
    assert cli.main(ok) == 0  # the fix it names works


def _dense(i: int, stamp: int, frame_id: str, points: Points) -> tuple[int, str, Points]:
    """Each point 20 times with 1 cm of noise: a cloud as dense as a LiDAR's in the image."""
    noise = np.random.default_rng(i).normal(0, 0.01, (points.shape[0] * 20, 3))
    return stamp, frame_id, np.repeat(points, 20, axis=0) + noise


def test_a_dense_cloud_is_thinned_and_the_summary_says_so(log: Path, tmp_path: Path) -> None:
    source = with_features(log, tmp_path / "f.mcap", _dense)
    summary = densify(source, tmp_path / "out.mcap", max_features=60)
    assert summary.feature_line is not None
    found = re.fullmatch(
        r"features: (\d+) points of /features in 4 of 4 frames, (\d+) used; 0 behind the "
        r"camera, \d+ outside the 310x94 image; (\d+) points per frame in the image, thinned to "
        r"(\d+) \(one per cell of \d+ px, --max-features 60\)",
        summary.feature_line,
    )
    assert found is not None
    points, used, per_frame, kept = (int(n) for n in found.groups())
    assert per_frame * 4 > 0.95 * points  # a few of the noisy copies fall off the image
    assert 40 <= kept <= 60
    assert abs(used - 4 * kept) <= 2  # the per-frame figures are means, rounded
    assert summary.warnings == []


def test_max_features_needs_a_stream_and_a_positive_count(
    log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = str(tmp_path / "out.mcap")
    assert cli.main(["densify", str(log), "-o", target, "--max-features", "100"]) == 2
    assert "add --features-topic or drop --max-features" in capsys.readouterr().err
    assert cli.main(["densify", str(log), "-o", target, *FEATURES, "--max-features", "0"]) == 2
    err = capsys.readouterr().err
    assert err == "pcainterp: error: --max-features must be at least 1, got 0\n"


def _normalized(i: int, stamp: int, frame_id: str, points: Points) -> Cloud:
    """VINS feature_tracker's points: normalized image coordinates (x/z, y/z, 1)."""
    return stamp, frame_id, points / points[:, 2:]


def _wall(i: int, stamp: int, frame_id: str, points: Points) -> Cloud:
    """The same rays on a wall facing the camera 5 m away, with 1 mm of depth noise."""
    depth = 5.0 + np.random.default_rng(i).normal(0.0, 0.001, points.shape[0])
    return stamp, frame_id, points / points[:, 2:] * depth[:, None]


def _noiseless_wall(i: int, stamp: int, frame_id: str, points: Points) -> Cloud:
    """The same rays on a wall facing the camera at 4.95 m, every z exactly that (float32):
    a simulator's depth sensor without a noise model."""
    return stamp, frame_id, points / points[:, 2:] * np.float32(4.95)


def test_a_noiseless_wall_is_densified_and_normalized_coordinates_still_refused(
    log: Path, tmp_path: Path
) -> None:
    """Bug hunt 8C F10: a simulator's cloud of a wall facing the camera (all z = 4.95 m, x and
    y over metres) refused the whole run as "not 3-D points"; only z = 1 is refused."""
    wall = with_features(log, tmp_path / "wall.mcap", _noiseless_wall)
    summary = densify(wall, tmp_path / "wall_out.mcap")
    assert summary.frames == FRAMES
    assert not [line for line in summary.warnings if "one depth" in line or "z = " in line]
    with open_log(tmp_path / "wall_out.mcap") as reader:
        depths = [image_of(reader.decode(raw)) for raw in reader.messages(["/pcainterp/depth"])]
    assert all(np.nanmedian(depth) == pytest.approx(4.95, rel=0.01) for depth in depths)
    # the refusal of z = 1 is unchanged, after a flat wall too
    refusals, _ = _checked([4.95] * 12, [1.0] * 12)
    assert refusals[0] is None
    assert refusals[1] is not None
    assert "has z = 1: not 3-D points" in refusals[1]


def test_normalized_image_coordinates_are_refused_and_a_flat_wall_is_not(
    log: Path, tmp_path: Path
) -> None:
    # every depth was 1 m, densified with a confident std and a 2.4e14x fit-check ratio
    source = with_features(log, tmp_path / "f.mcap", _normalized)
    with pytest.raises(
        PcaInterpError,
        match=rf"^{re.escape(str(source))}: every point of the cloud of --features-topic "
        r"/features at stamp [\d.]+ s \(\d+ points\) has z = 1: not 3-D points, whose depths "
        r"differ if only by noise; normalized image coordinates \(x/z, y/z, 1: VINS "
        r"feature_tracker's points\)\? densify needs x y z in metres in the left optical "
        r"frame$",
    ):
        densify(source, tmp_path / "out.mcap")
    assert sorted(path.name for path in tmp_path.iterdir()) == ["f.mcap"]  # nothing written
    wall = with_features(log, tmp_path / "wall.mcap", _wall)
    summary = densify(wall, tmp_path / "wall_out.mcap")
    assert summary.frames == 4
    assert not [line for line in summary.warnings if "one depth" in line]
    with open_log(tmp_path / "wall_out.mcap") as reader:
        (depth, *_) = [
            image_of(reader.decode(raw)) for raw in reader.messages(["/pcainterp/depth"])
        ]
    assert np.nanmedian(depth) == pytest.approx(5.0, rel=0.05)


def _first(count: int, depth: Callable[[int], float] | None = None) -> Damage:
    """Keep a cloud's first ``count`` points, moved to ``depth(i)`` (m) along their rays."""

    def first(i: int, stamp: int, frame_id: str, points: Points) -> Cloud:
        kept = points[:count]
        return stamp, frame_id, kept if depth is None else kept / kept[:, 2:] * depth(i)

    return first


def test_small_clouds_at_one_depth_are_judged_together(log: Path, tmp_path: Path) -> None:
    # clouds of fewer than 10 points were never judged: 3 normalized points a frame were
    # densified as a flat wall without a word (9 at z = 8 m in every frame are a flat wall:
    # test_small_clouds_of_real_points_are_densified_without_a_word)
    for count, depth, points, clouds in [(3, 1.0, 12, 4)]:
        source = with_features(log, tmp_path / "f.mcap", _first(count, lambda i, z=depth: z))
        guess = r"normalized image coordinates .*\? "
        with pytest.raises(
            PcaInterpError,
            match=rf"^{re.escape(str(source))}: every point of the {clouds} clouds of "
            r"--features-topic /features from stamp [\d.]+ s to [\d.]+ s "
            rf"\({points} points, fewer than 10 a cloud\) has z = {depth:g}: not 3-D points, "
            rf"whose depths differ if only by noise; {guess}densify needs x y z in metres in "
            r"the left optical frame$",
        ):
            densify(source, tmp_path / "out.mcap")
        assert sorted(path.name for path in tmp_path.iterdir()) == ["f.mcap"]  # nothing written
        source.unlink()
    # too few points to refuse (8): a warning
    source = with_features(log, tmp_path / "two.mcap", _first(2, lambda i: 1.0))
    (line,) = [w for w in densify(source, tmp_path / "two_out.mcap").warnings if "z = 1" in w]
    assert re.fullmatch(
        r"every point of the 4 clouds of --features-topic /features from stamp [\d.]+ s to "
        r"[\d.]+ s \(8 points, fewer than 10 a cloud\) has z = 1, and no cloud had points at "
        r"different depths: not 3-D points, whose depths differ if only by noise; normalized "
        r"image coordinates .*\? densify needs x y z in metres in the left optical frame "
        r"\(too few points to refuse the run\)",
        line,
    )


@pytest.mark.parametrize(
    ("count", "depth"),
    [(3, None), (1, None), (1, lambda i: 1.0), (3, lambda i: 5.0 + i), (9, lambda i: 8.0)],
    ids=[
        "3 points",
        "1 point",
        "1 point at z = 1",
        "3 points a cloud at one depth each",
        "9 points a cloud at z = 8 m",
    ],
)
def test_small_clouds_of_real_points_are_densified_without_a_word(
    log: Path, tmp_path: Path, count: int, depth: Callable[[int], float] | None
) -> None:
    source = with_features(log, tmp_path / "f.mcap", _first(count, depth))
    summary = densify(source, tmp_path / "out.mcap")
    assert summary.frames == FRAMES
    assert not [line for line in summary.warnings if "one depth" in line or "z = " in line]


def _checked(*depths: list[float]) -> tuple[list[str | None], list[str]]:
    """Hand clouds of these depths (one list a cloud) to a check: (its refusals, warnings)."""
    check = FeatureStreamCheck("/features")
    camera = StereoCamera(width=40, height=30, fx=30.0, fy=30.0, cx=19.5, cy=14.5, baseline=0.5)
    grey = np.zeros(camera.image_size, np.uint8)
    refusals = []
    for i, cloud in enumerate(depths):
        frame = StereoFrame(i, i * 10**8, i * 10**8, "left", grey, grey, camera)
        points = np.array([[0.0, 0.0, z] for z in cloud], np.float32).reshape(-1, 3)
        refusals.append(check.cloud(frame, SparseFeatures(i * 10**8, 0, "left", points)))
    return refusals, check.warnings(PairingStats())


def test_small_flat_clouds_count_until_a_depth_differs() -> None:
    one = [1.0, 1.0, 1.0]
    refusals, warnings = _checked(one, one, one, one)
    assert refusals[:3] == [None] * 3
    assert refusals[3] is not None
    assert refusals[3].startswith("every point of the 4 clouds of --features-topic /features ")
    # a cloud with spread, or one at another depth, ends the count; single points are not judged
    for depths in ([one, one, one, [2.0, 2.5], one], [one, [4.0, 4.0], one, one], [[1.0]] * 30):
        refusals, warnings = _checked(*depths)
        assert refusals == [None] * len(depths)
        assert warnings == []
    (line,) = _checked(one)[1]  # one cloud: said so
    assert line.startswith(
        "every point of the cloud of --features-topic /features at stamp 0.000000000 s (3 "
        "points, fewer than 10 a cloud) has z = 1, and no cloud had points at different depths: "
    )
    assert _checked([1.0, 1.0])[1] == []  # two points are too few to warn of


def test_flat_clouds_after_3d_ones_are_a_warning(log: Path, tmp_path: Path) -> None:
    source = with_features(
        log,
        tmp_path / "f.mcap",
        lambda i, s, f, p: (s, f, p) if i == 0 else _normalized(i, s, f, p),
    )
    assert (
        "3 clouds of /features had every point at one depth (the first z = 1): not 3-D points, "
        "their frames' depths are a flat wall (densify needs x y z in metres in the left "
        "optical frame)"
    ) in densify(source, tmp_path / "out.mcap").warnings


def test_a_frame_takes_the_nearest_cloud_and_the_line_says_how_far_it_was(
    log: Path, tmp_path: Path
) -> None:
    def twin(i: int, stamp: int, frame_id: str, points: Points) -> list[Cloud]:
        # a faster stream: a cloud 40 ms before the image (depths off, to tell), then its own
        return [(stamp - 40 * MS, frame_id, points * 1.3), (stamp, frame_id, points)]

    def empty_first(i: int, stamp: int, frame_id: str, points: Points) -> list[Cloud]:
        return [(stamp, frame_id, points[:0]), (stamp, frame_id, points)]

    sound = densify(
        with_features(log, tmp_path / "f.mcap"), tmp_path / "sound.mcap", tolerance_ms=45
    )
    twins = densify(
        with_features(log, tmp_path / "t.mcap", twin), tmp_path / "twin.mcap", tolerance_ms=45
    )
    assert twins.feature_line == sound.feature_line  # exact stamps: no gap to tell of
    assert twins.pairing.features_unmatched == 4  # the early clouds
    # two clouds of one stamp, the empty one first: it refused the run ("4 had an empty cloud")
    doubles = densify(
        with_features(log, tmp_path / "d.mcap", empty_first), tmp_path / "d_out.mcap"
    )
    assert doubles.warnings == []
    for output in ("twin.mcap", "d_out.mcap"):
        assert _depths(tmp_path / output) == _depths(tmp_path / "sound.mcap")
    late = densify(
        with_features(log, tmp_path / "l.mcap", _later(3)), tmp_path / "l_out.mcap", tolerance_ms=5
    )
    assert late.feature_line is not None
    assert late.feature_line.endswith("; 4 of the 4 clouds matched an image 3 ms from their stamp")


def test_clouds_stamped_0_are_named_and_paired_with_no_frame_whatever_the_tolerance(
    log: Path, tmp_path: Path
) -> None:
    """Bug hunt 8C F4: clouds whose publisher never set the stamp got the advice
    ``--stamp-tolerance-ms 1317046453000`` (41 years); taking it gave one frame a cloud."""
    source = with_features(log, tmp_path / "f.mcap", lambda i, s, f, p: (0, f, p))
    cause = (
        r"4 had no cloud: 4 clouds of /features have header stamp 0 \(not set by their "
        r"publisher\), which places them at no image, whatever the tolerance; stamp each cloud "
        r"with the header stamp of the image it was computed from$"
    )
    for tolerance_ms in (1, 1317046453000):
        with pytest.raises(PcaInterpError, match=rf"in any of the 4 frames: {cause}"):
            densify(source, tmp_path / "out.mcap", tolerance_ms=tolerance_ms)


def test_clouds_on_another_clock_are_named_and_no_tolerance_is_advised(
    log: Path, tmp_path: Path
) -> None:
    """Bug hunt 8C F4: clouds stamped on the wall clock beside a log in sensor time (4e8 s
    later) got the advice of a 12.7-year tolerance; one stamped over half a frame off, one
    that pairs each frame with its neighbour's cloud."""
    far = with_features(log, tmp_path / "far.mcap", _later(400_000_000_000))
    with pytest.raises(PcaInterpError) as refused:
        densify(far, tmp_path / "out.mcap")
    assert str(refused.value).endswith(
        "4 had no cloud within the 1 ms stamp tolerance (the nearest cloud was 4e+08 s (12.7 "
        "years) from an image's stamp: the clouds are stamped on another clock than the "
        "images, or another log's; a tolerance that wide pairs frames with other frames' "
        "clouds; stamp each cloud with the header stamp of the image it was computed from)"
    )
    # the tolerance taken anyway: each cloud matched beyond a second is warned of
    wide = densify(far, tmp_path / "wide.mcap", tolerance_ms=400_000_001_000)
    (line,) = [w for w in wide.warnings if "more than 1 s" in w]
    assert re.fullmatch(
        r"\d of the \d clouds of /features matched an image more than 1 s from their stamp "
        r"\(up to 4e\+08 s \(12.7 years\)\): not of the image's instant, their points are "
        r"likely another frame's \(a clock other than the images'\?\); stamp each cloud with "
        r"the header stamp of the image it was computed from",
        line,
    )
    # a nearest cloud half a frame away or more (frames 100 ms apart) is another frame's too
    check = FeatureStreamCheck("/features", frames=4, without_cloud=4)
    check.frame_stamps_ns = (0, 300 * MS)
    stats = PairingStats(tolerance_ns=MS, features_unmatched=4)
    stats.features_nearest_miss_ns = 40 * MS
    assert "pass --stamp-tolerance-ms 40 if" in str(check.error(stats))
    stats.features_nearest_miss_ns = 60 * MS
    assert str(check.error(stats)).endswith(
        "4 had no cloud within the 1 ms stamp tolerance (the nearest cloud was 60 ms from an "
        "image's stamp, 0.6 frame intervals of 100 ms: half a frame interval or more; a "
        "tolerance that wide pairs frames with other frames' clouds; stamp each cloud with "
        "the header stamp of the image it was computed from)"
    )


def _depths(path: Path) -> list[bytes]:
    with open_log(path) as reader:
        return [bytes(reader.decode(raw).data) for raw in reader.messages(["/pcainterp/depth"])]


def test_frames_without_a_cloud_in_temporal_mode_are_said_predicted(
    log: Path, tmp_path: Path
) -> None:
    # nothing carried (--carry-frames 0): it said "only the points carried from earlier frames"
    source = with_features(
        log, tmp_path / "f.mcap", lambda i, s, f, p: None if i % 2 else (s, f, p)
    )
    summary = densify(source, tmp_path / "out.mcap", temporal=True, carry=CarryConfig(frames=0))
    (line,) = summary.warnings
    assert line == (
        "2 of 4 frames got no point from --features-topic /features, so they have the temporal "
        "prior's prediction from the previous frame (wider std): 2 had no cloud within the "
        "1 ms stamp tolerance"
    )


def test_a_fit_check_with_exact_linear_interpolation_gives_no_ratio(
    log: Path, tmp_path: Path
) -> None:
    # nine points of one wall per frame, at 8, 9, 10, 11 m (each cloud at a depth of its own:
    # not refused as flat): linear interpolation is exact on the left-out ones, and the
    # warning gave a ratio of ~1e14 and "learn a basis"
    source = with_features(log, tmp_path / "f.mcap", _first(9, lambda i: 8.0 + i))
    summary = densify(source, tmp_path / "out.mcap")
    (line,) = [w for w in summary.prior_lines if w.startswith("warning:")]
    assert re.fullmatch(
        r"warning: linear interpolation is exact on this log's left-out measurements "
        r"\(\S+ px\): they are constant or exactly planar, as no measured scene is, so the fit "
        r"check compares nothing; check what the measurements are",
        line,
    )
    assert "x linear" not in " ".join(summary.prior_lines)


def test_an_old_pointcloud_topic_is_named_as_such(
    log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    source = tmp_path / "vins.mcap"
    point_cloud = rosmsg.TYPESTORE.types["sensor_msgs/msg/PointCloud"]
    header = rosmsg.TYPESTORE.types["std_msgs/msg/Header"]
    stamp = rosmsg.TYPESTORE.types["builtin_interfaces/msg/Time"]
    with open_log(log) as reader, open_writer(source, LogFormat.MCAP) as writer:
        for raw in reader.messages():
            writer.add_raw(raw)
        cloud = point_cloud(
            header=header(stamp=stamp(sec=0, nanosec=0), frame_id="l"), points=[], channels=[]
        )
        writer.add_message("/features", cloud, 0)
    target = tmp_path / "out.mcap"
    assert cli.main(["densify", str(source), "-o", str(target), *FEATURES]) == 2
    err = capsys.readouterr().err
    assert err == (
        "pcainterp: error: topic /features in vins.mcap has the old type "
        "sensor_msgs/msg/PointCloud (as VINS feature_tracker's features: normalized image "
        "coordinates, depth unknown); --features-topic needs a sensor_msgs/msg/PointCloud2 of "
        "3-D points in metres in the left optical frame (VINS's /vins_estimator/point_cloud, "
        "say, converted to PointCloud2 and transformed into that frame); the log has no topic "
        "of that type\n"
    )
    assert not target.exists()


def _shifted(source: Path, target: Path, topic: str, shift_ns: int) -> Path:
    """Copy a log with the log times (not the header stamps) of one topic moved."""
    with open_log(source) as reader:
        raws = list(reader.messages())
    moved = [
        raw._replace(log_time_ns=raw.log_time_ns + shift_ns) if raw.topic == topic else raw
        for raw in raws
    ]
    with open_writer(target, LogFormat.MCAP) as writer:
        for raw in sorted(moved, key=lambda raw: raw.log_time_ns):
            writer.add_raw(raw)
    return target


@pytest.mark.parametrize(("shift_ms", "order"), [(1000, "after"), (-1000, "before")])
def test_clouds_logged_later_than_the_pairing_holds_are_named_with_the_lag(
    log: Path, tmp_path: Path, shift_ms: int, order: str
) -> None:
    # a SLAM back end's latency (or images through a republisher): the clouds have their
    # images' stamps, logged 1 s apart; here the pairing holds 1 frame and 50 ms of log
    source = _shifted(
        with_features(log, tmp_path / "f.mcap"), tmp_path / "late.mcap", "/features", shift_ms * MS
    )
    processor = ProcessorConfig(source=MeasurementSource.FEATURES)
    pairing = PairingConfig(features_topic="/features")
    summary = jobs.densify(source, tmp_path / "out.mcap", pairing=pairing, processor=processor)
    assert summary.warnings == []
    short = PairingConfig(features_topic="/features", window=1, hold_ns=50 * MS)
    summary = jobs.densify(source, tmp_path / "out2.mcap", pairing=short, processor=processor)
    (line,) = summary.warnings
    held = "a frame for its cloud" if shift_ms > 0 else "a cloud for its frame"
    assert line == (
        "3 of 4 frames got no point from --features-topic /features, so they have no estimate "
        "(depth NaN): 3 had no cloud: the clouds of /features were logged ~1 s "
        f"{order} their images with the same stamps, beyond the 0.05 s of log the pairing "
        f"holds {held}; pass --hold-s 2"
    )
