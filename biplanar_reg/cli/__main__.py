"""``python -m biplanar_reg.cli``: the same as the ``biplanar-reg`` console script."""

from . import console_main

console_main()
