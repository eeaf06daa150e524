"""The suite's version: one definition, read by the package metadata (pyproject.toml)."""

__version__ = "0.1.0"
