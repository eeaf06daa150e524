"""The bottom layer, imported by every other: errors, the registry type, named constants and
tolerances, the one atomic file writer, coordinate-frame conventions, safe loading of data
files, checkpoints, torch thread control, progress bars and the version.

Nothing here imports from another ``grip_bench`` package (``docs/architecture.md``).
"""
