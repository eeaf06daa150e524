"""What a checkpoint unit's key holds of the profile (``bench.plan._train_profile``): the
sections its method's training reads, so an edit of one method's section retrains that
method alone (docs/architecture.md, "Cache keys")."""

from __future__ import annotations

import copy
import dataclasses

from grip_bench.bench.cache import Cache
from grip_bench.bench.plan import _train_profile, build_plan, make_config
from grip_bench.methods.api import MethodSpec


def _checkpoints(cfg, root) -> dict[str, str]:
    """{method: key} of the plan's checkpoint units (a shared GRIP unit under its first name)."""
    plan = build_plan(cfg, Cache(root / "cache"))
    return {u.params["method"]: u.key for u in plan.units if u.kind == "checkpoint"}


def _renewed(cfg, tmp_path, section: str, key: str) -> set[str]:
    before = _checkpoints(cfg, tmp_path / "a")
    profile = copy.deepcopy(cfg.profile)
    profile[section][key] = profile[section][key] + 1
    after = _checkpoints(dataclasses.replace(cfg, profile=profile), tmp_path / "b")
    assert before.keys() == after.keys()
    return {m for m in before if before[m] != after[m]}


def test_an_edit_of_grip_retrains_grip_alone(tmp_path):
    cfg = make_config("smoke", out=tmp_path / "out", progress=False)
    renewed = _renewed(cfg, tmp_path, "grip", "epochs_anet")
    assert renewed and all(m.startswith("grip") for m in renewed)
    assert {"grabnet", "toch", "manipnet", "nearest-neighbour"} <= set(
        _checkpoints(cfg, tmp_path / "c")) - renewed


def test_an_edit_of_a_baseline_section_retrains_its_methods_alone(tmp_path):
    cfg = make_config("smoke", out=tmp_path / "out", progress=False)
    assert _renewed(cfg, tmp_path, "grabnet", "epochs_coarse") == {"grabnet", "grabnet-smplx"}
    assert _renewed(cfg, tmp_path, "nearest", "max_sequences") == {"nearest-neighbour",
                                                                   "nearest-arm"}


def test_the_key_holds_the_declared_sections_and_a_plugin_gets_every_one_but_run(tmp_path):
    cfg = make_config("smoke", out=tmp_path / "out", progress=False)
    plan = build_plan(cfg, Cache(tmp_path / "cache"))
    by_method = {u.params["method"]: u for u in plan.units if u.kind == "checkpoint"}
    assert by_method["grip"].params["inputs"]["profile"] == {"grip": cfg.profile["grip"]}
    assert by_method["toch"].params["inputs"]["profile"] == {"toch": cfg.profile["toch"]}

    class Plugin:  # declares no profile_sections
        def __init__(self, name: str) -> None:
            self.name = name

    got = _train_profile(MethodSpec(name="plugin", description="", factory=Plugin).build(),
                         {**cfg.profile, "name": "smoke"})
    assert set(got) == set(cfg.profile) - {"run", "name"} and "grip" in got
