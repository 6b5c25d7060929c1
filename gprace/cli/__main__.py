"""``python -m gprace.cli``: the same as the ``gprace`` command."""

import sys

from gprace.cli import main

sys.exit(main())
