"""Benchmark backbone: results schema, statistics, tables, leaderboard, manifest, cache."""
