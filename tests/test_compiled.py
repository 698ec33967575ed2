"""scipy's compiled modules loaded without their subpackages: the same modules as scipy's.

Each case runs in a fresh interpreter: this one has imported scipy's subpackages already.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(code: str) -> list[object]:
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    )
    out: list[object] = json.loads(result.stdout.strip().splitlines()[-1])
    return out


def test_loaded_alone_then_imported_as_usual_they_are_one_module() -> None:
    out = _run(
        "import json, sys\n"
        "import numpy as np\n"
        "from pcainterp_stream import compiled\n"
        "qhull = compiled.module('spatial._qhull')\n"
        "tree = compiled.module('spatial._ckdtree')\n"
        "lapack = compiled.module('linalg.cython_lapack')\n"
        "alone = sorted(m for m in ('scipy.linalg', 'scipy.spatial') if m in sys.modules)\n"
        "rng = np.random.default_rng(1)\n"
        "points = rng.uniform(0, 100, (200, 2))\n"
        "at = rng.uniform(0, 100, (500, 2))\n"
        "ours = qhull.Delaunay(points)\n"
        "found = tree.cKDTree(points).query(at)\n"
        "import scipy.spatial, scipy.linalg.cython_lapack\n"
        "theirs = scipy.spatial.Delaunay(points)\n"
        "same = [scipy.spatial.Delaunay is qhull.Delaunay,\n"
        "        scipy.spatial.cKDTree is tree.cKDTree,\n"
        "        scipy.linalg.cython_lapack is lapack,\n"
        "        bool((ours.simplices == theirs.simplices).all()),\n"
        "        bool((ours.transform == theirs.transform).all()),\n"
        "        bool((found[1] == scipy.spatial.cKDTree(points).query(at)[1]).all())]\n"
        "print(json.dumps([alone, same]))\n"
    )
    alone, same = out
    assert alone == []
    assert same == [True] * 6


def test_a_module_not_found_as_a_file_is_imported_as_usual() -> None:
    out = _run(
        "import json, sys\n"
        "from pcainterp_stream import compiled\n"
        "def missing(full):\n"
        "    raise ImportError('not here')\n"
        "compiled._load_file = missing\n"
        "qhull = compiled.module('spatial._qhull')\n"
        "import scipy.spatial\n"
        "print(json.dumps([qhull.Delaunay is scipy.spatial.Delaunay,\n"
        "                  'scipy.spatial' in sys.modules]))\n"
    )
    assert out == [True, True]


def test_loading_leaves_the_blas_variable_as_it_was() -> None:
    out = _run(
        "import json, os\n"
        "os.environ['OPENBLAS_NUM_THREADS'] = '3'\n"
        "from pcainterp_stream import compiled\n"
        "compiled.module('linalg.cython_blas')\n"
        "print(json.dumps([os.environ.get('OPENBLAS_NUM_THREADS')]))\n"
    )
    assert out == ["3"]


def test_the_k_d_trees_imports_wait_for_their_first_use_and_are_then_scipys_own() -> None:
    out = _run(
        "import json, sys\n"
        "import numpy as np\n"
        "from pcainterp_stream import compiled\n"
        "tree = compiled.module('spatial._ckdtree')\n"
        "heavy = sorted(m for m in ('scipy._lib._array_api', 'numpy.f2py') if m in sys.modules)\n"
        "rng = np.random.default_rng(2)\n"
        "points = rng.uniform(0, 100, (200, 2))\n"
        "at = rng.uniform(0, 100, (300, 2))\n"
        "found = tree.cKDTree(points).query(at)\n"
        "after_query = 'scipy._lib._array_api' in sys.modules\n"
        "import importlib.util\n"
        "located = importlib.util.find_spec('scipy.sparse').name == 'scipy.sparse'\n"
        "after_query = after_query or 'scipy._lib._array_api' in sys.modules or not located\n"
        "matrix = tree.cKDTree(points).sparse_distance_matrix(tree.cKDTree(at), 5.0)\n"
        "import scipy.sparse\n"
        "from scipy._lib import _util\n"
        "usual = [type(matrix) is scipy.sparse.dok_matrix, matrix.nnz > 0,\n"
        "         type(sys.modules['scipy.sparse']) is type(sys), _util.copy_if_needed is\n"
        "         compiled.DEFERRED['spatial._ckdtree']['scipy._lib._util']['copy_if_needed']]\n"
        "dense = np.hypot(*(points[:, None, :] - at[None, :, :]).transpose(2, 0, 1))\n"
        "nearest = bool(np.allclose(found[0], dense.min(axis=0)))\n"
        "print(json.dumps([heavy, after_query, usual, nearest]))\n"
    )
    heavy, after_query, usual, nearest = out
    assert heavy == []  # scipy.sparse and scipy._lib._util were not imported by the load
    assert after_query is False
    assert usual == [True] * 4
    assert nearest is True
