"""The method API: what every method (GRIP, its variants, the baselines, reference rows)
provides, and the registry ``grip-bench`` finds them in (``api``)."""

from .api import (
    METHODS,
    Method,
    MethodSpec,
    PredictContext,
    TrainContext,
    load_all,
    predicted_hands,
    register_method,
    variants,
)

__all__ = ["METHODS", "Method", "MethodSpec", "PredictContext", "TrainContext", "load_all",
           "predicted_hands", "register_method", "variants"]
