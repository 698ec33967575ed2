"""Scale-out on a real dask.distributed LocalCluster (2 worker processes) on small logs."""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.linalg import subspace_angles

from pcainterp_stream.estimate.basis import Basis
from pcainterp_stream.frontend.pairing import PairingConfig
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.io.logwriter import LogFormat, open_writer
from pcainterp_stream.pipeline import distributed, jobs
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


def test_cli_densify_refuses_output_with_several_inputs(
    logs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from pcainterp_stream import cli

    code = cli.main(
        [
            "densify",
            str(logs["a"]),
            str(logs["b"]),
            "-o",
            str(tmp_path / "x.mcap"),
            "--basis",
            str(tmp_path / "b.npz"),
        ]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert err == [
        "pcainterp: error: -o takes one input but 2 were given; "
        "pass --out-dir DIR to densify several logs"
    ]
    assert not (tmp_path / "x.mcap").exists()
