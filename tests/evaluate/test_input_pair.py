"""evaluate reads the input pair as densify recorded it read it (bug hunt 6A F9)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from pcainterp_stream.evaluate.report import EvaluateOptions, Evaluation, evaluate_log
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.frontend.stereo import SgbmConfig, SgbmMode
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import open_writer
from pcainterp_stream.io.outputs import recorded_front_end
from pcainterp_stream.pipeline.densify import densify
from pcainterp_stream.pipeline.processor import ProcessorConfig
from pcainterp_stream.synth import SynthConfig
from pcainterp_stream.synth.raw import write_raw_log

FAST = {"linear": False, "basis": None, "mode": "stereo"}


@pytest.fixture(scope="module")
def raw_never(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A raw (plumb_bob) log densified with --rectify never, as a user's rectified images."""
    folder = tmp_path_factory.mktemp("pair")
    raw = folder / "raw.mcap"
    write_raw_log(SynthConfig(seed=2, frames=3, scale=0.25), raw, model="plumb_bob")
    dense = folder / "raw_never.mcap"
    densify(
        raw,
        dense,
        pairing=PairingConfig(discover=True, rectify="never", check_rows=False),
        processor=ProcessorConfig(sgbm=SgbmConfig(block_size=7, mode=SgbmMode.HH, downscale=2)),
    )
    front_end = recorded_front_end(dense)
    assert front_end is not None
    assert (front_end.rectify, front_end.images) == ("never", "as recorded")
    return dense


def _evaluate(path: Path, pairing: PairingConfig | None) -> Evaluation:
    options = EvaluateOptions(pairing=pairing, **FAST)  # type: ignore[arg-type]
    return evaluate_log(path, options)[0]


def _sgbm(result: Evaluation) -> float:
    """SGBM's mean Delta_2D against the truth."""
    return float(result.stereo["sgbm"].summary()["delta_2d_mean"])


def test_evaluate_matches_the_images_densify_matched(raw_never: Path) -> None:
    # before: evaluate decided --rectify auto itself, remapped the raw images densify used as
    # recorded, and scored densify's estimate against another pair's SGBM, silently
    followed = _evaluate(raw_never, PairingConfig(discover=True))  # the CLI's default
    never = _sgbm(_evaluate(raw_never, PairingConfig(discover=True, rectify="never")))
    always = _evaluate(raw_never, PairingConfig(discover=True, rectify="always"))
    assert _sgbm(followed) == pytest.approx(never)
    assert abs(_sgbm(followed) - _sgbm(always)) > 0.1 * _sgbm(always)
    # the library default (no pairing) follows the record too
    assert _sgbm(_evaluate(raw_never, None)) == pytest.approx(never)
    assert followed.input_pair == (
        "/camera/left/image_raw, /camera/right/image_raw, camera infos, --rectify never "
        "(topics, --rectify as densify recorded them; its images: as recorded)"
    )
    assert always.input_pair.endswith(
        "--rectify always (topics as densify recorded them; its images: as recorded; "
        "--rectify always given, densify used never)"
    )
    # densify's matcher is named, the resolution left out (evaluate's is full by design)
    assert followed.notes[-1] == (
        "densify matched with block_size 7, mode hh; evaluate's SGBM (reference, stereo rows, "
        "sweep) keeps its own settings, at full resolution"
    )


def test_a_log_without_the_record_is_read_as_before(raw_never: Path, tmp_path: Path) -> None:
    bare = tmp_path / "no_record.mcap"
    with open_log(raw_never) as reader, open_writer(bare, None) as writer:
        for raw in reader.messages():  # messages and channel metadata, no metadata record
            writer.add_raw(raw)
    assert recorded_front_end(bare) is None
    auto = _evaluate(bare, PairingConfig(discover=True))
    always = _evaluate(bare, PairingConfig(discover=True, rectify="always"))
    assert _sgbm(auto) == pytest.approx(_sgbm(always))  # raw infos: auto remaps, as before
    assert auto.input_pair.endswith(
        "--rectify auto (the log records none: --rectify auto decided again as densify decides)"
    )
    assert not any("densify matched" in note for note in auto.notes)


