"""Every metric id of docs/contract.md, "Definitions", is registered with a one-line description."""

import re

from grip_bench.cli import catalog
from grip_bench.core import constants as C
from grip_bench.metrics import METRICS

IDS = [
    "mpjpe", "mpvpe", "cc", "contact_drift", "cdev", "iv", "pen_depth", "contact_ratio",
    "contact_ratio_strict", "hold_qs", "hold_qs_mu05", "hold_qs_mu3", "hold_qs_axes",
    "sim_stable", "sim_disp", "hold_sim", "hold_sim_disp", "hold_sim_settle",
    "hold_sim_ruled", "hold_sim_mu05", "hold_sim_mu3", "hold_sim_weak", "hold_sim_strong",
    "hold_sim_axes", "jitter", "accel_err",
]


def test_all_ids_registered_and_described():
    assert METRICS.names() == IDS
    lines = catalog.describe("metrics")
    assert len(lines) == len(IDS) and all("\n" not in line for line in lines)
    assert METRICS.get("iv").to_report(1e-6) == 1.0  # 1 cm^3
    assert METRICS.get("pen_depth").unit == "mm" and METRICS.get("contact_ratio").higher_is_better
    assert {s.frame_mask for s in METRICS} == {"all", "held"}


# --- every number a definition states is the constant its code reads -----------------------
# (docs/contract.md, "Definitions": `grip-bench ls metrics` must match the code). Each
# metric's stated numbers, formatted from core/constants.py: a constant changed without its
# definition, or a new number written into a definition by hand, fails here.
def _mm(v: float) -> str:
    return f"{v * 1e3:g} mm"


def _cm(v: float) -> str:
    return f"{v * 1e2:g} cm"


def _s(v: float) -> str:
    return f"{v:g} s"


def _mu(v: float) -> str:
    return f"mu = {v:g}"


_HOLD = [_mm(C.HOLD_TOUCH), _mm(C.HOLD_TIGHTEN), _s(C.HOLD_SETTLE_SECONDS),
         _s(C.SIM_HOLD_SECONDS), _cm(C.HOLD_DISP), f"{C.HOLD_ROT:g} degrees",
         _mm(C.HOLD_SETTLE_FAIL), _mm(C.HOLD_MAX_DEPTH),
         f"{C.HOLD_WEDGE_WEIGHTS:g} object weights", _mu(C.SIM_FRICTION)]
_QS = [_mm(C.HOLD_TOUCH), _mm(C.HOLD_MAX_DEPTH), _mu(C.SIM_FRICTION)]
_SUPPORT = [f"{C.SIM_PAPER_STEPS} steps", f"1/{1 / C.SIM_DT:g} s",
            f"{C.SIM_FREE_FALL_5 * 1e3:.3g} mm"]  # free fall, to the 10 um printed


def _grip(f: float) -> list[str]:
    return [f"{C.HOLD_FINGER_KP * f:.3g} N m/rad", f"{C.HOLD_FINGER_TORQUE * f:.2g} N m", *_HOLD]


STATED = {
    "mpjpe": [], "mpvpe": [], "iv": [], "pen_depth": [], "accel_err": [],
    "cc": [_mm(C.CC_THRESHOLD)],
    "contact_drift": [_mm(C.CC_THRESHOLD)],
    "cdev": [_mm(C.CC_THRESHOLD)],
    "contact_ratio": [_mm(C.CONTACT_THRESHOLD)],
    "contact_ratio_strict": [_mm(C.HELD_TOUCH)],
    "hold_qs": _QS,
    "hold_qs_mu05": [_mu(0.5), *_QS[:2], _mu(0.5)],
    "hold_qs_mu3": [_mu(3), *_QS[:2], _mu(3)],
    "hold_qs_axes": _QS,
    "sim_stable": [_mm(C.SIM_STABLE_DISP), *_SUPPORT],
    "sim_disp": [*_SUPPORT, _mm(C.SIM_DISP_CAP)],
    "hold_sim": _HOLD,
    "hold_sim_disp": [_s(C.SIM_HOLD_SECONDS), _cm(C.HOLD_DISP_CAP), _cm(C.HOLD_DISP_CAP)],
    "hold_sim_settle": [_s(C.HOLD_SETTLE_SECONDS), _mm(C.HOLD_SETTLE_FAIL),
                        _cm(C.HOLD_DISP_CAP), _cm(C.HOLD_DISP_CAP)],
    "hold_sim_ruled": [_mm(C.HOLD_MAX_DEPTH), _mm(C.HOLD_SETTLE_FAIL),
                       f"{C.HOLD_WEDGE_WEIGHTS:g} object weights"],
    "hold_sim_mu05": [_mu(0.5), *_HOLD[:-1], _mu(0.5)],
    "hold_sim_mu3": [_mu(3), *_HOLD[:-1], _mu(3)],
    "hold_sim_weak": _grip(C.HOLD_GRIP_SENSITIVITY[0]),
    "hold_sim_strong": _grip(C.HOLD_GRIP_SENSITIVITY[1]),
    "hold_sim_axes": _HOLD,
    "jitter": [f"{C.FPS:g} fps"],
}
_NUMBER = re.compile(r"\d+(?:\.\d+)?(?:/\d+)?\s*(?:mm|cm|s\b|degrees|object weights|N m/rad|N m"
                     r"|steps|fps)|mu = \d+(?:\.\d+)?")


def test_every_stated_number_is_the_constant_the_code_reads():
    assert set(STATED) == set(METRICS.names())
    assert C.HOLD_MU_SENSITIVITY == (0.5, 3.0)  # the mu rows' ids name these values
    for mid in METRICS.names():
        got = sorted(_NUMBER.findall(METRICS.get(mid).description))
        assert got == sorted(STATED[mid]), mid
