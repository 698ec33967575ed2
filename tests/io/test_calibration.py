"""Stereo calibration files: camera_info_manager YAML, Kalibr camchain, EuRoC sensor.yaml."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import yaml

from pcainterp_stream.errors import CalibrationError
from pcainterp_stream.frontend.rectify import StereoCalibration, StereoRectifier
from pcainterp_stream.io.calibration import load_calibration
from pcainterp_stream.records import StereoCamera
from pcainterp_stream.synth.raw import raw_calibration

REALDATA = Path(__file__).resolve().parents[3] / "shared" / "realdata"
CAMERA = StereoCamera(width=320, height=120, fx=180.0, fy=180.0, cx=158.0, cy=60.0, baseline=0.5)


def _matrix(values: np.ndarray, rows: int, cols: int) -> dict[str, object]:
    return {"rows": rows, "cols": cols, "data": [float(v) for v in values.reshape(-1)]}


def write_camera_info_yaml(calibration: StereoCalibration, folder: Path) -> tuple[Path, Path]:
    """Write the pair as camera_calibration writes it (one file per camera)."""
    paths = []
    for side, cal in (("left", calibration.left), ("right", calibration.right)):
        data = {
            "image_width": cal.width,
            "image_height": cal.height,
            "camera_name": side,
            "camera_matrix": _matrix(cal.k, 3, 3),
            "distortion_model": cal.model,
            "distortion_coefficients": _matrix(cal.d, 1, cal.d.size),
            "rectification_matrix": _matrix(cal.r, 3, 3),
            "projection_matrix": _matrix(cal.p, 3, 4),
        }
        path = folder / f"{side}.yaml"
        path.write_text(yaml.safe_dump(data))
        paths.append(path)
    return paths[0], paths[1]


def write_camchain(calibration: StereoCalibration, path: Path, model: str = "radtan") -> Path:
    """Write the pair as a Kalibr camchain.yaml (cam1's T_cn_cnm1 from the rectification)."""
    left, right = calibration.left, calibration.right
    baseline = -right.p[0, 3] / right.p[0, 0]
    t = np.eye(4)
    t[:3, :3] = right.r.T @ left.r
    t[:3, 3] = -right.r.T @ np.array([baseline, 0.0, 0.0])
    data = {}
    for name, cal in (("cam0", left), ("cam1", right)):
        data[name] = {
            "camera_model": "pinhole",
            "intrinsics": [
                float(cal.k[0, 0]),
                float(cal.k[1, 1]),
                float(cal.k[0, 2]),
                float(cal.k[1, 2]),
            ],
            "distortion_model": model,
            "distortion_coeffs": [float(v) for v in cal.d[:4]],
            "resolution": [cal.width, cal.height],
            "rostopic": f"/{name}/image_raw",
        }
    data["cam1"]["T_cn_cnm1"] = t.tolist()
    path.write_text(yaml.safe_dump(data))
    return path


def test_camera_info_manager_pair_round_trips(tmp_path: Path) -> None:
    calibration = raw_calibration(CAMERA, "plumb_bob")
    loaded, topics = load_calibration(list(write_camera_info_yaml(calibration, tmp_path)))
    assert topics is None
    assert loaded.key() != b""
    for a, b in ((loaded.left, calibration.left), (loaded.right, calibration.right)):
        np.testing.assert_allclose(a.k, b.k)
        np.testing.assert_allclose(a.d, b.d)
        np.testing.assert_allclose(a.p, b.p)


@pytest.mark.parametrize(
    ("model", "distortion"), [("plumb_bob", "radtan"), ("equidistant", "equidistant")]
)
def test_kalibr_camchain_is_stereo_rectified(tmp_path: Path, model: str, distortion: str) -> None:
    calibration = raw_calibration(CAMERA, model)
    path = write_camchain(calibration, tmp_path / "camchain.yaml", distortion)
    loaded, topics = load_calibration([path])
    assert topics == ("/cam0/image_raw", "/cam1/image_raw")
    assert loaded.left.model == model
    rectifier = StereoRectifier(loaded)
    assert rectifier.camera.baseline == pytest.approx(CAMERA.baseline, rel=1e-6)
    # the rectifying rotations make both optical axes parallel: R_l R_l0^T is one rotation
    # about the baseline's x axis away from ours
    np.testing.assert_allclose(
        loaded.right.r @ calibration.right.r.T, loaded.left.r @ calibration.left.r.T, atol=1e-6
    )


def test_a_camchain_whose_cam0_is_the_right_camera_is_read_the_right_way_round(
    tmp_path: Path,
) -> None:
    # bug hunt 7A F14: Kalibr numbers the cameras in --topics order; a camchain with cam0 the
    # right camera gave "no baseline ... pass --baseline", then "swapped", then "not rectified"
    calibration = raw_calibration(CAMERA, "plumb_bob")
    path = write_camchain(calibration, tmp_path / "camchain.yaml")
    data = yaml.safe_load(path.read_text())
    t = np.linalg.inv(np.array(data["cam1"].pop("T_cn_cnm1")))  # right -> left
    data["cam0"], data["cam1"] = data["cam1"], {**data["cam0"], "T_cn_cnm1": t.tolist()}
    data["cam0"]["rostopic"], data["cam1"]["rostopic"] = "/cam0/image_raw", "/cam1/image_raw"
    assert t[0, 3] == pytest.approx(CAMERA.baseline, rel=1e-3)  # cam0 lies to cam1's right
    path.write_text(yaml.safe_dump(data))
    loaded, topics = load_calibration([path])
    assert topics == ("/cam1/image_raw", "/cam0/image_raw")
    assert (loaded.left.name, loaded.right.name) == (f"{path}:cam1", f"{path}:cam0")
    np.testing.assert_allclose(loaded.left.k, calibration.left.k)
    rectifier = StereoRectifier(loaded)
    assert rectifier.camera.baseline == pytest.approx(CAMERA.baseline, rel=1e-6)


@pytest.mark.skipif(not REALDATA.is_dir(), reason="../shared/realdata is absent")
@pytest.mark.parametrize(
    ("folder", "left", "right", "model"),
    [
        ("euroc_machine_hall", "sensorLeft.yaml", "sensorRight.yaml", "plumb_bob"),
        ("mynteye_fisheye", "left_sensor_fisheye.yaml", "right_sensor_fisheye.yaml", "equidistant"),
    ],
)
def test_euroc_sensor_yaml_rectifies_real_pairs(
    folder: str, left: str, right: str, model: str
) -> None:
    import cv2

    from pcainterp_stream.frontend.rectify import correspondences, row_offset

    base = REALDATA / folder
    if not (base / left).is_file():
        pytest.skip(f"{base} is absent")
    calibration, _ = load_calibration([base / left, base / right])
    assert calibration.left.model == model
    rectifier = StereoRectifier(calibration)
    assert 0.1 < rectifier.camera.baseline < 0.13
    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(base.glob("*.png"))[:2]]
    names = sorted(p.name for p in base.glob("*.png"))
    left_image = cv2.imread(str(base / next(n for n in names if n.startswith("left"))), 0)
    right_image = cv2.imread(str(base / next(n for n in names if n.startswith("right"))), 0)
    assert images
    raw = row_offset(correspondences(left_image, right_image))
    fixed = row_offset(correspondences(*rectifier.rectify(left_image, right_image)))
    assert raw.median_abs_dy > 5
    assert fixed.median_abs_dy < 0.5
    assert fixed.median_dx > 0


