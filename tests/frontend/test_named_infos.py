"""Image topics named on the command line: each image is read with its own camera info.

A robot with a ``/stereo`` head (``stereo_image_proc``'s namespace, the one ``synth`` writes)
and another one: ``--left-topic /front/left/image_rect --right-topic /front/right/image_rect``
reads ``/front/*/camera_info``, not the default ``/stereo/*/camera_info`` (bug hunt 13B F1:
the second head was densified with the first head's calibration, or refused for its size).
"""

from __future__ import annotations

import argparse
import dataclasses
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from pcainterp_stream import cli
from pcainterp_stream.cli import pairing as cli_pairing
from pcainterp_stream.errors import CalibrationError
from pcainterp_stream.frontend.camera_infos import camera_from_infos
from pcainterp_stream.frontend.discovery import resolve_pairing
from pcainterp_stream.frontend.images import PairImages
from pcainterp_stream.frontend.pairing import PairingConfig, iter_stereo_frames
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.io.reader_base import TopicInfo
from pcainterp_stream.io.stereo_log import stereo_messages
from pcainterp_stream.pipeline.learn import learn_pairing
from pcainterp_stream.records import StereoCamera

FRONT = ("/front/left/image_rect", "/front/right/image_rect")
CAMERA = StereoCamera(width=8, height=6, fx=50.0, fy=51.0, cx=4.0, cy=3.0, baseline=0.25)


class _Reader:
    """A log's topics alone (the named path reads no message)."""

    def __init__(self, *names: str) -> None:
        self.path = Path("robot.bag")
        self.damage: list[str] = []
        self._topics = {
            name: TopicInfo(
                name,
                rosmsg.CAMERA_INFO if name.endswith("camera_info") else rosmsg.IMAGE,
                10,
                "cdr",
                "ros2msg",
            )
            for name in names
        }

    def topics(self) -> dict[str, TopicInfo]:
        return self._topics

    def messages(self, topics: Any = None) -> Any:
        return iter(())


def _heads(*heads: str, infos: bool = True) -> _Reader:
    names = []
    for head in heads:
        for side in ("left", "right"):
            names.append(f"{head}/{side}/image_rect")
            if infos or head == "/stereo":
                names.append(f"{head}/{side}/camera_info")
    return _Reader(*names)


def _named(left: str, right: str, left_info: str | None = None) -> PairingConfig:
    """The pairing ``cli.pairing_config`` gives for both image topics named."""
    config = PairingConfig(left_topic=left, right_topic=right, named_sides=("left", "right"))
    return config if left_info is None else dataclasses.replace(config, left_info_topic=left_info)


def _resolve(reader: _Reader, config: PairingConfig) -> tuple[PairingConfig, list[str]]:
    said: list[str] = []
    resolved = resolve_pairing(reader, config, said.append)  # type: ignore[arg-type]
    return resolved, said


def test_both_named_images_take_their_own_infos_not_the_default_ones() -> None:
    config, said = _resolve(_heads("/stereo", "/front"), _named(*FRONT))
    assert (config.left_info_topic, config.right_info_topic) == (
        "/front/left/camera_info",
        "/front/right/camera_info",
    )
    assert said == [
        "topics: left /front/left/image_rect, right /front/right/image_rect with "
        "/front/left/camera_info and /front/right/camera_info (both named; each image with "
        "its own camera_info)"
    ]


def test_the_default_images_swapped_by_hand_take_their_own_infos() -> None:
    config, _ = _resolve(
        _heads("/stereo"), _named("/stereo/right/image_rect", "/stereo/left/image_rect")
    )
    assert (config.left_info_topic, config.right_info_topic) == (
        "/stereo/right/camera_info",
        "/stereo/left/camera_info",
    )


def test_an_info_below_the_image_is_its_own() -> None:
    # the MultiSense driver's IMAGE/camera_info, beside a /stereo head
    reader = _Reader(
        *(f"/stereo/{s}/{t}" for s in ("left", "right") for t in ("image_rect", "camera_info")),
        *(f"/ms/{s}/image_rect{t}" for s in ("left", "right") for t in ("", "/camera_info")),
    )
    config, _ = _resolve(reader, _named("/ms/left/image_rect", "/ms/right/image_rect"))
    assert config.right_info_topic == "/ms/right/image_rect/camera_info"


