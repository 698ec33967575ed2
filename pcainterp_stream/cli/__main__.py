"""``python -m pcainterp_stream.cli``: the ``pcainterp`` command."""

import sys

from pcainterp_stream.cli import console

sys.exit(console())
