"""Deprecated: moved to :mod:`slamlib.experiments.sweep` (experiment tooling is no part of the filter).

Importing this module warns (``DeprecationWarning``) and gives the new module's objects (its ``__all__``); it
will be removed. The filter never imports it (``tests/test_layers.py`` allows this one import of ``experiments``).
"""

import warnings

from slamlib.experiments.sweep import *  # noqa: F403
from slamlib.experiments.sweep import __all__  # noqa: F401

warnings.warn(
    "slamlib.slam3d.sweep is deprecated: it moved to slamlib.experiments.sweep; import it from there",
    DeprecationWarning,
    stacklevel=2,
)
