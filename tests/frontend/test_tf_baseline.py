"""The /tf_static baseline quoted when the right camera info has no Tx (bug hunt 16G F3)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from pcainterp_stream.frontend.discovery import resolve_pairing
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.records import StereoCamera

CAMERA = StereoCamera(width=160, height=60, fx=100.0, fy=100.0, cx=80.0, cy=30.0, baseline=0.5)
_T = rosmsg.TYPESTORE.types


def _transform(parent: str, child: str, xyz: tuple[float, float, float], q: Any) -> Any:
    return _T["geometry_msgs/msg/TransformStamped"](
        header=rosmsg.header(0, parent),
        child_frame_id=child,
        transform=_T["geometry_msgs/msg/Transform"](
            translation=_T["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]),
            rotation=_T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        ),
    )


def _log(path: Path, *, tx: bool = False, tf: bool = True) -> Path:
    """A raw pair whose infos have no Tx; /tf_static: base -> left (turned), base -> right."""
    image = np.random.default_rng(1).integers(0, 256, (60, 160), np.uint8)
    half = np.sqrt(0.5)
    with open_writer(path, "mcap") as writer:
        if tf:  # the right camera 0.5372 m along the left optical frame's x, via base_link
            left = _transform("base_link", "left_optical", (0.1, 0.2, 1.0), (-0.5, 0.5, -0.5, 0.5))
            right_in_base = (0.1, 0.2 - 0.5372, 1.0)  # the optical x is base's -y
            right = _transform("base_link", "right_optical", right_in_base, (0, 0, half, half))
            tfs = _T["tf2_msgs/msg/TFMessage"](transforms=[left, right])
            writer.add_message("/tf_static", tfs, 1)
        for side in ("left", "right"):
            camera = CAMERA if tx else dataclasses.replace(CAMERA, baseline=0.0)
            info = rosmsg.camera_info_message(camera, 1, f"{side}_optical", right=side == "right")
            writer.add_message(f"/cam/{side}/camera_info", info, 1)
            msg = rosmsg.image_message(image, 1, f"{side}_optical")
            writer.add_message(f"/cam/{side}/image_raw", msg, 1)
    return path


def _lines(path: Path) -> list[str]:
    said: list[str] = []
    with open_log(path) as reader:
        resolve_pairing(reader, PairingConfig(discover=True), said.append)
    return said


def test_the_tf_static_baseline_is_quoted_when_the_right_info_has_no_tx(tmp_path: Path) -> None:
    """Bug hunt 16G F3: "pass --baseline METRES" with the baseline in /tf_static unsaid."""
    said = _lines(_log(tmp_path / "tf.mcap"))
    assert said[-1] == (
        "baseline: /cam/right/camera_info has no Tx (P[0,3] = 0); pass --baseline 0.5372 "
        "(the /tf_static transform from left_optical to right_optical)"
    )


def test_no_baseline_line_with_tx_or_without_tf_static(tmp_path: Path) -> None:
    assert not any(s.startswith("baseline:") for s in _lines(_log(tmp_path / "a.mcap", tx=True)))
    no_tf = _log(tmp_path / "b.mcap", tf=False)
    assert not any(s.startswith("baseline:") for s in _lines(no_tf))
