"""Results as data: the tidy ``results.csv`` / ``frames.csv`` schema (``schema``), seeded
stratified bootstrap intervals (``stats``), run manifests (``manifest``) and the labels a
run's results share (``layout``). Imported by the metrics, the report and the runner."""
