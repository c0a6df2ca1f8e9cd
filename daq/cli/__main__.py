"""``python -m daq.cli``: the same as the ``daq`` command."""

import sys

from daq.cli.main import main

sys.exit(main())
