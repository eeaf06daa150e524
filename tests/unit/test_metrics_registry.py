"""Every metric id of docs/contract.md, "Definitions", is registered with a one-line description."""

from grip_bench.cli import catalog
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