def _bad(tmp_path: Path, text: str, name: str = "bad.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _binary(tmp_path: Path) -> Path:
    path = tmp_path / "image.png"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff")
    return path


@pytest.mark.parametrize(
    ("make", "expected"),
    [
        (lambda d: [d / "missing.yaml", d / "missing2.yaml"], "cannot read calibration file"),
        (lambda d: [_bad(d, "a: [1, 2\n")], "is not valid YAML"),
        (lambda d: [_binary(d), _binary(d)], "is not valid YAML (not UTF-8 text: byte 0x89"),
        (lambda d: [_bad(d, "- 1\n- 2\n")], "holds no YAML mapping"),
        (lambda d: [_bad(d, "cam0: {}\n")], "has no cam0 and cam1"),
        (lambda d: [_bad(d, "cam0: {}\ncam1: {}\n")], "cam1 has no T_cn_cnm1"),
        (lambda d: [_bad(d, "x: 1\n"), _bad(d, "y: 2\n", "b.yaml")], "has no camera_matrix"),
        (lambda d: [d / "a", d / "b", d / "c"], "got 3 files"),
    ],
)
def test_bad_files_are_refused_in_one_line(tmp_path: Path, make: object, expected: str) -> None:
    with pytest.raises(CalibrationError) as err:
        load_calibration(make(tmp_path))  # type: ignore[operator]
    assert expected in str(err.value)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (("camera_matrix", {"rows": 3, "cols": 3, "data": [1, 2]}), "'camera_matrix'"),
        (("distortion_model", "kb4"), "distortion model 'kb4'"),
        (
            ("projection_matrix", {"rows": 3, "cols": 4, "data": [float("nan")] * 12}),
            "'projection_matrix'",
        ),
        (("image_width", -3), "is not a size"),
    ],
)
def test_bad_camera_info_yaml_values(
    tmp_path: Path, change: tuple[str, object], expected: str
) -> None:
    left, right = write_camera_info_yaml(raw_calibration(CAMERA, "plumb_bob"), tmp_path)
    data = yaml.safe_load(right.read_text())
    data[change[0]] = change[1]
    right.write_text(yaml.safe_dump(data))
    with pytest.raises(CalibrationError) as err:
        load_calibration([left, right])
    assert expected in str(err.value)
    assert "\n" not in str(err.value)


