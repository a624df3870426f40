"""Deprecated: moved to :mod:`slamlib.experiments.render` (experiment tooling is no part of the filter).

Importing this module warns (``DeprecationWarning``) and gives the new module's objects (its ``__all__``); it
will be removed. The filter never imports it (``tests/test_layers.py`` allows this one import of ``experiments``).
"""

import warnings

from slamlib.experiments.render import *  # noqa: F403
from slamlib.experiments.render import __all__  # noqa: F401

warnings.warn(
    "slamlib.slam3d.render is deprecated: it moved to slamlib.experiments.render; import it from there",
    DeprecationWarning,
    stacklevel=2,
)
