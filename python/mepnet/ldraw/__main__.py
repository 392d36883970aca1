"""``python -m mepnet.ldraw``: see :mod:`mepnet.ldraw.cli`."""

from mepnet.ldraw.cli import main

raise SystemExit(main())
