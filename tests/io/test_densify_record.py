"""The ``pcainterp.densify`` record: the basis the channels name, option values, the front end."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from pcainterp_stream import cli
from pcainterp_stream.cli.common import sgbm_config
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.frontend.stereo import SgbmConfig, SgbmMode
from pcainterp_stream.io.densify_record import DENSIFY_RECORD, FrontEnd
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.io.outputs import (
    BASES_RECORD,
    BASIS_FINGERPRINT_KEY,
    BASIS_KEY,
    recorded_bases,
    recorded_front_end,
    recorded_metadata,
)
from pcainterp_stream.pipeline.densify import densify, own_basis_path
from pcainterp_stream.pipeline.jobs import synth
from pcainterp_stream.pipeline.processor import ProcessorConfig
from pcainterp_stream.synth import SynthConfig
from pcainterp_stream.synth.raw import RawDrive, write_raw_log

RAW = SynthConfig(seed=2, frames=3, scale=0.25)


def _record(path: Path) -> dict[str, str]:
    with path.open("rb") as stream:
        (record,) = [m for m in make_reader(stream).iter_metadata() if m.name == DENSIFY_RECORD]
    return dict(record.metadata)


def _matcher(sgbm: dict[str, Any]) -> SgbmConfig:
    """The matcher of recorded SGBM settings, as FrontEnd.sgbm's docstring says."""
    return SgbmConfig(**{**sgbm, "mode": SgbmMode[sgbm["mode"].upper()]})


@pytest.fixture(scope="module")
def raw_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("raw") / "raw.bag"
    write_raw_log(RAW, path, model="plumb_bob")
    return path


def test_the_record_names_the_adapted_basis_the_channels_name(tmp_path: Path) -> None:
    """Before: written before the fit check decided, it said ``built-in`` on a log whose
    channels name ``OUTPUT.basis.npz``."""
    log, out = tmp_path / "room.mcap", tmp_path / "room_dense.mcap"
    synth(log, frames=8, seed=1, scale=0.25, fmt=None, scene="indoor", camera="752x480")
    summary = densify(log, out, processor=ProcessorConfig(builtin="street"))
    assert summary.basis_written == own_basis_path(out)  # adapted
    record, channels = _record(out), recorded_metadata(out)
    assert record["basis"] == channels[BASIS_KEY] == own_basis_path(out).name
    assert record["basis_fingerprint"] == channels[BASIS_FINGERPRINT_KEY]
    assert record["basis_fingerprint"] == recorded_bases(out)[0].fingerprint
    assert BASES_RECORD in record["basis_scope"]
    with out.open("rb") as stream:  # written at the end, before the bases in force
        names = [m.name for m in make_reader(stream).iter_metadata()]
    assert names == [DENSIFY_RECORD, BASES_RECORD]


def test_the_front_end_and_the_options_read_back_as_given(
    capsys: pytest.CaptureFixture[str], raw_bag: Path, tmp_path: Path
) -> None:
    """--rectify never and SGBM flags: recorded so that evaluate can match as densify did.

    Before: the record had no front end, and its options held enum reprs
    (``"SgbmMode.HH"``, ``"MeasurementSource.STEREO"``) that no option takes.
    """
    out = tmp_path / "never.mcap"
    flags = ["--rectify", "never", "--sgbm-mode", "hh", "--num-disparities", "32"]
    flags += ["--block-size", "7", "--stereo-downscale", "1"]
    assert cli.main(["densify", str(raw_bag), "-o", str(out), *flags]) == 0, capsys.readouterr()
    used = SgbmConfig(num_disparities=32, block_size=7, mode=SgbmMode.HH, downscale=1)
    front_end = recorded_front_end(out)
    assert front_end is not None
    assert (front_end.rectify, front_end.images) == ("never", "as recorded")
    assert (front_end.remapped_pairs, front_end.pairs) == (0, RAW.frames)
    assert (front_end.calibration, front_end.calibration_files) == ("camera_info", ())
    assert front_end.calibration_values is None
    assert (front_end.left_topic, front_end.right_info_topic) == (
        "/camera/left/image_raw",
        "/camera/right/camera_info",
    )
    assert (front_end.source, front_end.features_topic, front_end.baseline) == (
        "stereo",
        None,
        None,
    )
    assert front_end.stamp_tolerance_ns == 1_000_000
    sgbm = front_end.sgbm
    assert sgbm["mode"] == "hh"
    assert _matcher(sgbm) == dataclasses.replace(used, full_width=True)  # review 57c F1: at 1,
    # the left band too (densify's by_camera adds it to the parsed matcher below)
    # the values are the command line's: its own parsing of them gives the same matcher
    again = argparse.Namespace(
        num_disparities=sgbm["num_disparities"],
        block_size=sgbm["block_size"],
        sgbm_mode=sgbm["mode"],
        stereo_downscale=sgbm["downscale"],
    )
    assert sgbm_config(again) == used
    processor = json.loads(_record(out)["processor"])
    assert (processor["sgbm"]["mode"], processor["source"]) == ("hh", "stereo")
    assert json.loads(_record(out)["pairing"])["rectify"] == "never"
    assert FrontEnd.from_json(front_end.to_json()) == front_end

    auto = tmp_path / "auto.mcap"  # the default: the raw pair remapped from its camera infos
    assert cli.main(["densify", str(raw_bag), "-o", str(auto)]) == 0, capsys.readouterr()
    front_end = recorded_front_end(auto)
    assert front_end is not None
    assert (front_end.rectify, front_end.images) == ("auto", "remapped")
    assert front_end.remapped_pairs == front_end.pairs == RAW.frames
    # --stereo-downscale auto, recorded as chosen: half resolution (f*b ~97 px*m at 0.25 scale)
    chosen = dataclasses.replace(ProcessorConfig().sgbm, downscale=2, by_camera=False)
    assert _matcher(front_end.sgbm) == chosen
    assert recorded_front_end(raw_bag) is None  # a log densify did not write


def test_calibration_files_are_recorded_with_their_values(raw_bag: Path, tmp_path: Path) -> None:
    """A log without camera infos densified with --calibration: evaluate needs no file."""
    bare, out = tmp_path / "bare.mcap", tmp_path / "files.mcap"
    with open_log(raw_bag) as reader, open_writer(bare, None) as writer:
        for raw in reader.messages():
            if not raw.topic.endswith("camera_info"):
                writer.add_raw(raw)
    calibration = RawDrive(RAW, "plumb_bob").calibration
    densify(bare, out, pairing=PairingConfig(discover=True, calibration=calibration))
    front_end = recorded_front_end(out)
    assert front_end is not None
    assert (front_end.calibration, front_end.images) == ("files", "remapped")
    assert front_end.calibration_files == (calibration.left.name, calibration.right.name)
    assert front_end.calibration_values is not None
    assert front_end.calibration_values.key() == calibration.key()
    assert front_end.calibration_values.left.model == calibration.left.model


def test_a_front_end_of_another_form_is_refused() -> None:
    text = json.dumps({"rectify": "auto"})
    with pytest.raises(ValueError, match=r"^not a front_end of pcainterp.densify: no left_topic"):
        FrontEnd.from_json(text)
