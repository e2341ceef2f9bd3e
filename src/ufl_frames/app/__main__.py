"""``python -m ufl_frames.app``: the ``ufl-frames`` command."""

import sys

from ufl_frames.app.cli import main

sys.exit(main())
