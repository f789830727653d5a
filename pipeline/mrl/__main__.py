"""``python -m pipeline.mrl``: the ``mrl`` command."""

import sys

from pipeline.mrl import main

sys.exit(main())
