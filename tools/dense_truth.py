"""Score dense mode against real ground truth (KITTI depth-annotated frames), split at SGBM's holes.

The folder is a KITTI odometry sequence with the depth-completion benchmark's annotations
(``image_2``/``image_3`` the rectified colour pair, ``calib.txt`` with P2/P3,
``image_depth_annotated`` uint16 PNG depth * 256, 0 = no truth). Its pairs are written as a
rectified stereo log and densified by the real job (in this process, as ``pcainterp
densify`` runs it): the default sparse job and ``--measurements dense``. Each map is scored
against the truth (disparity = f b / depth) on the truth pixels, split into the pixels
where full-resolution SGBM (the map dense mode fuses) has a value and its holes, with the
+-2 sigma coverage in both. SGBM itself and SGBM with its holes filled by the nearest valid
value (``evaluate``'s ``sgbm_nn``) are the references.

    python tools/dense_truth.py ../shared/realdata/kitti_depth_annotated_07

Few frames (three in the shared folder) decide nothing alone: read them with the synthetic
drives and the hidden-block test of the real clips (``tools/dense_holdout.py``).
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import harness
import numpy as np
import numpy.typing as npt

from pcainterp_stream.frontend.matchers import DEFAULT_DENSE_MATCHER

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]

ROWS = ("dense", "sparse", "sgbm", "sgbm_nn")
"""The maps scored: the two jobs, SGBM where it matched, SGBM with nearest-filled holes."""


@dataclass
class AnnotatedFrames:
    """The pairs and the truth of a depth-annotated sequence folder.

    Attributes:
        names: the frame file names.
        lefts: (H, W) uint8 left images (the colour images in grey, as the job matches).
        rights: (H, W) uint8 right images.
        truths: (H, W) float64 true disparity (px), NaN where there is no truth.
        camera: the rectified colour pair's calibration.
    """

    names: list[str]
    lefts: list[npt.NDArray[np.uint8]]
    rights: list[npt.NDArray[np.uint8]]
    truths: list[F64]
    camera: object


def read_annotated(folder: Path) -> AnnotatedFrames:
    """Read a depth-annotated KITTI sequence folder (the colour pair P2/P3 and its truth).

    Raises:
        SystemExit: a file is missing or unreadable (the message names it).
    """
    import cv2

    from pcainterp_stream.frontend.stereo import to_grey8
    from pcainterp_stream.records import StereoCamera

    calib = folder / "calib.txt"
    if not calib.is_file():
        raise SystemExit(f"error: {calib} not found; pass a KITTI depth-annotated sequence folder")
    rows: dict[str, F64] = {}
    for line in calib.read_text().splitlines():
        key, _, text = line.partition(":")
        if text.strip():
            rows[key.strip()] = np.array([float(v) for v in text.split()])
    if "P2" not in rows or "P3" not in rows:
        raise SystemExit(f"error: {calib} has no P2/P3 lines (the colour pair)")
    p2, p3 = rows["P2"].reshape(3, 4), rows["P3"].reshape(3, 4)
    names = sorted(p.name for p in (folder / "image_depth_annotated").glob("*.png"))
    if not names:
        raise SystemExit(f"error: no PNG in {folder / 'image_depth_annotated'}")
    frames = AnnotatedFrames(names, [], [], [], None)
    for name in names:
        images = []
        for sub in ("image_2", "image_3"):
            image = cv2.imread(str(folder / sub / name), cv2.IMREAD_COLOR)
            if image is None:
                raise SystemExit(f"error: cannot read {folder / sub / name}")
            images.append(to_grey8(np.ascontiguousarray(image[:, :, ::-1])))
        png = cv2.imread(str(folder / "image_depth_annotated" / name), cv2.IMREAD_UNCHANGED)
        if png is None or png.dtype != np.uint16:
            raise SystemExit(f"error: {folder / 'image_depth_annotated' / name} is not uint16")
        frames.lefts.append(images[0])
        frames.rights.append(images[1])
        depth = png.astype(np.float64) / 256.0
        frames.truths.append(depth)
    height, width = frames.lefts[0].shape[:2]
    fx = float(p2[0, 0])
    camera = StereoCamera(
        width,
        height,
        fx,
        float(p2[1, 1]),
        float(p2[0, 2]),
        float(p2[1, 2]),
        float((p2[0, 3] - p3[0, 3]) / fx),
    )
    frames.camera = camera
    with np.errstate(divide="ignore"):
        frames.truths = [
            np.where(depth > 0, camera.focal_baseline / depth, np.nan) for depth in frames.truths
        ]
    return frames


def write_log(frames: AnnotatedFrames, out: Path) -> None:
    """Write the pairs as a rectified stereo log (mono8 images, 10 Hz stamps)."""
    from pcainterp_stream.io.logwriter import open_writer
    from pcainterp_stream.io.stereo_log import stereo_messages
    from pcainterp_stream.records import StereoCamera

    assert isinstance(frames.camera, StereoCamera)
    with open_writer(out, None) as writer:
        for i, (left, right) in enumerate(zip(frames.lefts, frames.rights, strict=True)):
            stamp = 1_000_000_000 + i * 100_000_000
            for topic, message in stereo_messages(stamp, left, right, frames.camera):
                writer.add_message(topic, message, stamp)


@dataclass
class JobMaps:
    """The maps one densify job produced, per frame, and its wall time."""

    disparity: list[F32] = field(default_factory=list)
    std: list[F32] = field(default_factory=list)
    seconds: float = 0.0


def run_job(log: Path, processor: object, work: Path) -> JobMaps:
    """Densify ``log`` with ``processor`` (a ``ProcessorConfig``) as the command does."""
    from pcainterp_stream.frontend.pairing import PairingConfig
    from pcainterp_stream.pipeline.densify import densify
    from pcainterp_stream.pipeline.processor import ProcessorConfig

    assert isinstance(processor, ProcessorConfig)
    maps = JobMaps()

    def keep(result: object) -> None:
        maps.disparity.append(np.array(result.disparity, np.float32))  # type: ignore[attr-defined]
        maps.std.append(np.array(result.disparity_std, np.float32))  # type: ignore[attr-defined]

    started = time.perf_counter()
    densify(
        log,
        work / "out.mcap",
        pairing=PairingConfig(discover=True),
        processor=processor,
        on_frame=keep,
    )
    maps.seconds = time.perf_counter() - started
    return maps


MATCHERS = ("refined", "full", "split")
"""Dense mode's matchers ``--matcher`` chooses: ``refined`` (``REFINED_DENSE_SGBM``, the
default: half resolution refined at full resolution near it), ``full`` (``DENSE_SGBM``: the
whole range at full resolution) and ``split`` (the near half of the range at half
resolution, ``SgbmConfig.near_at_half``)."""


def dense_matcher(name: str = DEFAULT_DENSE_MATCHER) -> object:
    """Return the ``SgbmConfig`` of dense mode's matcher ``name`` (one of :data:`MATCHERS`)."""
    import dataclasses

    from pcainterp_stream.frontend.matchers import DENSE_MATCHERS, DENSE_SGBM

    if name in DENSE_MATCHERS:
        return DENSE_MATCHERS[name]
    if name == "split":
        return dataclasses.replace(DENSE_SGBM, near_at_half=True)
    raise ValueError(f"unknown matcher {name!r}; one of {', '.join(MATCHERS)}")


