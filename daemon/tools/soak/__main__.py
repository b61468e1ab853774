"""``python -m lunad.daemon.tools.soak DIR``: compare the two byte recordings that
``lunad soak --keep-logs DIR`` kept (``byte_check``); exit 0 when they agree. The soak
itself runs as ``lunad soak``."""

import sys

from lunad.daemon.tools.soak.byte_check import main

sys.exit(main())
