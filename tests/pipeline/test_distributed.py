"""Scale-out on a real dask.distributed LocalCluster (2 worker processes) on small logs."""

from __future__ import annotations

import dataclasses
import os
import shutil
import signal
import struct
import subprocess
import sys
import time
import zlib
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.linalg import subspace_angles

from pcainterp_stream.errors import ClusterTaskError, TopicNotFoundError
from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.io import rosmsg
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import LogFormat, open_writer
from pcainterp_stream.pipeline import densify_fleet, distributed, jobs
from pcainterp_stream.pipeline.learn import AUTO_PRIOR_MAPS, learn_pairing

pytest.importorskip("dask.distributed")


@pytest.fixture(scope="module")
def client() -> Iterator[Any]:
    with distributed.connect(workers=2) as connected:
        yield connected


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("distributed")
    first, second = folder / "a.mcap", folder / "b.mcap"
    jobs.synth(first, frames=14, seed=21, scale=0.25, fmt="mcap")
    jobs.synth(second, frames=10, seed=22, scale=0.25, fmt="mcap")
    return {"a": first, "b": second, "folder": folder}


def test_merge_of_summaries_matches_one_summary_of_all_maps() -> None:
    rng = np.random.default_rng(0)
    maps = rng.normal(size=(30, 200)).astype(np.float32) + np.linspace(0, 5, 200, dtype=np.float32)
    kwargs: dict[str, Any] = {"grid_size": (10, 20), "image_size": (40, 80), "focal_baseline": 1.0}
    whole = distributed.summarize(maps, 40, **kwargs)
    parts = [distributed.summarize(maps[i : i + 7], 40, **kwargs) for i in range(0, 30, 7)]
    merged = parts[0]
    for part in parts[1:]:
        merged = distributed.merge(merged, part, 40)
    assert merged is not None
    assert merged.n_maps == 30
    np.testing.assert_allclose(merged.mean, whole.mean, atol=1e-6)
    assert merged.squares == pytest.approx(whole.squares, rel=1e-6)
    gram_whole = whole.factor.astype(np.float64) @ whole.factor.T
    gram_merged = merged.factor.astype(np.float64) @ merged.factor.T
    np.testing.assert_allclose(gram_merged, gram_whole, atol=1e-3 * np.abs(gram_whole).max())


def test_merges_carry_the_count_of_a_chunk_of_blank_maps_and_ignore_its_statistics() -> None:
    # bug hunt 16D F6: a chunk whose maps were all blank returned None, its count lost
    from pcainterp_stream.pipeline.learn_sketch import empty

    rng = np.random.default_rng(1)
    maps = rng.normal(size=(9, 200)).astype(np.float32)
    kwargs: dict[str, Any] = {"grid_size": (10, 20), "image_size": (40, 80), "focal_baseline": 1.0}
    whole = distributed.summarize(maps, None, **kwargs)
    blank = empty((10, 20), (40, 80), 1.0, 5)
    some = dataclasses.replace(whole, blank_maps=2)
    for merged in (
        distributed.merge(blank, some, 40),
        distributed.merge(some, blank, 40),
        distributed.combine([blank, None, some]),
        distributed.combine([some, blank]),
    ):
        assert merged is not None
        assert (merged.n_maps, merged.blank_maps) == (9, 7)
        np.testing.assert_allclose(merged.mean, whole.mean, atol=1e-6)
        assert merged.squares == pytest.approx(whole.squares, rel=1e-6)
    only = distributed.combine([blank, None, blank])
    assert only is not None
    assert (only.n_maps, only.blank_maps) == (0, 10)
    both = distributed.merge(blank, blank, 40)
    assert both is not None
    assert (both.n_maps, both.blank_maps) == (0, 10)
    assert distributed.combine([None, None]) is None


def test_learn_on_cluster_matches_local_learner(
    logs: dict[str, Path], client: Any, tmp_path: Path
) -> None:
    options = jobs.LearnOptions(n_components=8, fit_prior=False)
    local = jobs.learn([logs["a"], logs["b"]], tmp_path / "local.npz", options, PairingConfig())
    remote = distributed.learn_distributed(
        [logs["a"], logs["b"]],
        tmp_path / "remote.npz",
        options,
        PairingConfig(),
        client,
        chunk_frames=5,
    )
    assert Basis.load(tmp_path / "remote.npz").n_train == local.n_train == 24
    assert remote.image_size == local.image_size
    assert remote.focal_baseline == pytest.approx(local.focal_baseline)
    np.testing.assert_allclose(remote.mean, local.mean, atol=1e-3)
    # 24 maps, rank <= 23 <= l + oversampling: the sketch is exact up to float32 rounding
    np.testing.assert_allclose(remote.eigenvalues, local.eigenvalues, rtol=1e-3)
    assert remote.total_variance == pytest.approx(local.total_variance, rel=1e-4)
    first = local.components.reshape(local.components.shape[0], -1).T.astype(np.float64)
    second = remote.components.reshape(remote.components.shape[0], -1).T.astype(np.float64)
    assert np.degrees(subspace_angles(first[:, :5], second[:, :5])).max() < 0.5


