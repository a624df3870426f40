"""The machine a benchmark ran on: :func:`slamlib.machine.describe` (``slamlib bench`` loads it from here)."""

from slamlib.machine import describe

__all__ = ["describe"]