def dense_config(
    model: object = None, *, matcher: str = DEFAULT_DENSE_MATCHER, gftt: object = None
) -> object:
    """The processor of ``densify --measurements dense`` (by default its default matcher).

    ``model``: a ``DenseModel`` in place of the default one; ``matcher``: one of
    :data:`MATCHERS`; ``gftt``: the sparse estimate's points (None: densify's own,
    ``dense_points()``).
    """
    from pcainterp_stream.estimate.dense import DenseModel
    from pcainterp_stream.frontend.matchers import dense_points
    from pcainterp_stream.frontend.stereo import GfttConfig, SgbmConfig
    from pcainterp_stream.pipeline.processor import ProcessorConfig

    assert model is None or isinstance(model, DenseModel)
    assert gftt is None or isinstance(gftt, GfttConfig)
    sgbm = dense_matcher(matcher)
    assert isinstance(sgbm, SgbmConfig)
    return ProcessorConfig(
        measurements="dense", sgbm=sgbm, gftt=gftt or dense_points(), dense=model or DenseModel()
    )


@dataclass
class Scores:
    """Sums over the truth pixels of one map: split at SGBM's holes."""

    pixels: dict[str, float] = field(default_factory=lambda: {"valid": 0.0, "holes": 0.0})
    error: dict[str, float] = field(default_factory=lambda: {"valid": 0.0, "holes": 0.0})
    inside: dict[str, float] = field(default_factory=lambda: {"valid": 0.0, "holes": 0.0})
    over3: dict[str, float] = field(default_factory=lambda: {"valid": 0.0, "holes": 0.0})
    has_std: bool = False

    def add(self, estimate: F32, std: F32 | None, truth: F64, valid: npt.NDArray[np.bool_]) -> None:
        """Add one frame: ``valid`` is where SGBM matched."""
        known = np.isfinite(truth)
        error = np.abs(estimate.astype(np.float64) - truth)
        error = np.where(np.isfinite(error), error, np.inf)  # no estimate counts as far off
        for part, mask in (("valid", known & valid), ("holes", known & ~valid)):
            self.pixels[part] += float(mask.sum())
            self.error[part] += float(error[mask].sum())
            self.over3[part] += float((error[mask] > 3.0).sum())
            if std is not None:
                self.has_std = True
                self.inside[part] += float((error[mask] <= 2.0 * std[mask]).sum())

    def mean(self, part: str | None = None) -> float:
        """Mean abs. error (px) in a part (``valid``/``holes``) or over all truth pixels."""
        parts = ("valid", "holes") if part is None else (part,)
        count = sum(self.pixels[p] for p in parts)
        return sum(self.error[p] for p in parts) / count if count else float("nan")

    def coverage(self, part: str) -> float:
        """Share of the truth within +-2 std in a part (NaN without a std)."""
        if not self.has_std or not self.pixels[part]:
            return float("nan")
        return self.inside[part] / self.pixels[part]

    def share_over3(self, part: str) -> float:
        """Share of the part's truth pixels off by more than 3 px."""
        return self.over3[part] / self.pixels[part] if self.pixels[part] else float("nan")


