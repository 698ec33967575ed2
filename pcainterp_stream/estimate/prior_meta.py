"""Validation of a basis file's fitted prior, ``meta["prior"]`` (:mod:`.basis` loads it).

``learn`` stores what it fitted as JSON in the basis (:meth:`fitting.LocalFit.to_meta`,
:func:`fitting.fit_prior`); ``densify --basis`` and ``info BASIS`` take those settings as
they are. A damaged or hand-edited value (an unknown kernel, a number stored as a string, a
variance below 0, a noise std of 0) is refused when the basis is read, as its arrays are,
rather than met as a traceback deep in a solve or a format string.
"""

from __future__ import annotations

import math
from typing import Any

from pcainterp_stream.estimate.prior import Kernel

PRIOR_FIX = (
    "the basis is damaged: re-run `pcainterp learn LOG... -o BASIS`, or remove the key "
    "'prior' from its 'meta' (densify then uses the paper's prior)"
)
"""The fix every message of :func:`check_fitted_prior` ends with."""

_LOCAL_NUMBERS = (
    # (key, required, lowest, lowest allowed itself, highest), px^2 / px / a share
    ("variance", True, 0.0, True, math.inf),
    ("length_scale", True, 0.0, False, math.inf),
    ("cell_weight", False, 0.0, True, 1.0),
)
"""The numbers of ``meta["prior"]["local"]`` (:meth:`prior.LocalPrior.to_meta`)."""

_PRIOR_NUMBERS = ("sigma", "plain_sigma", "process_noise", "std_scale", "innovation_std_scale")
"""The numbers of ``meta["prior"]`` densify uses, each optional and > 0 when present: the
noise std (px) with and without the local kernel, the temporal process noise and the std
calibration factors."""


def check_fitted_prior(meta: dict[str, Any]) -> None:
    """Refuse a basis's ``meta["prior"]`` that densify or info could not use.

    A missing or null prior is allowed (a basis learned with ``--no-fit-prior``), and so is
    a null ``local`` (the paper's prior had the best evidence); keys not listed here
    (candidates, evidence tables, notes) are informational and not checked.

    Args:
        meta: the basis's whole ``meta`` object.

    Raises:
        ValueError: one line naming the key (``prior.local.kernel`` ...), the value found,
            what was expected and :data:`PRIOR_FIX`; the caller prefixes the file.

    Examples:
        >>> check_fitted_prior({"prior": {"local": None, "sigma": 1.5}})
        >>> check_fitted_prior({"prior": {"sigma": "x"}})
        Traceback (most recent call last):
        ...
        ValueError: key 'meta' has prior.sigma = 'x', expected a number > 0; the basis is ...
    """
    fitted = meta.get("prior")
    if fitted is None:
        return
    if not isinstance(fitted, dict):
        _refuse("prior", fitted, "an object (or no key 'prior')")
    local = fitted.get("local")
    if local is not None:
        if not isinstance(local, dict):
            _refuse("prior.local", local, "an object or null")
        kernel = local.get("kernel", Kernel.LAPLACE.value)
        if kernel not in tuple(Kernel):
            _refuse("prior.local.kernel", kernel, " or ".join(repr(k.value) for k in Kernel))
        for key, required, lowest, closed, highest in _LOCAL_NUMBERS:
            if key not in local and not required:
                continue
            _check_number(local, f"prior.local.{key}", key, lowest, closed, highest)
    for key in _PRIOR_NUMBERS:
        if key in fitted:
            _check_number(fitted, f"prior.{key}", key, 0.0, False, math.inf)


def _check_number(
    where: dict[str, Any], name: str, key: str, lowest: float, closed: bool, highest: float
) -> None:
    if math.isinf(highest):
        expected = f"a number >= {lowest:g}" if closed else f"a number > {lowest:g}"
    else:
        expected = f"a number in [{lowest:g}, {highest:g}]"
    if key not in where:
        raise ValueError(f"key 'meta' has no {name}, expected {expected}; {PRIOR_FIX}")
    value = where[key]
    if isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value):
        if (value >= lowest if closed else value > lowest) and value <= highest:
            return
    _refuse(name, value, expected)


def _refuse(name: str, value: Any, expected: str) -> None:
    shown = repr(value)
    if isinstance(value, dict | list):  # a whole object or list would not fit one line
        shown = "an object" if isinstance(value, dict) else "a list"
    raise ValueError(f"key 'meta' has {name} = {shown}, expected {expected}; {PRIOR_FIX}")
