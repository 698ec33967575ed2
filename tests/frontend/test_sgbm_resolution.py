"""``--stereo-downscale auto``: SGBM's resolution chosen per camera (bug hunt 9B F7)."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import pytest

from pcainterp_stream import defaults
from pcainterp_stream.cli.common import add_stereo_options, sgbm_config
from pcainterp_stream.frontend.sgbm_resolution import by_camera
from pcainterp_stream.frontend.stereo import SgbmConfig
from pcainterp_stream.io.outputs import recorded_front_end
from pcainterp_stream.pipeline.densify import densify
from pcainterp_stream.pipeline.jobs import synth
from pcainterp_stream.pipeline.processor import ProcessorConfig

AUTO = ProcessorConfig().sgbm


def test_the_default_is_chosen_per_camera() -> None:
    """Before: densify matched every camera at half resolution (``downscale=2``)."""
    assert AUTO.by_camera
    assert AUTO.downscale == defaults.STEREO_DOWNSCALE == 2
    assert SgbmConfig().by_camera is False  # learn's and evaluate's matcher: as given


@pytest.mark.parametrize(
    ("focal_baseline", "width", "height", "downscale", "why"),
    [
        (23.98, 376, 240, 1, "f*b 24 < 90 px*m"),  # VI-sensor at half size (F7's hall)
        (48.0, 752, 480, 1, "f*b 48 < 90 px*m"),  # EuRoC's VI-sensor
        (9.6, 320, 240, 1, "f*b 9.6 < 90 px*m"),  # depth camera
        (84.0, 1280, 720, 1, "f*b 84 < 90 px*m"),  # the largest images matched whole
        (386.1, 1242, 375, 2, "f*b 386 >= 90 px*m"),  # KITTI keeps half resolution
        (96.5, 310, 94, 2, "f*b 96.5 >= 90 px*m"),
        (60.0, 1920, 1080, 2, "1920x1080 px images"),  # small f*b, but 4x the SGBM
    ],
)
def test_full_resolution_for_small_disparities_on_images_up_to_1280x720(
    focal_baseline: float, width: int, height: int, downscale: int, why: str
) -> None:
    chosen, phrase = by_camera(AUTO, focal_baseline, width, height)
    full_width = downscale == 1  # F6: the left band matched too at full resolution
    assert chosen == replace(AUTO, downscale=downscale, by_camera=False, full_width=full_width)
    resolution = "full" if downscale == 1 else "half"
    assert phrase == f"SGBM at {resolution} resolution (--stereo-downscale auto: {why})"


def test_full_resolution_matches_the_left_band_too() -> None:
    """Bug hunt 9B F6: SGBM left x < 128 empty, a third of a 376 px image, where the prior
    extrapolated (1.6-2.3x nearest's error on indoor halls) and the fit check never looked.
    Before: ``full_width`` stayed off at full resolution."""
    assert by_camera(AUTO, 23.98, 376, 240)[0].full_width
    assert by_camera(AUTO, 23.98, 376, 240)[0].valid_min_x == 0
    assert not by_camera(AUTO, 386.1, 1242, 375)[0].full_width  # KITTI: as before
    assert not by_camera(AUTO, 60.0, 1920, 1080)[0].full_width


def test_a_given_resolution_is_kept_and_not_said() -> None:
    for given in (SgbmConfig(downscale=2), replace(AUTO, downscale=2, by_camera=False)):
        assert by_camera(given, 24.0, 376, 240) == (given, None)
        assert by_camera(given, 386.0, 1242, 375) == (given, None)


def test_a_given_full_resolution_matches_the_left_band_as_auto_s_does() -> None:
    """Review 57c F1: a given ``--stereo-downscale 1`` left SGBM's band empty while ``auto``'s
    full resolution matched it: 0.227 px against auto's 0.059 on a 752x480 indoor log, worse
    than nearest neighbour. Before: returned as given, ``full_width`` off."""
    given = replace(AUTO, downscale=1, by_camera=False)
    auto, _ = by_camera(AUTO, 24.0, 376, 240)
    for focal_baseline, width, height in ((24.0, 376, 240), (386.0, 1242, 375)):
        assert by_camera(given, focal_baseline, width, height) == (auto, None)
    assert by_camera(SgbmConfig(), 386.0, 1242, 375) == (SgbmConfig(full_width=True), None)


def _parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_stereo_options(parser, command="densify")
    return parser.parse_args(list(argv))


def test_the_option_takes_auto_1_and_2() -> None:
    """Before: ``--stereo-downscale`` took 1 or 2 only, and 2 was the default."""
    assert sgbm_config(_parse(), AUTO) == AUTO
    assert sgbm_config(_parse("--stereo-downscale", "auto"), AUTO) == AUTO
    for value in (1, 2):
        given = sgbm_config(_parse("--stereo-downscale", str(value)), AUTO)
        assert given == replace(AUTO, downscale=value, by_camera=False)
    with pytest.raises(SystemExit):
        _parse("--stereo-downscale", "3")


@pytest.fixture(scope="module")
def vi_sensor(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("vi") / "hall.mcap"
    synth(path, frames=2, seed=1, scale=0.5, fmt=None, scene="hall", camera="752x480")
    return path


def test_a_small_disparity_camera_is_matched_at_full_resolution_and_said(
    vi_sensor: Path, tmp_path: Path
) -> None:
    """F7: a VI-sensor (f*b 24 px*m at 376x240) at half resolution had lookups biased by
    +0.3 px and a dense map 1.5x worse than at full resolution. Before: matched at half."""
    out = tmp_path / "auto.mcap"
    summary = densify(vi_sensor, out)
    front_end = recorded_front_end(out)
    assert front_end is not None
    assert (front_end.sgbm["downscale"], front_end.sgbm["by_camera"]) == (1, False)
    assert front_end.sgbm["full_width"] is True  # F6
    note = summary.pairing.camera_note()
    assert note is not None
    said = "SGBM at full resolution (--stereo-downscale auto: f*b 24 < 90 px*m)"
    assert note.endswith(f"f*b 23.98 px*m; {said}")


def test_a_given_full_resolution_is_recorded_with_the_band(vi_sensor: Path, tmp_path: Path) -> None:
    """F1: densify with ``--stereo-downscale 1`` matches the left band (before: it did not)."""
    out = tmp_path / "full.mcap"
    processor = ProcessorConfig(sgbm=replace(AUTO, downscale=1, by_camera=False))
    densify(vi_sensor, out, processor=processor)
    front_end = recorded_front_end(out)
    assert front_end is not None
    assert (front_end.sgbm["downscale"], front_end.sgbm["full_width"]) == (1, True)


def test_a_given_half_resolution_is_kept_and_the_camera_line_unchanged(
    vi_sensor: Path, tmp_path: Path
) -> None:
    out = tmp_path / "half.mcap"
    processor = ProcessorConfig(sgbm=SgbmConfig(downscale=2))  # --stereo-downscale 2
    summary = densify(vi_sensor, out, processor=processor)
    front_end = recorded_front_end(out)
    assert front_end is not None
    assert front_end.sgbm["downscale"] == 2
    note = summary.pairing.camera_note()
    assert note is not None
    assert note.endswith("f*b 23.98 px*m")


def test_the_beyond_range_check_counts_in_the_resolution_chosen(
    vi_sensor: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The check of frames measured beyond SGBM's range was built from the half-resolution
    settings before ``auto`` chose full resolution: --num-disparities 112 read 128 px (half
    resolution's range, a multiple of 32) in its warning and advice. Before: 128."""
    from pcainterp_stream.frontend import frame_checks
    from pcainterp_stream.pipeline import densify as job

    made: list[frame_checks.BeyondRange] = []

    class Kept(frame_checks.BeyondRange):
        def __init__(self, match_range: float, step: int) -> None:
            super().__init__(match_range, step)
            made.append(self)

    monkeypatch.setattr(job, "BeyondRange", Kept)
    config = ProcessorConfig()
    config = replace(config, sgbm=replace(config.sgbm, num_disparities=112))
    densify(vi_sensor, tmp_path / "o.mcap", processor=config)
    ((check,),) = (made,)
    assert (check.match_range, check.step) == (112, 16)