def test_the_report_states_the_input_pair(raw_never: Path, tmp_path: Path) -> None:
    from pcainterp_stream.evaluate.report import write_report

    write_report(raw_never, tmp_path / "r", EvaluateOptions(**FAST))  # type: ignore[arg-type]
    report = json.loads((tmp_path / "r" / "results.json").read_text())
    assert report["input_pair"].endswith(
        "--rectify never (topics, --rectify as densify recorded them; its images: as recorded)"
    )
    text = (tmp_path / "r" / "results.md").read_text()
    assert "\ninput pair: /camera/left/image_raw, /camera/right/image_raw, camera infos" in text


def test_a_log_of_two_equally_good_pairs_needs_no_topic_options(tmp_path: Path) -> None:
    # before: "2 stereo pairs ... are equally good ...; pass the options of the one to
    # densify" although the log records the one densify read (bug hunt 6A F9, related)
    from pcainterp_stream.synth import generate
    from pcainterp_stream.synth.log import write_synthetic_log

    single, log = tmp_path / "one.mcap", tmp_path / "heads.mcap"
    write_synthetic_log(generate(SynthConfig(seed=3, frames=2, scale=0.25)), single)
    with open_log(single) as reader, open_writer(log, None) as writer:
        for raw in reader.messages():  # every /stereo/* message also on /front/*
            writer.add_raw(raw)
            if raw.topic.startswith("/stereo/"):
                writer.add_raw(raw._replace(topic=raw.topic.replace("/stereo/", "/front/", 1)))
    dense = tmp_path / "heads_dense.mcap"
    front = PairingConfig(
        left_topic="/front/left/image_rect", discover=True, named_sides=("left",)
    )  # densify --left-topic /front/left/image_rect
    densify(log, dense, pairing=front)
    result = _evaluate(dense, PairingConfig(discover=True))
    assert result.input_pair.startswith("/front/left/image_rect, /front/right/image_rect, ")
    assert result.frames == 2


