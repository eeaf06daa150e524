"""Command-line interface: one module per subcommand, wired in :mod:`grip_bench.cli.main`."""
