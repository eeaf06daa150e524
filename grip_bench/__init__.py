"""grip-bench: evaluation and benchmark suite for hand-object interaction motion synthesis.

The package map (layers, who may import whom, where each fact lives) is
``docs/architecture.md``.
"""

from .core.version import __version__

__all__ = ["__version__"]
