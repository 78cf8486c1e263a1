"""``python -m catanc``: the same as the ``catanc`` command."""

from catanc.cli import main

main()
