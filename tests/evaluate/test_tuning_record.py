"""The fit check's tuning of a basis in the densified log's records, and what evaluate says of it.

The fit check may densify with the built-in indoor basis tuned (the street basis's local
kernel, a std scale refitted on the warm-up's SGBM: fix-ADAPT). Before, the output named the
basis only (``built-in-indoor``): nothing said the estimate was made with another kernel and
std scale than that basis's fitted prior, and ``evaluate`` said nothing of it either.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest
from mcap.reader import make_reader

from pcainterp_stream.estimate.basis import BUILT_IN, BUILT_IN_INDOOR, Basis
from pcainterp_stream.estimate.prior import LocalPrior
from pcainterp_stream.evaluate import tuning as tuning_module
from pcainterp_stream.evaluate.report import EvaluateOptions, evaluate_log
from pcainterp_stream.evaluate.tuning import describe_tuning, tuning_json, tuning_notes, tuning_of
from pcainterp_stream.io.densify_record import DENSIFY_RECORD
from pcainterp_stream.io.outputs import (
    BASES_RECORD,
    BASIS_TUNING_KEY,
    BasisInForce,
    OutputTopics,
    bases_record,
    recorded_bases,
    recorded_bases_of,
    recorded_metadata,
)
from pcainterp_stream.pipeline.adaptation import Adaptation, Candidate
from pcainterp_stream.pipeline.densify import densify
from pcainterp_stream.pipeline.jobs import synth
from pcainterp_stream.pipeline.processor import ProcessorConfig
from pcainterp_stream.records import StereoCamera, StereoFrame

STREET_KERNEL = LocalPrior(40.0, 64.0, "laplace")


@pytest.fixture(scope="module")
def room5(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The room where the check takes the indoor basis with the street kernel (seed 5,
    376x240: tests/pipeline/test_adaptation.py), rendered once."""
    log = tmp_path_factory.mktemp("room5") / "room5.mcap"
    synth(log, frames=8, seed=5, scale=0.5, fmt=None, scene="indoor", camera="752x480")
    return log


def _records(path: Path, name: str) -> list[dict[str, str]]:
    with path.open("rb") as stream:
        return [dict(m.metadata) for m in make_reader(stream).iter_metadata() if m.name == name]


def test_the_tuned_basis_is_recorded_with_its_kernel_and_std_scale(
    room5: Path, tmp_path: Path
) -> None:
    out = tmp_path / "dense.mcap"
    summary = densify(room5, out, processor=ProcessorConfig())
    assert any("with the street basis's kernel chosen" in line for line in summary.prior_lines)
    (entry,) = recorded_bases(out)
    assert (entry.basis, entry.fingerprint) == (BUILT_IN_INDOOR, Basis.indoor().fingerprint)
    tuning = tuning_of(entry.tuning)
    assert tuning["local_prior"] == STREET_KERNEL
    assert tuning["scale_by_innovation"] is True  # the indoor basis's rule (review58b R7)
    scale = tuning["std_scale"]
    assert isinstance(scale, float)
    assert 0.05 < scale < 1.0  # refitted on the warm-up's SGBM (x0.51 per frame measured)
    (record,) = _records(out, BASES_RECORD)
    assert record["0.tuning"] == entry.tuning
    # the channels (the first outputs' basis) and the densify record say it too
    assert recorded_metadata(out)[BASIS_TUNING_KEY] == entry.tuning
    (made,) = _records(out, DENSIFY_RECORD)
    assert made["basis_tuning"] == entry.tuning
    # evaluate says the stored estimate is the tuned model's, and that its re-densified rows
    # are the paper's model with the basis (as for every basis)
    result, _ = evaluate_log(out, EvaluateOptions(basis=Basis.indoor(), sweep_every=0))
    (note,) = [note for note in result.notes if "tuned" in note]
    assert note == (
        f"densify's fit check tuned the {BUILT_IN_INDOOR} basis from frame 0 (local kernel "
        f"laplace, 64 px, 40 px^2; std x{scale:.3g}): the stored estimate is that model's; the "
        "rows that re-densify with the basis use the paper's model (no local kernel, no std "
        "scale), as for every basis"
    )
    assert note in result.summary()["notes"]


