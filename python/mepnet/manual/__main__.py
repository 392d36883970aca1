"""``python -m mepnet.manual``: see :mod:`mepnet.manual.cli`."""

from mepnet.manual.cli import main

raise SystemExit(main())
