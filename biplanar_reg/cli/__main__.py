"""``python -m biplanar_reg.cli``: the same as the ``biplanar-reg`` console script."""

import sys

from . import main

sys.exit(main())