@pytest.fixture(scope="module")
def two_pairs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A raw log with its pair also on /other/*, densified on /camera/* with --rectify never."""
    folder = tmp_path_factory.mktemp("two")
    raw, log = folder / "raw.mcap", folder / "two.mcap"
    write_raw_log(SynthConfig(seed=2, frames=3, scale=0.25), raw, model="plumb_bob")
    with open_log(raw) as reader, open_writer(log, None) as writer:
        for message in reader.messages():
            writer.add_raw(message)
            if message.topic.startswith("/camera/"):
                other = message.topic.replace("/camera/", "/other/", 1)
                writer.add_raw(message._replace(topic=other))
    dense = folder / "two_dense.mcap"
    densify(
        log,
        dense,
        pairing=PairingConfig(
            left_topic="/camera/left/image_raw",
            right_topic="/camera/right/image_raw",
            left_info_topic="/camera/left/camera_info",
            right_info_topic="/camera/right/camera_info",
            rectify="never",
            check_rows=False,
        ),
    )
    return dense


def _other(**changes: object) -> PairingConfig:
    """evaluate --left-topic /other/left/image_raw --right-topic /other/right/image_raw."""
    config = PairingConfig(
        left_topic="/other/left/image_raw",
        right_topic="/other/right/image_raw",
        named_sides=("left", "right"),
    )
    return dataclasses.replace(config, **changes)  # type: ignore[arg-type]


def test_other_topics_named_do_not_take_the_recorded_rectify(two_pairs: Path) -> None:
    # before: densify's --rectify never (and its calibration, baseline) was applied to the
    # /other/* raw images too, silently: SGBM of unrectified images (review F2)
    other = _evaluate(two_pairs, _other())
    always = _evaluate(two_pairs, _other(rectify="always"))
    never = _evaluate(two_pairs, _other(rectify="never"))
    assert _sgbm(other) == pytest.approx(_sgbm(always))  # raw infos: auto remaps
    assert abs(_sgbm(other) - _sgbm(never)) > 0.1 * _sgbm(never)
    assert other.input_pair == (
        "/other/left/image_raw, /other/right/image_raw, camera infos, --rectify auto (other "
        "topics than densify read (/camera/left/image_raw, /camera/right/image_raw), so not "
        "its --rectify, calibration or baseline: --rectify auto decided again as densify "
        "decides)"
    )
    # one side named, another than the recorded one: the same
    left = PairingConfig(left_topic="/other/left/image_raw", discover=True, named_sides=("left",))
    assert _sgbm(_evaluate(two_pairs, left)) == pytest.approx(_sgbm(always))
    # the recorded topics named: the record applies to them
    named = PairingConfig(
        left_topic="/camera/left/image_raw",
        right_topic="/camera/right/image_raw",
        named_sides=("left", "right"),
    )
    recorded = _evaluate(two_pairs, named)
    assert _sgbm(recorded) == pytest.approx(_sgbm(never))
    assert recorded.input_pair.endswith(
        "(--rectify as densify recorded them; its images: as recorded)"
    )


def test_an_info_topic_named_alone_keeps_the_recorded_images(two_pairs: Path) -> None:
    # before: evaluate --left-info-topic X alone looked for /stereo/left/image_rect (the
    # library default): "topic /stereo/left/image_rect not found" (review F10)
    from pcainterp_stream.evaluate.input_pair import follow_densify

    info = PairingConfig(left_info_topic="/other/left/camera_info")  # as cli.pairing makes it
    with open_log(two_pairs) as reader:
        present = reader.topics()
    config, source, _ = follow_densify(two_pairs, info, present)
    assert config is not None
    assert (config.left_topic, config.right_topic) == (
        "/camera/left/image_raw",
        "/camera/right/image_raw",
    )
    assert (config.left_info_topic, config.right_info_topic) == (
        "/other/left/camera_info",
        "/camera/right/camera_info",
    )
    # another info topic than densify read: not its --rectify never (R55b-3)
    assert source == (
        "topics as densify recorded them; /other/left/camera_info named, not densify's "
        "/camera/left/camera_info, /camera/right/camera_info, so not its --rectify, "
        "calibration or baseline: --rectify auto decided again as densify decides"
    )
    result = _evaluate(two_pairs, info)
    assert result.frames == 3
    assert result.input_pair.startswith("/camera/left/image_raw, /camera/right/image_raw, ")


def test_an_info_topic_named_alone_without_the_record_finds_the_images(
    raw_never: Path, tmp_path: Path
) -> None:
    from pcainterp_stream.evaluate.input_pair import follow_densify

    bare = tmp_path / "no_record.mcap"
    with open_log(raw_never) as reader, open_writer(bare, None) as writer:
        for raw in reader.messages():
            writer.add_raw(raw)
        present = reader.topics()
    info = PairingConfig(right_info_topic="/camera/right/camera_info")
    config, _, _ = follow_densify(bare, info, present)
    assert config is not None
    assert config.discover  # the images found in the log
    result = _evaluate(bare, info)
    assert result.input_pair.startswith("/camera/left/image_raw, /camera/right/image_raw, ")


@pytest.fixture(scope="module")
def files_densified(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A raw log with its pair also on /other/*, densified on /camera/* from calibration files."""
    from pcainterp_stream.synth.raw import RawDrive

    folder = tmp_path_factory.mktemp("files")
    config = SynthConfig(seed=2, frames=3, scale=0.25)
    raw, log = folder / "raw.mcap", folder / "files.mcap"
    write_raw_log(config, raw, model="plumb_bob")
    with open_log(raw) as reader, open_writer(log, None) as writer:
        for message in reader.messages():
            writer.add_raw(message)
            if message.topic.startswith("/camera/"):
                writer.add_raw(message._replace(topic=message.topic.replace("/camera/", "/other/")))
    dense = folder / "files_dense.mcap"
    pairing = PairingConfig(
        left_topic="/camera/left/image_raw",
        right_topic="/camera/right/image_raw",
        calibration=RawDrive(config, "plumb_bob").calibration,  # densify --calibration
        check_rows=False,
    )
    densify(log, dense, pairing=pairing)
    front_end = recorded_front_end(dense)
    assert front_end is not None
    assert front_end.calibration == "files"
    return dense


def test_info_topics_named_are_used_not_the_recorded_calibration_files(
    files_densified: Path,
) -> None:
    # before: the record's calibration files (and --rectify, baseline) were taken, so the
    # info topics named were never read, and the line said "calibration files ... as densify
    # recorded them" with no word of them (review 55b R55b-3)
    from pcainterp_stream.evaluate.input_pair import follow_densify

    infos = PairingConfig(
        left_info_topic="/other/left/camera_info", right_info_topic="/other/right/camera_info"
    )
    with open_log(files_densified) as reader:
        present = reader.topics()
    config, source, front_end = follow_densify(files_densified, infos, present)
    assert config is not None
    assert front_end is not None
    assert config.calibration is None  # the infos named are read
    assert (config.left_topic, config.left_info_topic) == (
        "/camera/left/image_raw",
        "/other/left/camera_info",
    )
    assert (config.rectify, config.baseline) == ("auto", None)
    files = ", ".join(front_end.calibration_files)
    assert source == (
        "topics as densify recorded them; /other/left/camera_info, /other/right/camera_info "
        f"named, not densify's calibration files {files}, so not its --rectify, calibration or "
        "baseline: --rectify auto decided again as densify decides"
    )
    result = _evaluate(files_densified, infos)
    assert result.frames == 3
    assert result.input_pair.startswith(
        "/camera/left/image_raw, /camera/right/image_raw, camera infos, --rectify auto (topics "
    )
    # nothing named: the record's calibration files, as before
    followed = _evaluate(files_densified, None)
    assert ", calibration files, " in followed.input_pair
    assert "calibration files as densify recorded them" in followed.input_pair


def test_each_prefix_is_evaluated_with_its_own_record(two_pairs: Path, tmp_path: Path) -> None:
    # before: a log densified again for its second pair under another --output-prefix gave
    # evaluate of the first prefix the LAST record's pair: SGBM rows of the other camera
    # (a NumPy traceback when the pairs differ in size; bug hunt 9A F2)
    from pcainterp_stream.evaluate.input_pair import follow_densify
    from pcainterp_stream.io.outputs import OutputTopics, front_end_record, recorded_bases

    both = tmp_path / "both.mcap"
    densify(
        two_pairs,
        both,
        pairing=_other(rectify="always", check_rows=False),
        topics=OutputTopics.with_prefix("/rear"),
    )
    assert front_end_record(both, "/pcainterp") == (recorded_front_end(two_pairs), "")
    rear = front_end_record(both, "/rear").front_end
    assert rear is not None
    assert (rear.left_topic, rear.rectify) == ("/other/left/image_raw", "always")
    assert len(recorded_bases(both, "/rear")) == len(recorded_bases(both, "/pcainterp")) == 1
    first = _evaluate(both, PairingConfig(discover=True))
    assert first.input_pair == _evaluate(two_pairs, PairingConfig(discover=True)).input_pair
    assert first.input_pair.startswith("/camera/left/image_raw, /camera/right/image_raw, ")
    with open_log(both) as reader:
        present = reader.topics()
    config, source, _ = follow_densify(both, None, present, "/rear")
    assert config is not None
    assert (config.left_topic, config.rectify) == ("/other/left/image_raw", "always")
    # a prefix densify recorded nothing for (records of this version name theirs)
    _, source, front_end = follow_densify(both, None, present, "/side")
    assert front_end is None
    assert source == (
        "the log records densify only for the outputs of /pcainterp, /rear, none for /side: "
        "--rectify auto decided again as densify decides"
    )


def test_records_of_an_older_version_name_no_prefix() -> None:
    from pcainterp_stream.io.outputs import record_of_prefix

    old, new = {"front_end": "a"}, {"front_end": "b", "output_prefix": "/rear"}
    assert record_of_prefix([old], "/pcainterp") == (old, "")
    assert record_of_prefix([old, new], "/rear") == (new, "")
    assert record_of_prefix([old, new], "/pcainterp") == (
        old,
        "the log holds 2 densify records, 1 of an older version that names no output prefix: "
        "the last of those was taken",
    )
    assert record_of_prefix([old, new], None) == (new, "")  # the library's default: the last
    assert record_of_prefix([], "/pcainterp") == (None, "")


@pytest.fixture(scope="module")
def other_size(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A log with a second pair of half the size on /small/*, densified on /camera/*."""
    folder = tmp_path_factory.mktemp("size")
    raw, small, log = folder / "raw.mcap", folder / "small.mcap", folder / "log.mcap"
    write_raw_log(SynthConfig(seed=2, frames=3, scale=0.25), raw, model="plumb_bob")
    write_raw_log(SynthConfig(seed=2, frames=3, scale=0.125), small, model="plumb_bob")
    with open_log(raw) as reader, open_log(small) as other, open_writer(log, None) as writer:
        for message in reader.messages():
            writer.add_raw(message)
        for message in other.messages():
            if message.topic.startswith("/camera/"):
                writer.add_raw(message._replace(topic=message.topic.replace("/camera/", "/small/")))
    dense = folder / "dense.mcap"
    densify(
        log,
        dense,
        pairing=PairingConfig(
            left_topic="/camera/left/image_raw",
            right_topic="/camera/right/image_raw",
            left_info_topic="/camera/left/camera_info",
            right_info_topic="/camera/right/camera_info",
            rectify="never",
            check_rows=False,
        ),
    )
    return dense


def test_a_pair_of_another_size_than_the_estimate_is_refused_in_one_line(
    other_size: Path,
) -> None:
    # review 57b R2: a NumPy broadcast traceback (shapes (h, w) (h/2, w/2)) before
    from pcainterp_stream.errors import LogReadError

    small = PairingConfig(
        left_topic="/small/left/image_raw",
        right_topic="/small/right/image_raw",
        left_info_topic="/small/left/camera_info",
        right_info_topic="/small/right/camera_info",
        rectify="never",
        check_rows=False,
    )
    with pytest.raises(LogReadError) as caught:
        _evaluate(other_size, small)
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith("the input pair /small/left/image_raw, /small/right/image_raw is ")
    assert "these outputs were not densified from that pair" in message
    assert "--left-topic and --right-topic" in message
    assert "/camera/left/image_raw + /camera/right/image_raw" in message  # the recorded pair


def test_older_records_of_two_pairs_say_the_pair_may_be_another(two_pairs: Path) -> None:
    # review 57b R2: an older log densified for two pairs was scored on the last record's
    # pair with a note naming only the record taken
    from pcainterp_stream.io.outputs import record_of_prefix

    front_end = recorded_front_end(two_pairs)
    assert front_end is not None
    other = dataclasses.replace(
        front_end, left_topic="/other/left/image_raw", right_topic="/other/right/image_raw"
    )
    records = [{"front_end": front_end.to_json()}, {"front_end": other.to_json()}]
    record, note = record_of_prefix(records, "/pcainterp")
    assert record == records[1]
    assert note.startswith(
        "the log holds 2 densify records, 2 of an older version that names no output prefix: "
        "the last of those was taken, but these outputs may be of another pair (the records "
        "read /camera/left/image_raw + /camera/right/image_raw, /other/left/image_raw + "
        "/other/right/image_raw): "
    )
    assert "--left-topic and --right-topic" in note
    # one pair densified twice: no doubt
    assert record_of_prefix(records[:1] * 2, "/pcainterp")[1].endswith(
        "the last of those was taken"
    )


@pytest.mark.parametrize(
    "given",
    [None, PairingConfig(left_info_topic="/stereo/left/camera_info", named_infos=("left",))],
)
def test_the_recorded_infos_are_read_not_each_image_s_own(given: PairingConfig | None) -> None:
    """densify run with the row check's advice for swapped images (the recorded infos named,
    default names included) read /stereo/left/camera_info for the image on
    /stereo/right/image_rect: evaluate following its record took each image's own info
    (review 59d F1), since a default-named info counted as not given."""
    from pcainterp_stream.evaluate.input_pair import _follow, _topics_open
    from pcainterp_stream.io.densify_record import FrontEnd

    front_end = FrontEnd(
        "/stereo/right/image_rect",
        "/stereo/left/image_rect",
        "/stereo/left/camera_info",
        "/stereo/right/camera_info",
        1_000_000,
        None,
        "camera_info",
        (),
        None,
        "auto",
        "as recorded",
        0,
        4,
        "stereo",
        None,
        {},
    )
    present = {topic: None for topic in (front_end.left_topic, front_end.right_topic)}
    pairing, _, _ = _follow(given, front_end, present, _topics_open(given), "again")
    assert pairing is not None
    assert (pairing.left_info_topic, pairing.right_info_topic) == (
        "/stereo/left/camera_info",
        "/stereo/right/camera_info",
    )
    assert set(pairing.named_infos) == {"left", "right"}  # discovery keeps them
