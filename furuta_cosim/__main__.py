"""``python -m furuta_cosim``: the ``furuta-cosim`` command."""

import sys

from furuta_cosim.cli import main

sys.exit(main())
