"""Training with PyTorch DDP (gloo on localhost): N processes compute what one process
computes on the same global batches, up to floating-point summation order.

The 2-process jobs run in spawned processes (``grip_bench.nn.ddp.spawn``, a free port);
the references run in this process on the full global batch. Tiny widths and random
inputs of the networks' real shapes; dropout 0 (each rank has its own dropout stream, so
with dropout the runs agree in distribution only: docs/distributed_training.md).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch

from grip_bench.cli.main import main
from grip_bench.core.errors import InputError
from grip_bench.nn import ddp

N_TRAIN, N_VAL, BATCH = 37, 13, 8  # the last global batch (5) splits 3 / 2 over 2 ranks
HP = dict(lr=3e-3, weight_decay=1e-4, lr_factor=0.5, lr_patience=1, batch_size=BATCH,
          patience=5)


@pytest.fixture(autouse=True)
def _threads():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


# --- the problems: a network, its data and its loss -------------------------------------
def _cnet_problem() -> tuple[torch.nn.Module, dict, object]:
    """GRIP's CNet (BatchNorm everywhere) on random inputs; its real loss (no vertex term)."""
    from grip_bench.grip.cnet import CNetConfig
    from grip_bench.grip.losses import LossConfig, cnet_loss

    cfg = CNetConfig(ambient_dim=8, hidden=16, width=16, latent=8, dropout=0.0)
    torch.manual_seed(0)
    model = cfg.build()
    g = torch.Generator().manual_seed(1)
    n = N_TRAIN + N_VAL
    data = {"body": torch.randn(n, 2, cfg.body_dim, generator=g),
            "ambient": torch.rand(n, 2, 2, cfg.ambient_dim, generator=g),
            "proximity": torch.rand(n, 2, 2, cfg.proximity_dim, generator=g),
            "future": torch.randn(n, cfg.future_dim, generator=g)}
    for f in ("t", "t1"):
        data[f"poses_{f}"] = torch.randn(n, 2, 15, 6, generator=g)
        data[f"proximity_{f}"] = torch.rand(n, 2, cfg.proximity_dim, generator=g)

    def loss(m: torch.nn.Module, b: dict) -> tuple[torch.Tensor, dict]:
        out = m(b["body"], b["ambient"], b["proximity"], b["future"])
        return cnet_loss(out, b, LossConfig(), "latent")

    return model, data, loss


def _manipnet_problem() -> tuple[torch.nn.Module, dict, object]:
    """The ManipNet baseline (a BatchNorm residual MLP) with its pose L2 on random inputs."""
    from grip_baselines.manipnet import ManipNetConfig

    cfg = ManipNetConfig(n_past=2, n_future=2, voxel_res=4, width=16, hidden=16, n_blocks=2,
                         dropout=0.0, zero_init_head=False)
    torch.manual_seed(0)
    model = cfg.build()
    g = torch.Generator().manual_seed(1)
    n = N_TRAIN + N_VAL
    data = {"traj": torch.randn(n, cfg.traj_frames, 9, generator=g),
            "voxels": (torch.rand(n, 4, 4, 4, generator=g) > 0.5).float(),
            "distances": torch.randn(n, 1 + cfg.n_future, cfg.n_prox, generator=g) * 0.01,
            "prev_pose": torch.randn(n, 15, 6, generator=g),
            "target": torch.randn(n, 15, 6, generator=g)}

    def loss(m: torch.nn.Module, b: dict) -> tuple[torch.Tensor, dict]:
        pred = m(b["traj"], b["voxels"], b["distances"], b["prev_pose"])
        value = (pred - b["target"]).pow(2).mean()
        return value, {"pose": value}

    return model, data, loss


PROBLEMS = {"cnet": _cnet_problem, "manipnet": _manipnet_problem}


def _stage(kind: str):
    from grip_bench.grip.train import Stage

    model, data, loss = PROBLEMS[kind]()

    def batch(split: str, idx: np.ndarray) -> dict:
        rows = idx if split == "train" else N_TRAIN + idx
        return {k: v[rows] for k, v in data.items()}

    # the stage name only picks the seeds of the epoch order
    return Stage("cnet", model, N_TRAIN, N_VAL, batch, loss)


def _first_step_grads(kind: str, d: ddp.Dist) -> dict[str, torch.Tensor]:
    """Gradients of the first global batch (the first BATCH samples) on rank ``d``."""
    stage = _stage(kind)
    net = ddp.wrap(stage.model, d)
    stage.model.train()
    glob = np.arange(BATCH)
    mine = ddp.rank_share(glob, d) if d.active else glob
    loss, _ = stage.loss(net, stage.batch("train", mine))
    (loss * ddp.share_weight(len(mine), len(glob), d)).backward()
    return {k: p.grad.clone() for k, p in stage.model.named_parameters()}


