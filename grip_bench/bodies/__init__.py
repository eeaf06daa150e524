from grip_bench.bodies.body import BodyOutput, ProceduralBody  # noqa: F401
from grip_bench.bodies.hand import ProceduralHand  # noqa: F401