def test_left_and_right_files_swapped_are_refused(tmp_path: Path) -> None:
    left, right = write_camera_info_yaml(raw_calibration(CAMERA, "plumb_bob"), tmp_path)
    with pytest.raises(CalibrationError, match=r"pass LEFT\.yaml first"):
        load_calibration([right, left])


def test_camera_info_yaml_with_a_left_tx(tmp_path: Path) -> None:
    """A pair calibrated against a third camera: both P have a Tx; the baseline is their gap."""
    calibration = raw_calibration(CAMERA, "plumb_bob")
    sides = []
    for cal in (calibration.left, calibration.right):
        p = cal.p.copy()
        p[0, 3] += 0.6 * CAMERA.fx  # the right Tx is positive too (it was refused as swapped)
        sides.append(dataclasses.replace(cal, p=p))
    loaded, _ = load_calibration(list(write_camera_info_yaml(StereoCalibration(*sides), tmp_path)))
    assert loaded.right.p[0, 3] > 0
    assert StereoRectifier(loaded).camera.baseline == pytest.approx(CAMERA.baseline)
    with pytest.raises(CalibrationError, match=r"pass LEFT\.yaml first"):
        load_calibration(list(write_camera_info_yaml(StereoCalibration(*sides[::-1]), tmp_path)))


def test_uncalibrated_camera_info_yaml_is_refused(tmp_path: Path) -> None:
    left_path, right_path = write_camera_info_yaml(raw_calibration(CAMERA, "plumb_bob"), tmp_path)
    data = yaml.safe_load(left_path.read_text())
    data["camera_matrix"]["data"] = [0.0] * 9
    data["projection_matrix"]["data"] = [0.0] * 12
    left_path.write_text(yaml.safe_dump(data))
    with pytest.raises(CalibrationError, match="camera_matrix is all zeros") as err:
        load_calibration([left_path, right_path])
    assert "\n" not in str(err.value)


def test_a_camchain_stacked_vertically_is_refused_in_the_camera_infos_words(
    tmp_path: Path,
) -> None:
    """Review 15a R5: one test of a vertical pair (io.camera_model.stacked_vertically)."""
    calibration = raw_calibration(CAMERA, "plumb_bob")
    path = write_camchain(calibration, tmp_path / "camchain.yaml")
    data = yaml.safe_load(path.read_text())
    t = np.array(data["cam1"]["T_cn_cnm1"])
    t[:3, :3], t[:3, 3] = np.eye(3), [0.0, -CAMERA.baseline, 0.0]  # cam1 below cam0
    data["cam1"]["T_cn_cnm1"] = t.tolist()
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(CalibrationError) as err:
        load_calibration([path])
    message = str(err.value)
    assert message.startswith(f"{path}:cam1 rectified with {path}:cam0 has P[1,3] = ")
    assert "the cameras are stacked vertically (baseline mostly along y)" in message
    assert "\n" not in message


def test_a_byte_order_mark_and_a_comment_above_an_opencv_header_are_read(
    tmp_path: Path,
) -> None:
    """Bug hunt 17C F7: a `%YAML:1.0` file saved with a byte-order mark (Notepad), or with a
    comment line above its header, was refused: "not valid YAML (while scanning a
    directive)"."""
    calibration = raw_calibration(CAMERA, "plumb_bob")
    left, right = write_camera_info_yaml(calibration, tmp_path)
    text = left.read_text()
    left.write_text("\ufeff# calibrated on the bench\n%YAML:1.0\n---\n" + text, encoding="utf-8")
    right.write_text("\ufeff%YAML:1.0\n" + right.read_text(), encoding="utf-8")
    loaded, _ = load_calibration([left, right])
    np.testing.assert_allclose(loaded.left.k, calibration.left.k)


def test_a_yaml_error_names_its_line_and_column(tmp_path: Path) -> None:
    """Bug hunt 17C F7: "not valid YAML (while scanning for the next token)" for a tab, with
    no line, column or culprit."""
    calibration = raw_calibration(CAMERA, "plumb_bob")
    left, right = write_camera_info_yaml(calibration, tmp_path)
    lines = left.read_text().splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith("image_height"))
    lines[at] = lines[at].replace(": ", ":\t", 1)
    left.write_text("%YAML:1.0\n" + "\n".join(lines) + "\n")
    with pytest.raises(CalibrationError) as caught:
        load_calibration([left, right])
    said = str(caught.value)
    assert f"is not valid YAML (line {at + 2}, column " in said
    assert "found character '\\t' that cannot start any token" in said
    assert "spaces, not tabs" in said