def score(frames: AnnotatedFrames, jobs: dict[str, JobMaps]) -> dict[str, Scores]:
    """Score every job's maps and the two SGBM references on the truth pixels."""
    from pcainterp_stream.evaluate.metrics import fill_nearest
    from pcainterp_stream.frontend.stereo import SgbmConfig, compute_disparity

    results = {name: Scores() for name in (*jobs, "sgbm", "sgbm_nn")}
    for i, truth in enumerate(frames.truths):
        sgbm = compute_disparity(frames.lefts[i], frames.rights[i], SgbmConfig())
        with np.errstate(invalid="ignore"):
            valid = np.isfinite(sgbm) & (sgbm >= 0)
        sgbm = np.where(valid, sgbm, np.float32(np.nan)).astype(np.float32)
        filled = fill_nearest(sgbm)
        assert filled is not None
        for name, maps in jobs.items():
            results[name].add(maps.disparity[i], maps.std[i], truth, valid)
        results["sgbm"].add(sgbm, None, np.where(valid, truth, np.nan), valid)
        results["sgbm_nn"].add(filled, None, truth, valid)
    return results


def print_table(results: dict[str, Scores], reference: str = "sgbm_nn") -> None:
    """Print the Markdown table of the scores."""
    base = results[reference].mean()
    share = results[reference].pixels["holes"] / max(
        results[reference].pixels["holes"] + results[reference].pixels["valid"], 1.0
    )
    print(
        harness.table_header(
            [
                "map",
                "all truth px",
                f"x {reference}",
                "SGBM's pixels",
                f"SGBM's holes ({100 * share:.1f} %)",
                "holes > 3 px",
                "+-2 sigma valid",
                "+-2 sigma holes",
            ]
        )
    )
    for name, scores in results.items():
        whole = scores.mean() if scores.pixels["holes"] else float("nan")
        print(
            harness.table_row(
                [
                    name,
                    _figure(whole, "{:.3f}"),
                    _figure(whole / base, "{:.3f}"),
                    _figure(scores.mean("valid"), "{:.3f}"),
                    _figure(scores.mean("holes"), "{:.3f}"),
                    _figure(100 * scores.share_over3("holes"), "{:.1f} %"),
                    _figure(100 * scores.coverage("valid"), "{:.1f} %"),
                    _figure(100 * scores.coverage("holes"), "{:.1f} %"),
                ]
            )
        )


