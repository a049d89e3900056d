"""``python -m peeljax.cli``: the same as the ``peeljax`` command."""

from . import main

raise SystemExit(main())
