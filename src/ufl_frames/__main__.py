"""``python -m ufl_frames``: the ``ufl-frames`` command (as ``python -m ufl_frames.app``)."""

import sys

from ufl_frames.app.cli import main

sys.exit(main())
