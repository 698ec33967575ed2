"""Golden files on disk: what they may overwrite, their arrays file's name, info on them."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pcainterp_stream.cli import main
from pcainterp_stream.errors import GoldenError, GoldenToleranceError
from pcainterp_stream.golden import arrays_path, check_log, save_golden
from pcainterp_stream.records import StereoCamera, SynthFrame
from pcainterp_stream.synth.log import write_synthetic_log

CAMERA = StereoCamera(width=40, height=30, fx=30.0, fy=30.0, cx=19.5, cy=14.5, baseline=0.5)


def _write_log(path: Path, *, scale: float = 1.0, mirror: bool = False) -> Path:
    """A 2-frame log of a 40x30 camera: grey images, a depth with NaN rows on top."""
    rng = np.random.default_rng(0)
    frames = []
    for i in range(2):
        depth = np.linspace(3.0, 60.0, CAMERA.width, dtype=np.float32)[None, :] * scale
        depth = np.repeat(depth, CAMERA.height, axis=0) + rng.uniform(0, 1, CAMERA.image_size)
        depth = depth.astype(np.float32)
        depth[:5] = np.nan
        if mirror:
            depth = depth[:, ::-1].copy()
        grey = rng.integers(0, 256, size=CAMERA.image_size, dtype=np.uint8)
        frames.append(SynthFrame(i, 10**9 + i * 10**8, grey, grey, depth, np.eye(4), CAMERA))
    write_synthetic_log(frames, path)
    return path


@pytest.fixture
def log(tmp_path: Path) -> Path:
    return _write_log(tmp_path / "drive.mcap")


def _basis(path: Path) -> Path:
    np.savez(path, format=np.array("pcainterp-basis/1"), components=np.zeros((2, 3)))
    return path


def test_arrays_file_name_never_the_plain_npz() -> None:
    assert arrays_path("a.golden.json").name == "a.golden.npz"
    assert arrays_path("kitti.json").name == "kitti.golden.npz"
    assert arrays_path("d/x").name == "x.golden.npz"


def test_a_basis_beside_the_golden_file_is_kept(log: Path, tmp_path: Path) -> None:
    basis = _basis(tmp_path / "kitti.npz")
    before = basis.read_bytes()
    save_golden(log, tmp_path / "kitti.json", arrays=True)
    assert basis.read_bytes() == before
    assert (tmp_path / "kitti.golden.npz").is_file()


def test_a_file_not_ours_at_the_arrays_path_is_refused(
    log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    basis = _basis(tmp_path / "kitti.golden.npz")
    before = basis.read_bytes()
    golden = tmp_path / "kitti.golden.json"
    assert main(["golden", "save", str(log), "-o", str(golden), "--arrays"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert "kitti.golden.npz exists and is not a golden arrays file" in err
    assert "give the golden file another name" in err
    assert basis.read_bytes() == before
    assert not golden.exists()
    # check --update refuses too, before rewriting anything
    save_golden(log, tmp_path / "other.golden.json", arrays=True)
    shutil.copy(tmp_path / "other.golden.json", golden)
    shutil.copy(tmp_path / "other.golden.npz", tmp_path / "b.npz")
    document = json.loads(golden.read_text())
    document["arrays_file"] = "b.npz"
    golden.write_text(json.dumps(document))
    changed = _write_log(tmp_path / "changed.mcap", scale=1.1)
    with pytest.raises(GoldenError, match=r"kitti\.golden\.npz exists and is not a golden arrays"):
        check_log(changed, golden, update=True)
    assert basis.read_bytes() == before


def test_the_log_itself_is_never_overwritten(log: Path, tmp_path: Path) -> None:
    named = tmp_path / "drive.golden.npz"
    shutil.copy(log, named)
    before = named.read_bytes()
    with pytest.raises(GoldenError, match=r"drive.golden.npz is the log drive.golden.npz itself"):
        save_golden(named, tmp_path / "drive.json", arrays=True)
    assert named.read_bytes() == before
    assert not (tmp_path / "drive.json").exists()


def test_update_of_an_old_file_moves_its_arrays_and_keeps_others(log: Path, tmp_path: Path) -> None:
    # an older version wrote kitti.json + kitti.npz (keys a0, a1, ... and no marker)
    save_golden(log, tmp_path / "kitti.json", arrays=True)
    with np.load(tmp_path / "kitti.golden.npz") as data:
        old = {key: data[key] for key in data.files if key.startswith("a")}
    np.savez_compressed(tmp_path / "kitti.npz", **old)  # type: ignore[arg-type]
    (tmp_path / "kitti.golden.npz").unlink()
    document = json.loads((tmp_path / "kitti.json").read_text())
    document["arrays_file"] = "kitti.npz"
    (tmp_path / "kitti.json").write_text(json.dumps(document))
    assert check_log(log, tmp_path / "kitti.json").passed  # the old file still reads
    # a copy of that JSON names kitti.npz too: its update must not remove kitti's arrays
    shutil.copy(tmp_path / "kitti.json", tmp_path / "copy.json")
    changed = _write_log(tmp_path / "changed.mcap", scale=1.1)
    assert check_log(changed, tmp_path / "copy.json", update=True).updated
    assert (tmp_path / "kitti.npz").is_file()
    assert (tmp_path / "copy.golden.npz").is_file()
    assert check_log(changed, tmp_path / "kitti.json", update=True).updated
    assert not (tmp_path / "kitti.npz").exists()  # its own old arrays file, replaced
    assert json.loads((tmp_path / "kitti.json").read_text())["arrays_file"] == "kitti.golden.npz"
    assert check_log(changed, tmp_path / "kitti.json").passed


def test_a_mirrored_depth_fails_a_stats_only_golden(log: Path, tmp_path: Path) -> None:
    golden = tmp_path / "drive.golden.json"
    save_golden(log, golden)
    assert check_log(_write_log(tmp_path / "again.mcap"), golden).passed
    assert check_log(_write_log(tmp_path / "bits.mcap", scale=1 + 1e-6), golden).passed
    mirrored = check_log(_write_log(tmp_path / "mirrored.mcap", mirror=True), golden)
    whats = {(d.topic, d.what) for d in mirrored.differences}
    assert whats == {("/ground_truth/depth", "image block means")}  # every pooled stat passes
    assert "16 of 16 blocks beyond tolerance" in mirrored.differences[0].text
    # a golden file of the previous version (no blocks) still loads and checks what it holds
    document = json.loads(golden.read_text())
    for channel in document["channels"].values():
        for message in channel["messages"]:
            for stats in message.get("arrays", {}).values():
                stats.pop("blocks", None)
    del document["tolerance"]["blocks"]
    golden.write_text(json.dumps(document))
    assert check_log(_write_log(tmp_path / "mirrored.mcap", mirror=True), golden).passed


def test_info_names_golden_files(
    log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    golden = tmp_path / "drive.golden.json"
    save_golden(log, golden, arrays=True)
    capsys.readouterr()
    assert main(["info", str(tmp_path / "drive.golden.npz")]) == 0
    out = capsys.readouterr().out
    assert "the arrays of the golden file drive.golden.json" in out
    assert "learn" not in out
    assert main(["info", str(golden)]) == 0
    out = capsys.readouterr().out
    assert "pcainterp golden file (pcainterp-golden/3" in out
    assert "from drive.mcap" in out
    assert "arrays: drive.golden.npz" in out
    np.save(tmp_path / "plain.npy", np.zeros(3))  # np.load gives an array, not an npz
    assert main(["info", str(tmp_path / "plain.npy")]) == 2
    assert "plain.npy is not a log" in capsys.readouterr().err


def test_a_file_not_ours_at_the_golden_path_is_refused(log: Path, tmp_path: Path) -> None:
    for name in ("config.json", "kitti.npz"):
        other = tmp_path / name
        if name.endswith(".json"):
            other.write_text('{"my": "settings"}')
        else:
            _basis(other)
        before = other.read_bytes()
        with pytest.raises(GoldenError, match=rf"{name} exists and is not a golden file"):
            save_golden(log, other)
        assert other.read_bytes() == before
    golden = tmp_path / "drive.golden.json"
    save_golden(log, golden)
    save_golden(log, golden)  # its own file is rewritten


def test_damaged_npz_files_are_one_line_errors(
    log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    golden = tmp_path / "z.golden.json"
    save_golden(log, golden, arrays=True)
    whole = (tmp_path / "z.golden.npz").read_bytes()
    cut = tmp_path / "cut.npz"
    cut.write_bytes(whole[: len(whole) // 2])  # the zip magic, no zip directory
    fake = tmp_path / "fake.npz"
    fake.write_bytes(b"PK\x03\x04garbage")
    for damaged in (cut, fake):
        capsys.readouterr()
        assert main(["info", str(damaged)]) == 2  # the basis reader's error, as before
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0
        assert "is not a readable .npz archive" in err
        assert damaged.name in err
    (tmp_path / "z.golden.npz").write_bytes(cut.read_bytes())
    assert main(["golden", "check", str(log), str(golden)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert "z.golden.npz does not load" in err
    other = tmp_path / "other.json"
    (tmp_path / "other.golden.npz").write_bytes(cut.read_bytes())
    assert main(["golden", "save", str(log), "-o", str(other), "--arrays"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert "other.golden.npz exists and is not a golden arrays" in err
    assert not other.exists()


def test_a_json_and_a_golden_json_do_not_share_arrays(
    log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plain, dotted = tmp_path / "a.json", tmp_path / "a.golden.json"
    save_golden(log, plain, arrays=True)
    before = (tmp_path / "a.golden.npz").read_bytes()
    other_log = _write_log(tmp_path / "other.mcap", scale=2.0)
    with pytest.raises(GoldenError, match=r"holds the arrays of the golden file a\.json"):
        save_golden(other_log, dotted, arrays=True)
    assert (tmp_path / "a.golden.npz").read_bytes() == before
    assert not dotted.exists()
    assert check_log(log, plain).passed
    # as an older version left them: the other log's a.golden.json over a.json's arrays
    save_golden(other_log, tmp_path / "x.golden.json", arrays=True)
    document = json.loads((tmp_path / "x.golden.json").read_text())
    dotted.write_text(json.dumps(dict(document, arrays_file="a.golden.npz")))
    with np.load(tmp_path / "x.golden.npz") as data:
        stored = dict(data)
    marker = json.dumps({"format": "pcainterp-golden-arrays/1", "golden": "a.golden.json"})
    stored["__pcainterp_golden_arrays__"] = np.array(marker)
    np.savez_compressed(tmp_path / "a.golden.npz", **stored)  # type: ignore[arg-type]
    with pytest.raises(GoldenError, match=r"holds the arrays of the golden file a\.golden\.json"):
        check_log(log, plain)
    assert check_log(other_log, dotted).passed
    # the owner summarises the same channels (a copy of a.json): its arrays fit a.json too
    dotted.write_text(json.dumps(dict(json.loads(plain.read_text()), arrays_file="a.golden.npz")))
    assert check_log(log, plain).differences  # the stored arrays are other_log's: compared


def test_info_on_a_malformed_golden_file_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for n, channels in enumerate(({"a": 1}, {"a": {"message_count": "x"}})):
        bad = tmp_path / f"g{n}.json"
        bad.write_text(json.dumps({"format": "pcainterp-golden/2", "channels": channels}))
        assert main(["info", str(bad)]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0
        assert f"g{n}.json is a malformed golden file" in err


@pytest.mark.parametrize(
    ("tolerance", "message"),
    [
        (
            {"flaot": {"rel": 0.5}},
            r'tolerance\["flaot"\] is not a tolerance \(did you mean "float"',
        ),
        ({"nonsense": 3}, r'tolerance\["nonsense"\] is not a tolerance; the keys of tolerance are'),
        ({"float": {"rel": "abc"}}, r'tolerance\["float"\]\["rel"\] is "abc", not a finite number'),
        (
            {"float": {"rel": -0.1}},
            r"-0\.1, not a finite number >= 0; give a number such as 0\.002",
        ),
        ({"float": {"rel": float("inf")}}, r'\["rel"\] is inf, not a finite number'),
        ({"float": {"rel": True}}, r'\["rel"\] is True, not a finite number'),
        (
            {"float": {"rell": 0.1}},
            r'\["float"\]\["rell"\] is not .* the keys of tolerance\["float',
        ),
        ({"float": 0.5}, r'tolerance\["float"\] is 0\.5, not a group of tolerances; give e\.g\.'),
        ({"channels": []}, r'tolerance\["channels"\] is \[\], not a mapping of topic'),
        (
            {"channels": {"/ground_truth/dpeth": {"float": {"rel": 0.5}}}},
            r'\["/ground_truth/dpeth"\] names no channel recorded from drive\.mcap \(did you mean '
            r'"/ground_truth/depth"\?\); channels: /ground_truth/depth, .*; rename or remove',
        ),
        (
            {"channels": {"/ground_truth/depth": {"note": "loose"}}},
            r'\["/ground_truth/depth"\]\["note"\] is not a tolerance',
        ),
    ],
)
def test_a_bad_tolerance_is_refused_on_save_naming_the_key(
    log: Path, tmp_path: Path, tolerance: dict[str, Any], message: str
) -> None:
    golden = tmp_path / "drive.golden.json"
    with pytest.raises(GoldenToleranceError, match=message) as raised:
        save_golden(log, golden, tolerance=tolerance)
    assert str(raised.value).startswith(f"{golden}: tolerance")  # the file and the key
    assert not golden.exists()  # nothing written, not even the defaults


def test_a_hand_edited_tolerance_is_checked_on_load(
    log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    golden = tmp_path / "drive.golden.json"
    loose = {"channels": {"/ground_truth/depth": {"float": {"rel": np.float32(0.5)}}}}
    save_golden(log, golden, tolerance=loose)  # a numpy number is written as a float
    document = json.loads(golden.read_text())
    assert document["tolerance"]["channels"]["/ground_truth/depth"] == {"float": {"rel": 0.5}}
    changed = _write_log(tmp_path / "changed.mcap", scale=1.1)
    assert check_log(changed, golden).passed  # the override applies
    save_golden(log, tmp_path / "tight.golden.json")
    assert not check_log(changed, tmp_path / "tight.golden.json").passed
    edits = [
        (
            "/ground_truth/dpeth",
            {"float": {"rel": 0.5}},
            r'\["/ground_truth/dpeth"\] names no chan',
        ),
        ("/ground_truth/depth", {"float": {"rel": "0.5"}}, r'\["rel"\] is "0\.5", not a finite'),
        ("/ground_truth/depth", {"flaot": {"rel": 0.5}}, r'\["flaot"\] is not a tolerance \(did'),
    ]
    for topic, override, message in edits:
        document["tolerance"]["channels"] = {topic: override}
        golden.write_text(json.dumps(document))
        before = golden.read_text()
        with pytest.raises(GoldenToleranceError, match=message):
            check_log(changed, golden, update=True)
        assert golden.read_text() == before  # an edited file is fixed by hand, not replaced
        capsys.readouterr()
        assert main(["golden", "check", str(log), str(golden)]) == 2  # bad input, not "differs"
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0
        assert f"{golden}: tolerance" in err
        assert "of the golden file" in err or "not a" in err


def test_an_empty_topic_selection_is_refused(log: Path, tmp_path: Path) -> None:
    golden = tmp_path / "g.golden.json"
    with pytest.raises(GoldenError, match=r"topics=\[\] selects no channel"):
        save_golden(log, golden, topics=[])
    assert not golden.exists()
    save_golden(log, golden)
    with pytest.raises(GoldenError, match=r"topics=\[\] selects no channel"):
        check_log(log, golden, topics=[])


def test_one_topic_may_be_given_as_a_string(log: Path, tmp_path: Path) -> None:
    golden = tmp_path / "g.golden.json"
    topic = "/ground_truth/depth"
    save_golden(log, golden, topics=topic)
    assert json.loads(golden.read_text())["topics"] == [topic]
    assert check_log(log, golden, topics=topic).passed
