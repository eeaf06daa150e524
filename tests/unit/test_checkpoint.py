"""Checkpoints: bit-exact round trip, weights_only loading, clear errors for bad files."""

from __future__ import annotations

import dataclasses

import pytest
import torch

import grip_bench
from grip_bench.core.checkpoint import FORMAT, load_checkpoint, save_checkpoint
from grip_bench.core.errors import InputError, UnsafeFileError
from grip_bench.grip import ANetConfig, CNetConfig, RNetConfig

TINY = dict(hidden=32, width=16, dropout=0.0)
EXPECTED = {"cnet": CNetConfig, "anet": ANetConfig, "rnet": RNetConfig}


def tiny_configs() -> dict:
    return {
        "cnet": CNetConfig(body_dim=7, ambient_dim=16, future_dim=4, latent=8, **TINY),
        "anet": ANetConfig(latent=8, n_enc_blocks=2, n_dec_blocks=2, **TINY),
        "rnet": RNetConfig(n_blocks=3, zero_init_head=False, **TINY),
    }


@pytest.fixture
def saved(tmp_path):
    """A checkpoint with three tiny networks and an Adam state; returns (path, models)."""
    torch.manual_seed(0)
    configs = tiny_configs()
    models = {name: cfg.build() for name, cfg in configs.items()}
    params = [p for m in models.values() for p in m.parameters()]
    opt = torch.optim.Adam(params, lr=1e-3)
    sum(p.sum() for p in params).backward()
    opt.step()
    path = tmp_path / "run" / "grip.pt"
    save_checkpoint(
        path,
        model_state={name: m.state_dict() for name, m in models.items()},
        configs=configs,
        meta={"data_hash": "abc123", "seed": 0, "epoch": 3, "optimizer": opt.state_dict()},
    )
    return path, models


def tamper(path, edit) -> None:
    payload = torch.load(path, weights_only=True)
    edit(payload)
    torch.save(payload, path)


def test_round_trip_is_bit_exact(saved):
    path, models = saved
    ckpt = load_checkpoint(path, EXPECTED)
    assert ckpt.configs == tiny_configs()
    for name, model in models.items():
        for key, value in model.state_dict().items():
            assert torch.equal(ckpt.state[name][key], value), (name, key)
    assert ckpt.meta["suite_version"] == grip_bench.__version__
    assert ckpt.meta["torch_version"] == torch.__version__
    assert (ckpt.meta["data_hash"], ckpt.meta["seed"], ckpt.meta["epoch"]) == ("abc123", 0, 3)
    assert ckpt.meta["optimizer"]["param_groups"][0]["lr"] == 1e-3
    rebuilt = ckpt.models()
    assert not rebuilt["rnet"].training
    x = (torch.randn(3, 2, 15, 6), torch.rand(3, 2, 99))
    with torch.no_grad():
        assert torch.equal(rebuilt["rnet"](*x), models["rnet"].eval()(*x))


def test_file_is_plain_data_and_written_atomically(saved):
    path, _ = saved
    payload = torch.load(path, weights_only=True)
    assert payload["format"] == FORMAT
    assert sorted(p.name for p in path.parent.iterdir()) == ["grip.pt"]  # no temp file left
    subset = load_checkpoint(path, {"rnet": RNetConfig})  # other networks are ignored
    assert list(subset.configs) == ["rnet"]


def test_save_rejects_non_plain_meta(tmp_path):
    cfg = tiny_configs()["rnet"]
    with pytest.raises(InputError, match="plain data"):
        save_checkpoint(
            tmp_path / "x.pt",
            model_state={"rnet": cfg.build().state_dict()},
            configs={"rnet": cfg},
            meta={"when": object()},
        )
    with pytest.raises(InputError, match="differ"):
        save_checkpoint(tmp_path / "x.pt", model_state={}, configs={"rnet": cfg})
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("cut", [0.5, 0.01])
def test_truncated_file(saved, cut):
    path, _ = saved
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * cut)])
    with pytest.raises(InputError, match="not a readable torch checkpoint") as err:
        load_checkpoint(path, EXPECTED)
    assert err.value.where == str(path)


def test_not_a_checkpoint(tmp_path):
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"this is not a torch file at all" * 10)
    with pytest.raises(InputError, match="not a readable torch checkpoint"):
        load_checkpoint(garbage, EXPECTED)
    other = tmp_path / "other.pt"
    torch.save([torch.zeros(2)], other)
    with pytest.raises(InputError, match="not a grip-bench checkpoint"):
        load_checkpoint(other, EXPECTED)
    with pytest.raises(InputError, match="not found"):
        load_checkpoint(tmp_path / "missing.pt", EXPECTED)


@dataclasses.dataclass
class Smuggled:
    payload: str = "rm -rf /"


def test_pickled_objects_are_refused(tmp_path):
    path = tmp_path / "evil.pt"
    torch.save({"format": FORMAT, "models": {}, "configs": {}, "meta": {"x": Smuggled()}}, path)
    with pytest.raises(UnsafeFileError, match="non-plain"):
        load_checkpoint(path, EXPECTED)


def test_missing_network(saved):
    path, _ = saved
    tamper(path, lambda p: p["models"].pop("anet"))
    with pytest.raises(InputError, match=r"missing network\(s\) \['anet'\]"):
        load_checkpoint(path, EXPECTED)


def test_missing_and_unexpected_keys(saved):
    path, _ = saved

    def edit(p):
        sd = p["models"]["cnet"]
        sd["encoder.extra.weight"] = sd.pop("encoder.head.weight")

    tamper(path, edit)
    with pytest.raises(InputError) as err:
        load_checkpoint(path, EXPECTED)
    assert "missing keys: encoder.head.weight" in err.value.what
    assert "unexpected keys: encoder.extra.weight" in err.value.what
    assert err.value.where == f"{path}: cnet"


def test_many_missing_keys_are_summarised(saved):
    path, _ = saved
    tamper(path, lambda p: p["models"].__setitem__("rnet", {}))
    with pytest.raises(InputError, match=r"missing keys: .*\(\+\d+ more\)"):
        load_checkpoint(path, EXPECTED)


def test_shape_mismatch_names_key_and_shapes(saved):
    path, _ = saved
    tamper(path, lambda p: p["models"]["rnet"].__setitem__("net.head.weight", torch.zeros(180, 15)))
    with pytest.raises(
        InputError, match=r"net\.head\.weight: checkpoint \(180, 15\), model \(180, 16\)"
    ):
        load_checkpoint(path, EXPECTED)


def test_config_that_disagrees_with_weights(saved):
    path, _ = saved
    tamper(path, lambda p: p["configs"]["anet"].__setitem__("width", 24))
    with pytest.raises(InputError, match="shape mismatch"):
        load_checkpoint(path, EXPECTED)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("bogus_width", 3, r"unknown config field\(s\) \['bogus_width'\]"),
        ("width", "wide", "config field 'width' is 'wide', expected int"),
        ("consistency", "smooth", "invalid config: consistency must be one of"),
    ],
)
def test_bad_config_fields(saved, field, value, message):
    path, _ = saved
    tamper(path, lambda p: p["configs"]["cnet"].__setitem__(field, value))
    with pytest.raises(InputError, match=message):
        load_checkpoint(path, EXPECTED)
