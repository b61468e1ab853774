"""``python -m lunad.daemon.cli``: the ``lunad`` command, as the tests and the tools run it."""

import sys

from lunad.daemon.cli.main import main

sys.exit(main())
