"""Map a basis onto a log's camera by field of view (a measurement tool).

``densify`` maps a basis onto another camera by stretching: the log's pixel coordinates are
scaled to the basis image size and disparities by the f*b ratio. This tool writes the
alternative, a basis resampled over the angles the log's camera sees: each grid pixel of the
log's camera looks along ((x - cx) / fx, (y - cy) / fy); the basis (mean and components) is
sampled where the basis camera looks along the same ray (bilinear, edges repeated outside the
basis's field of view), disparities scaled by the f*b ratio (d / (f*b) = 1 / depth is the
same at the same ray), the components re-orthonormalised (the covariance they span is kept
exactly: QR then SVD), and the fitted prior's disparity-unit figures scaled the same way
(sigma by the ratio, local kernel and process noise variances by its square, kernel length
by the focal ratio). The result is an ordinary basis file for that camera: use it with
``pcainterp densify LOG --basis FILE`` and compare with ``--basis builtin``.

    python tools/fov_basis.py euroc.mcap euroc_fov.basis.npz            # the built-in basis
    python tools/fov_basis.py euroc.mcap out.npz --basis my.npz --basis-camera 700,700,620,180
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import harness
import numpy as np
import numpy.typing as npt

from pcainterp_stream.errors import PcaInterpError
from pcainterp_stream.estimate.basis import Basis, grid_size_for
from pcainterp_stream.records import StereoCamera

KITTI_GREY = (718.856, 718.856, 607.19, 185.22)
"""fx, fy, cx, cy of the camera the built-in basis was rendered for (px)."""


def log_camera(path: Path) -> StereoCamera:
    """The rectified camera of the log's first stereo pair."""
    from pcainterp_stream.frontend.pairing import PairingConfig, iter_stereo_frames
    from pcainterp_stream.io.logreader import open_log

    with open_log(path) as reader:
        for frame in iter_stereo_frames(reader, PairingConfig()):
            return frame.camera
    raise SystemExit(f"error: {path} has no stereo pair; give a stereo log")


def fov_map(
    basis: Basis, intrinsics: tuple[float, float, float, float], camera: StereoCamera
) -> Basis:
    """Resample ``basis`` (seen by ``intrinsics``) over the angles ``camera`` sees."""
    import cv2

    fx, fy, cx, cy = intrinsics
    height, width = basis.image_size
    gh, gw = basis.grid_size
    grid_scale = gw / width
    dgh, dgw = grid_size_for(camera.image_size, grid_scale)
    rows = (np.arange(dgh) + 0.5) * (camera.height / dgh) - 0.5
    cols = (np.arange(dgw) + 0.5) * (camera.width / dgw) - 0.5
    source_y = fy * (rows - camera.cy) / camera.fy + cy
    source_x = fx * (cols - camera.cx) / camera.fx + cx
    grid_y = ((source_y + 0.5) * (gh / height) - 0.5).astype(np.float32)
    grid_x = ((source_x + 0.5) * (gw / width) - 0.5).astype(np.float32)
    map_x, map_y = np.meshgrid(grid_x, grid_y)
    ratio = camera.focal_baseline / basis.focal_baseline

    def sample(values: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        out = cv2.remap(values, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return np.asarray(out, dtype=np.float32)

    mean = sample(basis.mean) * np.float32(ratio)
    n = basis.n_components
    sampled = np.stack([sample(component) for component in basis.components]).reshape(n, -1)
    spread = sampled.T.astype(np.float64) * (np.sqrt(basis.eigenvalues) * ratio)[None, :]
    q, r = np.linalg.qr(spread)
    v, s, _ = np.linalg.svd(r)
    components = (q @ v).T
    signs = np.sign(components[np.arange(n), np.argmax(np.abs(components), axis=1)])
    components *= signs[:, None]
    eigenvalues = s**2
    unexplained = max(0.0, basis.total_variance - float(basis.eigenvalues.sum()))
    unexplained *= ratio**2 * (dgh * dgw) / (gh * gw)
    meta: dict[str, Any] = json.loads(json.dumps(basis.meta))
    prior = meta.get("prior")
    if isinstance(prior, dict):
        prior["sigma"] = float(prior.get("sigma", 1.0)) * ratio
        prior["process_noise"] = float(prior.get("process_noise", 0.0)) * ratio**2
        if isinstance(prior.get("local"), dict):
            prior["local"]["variance"] *= ratio**2
            prior["local"]["length_scale"] *= camera.fx / fx
    meta["fov_mapped"] = {"from_camera": [fx, fy, cx, cy], "ratio": ratio}
    return Basis(
        mean=mean.astype(np.float32),
        components=components.reshape(n, dgh, dgw).astype(np.float32),
        eigenvalues=eigenvalues,
        total_variance=float(eigenvalues.sum() + unexplained),
        image_size=camera.image_size,
        focal_baseline=camera.focal_baseline,
        n_train=basis.n_train,
        meta=meta,
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Write the field-of-view mapped basis for the log's camera."""
    parser = harness.argument_parser(__doc__)
    parser.add_argument("log", type=Path, help="a stereo log (its first pair's camera)")
    parser.add_argument("out", type=Path, help="the basis file to write (.npz)")
    parser.add_argument("--basis", type=Path, help="a basis file (default: the built-in one)")
    parser.add_argument(
        "--basis-camera",
        default=",".join(map(str, KITTI_GREY)),
        help="fx,fy,cx,cy of the basis's camera (px; default: the built-in basis's)",
    )
    args = parser.parse_args(argv)
    values = tuple(float(v) for v in args.basis_camera.split(","))
    if len(values) != 4:
        parser.error(f"--basis-camera needs fx,fy,cx,cy, got {args.basis_camera!r}")
    try:
        basis = Basis.default() if args.basis is None else Basis.load(args.basis)
        camera = log_camera(args.log)
        mapped = fov_map(basis, (values[0], values[1], values[2], values[3]), camera)
        mapped.save(args.out)
    except (PcaInterpError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    print(f"wrote {args.out}: {camera.width}x{camera.height}, grid {mapped.grid_size}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
