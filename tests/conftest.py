"""Hypothesis settings profiles for the whole suite.

- ``ci``: derandomized, so a submission never fails on a draw it did not cause; loaded when
  the ``CI`` environment variable is set (``.ci/run`` sets it).
- ``thorough``: ten times the examples of every property test, random seeds; what a
  developer runs before stopping::

      HYPOTHESIS_PROFILE=thorough python -m pytest -q --hypothesis-seed=$RANDOM

- ``default``: hypothesis' defaults with the per-test example counts.

``HYPOTHESIS_PROFILE`` names a profile explicitly and wins over ``CI``.
"""

from __future__ import annotations

import os

from hypothesis import settings
from hypothesis_profiles import PROFILE_VARIABLE, THOROUGH

settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
settings.register_profile(THOROUGH, deadline=None, print_blob=True)

_profile = os.environ.get(PROFILE_VARIABLE) or ("ci" if os.environ.get("CI") else "default")
settings.load_profile(_profile)