def _fit(kind: str, epochs: int = 3) -> tuple[dict, list, list]:
    """GRIP's ``fit`` (the real loop: shares, weights, validation, early stopping)."""
    from grip_bench.grip.train import StageState, fit

    stage = _stage(kind)
    st = fit(stage, HP, StageState(), 0, epochs, lambda s: None, progress=False)
    return stage.model.state_dict(), st.train_curve, st.val_curve


def _job(kind: str, out: str) -> None:
    """One rank of the 2-process job: rank 0 saves what it computed."""
    torch.set_num_threads(1)
    with ddp.process_group("cpu") as d:
        grads = _first_step_grads(kind, d)
        state, train_curve, val_curve = _fit(kind)
        if d.main:
            torch.save({"grads": grads, "state": state, "train": train_curve,
                        "val": val_curve}, Path(out) / f"{kind}.pt")


@pytest.fixture(scope="module")
def ddp_results(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("ddp")
    for kind in PROBLEMS:
        ddp.spawn(_job, 2, (kind, str(out)))
    return out


@pytest.mark.parametrize("kind", sorted(PROBLEMS))
def test_two_processes_give_the_first_step_gradients_of_one(ddp_results, kind):
    two = torch.load(ddp_results / f"{kind}.pt", weights_only=True)["grads"]
    one = _first_step_grads(kind, ddp.SINGLE)
    assert set(two) == set(one)
    assert sum(float(g.abs().sum()) for g in one.values()) > 0
    for name, g in one.items():
        torch.testing.assert_close(two[name], g, rtol=1e-4, atol=1e-6, msg=name)


@pytest.mark.parametrize("kind", sorted(PROBLEMS))
def test_two_processes_train_the_weights_of_one(ddp_results, kind):
    """Three epochs of GRIP's loop (an uneven last batch, BatchNorm running statistics,
    Adam, the validation loss that drives the scheduler and early stopping)."""
    two = torch.load(ddp_results / f"{kind}.pt", weights_only=True)
    state, train_curve, val_curve = _fit(kind)
    moved = max(float((state[k] - v).abs().max()) for k, v in _stage(kind).model.state_dict()
                .items() if v.is_floating_point())
    assert moved > 1e-3  # training changed the weights
    # Adam divides by the root of the squared gradients, so float-level differences in a
    # small gradient move a weight by ~lr x 1e-3 per step: measured max 1.3e-5 after 15 steps
    for k, v in state.items():
        torch.testing.assert_close(two["state"][k], v, rtol=1e-3, atol=1e-4, msg=k)
    np.testing.assert_allclose(two["train"], train_curve, rtol=1e-5)
    np.testing.assert_allclose(two["val"], val_curve, rtol=1e-5)


def test_global_batchnorm_matches_batchnorm_state_dict_and_eval():
    bn = torch.nn.BatchNorm1d(5)
    bn.running_mean.fill_(0.3)
    root = ddp.convert_batchnorm(bn)
    assert isinstance(root, ddp.GlobalBatchNorm1d)
    assert root.state_dict().keys() == bn.state_dict().keys()
    x = torch.randn(4, 5)
    torch.testing.assert_close(root.eval()(x), bn.eval()(x))


def test_the_global_batch_must_split_evenly():
    with pytest.raises(InputError, match="must split evenly over 2 processes"):
        ddp.check_batch(9, ddp.Dist(rank=0, world=2), "grip.batch_size")
    ddp.check_batch(9, ddp.SINGLE, "grip.batch_size")
    with pytest.raises(InputError, match="int >= 1"):
        ddp.check_nproc(0)


def test_rank_shares_cover_the_global_batch_once():
    glob = np.random.default_rng(0).permutation(11)
    shares = [ddp.rank_share(glob, ddp.Dist(rank=r, world=3)) for r in range(3)]
    assert np.array_equal(np.concatenate(shares), glob)
    # DDP's average of the weighted per-rank means is the mean over the global batch
    x = np.random.default_rng(1).normal(size=11)
    weighted = [ddp.share_weight(len(s), 11, ddp.Dist(rank=0, world=3)) * x[s].mean()
                for s in shares]
    assert np.mean(weighted) == pytest.approx(x[glob].mean())


# --- the CLI ---------------------------------------------------------------------------------
def _tiny_profile(tmp_path: Path) -> Path:
    from grip_bench.profiles import PROFILE_DIR

    values = {"epochs_cnet": 1, "epochs_anet": 1, "epochs_rnet": 1, "batch_size": 32,
              "epochs": 1, "ss_epochs": 1, "width": 16, "hidden": 16, "n_blocks": 1}
    lines = []
    for line in (PROFILE_DIR / "smoke.toml").read_text().splitlines():
        key = line.split("=")[0].strip()
        lines.append(f"{key} = {values[key]}" if key in values and "=" in line else line)
    path = tmp_path / "tiny.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def grip_data(tmp_path_factory) -> Path:
    from tests.grip_fixtures import write_grip_dataset

    return write_grip_dataset(tmp_path_factory.mktemp("gripdata"), T=16)


def test_cli_trains_grip_on_two_processes_and_predict_loads_it(grip_data, tmp_path, capsys):
    profile = _tiny_profile(tmp_path)
    ckpt = tmp_path / "grip.pt"
    args = ["train", "grip", "--data", str(grip_data), "--out", str(ckpt), "--profile",
            str(profile), "--no-progress"]
    assert main([*args, "--nproc", "2"]) == 0
    assert ckpt.is_file() and not ckpt.with_name("grip.pt.partial").exists()
    from grip_bench.grip.train import load_grip

    nets, meta = load_grip(ckpt)
    assert meta["nproc"] == 2 and set(nets) == {"anet", "cnet", "rnet"}
    out = tmp_path / "pred"
    assert main(["predict", "--method", "grip", "--checkpoint", str(ckpt), "--input",
                 str(grip_data), "--split", "test", "--out", str(out)]) == 0
    from grip_bench.data.grab_io import list_sequences, read_grab

    files = list_sequences(out)
    assert files and np.isfinite(read_grab(files[0]).rhand["hand_pose"]).all()


def test_cli_refuses_a_batch_that_does_not_split(grip_data, tmp_path, capsys):
    profile = _tiny_profile(tmp_path)
    text = profile.read_text().replace("batch_size = 32", "batch_size = 33", 1)
    profile.write_text(text)
    assert main(["train", "grip", "--data", str(grip_data), "--out", str(tmp_path / "g.pt"),
                 "--profile", str(profile), "--no-progress", "--nproc", "2"]) == 1
    assert "must split evenly over 2 processes" in capsys.readouterr().err
    assert "RANK" not in os.environ  # the launcher leaves this process as it was


def test_nproc_1_writes_the_bytes_of_a_plain_run(grip_data, tmp_path):
    """``--nproc 1`` is the single-process path: the same bytes as without the flag."""
    profile = _tiny_profile(tmp_path)
    base = ["train", "manipnet", "--data", str(grip_data), "--profile", str(profile),
            "--no-progress"]
    assert main([*base, "--out", str(tmp_path / "a.pt")]) == 0
    assert main([*base, "--out", str(tmp_path / "b.pt"), "--nproc", "1"]) == 0
    assert (tmp_path / "a.pt").read_bytes() == (tmp_path / "b.pt").read_bytes()


def test_profiles_default_to_one_process_and_the_runner_passes_train_nproc(tmp_path,
                                                                           monkeypatch):
    from types import SimpleNamespace

    from grip_bench.bench.stages import train as stage
    from grip_bench.profiles import load_profile

    profile = load_profile("smoke")
    assert profile["run"]["train_nproc"] == 1
    profile["run"]["train_nproc"] = 2
    seen = {}

    def fake_train(name, data_dir, out, ctx, nproc=1):
        seen.update(name=name, nproc=nproc, sections=sorted(ctx.profile))
        out.write_bytes(b"ckpt")
        return out

    monkeypatch.setattr(stage, "train_checkpoint", fake_train)
    st = SimpleNamespace(cache=SimpleNamespace(root=tmp_path / "cache"),
                         data_dir=lambda k: tmp_path,
                         cfg=SimpleNamespace(profile=profile, seed=0, device="cpu", progress=False))
    # a checkpoint unit's inputs hold the profile sections its method trains on (plan.py)
    inputs = {"code": "0" * 16, "profile": {"grip": profile["grip"]}}
    unit = SimpleNamespace(key="k", deps=["d"], params={"method": "grip", "inputs": inputs})
    (tmp_path / "unit").mkdir()
    assert stage.train_method(st, unit, tmp_path / "unit") == {"file": "model.ckpt"}
    # [run] is read from the run's profile; training gets the keyed sections and the name
    assert seen == {"name": "grip", "nproc": 2, "sections": ["grip", "name"]}


def test_train_nproc_gets_its_own_checkpoint_units(tmp_path):
    """DDP equals one process only up to float rounding, so ``[run] train_nproc`` > 1 plans
    its own checkpoint units; at 1 the keys are those of a profile without the key."""
    from grip_bench.bench.cache import Cache
    from grip_bench.bench.plan import build_plan, make_config
    from tests.run_fixtures import tiny_run_profile

    def keys(name: str, **run) -> list[str]:
        path = tiny_run_profile(tmp_path / f"{name}.toml", methods=["nearest-neighbour"],
                                **run)
        plan = build_plan(make_config(str(path), out=tmp_path / name, progress=False),
                          Cache(tmp_path / "cache"))
        return [u.key for u in plan.of("checkpoint")]

    plain, one, two = keys("plain"), keys("one", train_nproc=1), keys("two", train_nproc=2)
    assert plain and plain == one
    assert len(two) == len(plain) and not set(two) & set(plain)
