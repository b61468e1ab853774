"""``python -m lunad.daemon.tools.bench``: the floor loop; ``... bench receive``: the
bench's receiver. Both are started as subprocesses by ``rounds.run_serve_once``."""

import sys

from lunad.daemon.tools.bench.floor import floor_main
from lunad.daemon.tools.bench.receiver import receiver_main

if sys.argv[1:2] == ["receive"]:
    sys.exit(receiver_main(sys.argv[2:]))
sys.exit(floor_main())
