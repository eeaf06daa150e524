"""tools/hold_settings.py: a variant's MuJoCo options and tightening apply only while it runs,
and the summary counts verdicts that differ from the committed test (docs/physics_hold.md,
"Measured in s44")."""

from __future__ import annotations

import pytest

from grip_bench.core import constants as C
from tools.hold_settings import VARIANTS, _names, constant, options, summarise, tightening


def test_options_are_restored_even_after_an_error():
    import mujoco

    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody/></mujoco>")
    before = (model.opt.impratio, model.opt.noslip_iterations)
    with options(model, VARIANTS["impratio 100"]["opt"]):
        assert model.opt.impratio == 100.0
    with pytest.raises(RuntimeError), options(model, VARIANTS["noslip 10"]["opt"]):
        assert model.opt.noslip_iterations == 10
        raise RuntimeError("a failed run")
    assert (model.opt.impratio, model.opt.noslip_iterations) == before


def test_tightening_is_restored():
    before = C.HOLD_TIGHTEN
    with tightening(0.002):
        assert C.HOLD_TIGHTEN == 0.002
    assert C.HOLD_TIGHTEN == before


def test_a_step_variant_compiles_its_step_and_is_restored():
    """The time-step variants rebuild the scene under their ``SIM_DT``: the compiled step is
    theirs (the settle and hold counts read the same constant), then 1/240 s again."""
    from grip_bench.metrics.hold import _spec

    before = C.SIM_DT
    dt = VARIANTS["step 1/120 s"]["dt"]
    with constant("SIM_DT", dt):
        model = _spec(C.UP).compile()
        assert model.opt.timestep == pytest.approx(1.0 / 120.0)
        assert int(round(C.SIM_HOLD_SECONDS / C.SIM_DT)) == 120
    assert C.SIM_DT == before == pytest.approx(1.0 / 240.0)
    assert _spec(C.UP).compile().opt.timestep == pytest.approx(1.0 / 240.0)


def test_summary_counts_differences_from_the_committed_verdicts():
    rows = {"committed": [(True, 0.1), (False, 0.1)],
            "tighten 2 mm": [(True, 0.2), (True, 0.3)]}
    s = summarise([True, False], rows)
    assert s["committed"] == {"frames": 2, "held_pct": 50.0, "differ": 0, "sim_ms": 100.0}
    assert s["tighten 2 mm"] == {"frames": 2, "held_pct": 100.0, "differ": 1, "sim_ms": 250.0}


def test_variant_names_are_checked():
    assert _names("noslip 10, tighten 1 mm") == ("noslip 10", "tighten 1 mm")
    with pytest.raises(ValueError, match="unknown variant"):
        _names("noslip 11")


@pytest.mark.slow  # ~15 s: the pinch's pose solve, its pieces and a few held seconds
def test_a_constructed_pinch_holds_under_every_variant():
    from tools.constructed_pinches import pinch_pose, pinch_scene
    from tools.hold_settings import run_variant
    from tools.pinch_opposition import PinchModel

    model = PinchModel()
    local, _ = pinch_pose(model, 0.03, starts=1, seed=0)
    scene = pinch_scene(model, local, "sphere", 0.0005)[2]

    class Pair:  # run_variant reads the gravity's up; tightening variants rebuild
        options = type("O", (), {"up": C.UP})()

    for name in ("impratio 100", "noslip 10", "ccd_iterations 10"):
        held, seconds = run_variant(Pair(), 0, scene, VARIANTS[name])
        assert held and seconds > 0
    assert run_variant(Pair(), 0, scene, None)[0]


def test_the_collision_engine_variants_set_mujocos_own_disable_bits():
    import mujoco

    bits = mujoco.mjtDisableBit
    assert VARIANTS["libccd"]["opt"]["disableflags"] == int(bits.mjDSBL_NATIVECCD)
    assert VARIANTS["no midphase"]["opt"]["disableflags"] == int(bits.mjDSBL_MIDPHASE)
    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody/></mujoco>")
    with options(model, VARIANTS["libccd"]["opt"]):
        assert model.opt.disableflags & int(bits.mjDSBL_NATIVECCD)
    assert model.opt.disableflags == 0
