"""Regenerate the project's golden files in ``tests/data`` with :mod:`pcainterp_stream.golden`.

Writes ``tests/data/golden_synth.mcap`` (a tiny synthetic log: 4 frames, scale 0.25, seed 0)
and its golden file ``golden_synth.json``, then densifies that log with
``tests/data/golden_basis.npz`` (16 components learned from the SGBM maps of another
40-frame drive, seed 7; re-learned only when missing or with ``--new-basis``) and writes
``golden_dense.json``, the golden file of ``pcainterp densify``'s output. The golden files
are what ``pcainterp golden save`` writes (format ``pcainterp-golden/2``): channels, counts,
log times, header stamps, values and robust array statistics with their tolerances; the
tests check against them with the ``log_golden`` fixture.

Usage (from the repository root; or ``pip install -e .`` and drop ``PYTHONPATH=.``)::

    PYTHONPATH=. python tools/make_golden.py            # regenerate tests/data/golden_*
    PYTHONPATH=. python tools/make_golden.py --check    # check a fresh render and densify

The same regeneration from the tests: ``python -m pytest tests/synth/test_golden_synth.py
tests/pipeline/test_golden_dense.py --update-golden`` (it keeps the committed log).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from pcainterp_stream.golden import check_log, format_differences, save_golden
from pcainterp_stream.io.logwriter import LogFormat
from pcainterp_stream.synth.log import write_synthetic_log

try:
    import harness
except ModuleNotFoundError:  # loaded by its path: tools/ is not on sys.path
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import harness

DATA_DIR = Path(__file__).resolve().parents[1] / "tests" / "data"
GOLDEN_LOG = "golden_synth.mcap"
GOLDEN_JSON = "golden_synth.json"
GOLDEN_BASIS = "golden_basis.npz"
GOLDEN_DENSE_JSON = "golden_dense.json"
SEED, FRAMES, SCALE = 0, 4, 0.25
BASIS_SEED, BASIS_FRAMES, BASIS_COMPONENTS = 7, 40, 16


def render_log(
    log_path: Path, *, seed: int = SEED, frames: int = FRAMES, scale: float = SCALE
) -> None:
    """Render the golden synthetic log to ``log_path``."""
    from pcainterp_stream.synth import SynthConfig, generate

    config = SynthConfig(seed=seed, frames=frames, scale=scale)
    write_synthetic_log(generate(config), log_path, format=LogFormat.MCAP, total=frames)


def learn_golden_basis(basis_path: Path) -> None:
    """Learn the small basis the dense golden test uses, from a separate synthetic drive."""
    from pcainterp_stream.frontend.pairing import PairingConfig
    from pcainterp_stream.pipeline.jobs import LearnOptions, learn

    with tempfile.TemporaryDirectory() as folder:
        train = Path(folder) / "train.mcap"
        render_log(train, seed=BASIS_SEED, frames=BASIS_FRAMES)
        learn([train], basis_path, LearnOptions(n_components=BASIS_COMPONENTS), PairingConfig())


def densify_log(log_path: Path, basis_path: Path, out_path: Path) -> None:
    """Densify the golden log with the golden basis (the defaults otherwise)."""
    from pcainterp_stream.pipeline.jobs import densify

    densify(log_path, out_path, basis_path)


def main(argv: list[str] | None = None) -> int:
    """Regenerate (or, with --check, verify) the golden log and golden files."""
    parser = harness.argument_parser(__doc__)
    parser.add_argument("--out-dir", type=Path, default=DATA_DIR, help="default: tests/data")
    parser.add_argument(
        "--check", action="store_true", help="render and densify afresh and check both"
    )
    parser.add_argument(
        "--new-basis", action="store_true", help="re-learn golden_basis.npz too (else kept)"
    )
    args = parser.parse_args(argv)
    out = args.out_dir
    if args.check:
        with tempfile.TemporaryDirectory() as folder:
            log, dense = Path(folder) / "golden.mcap", Path(folder) / "dense.mcap"
            render_log(log)
            densify_log(log, out / GOLDEN_BASIS, dense)
            failed = 0
            for path, golden in ((log, GOLDEN_JSON), (dense, GOLDEN_DENSE_JSON)):
                result = check_log(path, out / golden)
                print(format_differences(result.differences) or f"{golden}: matches")
                failed += not result.passed
        return 1 if failed else 0
    harness.work_dir(out)
    log_path = out / GOLDEN_LOG
    render_log(log_path)
    save_golden(log_path, out / GOLDEN_JSON)
    print(f"wrote {log_path} ({log_path.stat().st_size} bytes) and {GOLDEN_JSON}")
    basis_path = out / GOLDEN_BASIS
    if args.new_basis or not basis_path.exists():
        learn_golden_basis(basis_path)
        print(f"wrote {basis_path} ({basis_path.stat().st_size} bytes)")
    with tempfile.TemporaryDirectory() as folder:
        dense = Path(folder) / "dense.mcap"
        densify_log(log_path, basis_path, dense)
        save_golden(dense, out / GOLDEN_DENSE_JSON)
    print(f"wrote {GOLDEN_DENSE_JSON}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