def _figure(value: float, form: str) -> str:
    return "-" if not np.isfinite(value) else form.format(value)


def main(argv: Sequence[str] | None = None) -> int:
    """Print the table of docs/dense.md (real ground truth, split at SGBM's holes)."""
    from pcainterp_stream.pipeline.processor import ProcessorConfig

    parser = harness.argument_parser(__doc__)
    parser.add_argument(
        "folder",
        type=Path,
        help="a KITTI depth-annotated sequence folder (image_2, image_3, calib.txt, "
        "image_depth_annotated)",
    )
    parser.add_argument(
        "--matcher",
        choices=MATCHERS,
        default=DEFAULT_DENSE_MATCHER,
        help="dense mode's matcher: refined (half resolution refined at full resolution near "
        "it, the default), full (the whole range at full resolution, --dense-matcher full), "
        "split (the near half of the range at half resolution; measured only)",
    )
    harness.add_dense_points(parser)
    args = parser.parse_args(argv)
    if not args.folder.is_dir():
        parser.error(f"{args.folder} is not a folder; pass a KITTI depth-annotated sequence")
    frames = read_annotated(args.folder)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        log = work / "annotated.mcap"
        write_log(frames, log)
        jobs = {
            "dense": run_job(
                log, dense_config(matcher=args.matcher, gftt=harness.dense_points(args)), work
            ),
            "sparse": run_job(log, ProcessorConfig(), work),
        }
    print(f"{len(frames.names)} frames of {args.folder}\n")
    print_table(score(frames, jobs))
    print(f"\n{matching_cost(frames)}")
    return 0


def matching_cost(frames: AnnotatedFrames, rounds: int = 5) -> str:
    """Time dense mode's matchers against plain SGBM, rounds interleaved (CPU per frame)."""
    from pcainterp_stream.frontend.stereo import SgbmConfig, compute_disparity

    configs = {"plain": SgbmConfig(), **{name: dense_matcher(name) for name in MATCHERS}}
    seconds: dict[str, list[float]] = {name: [] for name in configs}
    for _ in range(rounds):
        for name, config in configs.items():
            assert isinstance(config, SgbmConfig)
            started = time.process_time()
            for left, right in zip(frames.lefts, frames.rights, strict=True):
                compute_disparity(left, right, config)
            seconds[name].append(time.process_time() - started)
    per_frame = {name: min(values) / len(frames.lefts) for name, values in seconds.items()}
    plain = per_frame["plain"]
    return (
        f"matching CPU per frame, best of {rounds}: plain SGBM {1000 * plain:.0f} ms; dense "
        f"mode's matchers (left band too): full {1000 * per_frame['full']:.0f} ms "
        f"({per_frame['full'] / plain:.2f}x), refined from half resolution "
        f"{1000 * per_frame['refined']:.0f} ms ({per_frame['refined'] / plain:.2f}x), near "
        f"half at half resolution {1000 * per_frame['split']:.0f} ms "
        f"({per_frame['split'] / plain:.2f}x)"
    )


if __name__ == "__main__":
    raise SystemExit(main())