def test_a_piped_output_carries_the_tuning_and_the_channels_stand_in_for_a_record(
    room5: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Densified to standard output: recorded as to a file. A log without the record (an
    interrupted run): evaluate reads the first outputs' tuning from the channels."""
    stream = io.BytesIO()
    densify(room5, stream, processor=ProcessorConfig())
    out = tmp_path / "piped.mcap"
    out.write_bytes(stream.getvalue())
    (entry,) = recorded_bases(out)
    assert tuning_of(entry.tuning)["local_prior"] == STREET_KERNEL
    assert recorded_metadata(out)[BASIS_TUNING_KEY] == entry.tuning
    monkeypatch.setattr(tuning_module, "recorded_bases", lambda *args: [])
    (note,) = tuning_notes(out, OutputTopics(), redensified=False)
    assert note.startswith(
        f"densify's fit check tuned the {BUILT_IN_INDOOR} basis of the first outputs (local "
        "kernel laplace, 64 px, 40 px^2; std x"
    )
    assert note.endswith("): the stored estimate is that model's")


def test_an_untuned_log_records_as_before(room5: Path, tmp_path: Path) -> None:
    """No tuning: no key more in the record, the channels or the densify record (their bytes
    as before), and evaluate has nothing to say of it."""
    out = tmp_path / "plain.mcap"
    densify(room5, out, processor=ProcessorConfig(adapt="off"))
    (record,) = _records(out, BASES_RECORD)
    assert sorted(record) == sorted(
        ["count", "output_prefix"]
        + [f"0.{name}" for name in BasisInForce._fields if name != "tuning"]
    )
    (entry,) = recorded_bases(out)
    assert (entry.basis, entry.tuning) == (BUILT_IN, "")
    assert BASIS_TUNING_KEY not in recorded_metadata(out)
    assert "basis_tuning" not in _records(out, DENSIFY_RECORD)[0]
    assert tuning_notes(out, OutputTopics(), redensified=True) == []


def test_the_record_of_bases_keeps_its_form_and_reads_older_records() -> None:
    plain = BasisInForce("built-in", "0123456789abcdef", 0, 5, 7)
    tuned = BasisInForce("built-in-indoor", "fedcba9876543210", 3, 8, 9, '{"std_scale":0.5}')
    record = bases_record([plain, tuned], "/pcainterp")
    assert list(record) == [
        "count",
        "output_prefix",
        *(f"0.{name}" for name in plain._fields[:5]),
        *(f"1.{name}" for name in plain._fields[:5]),
        "1.tuning",
    ]
    assert recorded_bases_of(record) == [plain, tuned]
    older = {key: value for key, value in record.items() if key != "1.tuning"}
    assert recorded_bases_of(older)[1].tuning == ""  # an older log: read as untuned


def test_a_tuning_reads_back_as_the_estimate_s_options() -> None:
    tuning: dict[str, object] = {
        "local_prior": LocalPrior(40.0, 64.0, "laplace"),
        "std_scale": 0.16628409922122955,
        "scale_by_innovation": False,
    }
    text = tuning_json(tuning)
    assert json.loads(text)["local_prior"]["kernel"] == "laplace"
    assert tuning_of(text) == tuning
    assert tuning_of("") == {}
    assert tuning_json({}) == ""
    assert describe_tuning(tuning) == "local kernel laplace, 64 px, 40 px^2; std x0.166"
    for bad in (
        '{"sigma": 3}',
        '{"local_prior": {"kernel": "cubic"}}',
        "[",
        '{"scale_by_innovation": 1}',
    ):
        with pytest.raises(ValueError, match="is not one this version reads"):
            tuning_of(bad)


def test_a_re_check_that_changes_only_the_tuning_starts_a_stretch() -> None:
    """The same basis object densified untuned, then tuned, then with another std scale:
    three stretches (before, one: the record named the first's settings for all)."""
    camera = StereoCamera(376, 240, 200.0, 200.0, 188.0, 120.0, 0.12)
    frames = [StereoFrame(i, i, i, "left", None, None, camera) for i in range(4)]  # type: ignore[arg-type]
    adaptation = Adaptation(
        mode="check", may_replace=True, warmup_frames=8, robust="none", calibrate=True
    )
    indoor = Basis.indoor()
    adaptation.bind(frames[:1], indoor)
    first = {"local_prior": STREET_KERNEL, "std_scale": 0.2, "scale_by_innovation": False}
    adaptation.switched = Candidate("indoor tuned", indoor, {}, first)
    adaptation.bind(frames[1:2], indoor)
    adaptation.bind(frames[2:3], indoor)  # unchanged: the same stretch
    adaptation.switched = Candidate("indoor tuned", indoor, {}, {**first, "std_scale": 0.3})
    adaptation.bind(frames[3:], indoor)
    starts = [(start.frame.index, start.tuning) for start in adaptation.in_force]
    assert starts == [(0, None), (1, first), (3, {**first, "std_scale": 0.3})]
