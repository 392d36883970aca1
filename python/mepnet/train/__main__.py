"""``python -m mepnet.train``: see :mod:`mepnet.train.cli`."""

from mepnet.train.cli import main

raise SystemExit(main())
