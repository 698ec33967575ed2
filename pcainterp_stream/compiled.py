"""scipy's few compiled modules a densify job calls, loaded without scipy's subpackages.

A job calls four of scipy's compiled modules: LAPACK and BLAS through their Cython
interfaces (``scipy.linalg.cython_lapack``, ``cython_blas``: the solve), Qhull
(``scipy.spatial._qhull``: the fit check's triangulation) and the k-d tree
(``scipy.spatial._ckdtree``: the check's nearest neighbours, the carried points' gaps).
Importing them the usual way runs the ``__init__`` of ``scipy.linalg`` and
``scipy.spatial``, which import the rest of both subpackages, ``scipy.special`` and more:
~0.2 s of CPU per job, all of it holding the GIL, for nothing the job calls (measured with
``python -X importtime``). :func:`module` loads each compiled module from its file in
scipy's package instead; they are the same modules, so every result is the same to the
bit. Where the file is not where scipy's wheels put it, the module is imported as usual.

The k-d tree's module imports two of scipy's modules when it is loaded: ``scipy.sparse``
for the one method that returns a sparse matrix (``sparse_distance_matrix``, which no job
calls) and ``scipy._lib._util`` for one constant (``copy_if_needed``). Those imports are
~0.2 s more of CPU holding the GIL (they pull in ``scipy._lib``'s array API layer and,
through it, ``numpy.f2py`` and ``numpy.testing``), paid by every job while its stereo
workers match the first pairs. :data:`DEFERRED` names them: while the module loads, each
stands in ``sys.modules`` as a placeholder (:class:`_Deferred`) that answers the names
it is given and imports the real module the first time anything else is looked up on it,
so a program that goes on to use ``scipy.sparse`` gets the real one, as usual. From scipy
1.18 on (Python >= 3.12) Qhull's module itself imports the array API layer (~0.1-0.2 s once a
job, on the densify thread): not deferred, as its names are used when it loads.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import os
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
from numpy.lib import NumpyVersion

NEEDS: dict[str, tuple[str, ...]] = {
    # Qhull's Cython code imports LAPACK's interface by name: loaded first, it is found in
    # sys.modules and scipy.linalg's __init__ does not run
    "spatial._qhull": ("linalg.cython_lapack",),
}
"""Modules loaded before a module that imports them by name."""


def _copy_if_needed() -> dict[str, Any]:
    """Return ``scipy._lib._util.copy_if_needed`` as scipy sets it, by name.

    None with NumPy 2 (NumPy's "copy only if needed"), False before it; nothing for NumPy
    2's pre-releases, where scipy probes NumPy (the module is then imported as usual).
    """
    version = NumpyVersion(np.__version__)
    if version >= "2.0.0":
        return {"copy_if_needed": None}
    if version < "1.28.0":
        return {"copy_if_needed": False}
    return {}


def _deferred_modules() -> dict[str, dict[str, dict[str, Any]]]:
    """Return :data:`DEFERRED`."""
    known = _copy_if_needed()
    return {
        "spatial._ckdtree": {
            "scipy.sparse": {},
            **({"scipy._lib._util": known} if known else {}),
        }
    }


DEFERRED = _deferred_modules()
"""Compiled module -> the modules it imports when it loads but uses only in functions a
job never calls, each with the names it takes from them at load (their values): those
modules are imported on first use instead (:class:`_Deferred`)."""

_LOCK = threading.RLock()


def module(name: str) -> ModuleType:
    """Return scipy's compiled module ``scipy.<name>`` (e.g. ``"spatial._qhull"``).

    The first call loads it from its file without the ``__init__`` of its subpackage (or
    imports it as usual when the file is not found); scipy's own OpenBLAS, if this loads
    it, starts with one thread (:func:`one_blas_thread_when_loaded`).
    """
    full = f"scipy.{name}"
    with _LOCK:
        loaded = sys.modules.get(full)
        if loaded is not None:
            return loaded
        for needed in NEEDS.get(name, ()):
            module(needed)
        _defer(DEFERRED.get(name, {}))
        with one_blas_thread_when_loaded():
            try:
                return _load_file(full)
            except (ImportError, OSError):
                return importlib.import_module(full)


class _Deferred(ModuleType):
    """Placeholder of a module in ``sys.modules``: the real one is imported on first use.

    It answers the names it was made with (the same values as the real module's) and
    carries the real module's spec (``importlib.util.find_spec`` reads it from
    ``sys.modules``); any other lookup (the module's functions, classes, submodules)
    imports the module, leaves ``sys.modules`` to it and hands the lookup on.
    """

    def __init__(
        self, name: str, known: dict[str, Any], spec: importlib.machinery.ModuleSpec
    ) -> None:
        super().__init__(name)
        self.__spec__ = spec
        self.__dict__.update(known)

    def __getattr__(self, name: str) -> Any:
        with _LOCK:
            if sys.modules.get(self.__name__) is self:
                del sys.modules[self.__name__]
            real = importlib.import_module(self.__name__)
        return getattr(real, name)


def _defer(modules: dict[str, dict[str, Any]]) -> None:
    """Put placeholders (:class:`_Deferred`) for the ``modules`` not yet imported.

    A placeholder stays: whoever imports its module later gets the real one through it on
    first use, as if it had been imported here.
    """
    for name, known in modules.items():
        if name in sys.modules:
            continue
        try:  # locates the module (importing its parent package, as loading it would)
            spec = importlib.util.find_spec(name)
        except (ImportError, ValueError):
            spec = None
        if spec is not None:  # else the module is imported as usual, or its import fails
            sys.modules[name] = _Deferred(name, known, spec)


def _load_file(full: str) -> ModuleType:
    """Load the extension module ``full`` from its file in scipy's installed package."""
    spec = importlib.util.find_spec("scipy")  # locates the package; imports nothing
    if spec is None or not spec.submodule_search_locations:
        raise ImportError("scipy is not installed as a package folder")
    parts = full.split(".")[1:]
    folder = Path(next(iter(spec.submodule_search_locations))).joinpath(*parts[:-1])
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        path = folder / (parts[-1] + suffix)
        if path.is_file():
            break
    else:
        raise ImportError(f"no compiled {full} in {folder}")
    file_spec = importlib.util.spec_from_file_location(full, path)
    if file_spec is None or file_spec.loader is None:
        raise ImportError(f"cannot load {path}")
    loaded = importlib.util.module_from_spec(file_spec)
    sys.modules[full] = loaded
    try:
        file_spec.loader.exec_module(loaded)
    except BaseException:
        del sys.modules[full]
        raise
    parent, _, child = full.rpartition(".")
    if parent in sys.modules:
        setattr(sys.modules[parent], child, loaded)
    else:  # its package, imported later, gets it as an attribute as usual
        _LOADED_ALONE.add(full)
        if _PARENT_HOOK not in sys.meta_path:
            sys.meta_path.insert(0, _PARENT_HOOK)
    return loaded


_LOADED_ALONE: set[str] = set()
"""Modules loaded from their files before their packages were imported."""


class _ParentHook(importlib.abc.MetaPathFinder):
    """Give a package imported after its compiled module was loaded alone that module.

    An import of ``scipy.spatial`` after :func:`module` loaded ``scipy.spatial._qhull``
    finds the module in ``sys.modules`` and does not set it as the package's attribute;
    this finder wraps such a package's loader so it does, as a plain import would have.
    """

    def find_spec(
        self, name: str, path: Any = None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        children = [full for full in _LOADED_ALONE if full.rpartition(".")[0] == name]
        if not children:
            return None
        for finder in sys.meta_path:
            find = getattr(finder, "find_spec", None)
            if finder is self or find is None:
                continue
            spec: importlib.machinery.ModuleSpec | None = find(name, path, target)
            if spec is not None and spec.loader is not None:
                setattr(spec.loader, "exec_module", _then_attach(spec.loader.exec_module, children))  # noqa: B010
                return spec
        return None


def _then_attach(run: Any, children: list[str]) -> Any:
    """Return ``run`` (a loader's ``exec_module``) followed by setting ``children``."""

    def exec_module(package: ModuleType) -> None:
        run(package)
        for full in children:
            if full in sys.modules:
                setattr(package, full.rpartition(".")[2], sys.modules[full])

    return exec_module


_PARENT_HOOK = _ParentHook()


@contextlib.contextmanager
def one_blas_thread_when_loaded() -> Iterator[None]:
    """Let an OpenBLAS loaded inside come up with one thread (``OPENBLAS_NUM_THREADS=1``).

    OpenBLAS reads the variable when it is loaded, so a library first loaded here never
    starts a second thread. Limiting it afterwards (threadpoolctl) held only when done
    from the main thread: from the densify thread, where a job loads scipy's LAPACK while
    the first pairs are matched, the solves ran on two spinning threads at ~5x the CPU
    (measured). The variable is put back as it was; the lock keeps two loads from racing.
    """
    with _LOCK:
        previous = os.environ.get("OPENBLAS_NUM_THREADS")
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
        try:
            yield
        finally:
            if previous is None:
                os.environ.pop("OPENBLAS_NUM_THREADS", None)
            else:
                os.environ["OPENBLAS_NUM_THREADS"] = previous


def hold_scipy_blas_at_one_thread() -> None:
    """Limit scipy's own OpenBLAS to one thread, if it is loaded (loaded before, elsewhere).

    A 300 x 300 factorisation gains nothing from threads, and OpenBLAS's idle threads spin
    after a call and slowed the next numpy product to half speed (docs/estimator.md). Only
    scipy's library, found by its path, is touched: numpy's is the processor's to limit.
    """
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        return
    for library in ThreadpoolController().lib_controllers:
        if "scipy.libs" in library.filepath:
            library.set_num_threads(1)
