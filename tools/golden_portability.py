r"""Show that golden files hold across OpenCV builds while real changes fail.

Renders a 4-frame synthetic log at scale 0.25, densifies it with the defaults under this
interpreter and under ``--other-python`` (an environment with another OpenCV build) and
under this one with OpenCV's SIMD code paths disabled,
saves a golden file (with ``--arrays``) under each and checks the other's output against
it. Then checks real changes against this interpreter's golden file: another basis
(``tests/data/golden_basis.npz``), ``--corners 15``, one frame dropped, ``/pcainterp/depth``
renamed. Prints a Markdown table (the one in docs/golden.md).

Usage::

    python tools/golden_portability.py --other-python /path/to/other/venv/bin/python \
        --work-dir /tmp/golden_portability

The other environment needs pcainterp-stream importable; e.g. a venv with another
``opencv-python-headless`` whose ``.pth`` adds this one's site-packages after its own.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

from mcap.writer import Writer

from pcainterp_stream.cli import main as pcainterp
from pcainterp_stream.golden import check_log, save_golden
from pcainterp_stream.io.logreader import open_log
from pcainterp_stream.records import RawMessage

try:
    import harness
except ModuleNotFoundError:  # loaded by its path: tools/ is not on sys.path
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import harness

OTHER_BASIS = harness.REPO / "tests" / "data" / "golden_basis.npz"


def _run(*args: str | Path | float) -> None:
    code = pcainterp([str(a) for a in args])
    if code:
        raise SystemExit(f"pcainterp {' '.join(map(str, args))} exited {code}")


# OpenCV's run-time dispatch falls back to plain SSE2 code with these disabled
NO_SIMD = "AVX512_SKX,AVX2,AVX,FMA3,FP16,POPCNT,SSE4_2,SSE4_1,SSSE3,SSE3"


def _run_other(python: Path, *args: str | Path, env: dict[str, str] | None = None) -> None:
    command = [str(python), "-m", "pcainterp_stream.cli", *map(str, args)]
    environment = None if env is None else {**os.environ, **env}
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL, env=environment)


def _opencv_version(python: Path) -> str:
    command = [str(python), "-c", "import cv2; print(cv2.__version__)"]
    return subprocess.run(command, check=True, capture_output=True, text=True).stdout.strip()


def copy_log(source: Path, target: Path, change: Callable[[RawMessage], RawMessage | None]) -> Path:
    """Copy an MCAP log message by message through ``change`` (None drops the message)."""
    with open_log(source) as reader, target.open("wb") as stream:
        writer = Writer(stream)
        writer.start(profile="ros2", library="golden_portability")
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for raw in reader.messages():
            changed = change(raw)
            if changed is None:
                continue
            if changed.schema_name not in schemas:
                schemas[changed.schema_name] = writer.register_schema(
                    changed.schema_name, changed.schema_encoding, changed.schema_data
                )
            if changed.topic not in channels:
                channels[changed.topic] = writer.register_channel(
                    changed.topic, changed.message_encoding, schemas[changed.schema_name]
                )
            writer.add_message(
                channels[changed.topic], changed.log_time_ns, changed.data, changed.publish_time_ns
            )
        writer.finish()  # type: ignore[no-untyped-call]
    return target


def _row(case: str, log: Path, golden: Path) -> str:
    result = check_log(log, golden)
    verdict = "passes" if result.passed else f"fails: {len(result.differences)} differences"
    first = f"`{result.differences[0]}`" if result.differences else ""
    return f"| {case} | {verdict} | {first} |"


def main(argv: list[str] | None = None) -> int:
    """Run the portability check and print its table."""
    parser = harness.argument_parser(__doc__)
    parser.add_argument("--other-python", type=Path, required=True, metavar="PYTHON")
    harness.add_work_dir(parser, Path("golden_portability"))
    args = parser.parse_args(argv)
    work = harness.work_dir(args.work_dir)
    here, there = Path(sys.executable), args.other_python
    log = work / "drive.mcap"
    _run("synth", log, "--frames", 4, "--scale", 0.25, "--seed", 0)
    dense_here, dense_there = work / "dense_here.mcap", work / "dense_there.mcap"
    _run("densify", log, "-o", dense_here)
    _run_other(there, "densify", log, "-o", dense_there)
    no_simd = work / "dense_no_simd.mcap"
    _run_other(here, "densify", log, "-o", no_simd, env={"OPENCV_CPU_DISABLE": NO_SIMD})
    golden_here, golden_there = work / "here.golden.json", work / "there.golden.json"
    save_golden(dense_here, golden_here, arrays=True)
    _run_other(there, "golden", "save", dense_there, "-o", golden_there, "--arrays")

    other_basis, fewer = work / "other_basis.mcap", work / "corners15.mcap"
    _run("densify", log, "-o", other_basis, "--basis", OTHER_BASIS)
    _run("densify", log, "-o", fewer, "--corners", 15)
    with open_log(dense_here) as reader:
        times = sorted({raw.log_time_ns for raw in reader.messages(["/pcainterp/depth"])})
    dropped = copy_log(
        dense_here, work / "dropped.mcap", lambda r: None if r.log_time_ns == times[2] else r
    )
    renamed = copy_log(
        dense_here,
        work / "renamed.mcap",
        lambda r: r._replace(topic="/pcainterp/range") if r.topic == "/pcainterp/depth" else r,
    )
    cv_here, cv_there = _opencv_version(here), _opencv_version(there)
    print(
        "| log checked against the golden file (stats and per-element arrays) | result | "
        "first difference |"
    )
    print("| --- | --- | --- |")
    print(
        _row(
            f"densified under OpenCV {cv_there}, golden saved under {cv_here}",
            dense_there,
            golden_here,
        )
    )
    print(
        _row(
            f"densified under OpenCV {cv_here}, golden saved under {cv_there}",
            dense_here,
            golden_there,
        )
    )
    print(_row(f"OpenCV {cv_here} without SIMD (OPENCV_CPU_DISABLE)", no_simd, golden_here))
    print(_row("another basis (tests/data/golden_basis.npz)", other_basis, golden_here))
    print(_row("`--corners 15`", fewer, golden_here))
    print(_row("frame 2 dropped", dropped, golden_here))
    print(_row("/pcainterp/depth renamed /pcainterp/range", renamed, golden_here))
    return 0


if __name__ == "__main__":
    sys.exit(main())
