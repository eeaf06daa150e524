"""Labels of a run's results shared by the planner, the stages and the report."""

MAIN_SPLIT = "test"  # the split every method is scored on
CLEAN = "none"  # the ``perturbation`` label of unperturbed results
