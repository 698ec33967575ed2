"""A basis's fitted prior (``meta["prior"]``) is checked when the file is read (bug hunt 16A F1).

Before, a damaged or hand-edited value passed every load check and then crashed
``densify --basis`` (10 variants) and ``info BASIS`` (5) with a traceback.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pcainterp_stream import cli
from pcainterp_stream.errors import BasisError
from pcainterp_stream.estimate.basis import Basis, default_basis_path
from pcainterp_stream.pipeline.jobs import synth


def _edited(path: Path, edit: Any) -> Path:
    """Write the built-in basis to ``path`` with ``edit(meta)`` applied to its meta."""
    with np.load(default_basis_path(), allow_pickle=False) as archive:
        data = {key: archive[key] for key in archive.files}
    meta = json.loads(str(data["meta"]))
    edit(meta)
    data["meta"] = np.array(json.dumps(meta))
    np.savez(path, **data)
    return path


def _set(*keys: str, value: Any) -> Any:
    """An edit that sets meta["prior"][keys...] to value."""

    def edit(meta: dict[str, Any]) -> None:
        where = meta["prior"]
        for key in keys[:-1]:
            where = where[key]
        where[keys[-1]] = value

    return edit


def _drop(*keys: str) -> Any:
    def edit(meta: dict[str, Any]) -> None:
        where = meta["prior"]
        for key in keys[:-1]:
            where = where[key]
        del where[keys[-1]]

    return edit


# (case, edit, the key the message names, the value it shows); the first ten are the
# hunter's densify crashes, of which var, localnovar, sigma, pnstr and stdscale crashed info
DAMAGED = [
    ("kernel", _set("local", "kernel", value="bogus"), "prior.local.kernel", "'bogus'"),
    ("var", _set("local", "variance", value="x"), "prior.local.variance", "'x'"),
    ("varneg", _set("local", "variance", value=-5), "prior.local.variance", "-5"),
    ("ls0", _set("local", "length_scale", value=0), "prior.local.length_scale", "0"),
    ("localstr", _set("local", value="x"), "prior.local", "'x'"),
    ("localnovar", _drop("local", "variance"), "no prior.local.variance", None),
    ("sigma", _set("sigma", value="x"), "prior.sigma", "'x'"),
    ("sigma0", _set("sigma", value=0), "prior.sigma", "0"),
    ("sigmaneg", _set("sigma", value=-1), "prior.sigma", "-1"),
    ("pnstr", _set("process_noise", value="x"), "prior.process_noise", "'x'"),
    ("stdscale", _set("std_scale", value="x"), "prior.std_scale", "'x'"),
    ("pn", _set("process_noise", value=-1), "prior.process_noise", "-1"),
    ("stdscaleneg", _set("std_scale", value=-1), "prior.std_scale", "-1"),
    ("innovation", _set("innovation_std_scale", value=0), "prior.innovation_std_scale", "0"),
    ("plain", _set("plain_sigma", value=None), "prior.plain_sigma", "None"),
    ("inf", _set("local", "length_scale", value=math.inf), "prior.local.length_scale", "inf"),
    ("bool", _set("sigma", value=True), "prior.sigma", "True"),
    ("cellweight", _set("local", "cell_weight", value=2), "prior.local.cell_weight", "2"),
    ("nolength", _drop("local", "length_scale"), "no prior.local.length_scale", None),
    ("localempty", _set("local", value={}), "no prior.local.variance", None),
    ("locallist", _set("local", value=[1]), "prior.local", "a list"),
]
DENSIFY_CRASHED = [case[0] for case in DAMAGED[:10]]
INFO_CRASHED = ["var", "localnovar", "sigma", "pnstr", "stdscale"]


@pytest.mark.parametrize(("case", "edit", "key", "shown"), DAMAGED, ids=[c[0] for c in DAMAGED])
def test_load_refuses_a_damaged_fitted_prior(
    tmp_path: Path, case: str, edit: Any, key: str, shown: str | None
) -> None:
    path = _edited(tmp_path / f"{case}.npz", edit)
    with pytest.raises(BasisError) as caught:
        Basis.load(path)
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith(f"basis file {path}: key 'meta' ")
    assert key in message
    if shown is not None:
        assert f"{key} = {shown}, expected" in message
    assert "pcainterp learn" in message
    assert "remove the key 'prior'" in message


def test_load_refuses_a_prior_that_is_not_an_object(tmp_path: Path) -> None:
    path = _edited(tmp_path / "b.npz", lambda meta: meta.update(prior="x"))
    with pytest.raises(BasisError, match=r"key 'meta' has prior = 'x', expected an object"):
        Basis.load(path)


@pytest.mark.parametrize(
    "edit",
    [
        lambda meta: meta.pop("prior"),  # learn --no-fit-prior
        lambda meta: meta.update(prior=None),
        _set("local", value=None),  # the paper's prior had the best evidence
        _drop("local", "kernel"),  # the Laplace kernel (LocalPrior.from_meta's default)
        _drop("local", "cell_weight"),
        _drop("sigma"),
        _set("candidates", value="anything"),  # informational keys are not checked
    ],
    ids=[
        "no-prior",
        "null-prior",
        "null-local",
        "no-kernel",
        "no-cell-weight",
        "no-sigma",
        "notes",
    ],
)
def test_load_accepts_what_learn_can_write(tmp_path: Path, edit: Any) -> None:
    Basis.load(_edited(tmp_path / "b.npz", edit))


def test_the_built_in_bases_pass() -> None:
    from pcainterp_stream.estimate.prior_meta import check_fitted_prior

    for basis in (Basis.default(), Basis.indoor()):
        check_fitted_prior(copy.deepcopy(basis.meta))


@pytest.fixture(scope="module")
def tiny_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("log") / "tiny.mcap"
    synth(path, frames=2, seed=5, scale=0.25, fmt="mcap")
    return path


def _error_line(capsys: pytest.CaptureFixture[str], *args: str | Path) -> str:
    capsys.readouterr()
    code = cli.main([str(arg) for arg in args])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    lines = err.splitlines()
    assert len(lines) == 1, lines
    return lines[0]


@pytest.mark.parametrize("case", DENSIFY_CRASHED)
def test_densify_with_a_damaged_prior_says_one_line(
    tmp_path: Path, tiny_log: Path, capsys: pytest.CaptureFixture[str], case: str
) -> None:
    _, edit, key, _ = next(entry for entry in DAMAGED if entry[0] == case)
    basis = _edited(tmp_path / f"{case}.npz", edit)
    out = tmp_path / "out.mcap"
    line = _error_line(capsys, "densify", tiny_log, "-o", out, "--basis", basis)
    assert f"basis file {basis}: key 'meta' " in line
    assert key in line
    assert not out.exists()


@pytest.mark.parametrize("case", INFO_CRASHED)
def test_info_of_a_damaged_prior_says_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str
) -> None:
    _, edit, key, _ = next(entry for entry in DAMAGED if entry[0] == case)
    basis = _edited(tmp_path / f"{case}.npz", edit)
    line = _error_line(capsys, "info", basis)
    assert f"basis file {basis}: key 'meta' " in line
    assert key in line


def test_info_of_a_basis_without_a_kernel_name_says_laplace(tmp_path: Path) -> None:
    """A kernel name is optional (the Laplace kernel); info used to index it (KeyError)."""
    from pcainterp_stream.pipeline import jobs

    text = jobs.info(_edited(tmp_path / "b.npz", _drop("local", "kernel")))
    assert "fitted prior     laplace kernel, 64 px" in text


@pytest.mark.skipif(not Path("/proc/self/mem").exists(), reason="needs /proc/self/mem")
def test_info_of_an_unreadable_file_says_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    """Reading /proc/self/mem fails (EIO), as a failing disk does (bug hunt 16A F6)."""
    line = _error_line(capsys, "info", "/proc/self/mem")
    assert line.endswith("cannot open /proc/self/mem: OSError: [Errno 5] Input/output error")