def test_learn_on_cluster_warns_of_the_far_cut_as_one_process_does(
    client: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """16D F8: `learn --no-fit-prior --workers N` on a small-f*b camera said nothing of it."""
    from pcainterp_stream.synth import SynthConfig, generate
    from pcainterp_stream.synth.indoor import camera_options
    from pcainterp_stream.synth.log import write_synthetic_log

    config = {"seed": 11, "frames": 6, "scale": 0.5, "scene": "indoor"}
    log = tmp_path / "d.mcap"
    write_synthetic_log(generate(SynthConfig(**config, **camera_options("640x480"))), log)  # type: ignore[arg-type]
    options = jobs.LearnOptions(fit_prior=False, n_components=3)
    capsys.readouterr()
    jobs.learn([log], tmp_path / "here.npz", options, PairingConfig())
    here = [line for line in capsys.readouterr().out.splitlines() if "too far" in line]
    distributed.learn_distributed([log], tmp_path / "there.npz", options, PairingConfig(), client)
    there = [line for line in capsys.readouterr().out.splitlines() if "too far" in line]
    assert len(here) == 1
    assert "of the maps' pixels have a disparity below 2 px (beyond 4.81 m)" in here[0]
    assert there == here


def test_learn_on_cluster_reads_each_log_with_its_own_topics(
    logs: dict[str, Path], client: Any, tmp_path: Path
) -> None:
    renamed = tmp_path / "cam.mcap"
    with open_log(logs["b"]) as reader, open_writer(renamed, LogFormat.MCAP) as writer:
        for raw in reader.messages():
            topic = raw.topic.replace("/stereo/", "/cam/", 1)
            writer.add_message(topic, reader.decode(raw), raw.log_time_ns)
    options = jobs.LearnOptions(n_components=3)  # and the prior fitted on held-out frames
    both = [logs["a"], renamed]
    pairing = learn_pairing(both, PairingConfig(discover=True))
    remote = distributed.learn_distributed(
        both, tmp_path / "remote.npz", options, pairing, client, chunk_frames=5
    )
    assert remote.n_train == 11 + 8  # 80 % of 14 and of 10 frames
    assert remote.meta["prior"]["fit_logs"] == [str(logs["a"]), str(renamed)]


def test_learn_on_cluster_with_truncation_keeps_leading_subspace(
    logs: dict[str, Path], client: Any, tmp_path: Path
) -> None:
    options = jobs.LearnOptions(n_components=3, fit_prior=False)
    local = jobs.learn([logs["a"]], tmp_path / "local.npz", options, PairingConfig())
    remote = distributed.learn_distributed(
        [logs["a"]],
        tmp_path / "r.npz",
        options,
        PairingConfig(),
        client,
        chunk_frames=4,
        oversampling=3,
    )
    # r = 6 columns kept from 14 maps: the leading eigenpairs stay close, not exact
    np.testing.assert_allclose(remote.eigenvalues[:2], local.eigenvalues[:2], rtol=0.05)
    first = local.components[:2].reshape(2, -1).T.astype(np.float64)
    second = remote.components[:2].reshape(2, -1).T.astype(np.float64)
    assert np.degrees(subspace_angles(first, second)).max() < 10.0


def _eigenpairs(basis: Basis, top: int) -> tuple[np.ndarray, np.ndarray]:
    return basis.eigenvalues, basis.components[:top].reshape(top, -1).T.astype(np.float64)


def test_learn_on_cluster_is_one_process_s_fine_tune_and_the_same_file_every_run(
    logs: dict[str, Path], client: Any, tmp_path: Path
) -> None:
    # bug hunt 7B F5: chunks truncated to r columns before the built-in basis joined, merged
    # in finishing order: another (worse) basis than one process's, another every run.
    # Maps that fit learn.ONE_STEP_BYTES are merged here in one exact step, in chunk order.
    options = jobs.LearnOptions(n_components=3, fit_prior=False, with_synthetic="auto")
    both = [logs["a"], logs["b"]]
    local = jobs.learn(both, tmp_path / "local.npz", options, PairingConfig())
    assert "finetune" in local.meta
    runs = [tmp_path / "c1.npz", tmp_path / "c2.npz"]
    for run in runs:  # r = l + 1 = 4 columns: chunks of 3 maps would not be truncated
        distributed.learn_distributed(
            both, run, options, PairingConfig(), client, chunk_frames=2, oversampling=1
        )
    assert runs[0].read_bytes() == runs[1].read_bytes()
    remote = Basis.load(runs[0])
    assert remote.meta["distributed"]["merge"] == "in one step"
    values_here, here = _eigenpairs(local, 3)
    values_there, there = _eigenpairs(remote, 3)
    np.testing.assert_allclose(values_there, values_here, rtol=1e-4)
    assert subspace_angles(here, there).max() < 1e-3  # rad


def test_learn_on_cluster_beyond_one_step_merges_in_chunk_order_the_same_file(
    logs: dict[str, Path], client: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from pcainterp_stream.pipeline import learn as learn_module

    monkeypatch.setattr(learn_module, "ONE_STEP_BYTES", 0)  # the truncated tree
    options = jobs.LearnOptions(n_components=3, fit_prior=False, with_synthetic=0)
    runs = [tmp_path / "t1.npz", tmp_path / "t2.npz"]
    for run in runs:
        distributed.learn_distributed(
            [logs["a"], logs["b"]], run, options, PairingConfig(), client, chunk_frames=1
        )
    assert Basis.load(runs[0]).meta["distributed"]["merge"] == "tree"
    assert runs[0].read_bytes() == runs[1].read_bytes()


def _messages(path: Path) -> list[tuple[str, int, Any]]:
    """A log's messages, a PNG's deflate stream replaced by what it inflates to.

    ISA-L's deflate (the PNGs of compressedDepth) has once written another valid stream
    for the same rows in another process; everything else is compared byte for byte.
    """
    with open_log(path) as reader:
        return [(raw.topic, raw.log_time_ns, _inflated(reader, raw)) for raw in reader.messages()]


def _inflated(reader: Any, raw: Any) -> Any:
    data = bytes(raw.data)
    if b"\x89PNG" not in data:
        return data
    message = reader.decode(raw)
    payload = bytes(message.data)
    start = payload.index(b"\x89PNG") + 8
    chunks: list[tuple[bytes, bytes]] = []
    while start < len(payload):
        (length,) = struct.unpack(">I", payload[start : start + 4])
        kind = payload[start + 4 : start + 8]
        body = payload[start + 8 : start + 8 + length]
        chunks.append((kind, zlib.decompress(body) if kind == b"IDAT" else body))
        start += 12 + length
    stamp = message.header.stamp
    return (
        stamp.sec,
        stamp.nanosec,
        message.header.frame_id,
        message.format,
        payload[: payload.index(b"\x89PNG")],
        chunks,
    )


def test_densify_many_matches_one_by_one_and_reports_a_failing_log(
    logs: dict[str, Path], client: Any, tmp_path: Path
) -> None:
    basis = tmp_path / "basis.npz"
    jobs.learn(
        [logs["a"]], basis, jobs.LearnOptions(n_components=6, fit_prior=False), PairingConfig()
    )
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(b"not a log at all")
    out_dir = tmp_path / "out"
    outcomes = distributed.densify_many(
        [logs["a"], broken, logs["b"]], out_dir, basis, client, pairing=PairingConfig()
    )
    assert [o.error is None for o in outcomes] == [True, False, True]
    assert "broken.mcap" in str(outcomes[1].error)
    assert [o.frames for o in outcomes] == [14, 0, 10]
    for name in ("a", "b"):
        alone = tmp_path / f"{name}_alone.mcap"
        jobs.densify(logs[name], alone, basis, pairing=PairingConfig())
        together = distributed.output_path(logs[name], out_dir)
        assert _messages(together) == _messages(alone)


def _reported(kwargs: dict[str, Any], outcomes: list[Any]) -> list[Any]:
    """Hand a fake densify_many's outcomes to the caller's on_outcome, then return them."""
    for outcome in outcomes:
        kwargs["on_outcome"](outcome)
    return outcomes


def _assert_same_model(here: Basis, there: Basis) -> None:
    """The bar of a cluster's learn: the local learner's model up to the sketch's truncation."""
    assert there.components.shape == here.components.shape
    assert there.n_train == here.n_train
    assert there.image_size == here.image_size
    assert there.focal_baseline == pytest.approx(here.focal_baseline)
    top = min(5, here.n_components)
    first = here.components[:top].reshape(top, -1).T.astype(np.float64)
    second = there.components[:top].reshape(top, -1).T.astype(np.float64)
    assert subspace_angles(first, second).max() < 0.05  # rad
    np.testing.assert_allclose(there.eigenvalues, here.eigenvalues, rtol=0.02)
    assert there.meta["source"] == here.meta["source"]
    assert ("finetune" in there.meta) == ("finetune" in here.meta)
    if "finetune" in here.meta:
        assert there.meta["finetune"] == here.meta["finetune"]
    prior_here, prior_there = here.meta["prior"], there.meta["prior"]
    assert prior_there["held_out_frames"] == prior_here["held_out_frames"]
    assert prior_there["fit_logs"] == prior_here["fit_logs"]
    local_here, local_there = prior_here["local"], prior_there["local"]
    assert (local_there is None) == (local_here is None)
    if local_here is not None:
        assert local_there["kernel"] == local_here["kernel"]
        assert local_there["length_scale"] == pytest.approx(local_here["length_scale"], rel=0.05)
    assert prior_there["sigma"] == pytest.approx(prior_here["sigma"], rel=0.05)
    assert prior_there["process_noise"] == pytest.approx(prior_here["process_noise"], rel=0.05)
    assert prior_there["std_scale"] == pytest.approx(prior_here["std_scale"], rel=0.05)


@pytest.mark.parametrize(
    ("flags", "cluster"),
    [
        pytest.param([], ["--workers", "2"], id="defaults-workers-2"),
        pytest.param(["--with-synthetic", "0"], None, id="synthetic-0-scheduler"),
    ],
)
def test_cli_learn_on_the_cluster_learns_the_model_learn_learns_here(
    logs: dict[str, Path],
    client: Any,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    flags: list[str],
    cluster: list[str] | None,
) -> None:
    from pcainterp_stream import cli

    args = ["learn", str(logs["a"]), str(logs["b"]), "--components", "6", *flags]
    here, there = tmp_path / "here.npz", tmp_path / "there.npz"
    assert cli.main([*args, "-o", str(here)]) == 0
    notes_here = [line for line in capsys.readouterr().out.splitlines() if "note" in line]
    where = cluster if cluster is not None else ["--scheduler", client.scheduler.address]
    assert cli.main([*args, "-o", str(there), *where]) == 0
    notes_there = [line for line in capsys.readouterr().out.splitlines() if "note" in line]
    assert notes_there == notes_here
    local, remote = Basis.load(here), Basis.load(there)
    _assert_same_model(local, remote)
    # 20 % of each log held out for the fit: 11 of 14 and 8 of 10 maps learned
    merged = 0 if flags else AUTO_PRIOR_MAPS
    assert remote.n_train == 11 + 8 + merged
    assert ("finetune" in remote.meta) is (not flags)
    assert remote.meta["learning"]["method"] == (
        "distributed" if flags else "finetune, distributed"
    )
    assert remote.meta["distributed"]["tasks"] >= 2


def test_cli_learn_on_the_cluster_fits_the_prior_on_fit_logs(
    logs: dict[str, Path], client: Any, tmp_path: Path
) -> None:
    from pcainterp_stream import cli

    args = ["learn", str(logs["a"]), "--components", "4", "--with-synthetic", "0"]
    args += ["--fit-logs", str(logs["b"])]
    here, there = tmp_path / "here.npz", tmp_path / "there.npz"
    assert cli.main([*args, "-o", str(here)]) == 0
    assert cli.main([*args, "-o", str(there), "--scheduler", client.scheduler.address]) == 0
    local, remote = Basis.load(here), Basis.load(there)
    assert remote.n_train == local.n_train == 14  # no share held out: all of a's maps
    assert remote.meta["prior"]["fit_logs"] == [str(logs["b"])]
    _assert_same_model(local, remote)


def test_cli_densify_out_dir_on_the_cluster_uses_densify_s_defaults(
    logs: dict[str, Path], client: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from pcainterp_stream import cli

    address = client.scheduler.address
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(b"\x89MCAP0\r\n")  # a magic and nothing else
    code = cli.main(
        [
            "densify",
            str(logs["a"]),
            str(broken),
            str(logs["b"]),
            "--out-dir",
            str(tmp_path / "out"),
            "--scheduler",
            address,
        ]
    )
    captured = capsys.readouterr()
    assert code == 1
    assert "2 of 3 logs densified, 24 frames" in captured.out
    assert len([line for line in captured.err.splitlines() if "broken.mcap" in line]) == 1
    assert (tmp_path / "out" / "a_dense.mcap").exists()
    # the same command's defaults as densify -o (the built-in basis, every estimate default)
    alone = tmp_path / "b_alone.mcap"
    assert cli.main(["densify", str(logs["b"]), "-o", str(alone)]) == 0
    assert _messages(tmp_path / "out" / "b_dense.mcap") == _messages(alone)


def test_densify_many_without_a_basis_uses_the_built_in_one(
    logs: dict[str, Path], client: Any, tmp_path: Path
) -> None:
    from pcainterp_stream.io.outputs import BASIS_KEY, recorded_metadata

    outcomes = distributed.densify_many([logs["b"]], tmp_path / "out", None, client)
    assert [outcome.error for outcome in outcomes] == [None]
    assert outcomes[0].frames == 10
    assert recorded_metadata(outcomes[0].output)[BASIS_KEY] == "built-in"
    assert outcomes[0].adapted is None  # nothing to say of a basis of its own
    assert outcomes[0].bases == ()


def test_densify_many_removes_the_staging_folder_of_a_killed_run_and_names_its_own(
    logs: dict[str, Path],
    client: Any,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A killed ``densify --out-dir`` (SIGKILL, out of memory) left its staging folders,
    named without the writer, for ever (fix-OUT's note on bug hunt 7B F8): they carry this
    process's id and machine now, and the next run removes a dead run's, in one line."""
    from pcainterp_stream.io import output_paths

    out_dir = tmp_path / "out"
    out_dir.mkdir()
    target = distributed.output_path(logs["b"], out_dir)
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()

    def named(pid: int, suffix: str) -> Path:
        prefix = output_paths.partial_prefix(target).replace(f"-{os.getpid()}@", f"-{pid}@")
        return out_dir / (prefix + suffix)

    stale, live = named(process.pid, "abc12345"), named(os.getppid(), "def67890")
    stale.mkdir()
    (stale / target.name).write_bytes(bytes(2_500_000))
    live.mkdir()
    staged: list[str] = []
    commit = densify_fleet._commit
    monkeypatch.setattr(
        densify_fleet,
        "_commit",
        lambda folder, out: (staged.append(folder.name), commit(folder, out)),
    )
    [outcome] = distributed.densify_many([logs["b"]], out_dir, None, client)
    assert outcome.error is None
    assert not stale.exists()
    assert live.is_dir()  # a run still going (here: this test's parent) is never touched
    assert capsys.readouterr().err.strip() == (
        f"note: removed {target}'s partial output left by an earlier run that was killed (2.5 MB)"
    )
    [name] = staged
    assert name.startswith(output_paths.partial_prefix(target))  # was: .b_dense.mcap.partial-
    assert sorted(path.name for path in out_dir.iterdir()) == [live.name, target.name]


def test_densify_many_says_which_logs_adapted_and_where_their_basis_is(
    client: Any, tmp_path: Path
) -> None:
    """A room the street basis does not fit gets a basis of its own, saved beside its output:
    the outcome says so (densify -o prints it; --out-dir printed nothing of it)."""
    from pcainterp_stream.pipeline.densify import own_basis_path
    from pcainterp_stream.pipeline.processor import ProcessorConfig

    room = tmp_path / "room.mcap"
    jobs.synth(room, frames=8, seed=1, scale=0.25, fmt="mcap", scene="indoor", camera="752x480")
    out = tmp_path / "out"
    processor = ProcessorConfig(builtin="street")
    (outcome,) = distributed.densify_many([room], out, None, client, processor=processor)
    assert outcome.error is None
    assert outcome.adapted is not None
    assert outcome.adapted.startswith("the built-in street basis does not fit this camera")
    assert outcome.bases == (own_basis_path(out / "room_dense.mcap"),)
    assert outcome.bases[0].is_file()


def test_cli_densify_out_dir_prints_a_line_per_adapted_log(
    logs: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    from contextlib import nullcontext

    from pcainterp_stream import cli

    def densify_many(inputs: list[Path], out_dir: Path, *args: Any, **kwargs: Any) -> Any:
        own, final = out_dir / "b_dense.basis.npz", out_dir / "b_dense.final.basis.npz"
        return _reported(
            kwargs,
            [
                distributed.DensifyOutcome(inputs[0], out_dir / "a_dense.mcap", 1, 1.0, None),
                distributed.DensifyOutcome(
                    inputs[1], out_dir / "b_dense.mcap", 9, 1.0, None, adapted="why", bases=(own,)
                ),
                distributed.DensifyOutcome(
                    inputs[1],
                    out_dir / "b_dense.mcap",
                    9,
                    1.0,
                    None,
                    adapted="why",
                    bases=(own, final),
                ),
            ],
        )

    monkeypatch.setattr(distributed, "connect", lambda *args, **kwargs: nullcontext(None))
    monkeypatch.setattr(distributed, "densify_many", densify_many)
    args = [str(logs["a"]), str(logs["b"]), str(logs["b"]), "--out-dir", str(tmp_path)]
    assert cli.main(["densify", *args, "--workers", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == (
        f"densified 1 frame of {logs['a']} -> {tmp_path / 'a_dense.mcap'} (1 of 3 logs done)"
    )
    assert lines[1].startswith("densified 9 frames of ")
    assert lines[2] == f"adapted: b.mcap: why; wrote {tmp_path / 'b_dense.basis.npz'}"
    assert lines[4] == (
        f"adapted: b.mcap: why; wrote {tmp_path / 'b_dense.basis.npz'} and "
        f"{tmp_path / 'b_dense.final.basis.npz'}"
    )
    assert lines[5].startswith("3 of 3 logs densified, 19 frames in ")


def test_cli_densify_refuses_output_with_several_logs(
    logs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Several inputs with -o are the parts of one split recording: two logs are not."""
    from pcainterp_stream import cli

    code = cli.main(["densify", str(logs["a"]), str(logs["b"]), "-o", str(tmp_path / "x.mcap")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1
    assert err[0].startswith(f"pcainterp: error: {logs['a']} (")
    assert "they are not the parts of one split recording" in err[0]
    assert err[0].endswith("to densify them as separate logs, pass --out-dir DIR")
    assert not (tmp_path / "x.mcap").exists()


def test_a_task_returns_the_error_it_meets_and_the_caller_raises_it_in_one_line() -> None:
    """Tasks never raise (Dask would log a multi-line "Compute Failed" block on the worker's
    stderr): this package's errors reach the caller as they are, anything else in one line."""

    def missing_topic() -> None:
        raise TopicNotFoundError("topic /left not found in a.mcap; pass --left-topic")

    def bug() -> None:
        raise ValueError("a bug\nwith a second line")

    def done(value: Any) -> Future[Any]:
        future: Future[Any] = Future()
        future.set_result(value)
        return future

    failure = distributed.run_task(missing_topic)
    assert isinstance(failure, distributed.TaskFailure)
    with pytest.raises(TopicNotFoundError, match="pass --left-topic"):
        distributed.task_result(done(failure), "a task")
    unexpected = distributed.run_task(bug)
    assert isinstance(unexpected, distributed.TaskFailure)
    assert unexpected.error is None
    with pytest.raises(ClusterTaskError) as raised:
        distributed.task_result(done(unexpected), "a learning task")
    assert str(raised.value) == (
        "a learning task failed on the cluster with an unexpected ValueError: a bug"
    )
    # a merge of a failed chunk passes the failure on, unrun
    assert distributed.run_task(distributed.merge, unexpected, None, 3) is unexpected
    assert distributed.run_task(lambda a, b: a + b, 1, 2) == 3


def test_densify_many_reports_an_unexpected_error_as_such(
    logs: dict[str, Path], client: Any, tmp_path: Path
) -> None:
    outcomes = distributed.densify_many([logs["b"]], tmp_path / "out", None, client, processor=1)
    assert outcomes[0].unexpected
    assert outcomes[0].error is not None
    assert "failed on the cluster with an unexpected" in outcomes[0].error
    assert list((tmp_path / "out").iterdir()) == []  # its staging folder is gone


def test_cli_densify_out_dir_adds_a_hint_to_an_unexpected_error(
    logs: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    from contextlib import nullcontext

    from pcainterp_stream import cli

    def densify_many(inputs: list[Path], out_dir: Path, *args: Any, **kwargs: Any) -> Any:
        return _reported(
            kwargs,
            [distributed.DensifyOutcome(inputs[0], out_dir / "a_dense.mcap", 0, 0.0, "boom", True)],
        )

    monkeypatch.setattr(distributed, "connect", lambda *args, **kwargs: nullcontext(None))
    monkeypatch.setattr(distributed, "densify_many", densify_many)
    code = cli.main(["densify", str(logs["a"]), "--out-dir", str(tmp_path), "--workers", "1"])
    assert code == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == (
        f"pcainterp: error: {logs['a']}: boom; densify this log alone "
        f"(pcainterp densify {logs['a']} -o OUTPUT) to see where it failed (1 of 1 logs done)"
    )


def test_cli_learn_on_the_cluster_adds_a_hint_to_an_unexpected_error(
    logs: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    from contextlib import nullcontext

    from pcainterp_stream import cli

    def learn_distributed(*args: Any) -> Any:
        raise ClusterTaskError("a learning task failed on the cluster with an unexpected X: y")

    monkeypatch.setattr(distributed, "connect", lambda *args, **kwargs: nullcontext(None))
    monkeypatch.setattr(distributed, "learn_distributed", learn_distributed)
    args = ["learn", str(logs["a"]), "-o", str(tmp_path / "b.npz"), "--workers", "1"]
    assert cli.main(args) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.endswith("y; run learn without --scheduler/--workers to see where it failed")


# --- the command in a process of its own: what the user sees on stderr, and Ctrl-C ---------

PCAINTERP = [sys.executable, "-m", "pcainterp_stream.cli"]
REPEATS = 40  # the long log: the 10-frame log 40 times, ~15 s of densify: still running
START_S = 120  # generous: a cluster starts in 2-8 s on a loaded two-core machine
EXIT_S = 30


@pytest.fixture(scope="module")
def long_log(logs: dict[str, Path]) -> Path:
    """Log "b" repeated REPEATS times, stamps shifted so every pair is distinct."""
    path = logs["folder"] / "long.mcap"
    with open_log(logs["b"]) as reader:
        raws = list(reader.messages())
    span_ns = raws[-1].log_time_ns - raws[0].log_time_ns + 100_000_000
    with open_writer(path, "mcap") as writer:
        for repeat in range(REPEATS):
            for raw in raws:
                writer.add_raw(_shifted(raw, repeat * span_ns))
    return path


def _shifted(raw: Any, shift_ns: int) -> Any:
    message = rosmsg.deserialize(raw.data, raw.msgtype)
    stamp = rosmsg.stamp_ns(message) + shift_ns
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, 10**9)
    return raw._replace(
        data=rosmsg.serialize(message),
        log_time_ns=raw.log_time_ns + shift_ns,
        publish_time_ns=raw.publish_time_ns + shift_ns,
    )


def _default_signals() -> None:
    """Default SIGINT in the child (a shell running the tests in the background ignores it)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _writing(out_dir: Path) -> list[str]:
    """The outputs a worker is writing: a file of the output's name in a hidden partial."""
    names = (staging.name.split(".partial-")[0][1:] for staging in out_dir.glob(".*.partial-*"))
    return sorted(name for name in names if any(out_dir.glob(f".{name}.partial-*/**/{name}")))


def _interrupt_out_dir(
    args: list[str],
    out_dir: Path,
    ready: Callable[[], bool],
    send: Callable[[subprocess.Popen[str]], None],
) -> tuple[subprocess.Popen[str], str, list[str]]:
    """Run ``pcainterp ARGS`` in a session of its own, ``send`` it a signal once ``ready()``.

    Returns:
        The ended process, its stderr, and the committed outputs at the signal.
    """
    process = subprocess.Popen(
        [*PCAINTERP, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_default_signals,
        start_new_session=True,  # its own process group, as a terminal's foreground job
    )
    try:
        deadline = time.monotonic() + START_S
        while not (out_dir.is_dir() and ready()):
            assert process.poll() is None, process.communicate()
            assert time.monotonic() < deadline, "the tasks never started writing"
            time.sleep(0.05)
        committed = sorted(p.name for p in out_dir.glob("*.mcap"))
        send(process)
        # stderr closes when the command and every process it started (workers, the
        # resource tracker, which would warn of leaked semaphores) have ended
        _, err = process.communicate(timeout=EXIT_S)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    return process, err, committed


def _group_has_ended(group: int) -> bool:
    """Whether no live process (zombies aside) is left in process group ``group``."""
    deadline = time.monotonic() + 10
    while True:
        alive = []
        for status in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = status.read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[2]) == group and fields[0] != "Z":
                alive.append(status.parent.name)
        if not alive or time.monotonic() > deadline:
            return not alive
        time.sleep(0.1)


@pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="needs /proc")
@pytest.mark.slow  # a cluster starts: 2-8 s on a loaded two-core machine
def test_ctrl_c_at_the_terminal_stops_densify_out_dir_at_once(
    long_log: Path, tmp_path: Path
) -> None:
    """SIGINT to the whole process group (a terminal's Ctrl-C: the workers get it too) while
    both workers write: exit 130, one line, no staging folder, no output, no process left."""
    first, second = tmp_path / "first.mcap", tmp_path / "second.mcap"
    shutil.copy(long_log, first)
    shutil.copy(long_log, second)
    out_dir = (tmp_path / "dense").resolve()
    process, err, committed = _interrupt_out_dir(
        ["densify", str(first), str(second), "--out-dir", str(out_dir), "--workers", "2"],
        out_dir,
        lambda: _writing(out_dir) == ["first_dense.mcap", "second_dense.mcap"],
        lambda running: os.killpg(running.pid, signal.SIGINT),
    )
    assert committed == []
    assert process.returncode == 130, err
    assert err.splitlines() == [
        f"pcainterp: interrupted; no partial output was left in {out_dir}; "
        "no output was finished before the signal"
    ]
    assert not out_dir.exists()  # the run made it: removed again, empty
    assert _group_has_ended(process.pid)


@pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="needs /proc")
@pytest.mark.slow  # a cluster starts: 2-8 s on a loaded two-core machine
def test_sigterm_keeps_the_outputs_committed_before_it_and_no_other(
    logs: dict[str, Path], long_log: Path, tmp_path: Path
) -> None:
    """SIGTERM to the command alone after one log was done, the other being written (one
    worker): the first output stays and is named, the other is neither committed nor left."""
    out_dir = (tmp_path / "dense").resolve()
    out_dir.mkdir()
    (out_dir / "unrelated.txt").write_text("the user's")

    def ready() -> bool:
        done = [p.name for p in out_dir.glob("*.mcap")]
        return len(done) == 1 and len(_writing(out_dir)) == 1

    process, err, committed = _interrupt_out_dir(
        ["densify", str(logs["a"]), str(long_log), "--out-dir", str(out_dir), "--workers", "1"],
        out_dir,
        ready,
        lambda running: running.send_signal(signal.SIGTERM),
    )
    assert process.returncode == 130, err
    (kept,) = committed
    assert err.splitlines() == [
        f"pcainterp: interrupted; no partial output was left in {out_dir}; kept 1 of 2 "
        f"outputs, finished before the signal: {out_dir / kept}"
    ]
    left = sorted(p.name for p in out_dir.iterdir())
    assert [name for name in left if name.startswith(".")] == []
    assert [name for name in left if name.endswith(".mcap")] == [kept]
    assert "unrelated.txt" in left
    assert _group_has_ended(process.pid)


@pytest.mark.slow  # a cluster starts: 2-8 s on a loaded two-core machine
def test_a_failing_log_of_out_dir_is_one_line_without_dask_s_report(
    logs: dict[str, Path], tmp_path: Path
) -> None:
    """A log cut after its magic bytes (it passes the check before the cluster, bug hunt
    15E F4, and fails in its task): our one-line error and the summary, no "Compute Failed"
    block."""
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(b"\x89MCAP0\r\n")
    out_dir = tmp_path / "dense"
    args = ["densify", str(logs["a"]), str(cut), "--out-dir", str(out_dir), "--workers", "1"]
    process = subprocess.run(
        [*PCAINTERP, *args],
        capture_output=True,
        text=True,
        timeout=START_S,
        check=False,
    )
    assert process.returncode == 1, process.stderr
    [line] = process.stderr.splitlines()
    text = line.removesuffix(" (1 of 2 logs done)").removesuffix(" (2 of 2 logs done)")
    assert text.startswith(f"pcainterp: error: no stereo pair found in {cut.resolve()}: ")
    assert text.endswith("; repair or re-record the log")
    assert "1 of 2 logs densified" in process.stdout.splitlines()[-2]
    assert (
        process.stdout.splitlines()[-1]
        == line.replace("pcainterp: error: ", "failed: ", 1)[: -len(" (1 of 2 logs done)")]
    )
    assert sorted(p.name for p in out_dir.iterdir()) == ["a_dense.mcap"]


def test_densify_many_refuses_an_output_that_is_a_folder_and_densifies_the_others(
    logs: dict[str, Path], client: Any, tmp_path: Path
) -> None:
    """Outputs are committed by the caller: a folder in the way is one log's error, before
    its work (no traceback when renaming onto it), and nothing hidden is left."""
    out_dir = tmp_path / "out"
    (out_dir / "a_dense.mcap").mkdir(parents=True)
    outcomes = distributed.densify_many([logs["a"], logs["b"]], out_dir, None, client)
    assert outcomes[0].error is not None
    assert "is a folder" in outcomes[0].error
    assert not outcomes[0].unexpected
    assert outcomes[1].error is None
    assert sorted(p.name for p in out_dir.iterdir()) == ["a_dense.mcap", "b_dense.mcap"]
    assert (out_dir / "a_dense.mcap").is_dir()


def test_cli_densify_out_dir_prints_each_log_s_warnings(
    logs: dict[str, Path], client: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run of several logs says per log what densify -o would warn of (here: pairs lost)."""
    from pcainterp_stream import cli

    late = tmp_path / "late.mcap"  # the first 3 right images stamped 2 ms after their left
    with open_log(logs["b"]) as reader, open_writer(late, "mcap") as writer:
        shifted = 0
        for raw in reader.messages():
            if raw.topic != "/stereo/right/image_rect" or shifted == 3:
                writer.add_raw(raw)
                continue
            shifted += 1
            message = rosmsg.deserialize(raw.data, raw.msgtype)
            stamp = rosmsg.stamp_ns(message) + 2_000_000
            message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, 10**9)
            writer.add_raw(raw._replace(data=rosmsg.serialize(message)))
    code = cli.main(
        [
            "densify",
            str(logs["a"]),
            str(late),
            "--out-dir",
            str(tmp_path / "out"),
            "--scheduler",
            client.scheduler.address,
        ]
    )
    out, err = capsys.readouterr()
    assert code == 0, out
    assert f"densified 7 frames of {late} ->" in out
    assert "warning:" not in out  # diagnostics on standard error, the report on standard output
    warnings = [line for line in err.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1, out
    assert warnings[0].startswith("warning: late.mcap: all 6 images dropped unpaired had an")
    assert warnings[0].endswith("pass --stamp-tolerance-ms 2 to pair them")
