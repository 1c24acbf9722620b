"""Training: over-fitting one batch, gradients through the renderer, every stage's checkpoint /
kill / resume giving identical state, DDP on CPU matching one process, weights files."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from support.paths import REPO
from support.tiny_scenes import tiny_scenes, write_dataset

from phyir.errors import InputError, PhyIRError
from phyir.learn.datasets import Augment, TensorSceneDataset, normalize_scene
from phyir.learn.losses import LossOptions, LossWeights, total_loss
from phyir.learn.train import STAGE_ORDER, TrainConfig, train
from phyir.learn.weights import load_model, save_weights
from phyir.nets import PhyIRModel
from phyir.scene import PanoScene

H, W, GRID, PROBE = 32, 64, (2, 4), (8, 16)
ALL_TERMS = ("albedo", "roughness", "metallic", "depth", "normal", "depth_grad", "probe", "sc", "render")


pytestmark = pytest.mark.usefixtures("one_thread")


def _model(seed: int = 0) -> PhyIRModel:
    torch.manual_seed(seed)
    return PhyIRModel(dataclasses.replace(PhyIRModel("lite").config, probe_size=PROBE))


def _batch(n: int, room: str = "box", coherent: bool = False) -> PanoScene:
    scenes = tiny_scenes(n, H=H, W=W, grid=GRID, probe_size=PROBE, room=room)
    if coherent:  # one probe for the whole room: spatially coherent light (SC loss can reach 0)
        scenes = [s.replace(probes=s.probes[:1, :1].expand_as(s.probes).clone()) for s in scenes]
    return PanoScene.stack([normalize_scene(s) for s in scenes])


def test_overfit_one_batch_all_losses_fall_tenfold():
    """Every loss term (each normalised by its first value) is driven down >= 10x on one scene."""
    batch = _batch(1, room="ellipsoid", coherent=True)
    model = _model()
    with torch.no_grad():  # start from varied probes so the SC term has something to remove
        model.lnet.head[-1].weight.mul_(20)
    opts = LossOptions(render_size=(H // 2, W // 2))
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    weights, first, hist = LossWeights(**dict.fromkeys(ALL_TERMS, 1.0)), None, []
    for _ in range(120):  # 90 sufficed at two threads, not quite at one (depth_grad 0.113)
        loss, terms = total_loss(model.forward_parts(batch.image, GRID), batch, weights, opts, refined=True)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if first is None:
            first = {k: float(v) for k, v in terms.items()}
            weights = LossWeights(**{k: 1.0 / first[k] for k in ALL_TERMS})
        hist.append({k: float(v) / first[k] for k, v in terms.items()})
    last = {k: sum(h[k] for h in hist[-3:]) / 3 for k in ALL_TERMS}
    assert set(first) == set(ALL_TERMS)
    assert all(v <= 0.1 for v in last.values()), last


def test_joint_stage_gradients_reach_gmnet_through_the_renderer():
    from phyir.learn.train import STAGES, StageForward

    batch = _batch(2)
    model = _model()
    net = StageForward(model, STAGES["joint"])
    opts = LossOptions(render_size=(H // 2, W // 2))
    pred = net(batch.image, GRID)
    pred["probes"] = pred["probes"].detach()  # leave only the path through the rendering layer
    loss, _ = total_loss(pred, batch, LossWeights(render=1.0), opts)
    loss.backward()
    for head in ("normal", "albedo", "roughness", "metallic"):
        g = model.gmnet.decoders[head].out.weight.grad
        assert g is not None and g.abs().sum() > 0, head
    assert model.gmnet.encoder.conv1.weight.grad.abs().sum() > 0
    assert all(p.grad is None for p in model.lnet.parameters())


# ---------------------------------------------------------------------------------------------
# checkpoint / kill / resume


def _datasets():
    scenes = tiny_scenes(6, H=H, W=W, grid=GRID, probe_size=PROBE)
    return (TensorSceneDataset(scenes[:4], augment=Augment(p_ldr=0.5)),
            TensorSceneDataset(scenes[4:]))


def _cfg(out: Path, stage: str, **kw) -> TrainConfig:
    base = dict(stage=stage, out=str(out), epochs=2, batch_size=2, size=None, probe_grid=None,
                progress=False, ckpt_every=100, loss={"render_size": [H // 2, W // 2]})
    return TrainConfig(**{**base, **kw})


def _state(out: Path, stage: str) -> dict:
    ck = torch.load(out / stage / "checkpoint.pt", weights_only=True)
    return {"model": ck["model"], "opt": ck["optimizer"]["state"], "sched": ck["scheduler"],
            "rng": ck["rng"], "pos": (ck["epoch"], ck["batch"], ck["step"])}


def _assert_same(a, b, path="state"):
    if isinstance(a, torch.Tensor):
        assert torch.equal(a, b), path
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            _assert_same(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_same(x, y, f"{path}[{i}]")
    else:
        assert a == b, path


def test_every_stage_resumes_exactly(tmp_path):
    """Each stage: an uninterrupted run vs one stopped twice (mid-epoch and at an epoch boundary)
    and resumed; model, optimiser, scheduler, RNG and position must be bitwise identical."""
    data = _datasets()
    full, cut = tmp_path / "full", tmp_path / "cut"
    for stage in STAGE_ORDER:
        init = {} if stage == "gm" else {"init": str(full / "gm" / "model.safetensors"), "val": False}
        ref = train(_cfg(full, stage, **init), datasets=data)
        assert ref["status"] == "done" and ref["step"] == 4
        r1 = train(_cfg(cut, stage, max_steps=1, **init), datasets=data)
        assert (r1["status"], r1["step"]) == ("stopped", 1)
        r2 = train(_cfg(cut, stage, max_steps=2, **init), datasets=data)  # stops at the epoch's end
        assert (r2["status"], r2["step"]) == ("stopped", 2)
        r3 = train(_cfg(cut, stage, **init), datasets=data)
        assert (r3["status"], r3["step"]) == ("done", 4)
        assert r1["losses"] + r2["losses"] + r3["losses"] == ref["losses"], stage
        _assert_same(_state(full, stage), _state(cut, stage))
        if stage != STAGE_ORDER[-1]:  # next stages of 'cut' start from the same weights as 'full'
            shutil.copy(full / stage / "model.safetensors", cut / stage / "model.safetensors")
    log = [ln for ln in (cut / "gm" / "log.jsonl").read_text().splitlines() if ln]
    assert len(log) == 4  # one line per step, none duplicated by the resumes


def test_killed_cli_run_resumes_to_the_same_weights(tmp_path):
    """`phyir train` killed (SIGKILL) after its first checkpoints, then re-run, ends with exactly the
    weights of an uninterrupted run."""
    data = tmp_path / "data"
    write_dataset(data, n_train=4, n_val=1, H=H, W=W, grid=GRID, probe_size=PROBE)
    args = ["--data", str(data), "--stage", "gm", "--epochs", "3", "--batch-size", "2", "--size", "native",
            "--probe-grid", "native", "--ckpt-every", "1", "--no-progress"]
    cmd = [sys.executable, "-m", "phyir.cli", "train", *args]
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}  # as this process (fixture)
    run = tmp_path / "killed"
    proc = subprocess.Popen([*cmd, "--out", str(run)], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    log = run / "gm" / "log.jsonl"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if log.is_file() and len(log.read_text().splitlines()) >= 2:
            break
        time.sleep(0.05)
    killed = proc.poll() is None
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert killed, proc.stderr.read().decode()
    assert (run / "gm" / "checkpoint.pt").is_file()
    assert not (run / "gm" / "model.safetensors").exists()
    out = subprocess.run([*cmd, "--out", str(run)], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "resuming at epoch" in out.stderr
    # reference: the same training uninterrupted, in this process
    from phyir.cli import main

    assert main(["train", *args, "--out", str(tmp_path / "ref")]) == 0
    a = load_model(run / "gm" / "model.safetensors").state_dict()
    b = load_model(tmp_path / "ref" / "gm" / "model.safetensors").state_dict()
    _assert_same(a, b)


@pytest.mark.slow
def test_ddp_two_processes_match_one_process(tmp_path):
    """torchrun --nproc_per_node=2 (gloo, CPU) follows the single-process loss curve at the same
    global batch."""
    data = tmp_path / "data"
    write_dataset(data, n_train=8, n_val=2, H=H, W=W, grid=GRID, probe_size=PROBE)
    args = ["train", "--data", str(data), "--stage", "gm", "--epochs", "2", "--batch-size", "4",
            "--size", "native", "--probe-grid", "native", "--no-progress"]
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    torchrun = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2"]
    ddp = subprocess.run([*torchrun, "-m", "phyir.cli", *args, "--out", str(tmp_path / "ddp")], env=env,
                         capture_output=True, text=True, timeout=300)
    assert ddp.returncode == 0, ddp.stderr[-3000:]
    one = subprocess.run([sys.executable, "-m", "phyir.cli", *args, "--out", str(tmp_path / "one")], env=env,
                         capture_output=True, text=True, timeout=300)
    assert one.returncode == 0, one.stderr[-3000:]
    import json

    def curve(run):
        return [json.loads(ln)["loss"] for ln in
                         (tmp_path / run / "gm" / "log.jsonl").read_text().splitlines()]
    a, b = curve("ddp"), curve("one")
    assert len(a) == len(b) == 4
    rel = max(abs(x - y) / abs(y) for x, y in zip(a, b))
    print(f"DDP vs one process: losses {a} vs {b}, max relative difference {rel:.2e}")
    assert rel < 1e-4, (a, b)
    assert a[-1] < a[0]


# ---------------------------------------------------------------------------------------------
# weights files and user errors


def test_weights_round_trip_and_refusals(tmp_path):
    model = _model()
    p = save_weights(model, tmp_path / "m.safetensors", {"note": "test"})
    again = load_model(p)
    _assert_same(model.state_dict(), again.state_dict())
    assert again.config == model.config
    assert (tmp_path / "m.json").is_file()
    # another architecture
    full = PhyIRModel("full")
    from phyir.learn.weights import load_into

    with pytest.raises(InputError) as e:
        load_into(full, p)
    msg = str(e.value)
    assert msg.startswith(str(p)) and "'lite'" in msg and "\n" not in msg
    # corrupt / truncated / not weights at all
    for name, data in (("trunc", p.read_bytes()[:1000]), ("junk", b"\x00" * 64), ("empty", b"")):
        bad = tmp_path / f"{name}.safetensors"
        bad.write_bytes(data)
        with pytest.raises(InputError) as e:
            load_model(bad)
        assert str(e.value).startswith(str(bad)) and "\n" not in str(e.value)
    with pytest.raises(InputError, match="not found"):
        load_model(tmp_path / "missing.safetensors")


def test_ship_stores_half_precision_with_the_sidecar(tmp_path):
    import json

    from phyir.learn.weights import ship

    model = _model()
    src = save_weights(model, tmp_path / "run.safetensors", {"data": {"resolution": "128x256"}})
    dst = ship(src, tmp_path / "ship" / "phyir-lite.safetensors", {"eval": {"depth.abs_rel": 0.2}})
    assert dst.stat().st_size < 0.6 * src.stat().st_size
    side = json.loads((tmp_path / "ship" / "phyir-lite.json").read_text())
    assert side["data"]["resolution"] == "128x256" and side["stored_as"] == "float16"
    assert side["eval"]["depth.abs_rel"] == 0.2
    again = load_model(dst)
    for k, v in model.state_dict().items():  # float16 rounding only
        if v.is_floating_point():
            assert torch.allclose(again.state_dict()[k], v, rtol=1e-3, atol=1e-4), k


def test_cli_reports_bad_weights_in_one_line(tmp_path, capsys):
    write_dataset(tmp_path / "data", n_train=2, n_val=0, H=H, W=W, grid=GRID, probe_size=PROBE)
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"garbage")
    from phyir.cli import main

    assert main(["train", "--data", str(tmp_path / "data"), "--stage", "light", "--init", str(bad),
                 "--out", str(tmp_path / "o"), "--size", "native"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and "safetensors" in err[0], err


def test_config_file_and_flags(tmp_path):
    import argparse

    from phyir.commands.train import add_arguments, options

    toml = 'stage = "light"\nepochs = 3\nsize = [64, 128]\n[loss]\nsc_sigma = 0.2\n'
    (tmp_path / "c.toml").write_text(toml)
    p = argparse.ArgumentParser()
    add_arguments(p)
    cfg = TrainConfig.from_dict(options(p.parse_args(["--config", str(tmp_path / "c.toml"), "--epochs", "5",
                                                      "--probe-grid", "native"])))
    assert (cfg.stage, cfg.epochs, cfg.size, cfg.probe_grid) == ("light", 5, (64, 128), None)
    stage, _, opts = cfg.resolved()
    assert (stage.epochs, stage.lr, stage.batch_size, opts.sc_sigma) == (5, 1e-4, 4, 0.2)
    cfg = TrainConfig.from_dict(options(p.parse_args(["--config", str(tmp_path / "c.toml"), "--loss",
                                                      "metallic_loss=l2", "--loss", "render_spp=8",
                                                      "--train-only", "gmnet.decoders.metallic"])))
    _, _, opts = cfg.resolved()
    assert (opts.sc_sigma, opts.metallic_loss, opts.render_spp) == (0.2, "l2", 8)
    assert cfg.train_only == ("gmnet.decoders.metallic",) and LossOptions().metallic_loss == "bce"
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(InputError, match="bad.json: not a valid json config"):
        options(p.parse_args(["--config", str(tmp_path / "bad.json")]))


def test_bad_options_are_user_errors(tmp_path):
    with pytest.raises(PhyIRError, match="unknown training option"):
        TrainConfig.from_dict({"stagee": "gm"})
    with pytest.raises(PhyIRError, match="unknown stage"):
        train(TrainConfig(stage="nope"))
    with pytest.raises(PhyIRError, match="earlier stage"):
        train(_cfg(tmp_path, "light"), datasets=_datasets())


def test_train_only_and_reinit_fine_tune_one_head(tmp_path):
    """``train_only`` freezes every other parameter of the stage; ``reinit`` resets the named module
    first; both are recorded in the export; bad names are one-line errors."""
    gm = _cfg(tmp_path / "a", "gm", epochs=1)
    train(gm, datasets=_datasets())
    start = load_model(tmp_path / "a" / "gm" / "model.safetensors").state_dict()
    head = "gmnet.decoders.metallic"
    cfg = _cfg(tmp_path / "b", "gm", epochs=1, init=str(tmp_path / "a" / "gm" / "model.safetensors"),
               train_only=(head,), reinit=(head + ".out",), loss={"metallic_loss": "bce"})
    train(cfg, datasets=_datasets())
    path = tmp_path / "b" / "gm" / "model.safetensors"
    after = load_model(path).state_dict()
    changed = {k for k in start if not torch.equal(start[k], after[k])}
    assert changed and all(k.startswith(head + ".") for k in changed), sorted(changed)[:5]
    assert any(k.startswith(head + ".iconv") for k in changed)  # trained, not only re-initialised
    info = json.loads(path.with_suffix(".json").read_text())
    assert info["train_only"] == [head] and info["loss"] == {"metallic_loss": "bce"}
    with pytest.raises(PhyIRError, match="train_only: 'gmnet.nope'"):
        train(_cfg(tmp_path / "c", "gm", train_only=("gmnet.nope",)), datasets=_datasets())
    with pytest.raises(PhyIRError, match="reinit: no module 'lnet.nope'"):
        train(_cfg(tmp_path / "d", "gm", reinit=("lnet.nope",)), datasets=_datasets())
    with pytest.raises(PhyIRError, match="metallic_loss must be"):
        train(_cfg(tmp_path / "e", "gm", loss={"metallic_loss": "l1"}), datasets=_datasets())


def test_a_frozen_pretrained_encoder_keeps_its_weights_and_its_batch_statistics(tmp_path):
    """A fresh ``effnet`` gm stage starts from the ImageNet encoder; with only the decoders trained the
    encoder's weights and its batch norms' running statistics stay the pretrained ones (a frozen
    norm layer in training mode would otherwise re-estimate them on the synthetic images)."""
    from phyir.nets.efficientnet import pretrained_state_dict

    cfg = _cfg(tmp_path, "gm", epochs=1, model="effnet", train_only=("gmnet.decoders",))
    train(cfg, datasets=_datasets())
    enc = {k.removeprefix("gmnet.encoder."): v
           for k, v in load_model(tmp_path / "gm" / "model.safetensors").state_dict().items()
           if k.startswith("gmnet.encoder.")}
    ref = pretrained_state_dict()
    assert set(enc) == set(ref)
    for k, v in ref.items():  # (stored as float32 in the export)
        torch.testing.assert_close(enc[k].to(v.dtype), v, rtol=0, atol=0, msg=k)


def test_ship_a_checkpoint_records_its_resolution_and_takes_lnet_gsnet_from_another_file(tmp_path):
    import json

    from phyir.learn.weights import ship, with_networks_of

    train(_cfg(tmp_path / "run", "gm", epochs=1, size=(H, W)), datasets=_datasets())
    dst = ship(tmp_path / "run" / "gm" / "checkpoint.pt", tmp_path / "geo.safetensors")
    assert json.loads(dst.with_suffix(".json").read_text())["data"]["resolution"] == f"{H}x{W}"
    torch.manual_seed(5)
    other_model = _model()
    other_model.config = dataclasses.replace(other_model.config, probe_block=4)  # LNet run on a finer grid
    other = save_weights(other_model, tmp_path / "other.safetensors")
    geo = load_model(dst)
    assert geo.config.probe_block != 4
    mixed = with_networks_of(load_model(dst), other)
    ref = load_model(other).state_dict()
    for k, v in mixed.state_dict().items():
        want = ref[k] if k.split(".")[0] in ("lnet", "gsnet") else geo.state_dict()[k]
        assert torch.equal(v, want), k
    # how LNet is run comes with it: its probe grid, not the geometry run's
    assert mixed.config.probe_block == 4 and mixed.default_grid(32, 64) == (8, 16)
    assert mixed.config.gm_encoder == geo.config.gm_encoder


def test_load_model_matches_a_model_built_on_the_cpu():
    """load_model builds on the meta device and gives it memory: the same values, dtypes and
    strides (the layout picks the kernels) as a model built on the CPU with the weights loaded in."""
    from phyir.learn.weights import default_weights_path, load_into, model_config, read_weights
    from phyir.nets.model import PhyIRModel

    path = default_weights_path()
    fast = load_model(path).state_dict()
    ref = PhyIRModel(model_config(path, read_weights(path)[1]))
    load_into(ref, path)
    slow = ref.state_dict()
    assert fast.keys() == slow.keys()
    for k in slow:
        assert torch.equal(fast[k], slow[k]) and fast[k].stride() == slow[k].stride(), k
