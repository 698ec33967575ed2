"""Stereo calibration from files, for logs that record no ``CameraInfo``.

Three formats, told apart by their keys:

- ROS ``camera_calibration`` / ``camera_info_manager`` YAML, one file per camera
  (``image_width``, ``camera_matrix``, ``distortion_model``, ``distortion_coefficients``,
  ``rectification_matrix``, ``projection_matrix``): the stereo rectification is in R and P
  already, as in a ``CameraInfo``.
- Kalibr ``camchain.yaml``, one file for both (``cam0``, ``cam1`` with ``intrinsics``,
  ``distortion_model`` radtan or equidistant, ``resolution``; ``cam1.T_cn_cnm1`` maps cam0
  coordinates into cam1's): rectified with ``cv2.stereoRectify`` (``cv2.fisheye.stereoRectify``
  for equidistant). Kalibr numbers the cameras in its ``--topics`` order: the left camera is
  the one with the other to its right (cam1 when ``T_cn_cnm1``'s x translation, cam0's
  centre in cam1's frame, is positive), named ``PATH:cam1`` then, its ``rostopic`` the left.
- EuRoC ``sensor.yaml``, one file per camera (``T_BS``, the camera's pose in the body frame,
  ``intrinsics``, ``distortion_model``, ``resolution``): cam0-to-cam1 is
  inv(T_BS_1) @ T_BS_0, then as Kalibr.

Every file that cannot be used is refused with one line naming the file, the key and the fix.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import yaml

from pcainterp_stream.errors import CalibrationError
from pcainterp_stream.io.camera_model import (
    CameraCalibration,
    StereoCalibration,
    stacked_vertically,
)

_FISHEYE = ("equidistant", "fisheye", "kannala_brandt")


def _read_yaml(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text(encoding="utf-8-sig")  # a byte-order mark, as Notepad saves
    except OSError as err:
        raise CalibrationError(f"cannot read calibration file {path}: {err.strerror}") from err
    except UnicodeDecodeError as err:  # a binary file (an image, a log) given as calibration
        raise CalibrationError(
            f"calibration file {path} is not valid YAML (not UTF-8 text: byte "
            f"0x{err.object[err.start]:02x} at offset {err.start}); pass the calibration YAML"
        ) from err
    # lines left out are blanked, not dropped, so that an error's line is the file's
    lines = ["" if line.strip().startswith("---") else line for line in text.splitlines()]
    head = next((i for i, line in enumerate(lines) if line.strip() and line[0] != "#"), None)
    if head is not None and lines[head].startswith("%YAML"):  # OpenCV's "%YAML:1.0" header
        lines[head] = ""
    text = "\n".join(lines).replace("!!opencv-matrix", "")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise CalibrationError(f"calibration file {path} is not valid YAML ({_said(err)})") from err
    if not isinstance(data, dict):
        raise CalibrationError(
            f"calibration file {path} holds no YAML mapping; expected a camera_info_manager "
            "YAML, a Kalibr camchain.yaml or a EuRoC sensor.yaml"
        )
    return data


def _said(err: yaml.YAMLError) -> str:
    """A YAML error in a few words: what is wrong, and where (line and column, from 1)."""
    if isinstance(err, yaml.MarkedYAMLError) and err.problem_mark is not None:
        mark = err.problem_mark
        what = err.problem or err.context or type(err).__name__
        if "'\\t'" in what:  # PyYAML quotes the character it found
            what += ": YAML separates and indents with spaces, not tabs"
        return f"line {mark.line + 1}, column {mark.column + 1}: {what}"
    return str(err).splitlines()[0] if str(err) else type(err).__name__


def _numbers(
    path: Path, data: dict[str, Any], key: str, count: int | None
) -> npt.NDArray[np.float64]:
    value = data.get(key)
    if isinstance(value, dict):
        value = value.get("data")
    try:
        array = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        array = np.zeros(0)
    if value is None or (count is not None and array.size != count) or not np.isfinite(array).all():
        want = f"{count} finite numbers" if count is not None else "finite numbers"
        raise CalibrationError(
            f"calibration file {path}: key {key!r} is {value!r:.60}, expected {want}; fix the file"
        )
    return array


def _size(path: Path, data: dict[str, Any]) -> tuple[int, int]:
    if "resolution" in data:
        w, h = _numbers(path, data, "resolution", 2)
    else:
        w, h = _numbers(path, data, "image_width", 1)[0], _numbers(path, data, "image_height", 1)[0]
    if not (w >= 1 and h >= 1 and w == int(w) and h == int(h)):
        raise CalibrationError(f"calibration file {path}: image size {w}x{h} is not a size")
    return int(w), int(h)


def camera_info_yaml(path: Path, data: dict[str, Any]) -> CameraCalibration:
    """Read one camera of a ``camera_info_manager`` YAML file."""
    width, height = _size(path, data)
    model = str(data.get("distortion_model", "plumb_bob"))
    d = _numbers(path, data, "distortion_coefficients", None)
    k = _numbers(path, data, "camera_matrix", 9).reshape(3, 3)
    p = _numbers(path, data, "projection_matrix", 12).reshape(3, 4)
    for key, matrix in (("camera_matrix", k), ("projection_matrix", p[:, :3])):
        if not np.any(matrix):
            raise CalibrationError(
                f"calibration file {path}: {key} is all zeros (a camera without a calibration); "
                "pass the files ROS camera_calibration wrote for this camera"
            )
    return CameraCalibration(
        width=width,
        height=height,
        model=model,
        k=k,
        d=d,
        r=_numbers(path, data, "rectification_matrix", 9).reshape(3, 3),
        p=p,
        name=str(path),
    )


def _intrinsics(
    path: Path, data: dict[str, Any]
) -> tuple[str, npt.NDArray[np.float64], npt.NDArray[np.float64], tuple[int, int]]:
    model = str(data.get("camera_model", "pinhole")).lower()
    if model != "pinhole":
        raise CalibrationError(
            f"calibration file {path}: camera_model {model!r} is not supported (pinhole only, "
            "with radtan or equidistant distortion); recalibrate with a pinhole model"
        )
    fu, fv, cu, cv = _numbers(path, data, "intrinsics", 4)
    k = np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])
    distortion = str(data.get("distortion_model", "radtan")).lower()
    key = "distortion_coeffs" if "distortion_coeffs" in data else "distortion_coefficients"
    d = _numbers(path, data, key, None)
    if distortion in _FISHEYE:
        if d.size != 4:
            raise CalibrationError(
                f"calibration file {path}: equidistant distortion needs 4 coefficients, got "
                f"{d.size}"
            )
        model_name = "equidistant"
    elif distortion in ("radtan", "radial-tangential", "plumb_bob"):
        if d.size not in (4, 5, 8):
            raise CalibrationError(
                f"calibration file {path}: radtan distortion needs 4 coefficients, got {d.size}"
            )
        model_name = "plumb_bob"
    else:
        raise CalibrationError(
            f"calibration file {path}: distortion_model {distortion!r} is not supported "
            "(radtan, equidistant); recalibrate with one of those"
        )
    return model_name, k, d, _size(path, data)


def _transform(path: Path, data: dict[str, Any], key: str) -> npt.NDArray[np.float64]:
    t = _numbers(path, data, key, 16).reshape(4, 4)
    rot = t[:3, :3]
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-3) or not np.linalg.det(rot) > 0:
        raise CalibrationError(
            f"calibration file {path}: {key} has no rotation in its upper-left 3x3; fix the file"
        )
    return t


def rectify_pair(
    left: tuple[str, npt.NDArray[np.float64], npt.NDArray[np.float64], tuple[int, int]],
    right: tuple[str, npt.NDArray[np.float64], npt.NDArray[np.float64], tuple[int, int]],
    t_right_left: npt.NDArray[np.float64],
    names: tuple[str, str],
) -> StereoCalibration:
    """Rectify two calibrated cameras: ``t_right_left`` maps left coordinates into the right's.

    Uses ``cv2.stereoRectify`` (``cv2.fisheye.stereoRectify`` for equidistant cameras) with
    zero disparity at infinity and only valid pixels in view.
    """
    model, k1, d1, size = left
    model2, k2, d2, size2 = right
    if model != model2 or size != size2:
        raise CalibrationError(
            f"{names[0]} and {names[1]} describe different cameras ({model} {size[0]}x{size[1]} "
            f"and {model2} {size2[0]}x{size2[1]}); pass the calibration of one stereo pair"
        )
    rot = np.ascontiguousarray(t_right_left[:3, :3])
    trans = np.ascontiguousarray(t_right_left[:3, 3])
    if not np.linalg.norm(trans) > 0:
        raise CalibrationError(f"{names[1]}: the cameras are 0 m apart; fix the extrinsics")
    if model == "equidistant":
        r1, r2, p1, p2, _ = cv2.fisheye.stereoRectify(
            k1,
            d1.reshape(4, 1),
            k2,
            d2.reshape(4, 1),
            size,
            rot,
            trans.reshape(3, 1),
            flags=cv2.CALIB_ZERO_DISPARITY,
            balance=0.0,
            fov_scale=1.0,
        )
    else:
        r1, r2, p1, p2, *_ = cv2.stereoRectify(
            k1, d1, k2, d2, size, rot, trans.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=0
        )
    # stereoRectify puts the whole baseline in Tx or in Ty (the other is 0): no noise floor
    p_left, p_right = np.asarray(p1, np.float64), np.asarray(p2, np.float64)
    vertical = stacked_vertically(p_left, p_right, f"{names[1]} rectified with {names[0]}", least=0)
    if vertical is not None:
        raise CalibrationError(vertical)
    cams = []
    for name, (mod, k, d, (w, h)), r, p in ((names[0], left, r1, p1), (names[1], right, r2, p2)):
        cams.append(CameraCalibration(w, h, mod, k, d, np.asarray(r), np.asarray(p), name=name))
    return StereoCalibration(cams[0], cams[1])


def load_calibration(paths: list[Path]) -> tuple[StereoCalibration, tuple[str, str] | None]:
    """Load a stereo calibration from one Kalibr file or two per-camera files.

    Returns:
        The calibration, and the image topics the file names (Kalibr ``rostopic``), if any.

    Raises:
        CalibrationError: one line naming the file and what is wrong with it.
    """
    if len(paths) == 1:
        path = paths[0]
        data = _read_yaml(path)
        if "cam0" not in data or "cam1" not in data:
            raise CalibrationError(
                f"calibration file {path} has no cam0 and cam1 (Kalibr camchain); pass LEFT.yaml "
                "RIGHT.yaml for per-camera files"
            )
        cam0, cam1 = data["cam0"], data["cam1"]
        if not isinstance(cam0, dict) or not isinstance(cam1, dict):
            raise CalibrationError(f"calibration file {path}: cam0 and cam1 must be mappings")
        if "T_cn_cnm1" not in cam1:
            raise CalibrationError(
                f"calibration file {path}: cam1 has no T_cn_cnm1 (cam0 to cam1 transform)"
            )
        t = _transform(path, cam1, "T_cn_cnm1")
        cams = [(f"{path}:cam0", cam0), (f"{path}:cam1", cam1)]
        if t[0, 3] > 0:
            # Kalibr numbers the cameras in --topics order: cam0's centre lies to cam1's
            # right (x > 0 in cam1's frame), so cam1 is the left camera
            cams.reverse()
            t = np.asarray(np.linalg.inv(t), dtype=np.float64)
        (left_name, left_data), (right_name, right_data) = cams
        calibration = rectify_pair(
            _intrinsics(path, left_data), _intrinsics(path, right_data), t, (left_name, right_name)
        )
        topics = (left_data.get("rostopic"), right_data.get("rostopic"))
        named = (str(topics[0]), str(topics[1])) if all(topics) else None
        return calibration, named
    if len(paths) != 2:
        raise CalibrationError(
            "--calibration takes a Kalibr camchain.yaml or LEFT.yaml RIGHT.yaml, got "
            f"{len(paths)} files"
        )
    left_data, right_data = _read_yaml(paths[0]), _read_yaml(paths[1])
    if "T_BS" in left_data and "T_BS" in right_data:  # EuRoC sensor.yaml
        t_left = _transform(paths[0], left_data, "T_BS")
        t_right = _transform(paths[1], right_data, "T_BS")
        t = np.linalg.inv(t_right) @ t_left
        calibration = rectify_pair(
            _intrinsics(paths[0], left_data),
            _intrinsics(paths[1], right_data),
            t,
            (str(paths[0]), str(paths[1])),
        )
        return calibration, None
    for path, data in ((paths[0], left_data), (paths[1], right_data)):
        if "camera_matrix" not in data:
            raise CalibrationError(
                f"calibration file {path} has no camera_matrix (camera_info_manager YAML) and no "
                "T_BS (EuRoC sensor.yaml); pass the files camera_calibration wrote"
            )
    left = camera_info_yaml(paths[0], left_data)
    right = camera_info_yaml(paths[1], right_data)
    if not left.baseline(right) > 0:
        left_tx = f" (and {paths[0]} Tx = {left.p[0, 3]})" if left.p[0, 3] else ""
        raise CalibrationError(
            f"calibration file {paths[1]}: projection_matrix has Tx = {right.p[0, 3]}{left_tx} "
            "(expected the left Tx - the right Tx = fx * baseline > 0: the right camera of a "
            "stereo calibration); pass LEFT.yaml first, or the files of a stereo calibration"
        )
    return StereoCalibration(left, right), None


def camera_info_message(calibration: CameraCalibration, stamp_ns: int, frame_id: str) -> Any:
    """Build the ``sensor_msgs/msg/CameraInfo`` of a camera as a driver publishes it (raw K, D)."""
    from pcainterp_stream.io import rosmsg

    types = rosmsg.TYPESTORE.types
    x, y, w, h = calibration.roi
    return types[rosmsg.CAMERA_INFO](
        header=rosmsg.header(stamp_ns, frame_id),
        height=calibration.height,
        width=calibration.width,
        distortion_model=calibration.model,
        d=np.asarray(calibration.d, np.float64).copy(),
        k=calibration.k.reshape(-1).copy(),
        r=calibration.r.reshape(-1).copy(),
        p=calibration.p.reshape(-1).copy(),
        binning_x=calibration.binning[0] if calibration.binning[0] > 1 else 0,
        binning_y=calibration.binning[1] if calibration.binning[1] > 1 else 0,
        roi=types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=x, y_offset=y, height=h, width=w, do_rectify=(w, h) != (0, 0)
        ),
    )


def kitti_calibration(path: Path, left: str = "00", right: str = "01") -> StereoCalibration:
    """Read two cameras of a KITTI raw ``calib_cam_to_cam.txt`` as kitti2bag writes them.

    Camera ``xx`` is K_xx, D_xx (plumb_bob), R_rect_xx, P_rect_xx at the raw size S_xx.

    Raises:
        CalibrationError: the file misses a key or a value is not numeric.
    """
    values: dict[str, npt.NDArray[np.float64]] = {}
    try:
        lines = path.read_text().splitlines()
    except OSError as err:
        raise CalibrationError(f"cannot read KITTI calibration {path}: {err.strerror}") from err
    for line in lines:
        key, _, text = line.partition(":")
        try:
            values[key.strip()] = np.array([float(v) for v in text.split()])
        except ValueError:
            continue
    cams = []
    for cam in (left, right):
        try:
            w, h = values[f"S_{cam}"]
            cams.append(
                CameraCalibration(
                    width=int(w),
                    height=int(h),
                    model="plumb_bob",
                    k=values[f"K_{cam}"].reshape(3, 3),
                    d=values[f"D_{cam}"],
                    r=values[f"R_rect_{cam}"].reshape(3, 3),
                    p=values[f"P_rect_{cam}"].reshape(3, 4),
                    name=f"{path.name}:{cam}",
                )
            )
        except (KeyError, ValueError) as err:
            raise CalibrationError(
                f"KITTI calibration {path} misses or garbles camera {cam} ({err}); expected "
                "S_xx, K_xx, D_xx, R_rect_xx and P_rect_xx"
            ) from err
    return StereoCalibration(cams[0], cams[1])
