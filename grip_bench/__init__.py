"""grip-bench: evaluation and benchmark suite for hand-object interaction motion synthesis."""

__version__ = "0.1.0"
