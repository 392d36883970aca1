"""mepnet: LEGO building manuals to machine-executable build plans.

Users import from here (or the submodules ``mepnet.geom``, ``mepnet.ldraw``, ...), never from
``mepnet._brickgeom``. The top level re-exports :mod:`mepnet.geom`.
"""

from mepnet import geom as _geom
from mepnet.geom import *  # noqa: F403 (the public geometry API, listed in geom.__all__)

__version__ = "0.1.0"

__all__ = list(_geom.__all__)
