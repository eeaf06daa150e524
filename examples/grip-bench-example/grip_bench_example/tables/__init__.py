"""Table files of the example plug-in (entry point ``grip_bench.tables``: this package's
``*.toml`` resources)."""
