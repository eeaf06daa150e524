"""``grip-bench run``: plan the work units of a run (``plan``, keys from ``codehash``), execute
them (``execute``, with each unit kind's work in ``stages``), cache them (``cache``) and
assemble the report (``runner``). The top layer below the CLI (``docs/architecture.md``)."""
