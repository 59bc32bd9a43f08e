"""cloudsieve: entropy-based simplification of point clouds too large for memory."""

from __future__ import annotations

import logging

from .errors import *  # noqa: F401,F403
from .errors import __all__ as _errors_all

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())

__all__ = ["__version__", *_errors_all]
