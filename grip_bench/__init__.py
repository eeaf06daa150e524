"""grip-bench: evaluation and benchmark suite for hand-object interaction motion synthesis.

The package map (layers, who may import whom, where each fact lives) is
``docs/architecture.md``.
"""

# First, before numpy and torch load: pin their kernels so that a seed gives the same bits
# on every x86-64 processor with AVX2 (``core/numerics.py``; GRIP_BENCH_NUMERICS=native
# turns it off).
from .core import numerics as _numerics

_numerics.pin()

from .core.version import __version__  # noqa: E402

__all__ = ["__version__"]
