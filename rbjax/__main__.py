"""``python -m rbjax``: see :mod:`rbjax._cli`."""

import sys

from ._cli import main

sys.exit(main())