def test_an_info_topic_named_wins_over_the_images_own() -> None:
    named = _named(*FRONT, left_info="/calib/left/camera_info")
    config, said = _resolve(_heads("/stereo", "/front"), named)
    assert (config.left_info_topic, config.right_info_topic) == (
        "/calib/left/camera_info",
        "/front/right/camera_info",
    )
    assert said[0].endswith("(both named; left: --left-info-topic; right: its own camera_info)")


def test_a_named_image_without_an_info_of_its_own_keeps_the_default_and_says_so() -> None:
    config, said = _resolve(_heads("/stereo", "/front", infos=False), _named(*FRONT))
    assert (config.left_info_topic, config.right_info_topic) == (
        "/stereo/left/camera_info",
        "/stereo/right/camera_info",
    )
    assert said[0].endswith(
        "(both named; left: the default, /front/left/image_rect has no camera_info of its "
        "own; right: the default, /front/right/image_rect has no camera_info of its own)"
    )


def test_library_pairings_resolve_alike_without_a_line() -> None:
    # topics given to the library (no command line: no named_sides): no line, the same infos
    config = PairingConfig(left_topic=FRONT[0], right_topic=FRONT[1])
    resolved, said = _resolve(_heads("/stereo", "/front"), config)
    assert resolved.left_info_topic == "/front/left/camera_info"
    assert said == []


