"""``python -m gnss_citygml``: the same as the ``gnss-citygml`` command."""

from .cli import main

main()
