"""Example counts of the property tests, scaled by the active hypothesis profile.

A test's own ``@settings(max_examples=...)`` wins over a profile's, so the tests ask
:func:`examples` for their count and the ``thorough`` profile multiplies it.
"""

from __future__ import annotations

import os

PROFILE_VARIABLE = "HYPOTHESIS_PROFILE"
THOROUGH = "thorough"
THOROUGH_FACTOR = 10


def examples(count: int) -> int:
    """Return ``count``, times :data:`THOROUGH_FACTOR` under the ``thorough`` profile."""
    if os.environ.get(PROFILE_VARIABLE) == THOROUGH:
        return count * THOROUGH_FACTOR
    return count