def _run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    capsys.readouterr()
    code = cli.main([str(a) for a in args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture(scope="module")
def heads(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Two-head logs: a ``/stereo`` head and a ``/front`` one of another size, or the same.

    ``/stereo``: a 752x480 VI-sensor (fx 436, b 0.11 m) at scale 0.5; ``/front``: KITTI's
    pair at scale 0.25 (310x94 px, b 0.5372 m), or a fisheye rectified to 752x480 at scale
    0.5 (fx 306.7, b 0.12 m: the same size, another calibration).
    """
    folder = tmp_path_factory.mktemp("heads")
    synth = {
        "stereo": ["--scene", "indoor", "--camera", "752x480", "--scale", 0.5, "--seed", 2],
        "other_size": ["--scale", 0.25, "--seed", 1],
        "same_size": ["--scene", "indoor", "--camera", "fisheye-752x480", "--scale", 0.5],
    }
    for name, options in synth.items():
        assert (
            cli.main([str(a) for a in ["synth", folder / f"{name}.mcap", "--frames", 3, *options]])
            == 0
        )
    logs = {}
    for front in ("other_size", "same_size"):
        logs[front] = folder / f"twohead_{front}.mcap"
        _merge(folder / "stereo.mcap", folder / f"{front}.mcap", logs[front])
    return logs


def _merge(stereo: Path, front: Path, target: Path) -> None:
    """Write ``stereo``'s log with ``front``'s camera topics moved to ``/front``."""
    messages = []
    with target.open("wb") as out:
        writer = Writer(out)
        writer.start("ros2", "test")
        for path, rename in ((stereo, False), (front, True)):
            schemas: dict[int, int] = {}
            channels: dict[int, int] = {}
            with path.open("rb") as stream:
                for schema, channel, message in make_reader(stream).iter_messages():
                    topic = channel.topic
                    if rename:
                        if not topic.startswith("/stereo/"):
                            continue  # one ground truth: the /stereo head's
                        topic = "/front/" + topic.removeprefix("/stereo/")
                    if channel.id not in channels:
                        assert schema is not None
                        if schema.id not in schemas:
                            schemas[schema.id] = writer.register_schema(
                                schema.name, schema.encoding, schema.data
                            )
                        channels[channel.id] = writer.register_channel(
                            topic, channel.message_encoding, schemas[schema.id]
                        )
                    messages.append((message.log_time, channels[channel.id], message.data))
        for log_time, channel_id, data in sorted(messages, key=lambda m: m[0]):
            writer.add_message(channel_id, log_time, data, log_time)
        writer.finish()


@pytest.mark.parametrize(
    ("front", "camera"),
    [
        ("other_size", "camera: 310x94 px, fx 179.714 px, baseline 0.5372 m"),
        ("same_size", "camera: 376x240 px, fx 153.35 px, baseline 0.12 m"),
    ],
)
def test_densify_reads_a_second_head_with_its_own_calibration(
    capsys: pytest.CaptureFixture[str],
    heads: dict[str, Path],
    tmp_path: Path,
    front: str,
    camera: str,
) -> None:
    # before: the /stereo head's calibration (376x240, fx 218, b 0.11 m): refused for the
    # other size ("camera info on /stereo/left/camera_info is for 376x240 px images"),
    # silently used for the same size
    out = tmp_path / "dense.mcap"
    code, printed, err = _run(
        capsys,
        "densify",
        heads[front],
        "-o",
        out,
        "--left-topic",
        FRONT[0],
        "--right-topic",
        FRONT[1],
    )
    assert code == 0, err
    lines = printed.splitlines()
    line = next(line for line in lines if line.startswith("camera: "))
    assert line.startswith(camera), line
    assert "(from P of /front/right/camera_info)" in line
    assert lines[0] == (
        f"topics: left {FRONT[0]}, right {FRONT[1]} with /front/left/camera_info and "
        "/front/right/camera_info (both named; each image with its own camera_info)"
    )


def test_learn_and_evaluate_read_a_named_head_with_its_own_infos(heads: dict[str, Path]) -> None:
    log = heads["same_size"]
    named = _named(*FRONT)
    # learn: the pairing of its logs (printed), and of each log where it is opened
    learned = learn_pairing([log], named)
    assert learned.right_info_topic == "/front/right/camera_info"
    # evaluate: the input pair of a log (its images remapped as densify did)
    images = PairImages(named)
    with open_log(log) as reader:
        images.resolve(reader)
    assert images.config.left_info_topic == "/front/left/camera_info"


# review 59c F2: an info topic given on the command line is read, the default name too


def test_an_info_topic_given_with_the_default_name_wins_over_the_images_own() -> None:
    # the row check's advice for swapped images: the recorded infos named, each by its name
    swapped = _named("/stereo/right/image_rect", "/stereo/left/image_rect")
    given = dataclasses.replace(swapped, named_infos=("left", "right"))
    config, said = _resolve(_heads("/stereo"), given)
    assert (config.left_info_topic, config.right_info_topic) == (
        "/stereo/left/camera_info",
        "/stereo/right/camera_info",
    )
    assert said[0].endswith("(both named; left: --left-info-topic; right: --right-info-topic)")
    # one given: that side keeps it, the other takes its image's own
    one = dataclasses.replace(swapped, named_infos=("left",))
    config, _ = _resolve(_heads("/stereo"), one)
    assert (config.left_info_topic, config.right_info_topic) == (
        "/stereo/left/camera_info",
        "/stereo/left/camera_info",
    )


def test_an_info_topic_given_with_the_default_name_stays_when_the_pair_is_found() -> None:
    # no image topic named: the pair (/cam) is found, the info topics given are kept
    reader = _Reader(
        *(f"/cam/{s}/{t}" for s in ("left", "right") for t in ("image_rect", "camera_info")),
        "/stereo/left/camera_info",
        "/stereo/right/camera_info",
    )
    given = PairingConfig(discover=True, named_infos=("left", "right"))
    config, said = _resolve(reader, given)
    assert (config.left_topic, config.left_info_topic, config.right_info_topic) == (
        "/cam/left/image_rect",
        "/stereo/left/camera_info",
        "/stereo/right/camera_info",
    )
    assert " with /stereo/left/camera_info and /stereo/right/camera_info (found" in said[0]
    # not given: the pair's own
    config, _ = _resolve(reader, PairingConfig(discover=True))
    assert config.left_info_topic == "/cam/left/camera_info"


def test_the_command_line_records_which_info_topics_were_given() -> None:
    parser = argparse.ArgumentParser()
    cli_pairing.add_topic_options(parser)
    args = parser.parse_args(["--left-topic", "/a", "--right-topic", "/b"])
    assert cli_pairing.pairing_config(args).named_infos == ()
    args = parser.parse_args(["--right-info-topic", "/stereo/right/camera_info"])
    assert cli_pairing.pairing_config(args).named_infos == ("right",)


def _swap_images(source: Path, target: Path) -> None:
    """Write ``source``'s pairs with the two images exchanged, the camera infos as recorded."""
    stamp = 1_000_000_000
    with open_log(source) as reader, open_writer(target) as writer:
        for frame in iter_stereo_frames(reader, PairingConfig()):
            right, left = np.asarray(frame.right), np.asarray(frame.left)
            for topic, message in stereo_messages(stamp, right, left, frame.camera):
                writer.add_message(topic, message, stamp)
            stamp += 100_000_000


def test_a_log_with_swapped_images_densifies_with_the_row_checks_advice(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    # before: the advice's --left-info-topic /stereo/left/camera_info (the default name) was
    # taken as not given, each image read its own info: "camera info on
    # /stereo/left/camera_info gives no baseline ... the sides look swapped" (rc 2)
    recorded, swapped = tmp_path / "kitti.mcap", tmp_path / "swapped.mcap"
    synth = ["synth", recorded, "--frames", 3, "--scale", 0.25, "--seed", 1]
    assert cli.main([str(a) for a in synth]) == 0
    _swap_images(recorded, swapped)
    out = tmp_path / "dense.mcap"
    code, _, err = _run(capsys, "densify", swapped, "-o", out)
    assert code == 2
    advice = re.search(r"look swapped; pass (--left-topic .*?) \(or fix", err)
    assert advice is not None, err
    flags = advice.group(1).split()
    assert flags == [
        "--left-topic",
        "/stereo/right/image_rect",
        "--right-topic",
        "/stereo/left/image_rect",
        "--left-info-topic",
        "/stereo/left/camera_info",
        "--right-info-topic",
        "/stereo/right/camera_info",
    ]
    code, printed, err = _run(capsys, "densify", swapped, "-o", out, *flags)
    assert code == 0, err
    camera = next(line for line in printed.splitlines() if line.startswith("camera: "))
    assert "baseline 0.5372 m (from P of /stereo/right/camera_info)" in camera
    # the images swapped by hand without the infos: the advice on the infos works as given
    named = ["--left-topic", "/stereo/right/image_rect", "--right-topic", "/stereo/left/image_rect"]
    code, _, err = _run(capsys, "densify", swapped, "-o", out, *named)
    assert code == 2
    fix = re.search(r"infos are crossed, pass (--left-info-topic \S+ --right-info-topic \S+)", err)
    assert fix is not None, err
    assert _run(capsys, "densify", swapped, "-o", out, *named, *fix.group(1).split())[0] == 0


# review 59c F7: two named images whose one camera info is their namespace's


def test_two_images_sharing_their_namespace_info_are_said_so_with_the_fix() -> None:
    reader = _Reader(
        "/camera/left_image",
        "/camera/right_image",
        "/camera/camera_info",
        "/stereo/left/camera_info",
        "/stereo/right/camera_info",
    )
    config, said = _resolve(reader, _named("/camera/left_image", "/camera/right_image"))
    assert config.left_info_topic == config.right_info_topic == "/camera/camera_info"
    assert "each image with its own camera_info" not in said[0]
    assert said[0].endswith(
        "(both named; both images take /camera/camera_info, the one camera_info of their "
        "namespace: one camera info gives no baseline, --left-info-topic and "
        "--right-info-topic name each side's; other camera infos in the log: "
        "/stereo/left/camera_info, /stereo/right/camera_info)"
    )
    # with --baseline one info does: no advice
    with_baseline = dataclasses.replace(
        _named("/camera/left_image", "/camera/right_image"), baseline=0.1
    )
    _, said = _resolve(reader, with_baseline)
    assert said[0].endswith(
        "(both named; both images take /camera/camera_info, the one camera_info of their namespace)"
    )


def test_one_info_read_for_both_sides_names_the_info_options() -> None:
    info = rosmsg.camera_info_message(CAMERA, 0, "l")
    with pytest.raises(CalibrationError) as caught:
        camera_from_infos(
            info, info, width=8, height=6, left_topic="/c/camera_info", right_topic="/c/camera_info"
        )
    assert str(caught.value).endswith(
        "/c/camera_info was read for both sides: pass --left-info-topic and "
        "--right-info-topic (each camera's own), or --baseline METRES"
    )
