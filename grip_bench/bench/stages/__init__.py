"""The work of each unit kind, one module per kind (``dataset``/``perturbed``: ``data``,
``checkpoint``: ``train``, ``prediction``: ``predict``, ``metrics``: ``evaluate``,
``runtime``: ``runtime``).

Each module imports only what its units run: a unit's cache key hashes the import closure
of its stage module (:mod:`grip_bench.bench.codehash`), so the modules stay apart and the
run state is imported for type checking only.
"""
