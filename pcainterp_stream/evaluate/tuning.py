"""The fit check's tuning of a basis, as a densified log records it (JSON), and read back.

The fit check may densify with a built-in basis *tuned*: the indoor basis with the street
basis's local kernel and a std scale refitted on the warm-up's SGBM maps
(``Adaptation.tuning``). Its record (``pcainterp.basis``: ``N.tuning``, the channels'
``pcainterp.basis_tuning``) holds those settings, the estimate's keyword options beyond the
basis's fitted prior, as JSON: ``local_prior`` as its fields, the rest as they are. A basis
densified as fitted records nothing, so the record of an untuned log is as before.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from pathlib import Path

from pcainterp_stream.errors import PcaInterpError
from pcainterp_stream.estimate.prior import Kernel, LocalPrior
from pcainterp_stream.io.outputs import (
    BASIS_KEY,
    BASIS_TUNING_KEY,
    OutputTopics,
    recorded_bases,
    recorded_metadata,
)

KNOWN = ("local_prior", "std_scale", "scale_by_innovation")
"""The settings a tuning may hold (keyword options of ``estimate.estimator.densify``)."""


def tuning_json(tuning: Mapping[str, object]) -> str:
    """Return the record's JSON of a tuning ("" for none).

    Examples:
        >>> tuning_json({"local_prior": LocalPrior(40.0, 64.0), "std_scale": 0.5})
        '{"local_prior":{"cell_weight":1.0,"kernel":"laplace","length_scale":64.0,"variance":40.0},"std_scale":0.5}'
        >>> tuning_json({})
        ''
    """
    if not tuning:
        return ""
    values: dict[str, object] = {}
    for name, value in tuning.items():
        if isinstance(value, LocalPrior):
            value = {**dataclasses.asdict(value), "kernel": str(value.kernel)}
        elif not isinstance(value, bool | int | float | str):
            raise TypeError(f"cannot record the tuned setting {name}={value!r}")
        values[name] = value
    return json.dumps(values, sort_keys=True, separators=(",", ":"))


def tuning_of(text: str) -> dict[str, object]:
    """Return the settings a record's tuning JSON holds ({} for ""): :func:`tuning_json`'s inverse.

    Raises:
        ValueError: not a tuning this version can read (one line naming the value).
    """
    if not text:
        return {}
    try:
        values = json.loads(text)
        if not isinstance(values, dict) or set(values) - set(KNOWN):
            raise ValueError(f"settings other than {', '.join(KNOWN)}")
        tuning: dict[str, object] = {}
        for name, value in values.items():
            if name == "local_prior":
                fields = {**value, "kernel": Kernel(value["kernel"])}
                value = LocalPrior(**fields)
            elif name == "std_scale":
                value = float(value)
            elif not isinstance(value, bool):
                raise ValueError(f"{name} is not true or false")
            tuning[name] = value
    except (TypeError, ValueError, KeyError) as err:
        raise ValueError(
            f"the tuning {text!r} is not one this version reads ({err}); densify the log again "
            "with this version"
        ) from None
    return tuning


def describe_tuning(tuning: Mapping[str, object]) -> str:
    """Return what a tuning changes, in words ("" for none).

    Examples:
        >>> describe_tuning({"local_prior": LocalPrior(40.0, 64.0), "std_scale": 0.1712})
        'local kernel laplace, 64 px, 40 px^2; std x0.171'
    """
    parts = []
    local = tuning.get("local_prior")
    if isinstance(local, LocalPrior):
        kernel = f"local kernel {local.kernel}, {local.length_scale:g} px, {local.variance:g} px^2"
        parts.append(kernel + (f", cell weight {local.cell_weight:g}" if local.edge_aware else ""))
    scale = tuning.get("std_scale")
    if isinstance(scale, float):
        parts.append(f"std x{scale:.3g}")
    return "; ".join(parts)


def tuning_notes(path: Path, topics: OutputTopics, redensified: bool) -> list[str]:
    """Return ``evaluate``'s notes on each basis stretch of a log densified tuned ([]: none).

    Read from the log's ``pcainterp.basis`` record of ``topics``' prefix, else (an output
    written to standard output has no record) from the output channels' metadata, which name
    the first outputs' basis. ``redensified``: the rows that re-densify with the basis run;
    they use the paper's model (no local kernel, no std scale) for every basis, so the note
    says that the stored estimate is the one made with the tuned model.
    """
    try:
        bases = recorded_bases(path, topics.prefix)
        tuned = [(b.basis, f"from frame {b.first_frame}", b.tuning) for b in bases if b.tuning]
        if not bases:
            channels = recorded_metadata(path, topics)
            if channels.get(BASIS_TUNING_KEY):
                basis = channels.get(BASIS_KEY, "the basis")
                tuned = [(basis, "of the first outputs", channels[BASIS_TUNING_KEY])]
    except (PcaInterpError, ValueError):  # no record to read: nothing to say of it
        return []
    notes = []
    for basis, when, text in tuned:
        try:
            what = describe_tuning(tuning_of(text))
        except ValueError as err:
            what = str(err)
        notes.append(
            f"densify's fit check tuned the {basis} basis {when} ({what}): the stored estimate "
            "is that model's"
            + (
                "; the rows that re-densify with the basis use the paper's model (no local "
                "kernel, no std scale), as for every basis"
                if redensified
                else ""
            )
        )
    return notes
