"""The trainer on a small collected data set: learning, pruning, run folders, resume, errors.

One data set (6 trajectories x 3 pushes: 4 train, 1 val, 1 test) is collected once for the
module; models are tiny except in the end-to-end test.
"""

from __future__ import annotations

import csv
import dataclasses
import itertools
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from latent_sindy.configs import from_json
from latent_sindy.data import read_sequences, write_sequences
from latent_sindy.data.windows import Normalizer, WindowDataset
from latent_sindy.equations import equations_report, name_actions
from latent_sindy.errors import UserError
from latent_sindy.models import (
    DYNAMICS_KINDS,
    AutoencoderConfig,
    LatentModel,
    LossWeights,
    ModelConfig,
)
from latent_sindy.training import (
    METRIC_COLUMNS,
    RunDir,
    TrainConfig,
    TrainingDiverged,
    load_run,
    read_metrics,
    train,
)
from latent_sindy.training.config import resolve_device
from latent_sindy.training.record import run_record
from latent_sindy.worlds.push.collect import CollectionPlan, collect

KINDS = ("sindy", "linear", "mlp")
TINY_AE = {"latent_dim": 4, "encoder_hidden": 16, "decoder_hidden": (32,)}
CSV_FILE, JSON_FILE = RunDir.COEFFICIENTS_CSV, RunDir.COEFFICIENTS_JSON


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("data") / "push.h5"
    plan = CollectionPlan(trajectories=6, steps=3, seed=0, val_fraction=0.2, test_fraction=0.2)
    return collect(out, plan, workers=1)


def config(data: Path, out: Path, kind: str = "sindy", **kw) -> TrainConfig:
    """A tiny model; ``autoencoder={...}`` and ``dynamics={...}`` override its parts."""
    dyn = {"mlp": {"hidden": 16}}.get(kind, {}) | kw.pop("dynamics", {})
    auto = AutoencoderConfig(**{**TINY_AE, **kw.pop("autoencoder", {})})
    model = ModelConfig(observation=auto, dynamics=DYNAMICS_KINDS[kind](**dyn))
    kw = {"epochs": 4, "batch_size": 5, "lr": 3e-3, "prune_every": 0, "starts": 1, **kw}
    return TrainConfig(data=data, out=out, model=model, **kw)


def states_equal(a: torch.nn.Module, b: torch.nn.Module) -> None:
    sa, sb = a.state_dict(), b.state_dict()
    assert sa.keys() == sb.keys()
    for k in sa:
        assert torch.equal(sa[k], sb[k]), f"{k} differs"


def losses(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "time_s"} for r in rows]


class Recorder:
    """A Progress that remembers what it was told."""

    def __init__(self, on_update=None) -> None:
        self.calls: list[tuple] = []
        self.on_update = on_update

    def start(self, total: int, initial: int) -> None:
        self.calls.append(("start", total, initial))

    def update(self, epoch: int, metrics) -> None:
        self.calls.append(("update", epoch, dict(metrics)))
        if self.on_update:
            self.on_update(epoch)

    def note(self, text: str) -> None:
        self.calls.append(("note", text))

    def close(self) -> None:
        self.calls.append(("close",))


# ----------------------------------------------------------------------------- learning
def _dark_centroid(img: np.ndarray, level: float = 150.0) -> np.ndarray:
    ys, xs = np.nonzero(img < level)
    return np.array([ys.mean(), xs.mean()]) if len(ys) else np.array([np.inf, np.inf])


def test_end_to_end_learns_recognisable_images(data: Path, tmp_path: Path) -> None:
    cfg = TrainConfig(
        data=data, out=tmp_path / "run", epochs=120, lr=3e-3, batch_size=500, prune_every=30
    )
    run = train(cfg)
    for name in ("config.json", "model.pt", "checkpoint.pt", "metrics.csv", "loss.png"):
        assert (run / name).is_file(), name
    rows = read_metrics(run)
    assert [r["epoch"] for r in rows] == list(range(1, 121))
    assert rows[-1]["train/objective"] < 0.1 * rows[0]["train/objective"]
    assert rows[-1]["sindy/active"] < rows[0]["sindy/active"]  # pruned at 30, 60, 90, 120

    model, norm, loaded_cfg, *_ = load_run(run)
    assert loaded_cfg == cfg
    d = read_sequences(data).split("train")
    x = norm.normalize(d.images)  # (4, 4, 1, 32, 32)
    with torch.no_grad():
        x_rec = model.decode(model.encode(x))
    mse = float((x_rec - x).square().mean())
    mean_image_mse = float((x - x.mean(dim=(0, 1))).square().mean())
    assert mse < 0.2 * mean_image_mse
    pixels = norm.denormalize(x_rec).numpy()
    errors = [np.linalg.norm(_dark_centroid(d.images[i, t, 0]) - _dark_centroid(pixels[i, t, 0]))
              for i in range(d.n) for t in range(d.steps + 1)]
    # the block is drawn where it is: within a pixel typically, never 3 pixels off
    assert np.median(errors) < 1.0 and max(errors) < 3.0, errors


@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_trains_and_logs(data: Path, tmp_path: Path, kind: str) -> None:
    progress = Recorder()
    cfg = config(data, tmp_path / kind, kind, epochs=6, window=2)
    run = train(cfg, progress)
    rows = read_metrics(run)
    with (run / "metrics.csv").open() as f:
        assert tuple(next(csv.reader(f))) == METRIC_COLUMNS
    assert rows[-1]["train/objective"] < rows[0]["train/objective"]
    assert rows[-1]["val/objective"] is not None
    for r in rows:
        assert math.isclose(
            r["train/total"] - r["train/objective"], cfg.loss.lambda_l1 * r["train/l1"],
            abs_tol=1e-6
        )
        assert (r["train/l1"] > 0) == (kind == "sindy")
        assert (r["sindy/active"] is not None) == (kind == "sindy")
    assert progress.calls[0] == ("start", 6, 0) and progress.calls[-1] == ("close",)
    assert [c[1] for c in progress.calls if c[0] == "update"] == list(range(1, 7))


# ----------------------------------------------------------------------------- pruning and mask
@pytest.fixture(scope="module")
def pruned_run(data: Path, tmp_path_factory: pytest.TempPathFactory):
    """A SINDy run pruned every 2 epochs, with the mask of every epoch's checkpoint."""
    out = tmp_path_factory.mktemp("pruned") / "run"
    masks: list[torch.Tensor] = []

    def grab(epoch: int) -> None:
        ckpt = torch.load(out / "checkpoint.pt", weights_only=True)
        assert ckpt["epoch"] == epoch
        masks.append(ckpt["model"]["dynamics.mask"].clone())

    cfg = config(
        data,
        out,
        epochs=8,
        prune_below=3e-3,
        prune_every=2,
        checkpoint_every=1,
        dynamics={"init_scale": 3e-3},
    )
    return train(cfg, Recorder(grab)), masks


def test_pruning_never_revives_a_term(pruned_run) -> None:
    run, masks = pruned_run
    counts = [int(m.sum()) for m in masks]
    assert counts[0] == masks[0].numel()  # nothing pruned before epoch 2
    assert counts[-1] < counts[1] < counts[0]  # pruned at 2 and again later
    for before, after in itertools.pairwise(masks):
        assert not (after & ~before).any()  # once off, off for good
    assert all(counts[i] == counts[i - 1] for i in (2, 4, 6))  # pruned at even epochs only
    rows = read_metrics(run)
    assert [int(r["sindy/active"]) for r in rows] == counts
    model = load_run(run).model
    assert (model.dynamics.psi[~model.dynamics.mask] == 0).all()  # AdamW moments cleared too


def test_mask_survives_load_and_drives_step(pruned_run) -> None:
    run, masks = pruned_run
    dyn = load_run(run).model.dynamics
    assert torch.equal(dyn.mask, masks[-1]) and not dyn.mask.all()
    g = torch.Generator().manual_seed(0)
    z, u = torch.randn(7, 4, generator=g), torch.rand(7, 3, generator=g)
    before = dyn.step(z, u)
    with torch.no_grad():
        dyn.psi[~dyn.mask] = 5.0  # pruned coefficients must not matter
    torch.testing.assert_close(dyn.step(z, u), before, rtol=0, atol=0)
    torch.testing.assert_close(dyn.compile_sparse().step(z, u), before)


def test_equations_report_lists_the_active_terms(pruned_run) -> None:
    run, _ = pruned_run
    dyn = load_run(run).model.dynamics
    text = equations_report(run)
    eqs = [line for line in text.splitlines() if re.match(r"z\d+\[t\+1\] = ", line)]
    assert len(eqs) == dyn.nz
    assert f"active coefficients: {dyn.n_active()} of {dyn.mask.numel()}" in text
    for j, line in enumerate(eqs):
        rhs = line.split(" = ", 1)[1]
        parts = re.split(r" [+-] ", rhs)[1:]  # the first part is the residual z_j
        terms = {p.split(" ", 1)[1] if " " in p else "1" for p in parts}
        names = name_actions(dyn.names, load_run(run).description["action_names"])
        assert terms == {names[i] for i in dyn.mask[:, j].nonzero().flatten().tolist()}
    expected = dyn.coefficient_rows()
    with (run / CSV_FILE).open() as f:
        got = [(r["state"], r["term"], float(r["value"])) for r in csv.DictReader(f)]
    assert got == expected
    doc = json.loads((run / JSON_FILE).read_text())
    assert [(c["state"], c["term"], c["value"]) for c in doc["coefficients"]] == expected
    assert doc["n_active"] == dyn.n_active() == len(expected)


def test_equations_of_linear_and_mlp_runs(data: Path, tmp_path: Path) -> None:
    lin = train(config(data, tmp_path / "linear", "linear", epochs=1))
    text = equations_report(lin)
    A = load_run(lin).model.dynamics.A.detach()
    assert "z[t+1] = A z + B u + c" in text
    assert sum(bool(re.match(r"z\d+\[t\+1\] = ", line)) for line in text.splitlines()) == 4
    with (lin / CSV_FILE).open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 4 * (4 + 3 + 1)
    assert float(rows[1]["value"]) == float(A[0, 1]) and rows[1]["term"] == "z1"
    mlp = train(config(data, tmp_path / "mlp", "mlp", epochs=1))
    assert "no readable equations" in equations_report(mlp)
    assert not (mlp / CSV_FILE).exists()


# ----------------------------------------------------------------------------- resume
@pytest.mark.parametrize(("kind", "batching"), [(k, "trajectories") for k in KINDS]
                         + [("sindy", "windows")])
def test_resume_equals_uninterrupted(data: Path, tmp_path: Path, kind: str,
                                     batching: str) -> None:
    """N epochs, then resume to 2N == 2N straight (pruning at epochs 2 and 4 included)."""
    scale = {} if kind == "mlp" else {"init_scale": 3e-3}  # an MLP has no coefficient scale
    kw = {"prune_below": 3e-3, "prune_every": 2, "dynamics": scale, "batching": batching}
    straight = train(config(data, tmp_path / "straight", kind, epochs=6, **kw))
    part = config(data, tmp_path / "resumed", kind, epochs=3, checkpoint_every=1, **kw)
    train(part)
    progress = Recorder()
    resumed = train(dataclasses.replace(part, epochs=6, resume=True), progress)
    assert progress.calls[0] == ("start", 6, 3)
    states_equal(load_run(straight).model, load_run(resumed).model)
    assert losses(read_metrics(straight)) == losses(read_metrics(resumed))
    # The comparison is sensitive: another shuffle order gives another model.
    other = train(config(data, tmp_path / "other", kind, epochs=6, seed=1, **kw))
    with pytest.raises(AssertionError):
        states_equal(load_run(straight).model, load_run(other).model)


def test_resume_after_a_kill_mid_run(data: Path, tmp_path: Path) -> None:
    """Killed in epoch 5 with checkpoints every 2: resume restarts after epoch 4."""
    kw = {"prune_every": 3, "prune_below": 3e-3, "dynamics": {"init_scale": 3e-3}}
    straight = train(config(data, tmp_path / "straight", epochs=6, **kw))
    cfg = config(data, tmp_path / "killed", epochs=6, checkpoint_every=2, **kw)

    def kill(epoch: int) -> None:
        if epoch == 5:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(cfg, Recorder(kill))
    assert not (cfg.out / "model.pt").exists()
    assert len(read_metrics(cfg.out)) == 5  # epoch 5 was logged, but not checkpointed
    with pytest.raises(UserError, match="interrupted run"):
        train(cfg)
    with pytest.raises(UserError, match="did not finish"):
        load_run(cfg.out)
    assert load_run(cfg.out, checkpoint=True).model is not None
    train(dataclasses.replace(cfg, resume=True))
    states_equal(load_run(straight).model, load_run(cfg.out).model)
    assert losses(read_metrics(straight)) == losses(read_metrics(cfg.out))


def test_resume_with_other_settings_names_them(data: Path, tmp_path: Path) -> None:
    cfg = config(data, tmp_path / "run", epochs=2)
    train(cfg)
    changed = dataclasses.replace(
        cfg, resume=True, epochs=4, lr=1e-2,
        model=dataclasses.replace(cfg.model, dynamics=dataclasses.replace(cfg.model.dynamics,
                                                                          order=3)))
    with pytest.raises(UserError, match=r"lr \(run 0\.003, now 0\.01\); model\.dynamics\.order"):
        train(changed)
    with pytest.raises(UserError, match="past --epochs"):
        train(dataclasses.replace(cfg, resume=True, epochs=1))


# ----------------------------------------------------------------------------- eval_every
def reference_model(cfg: TrainConfig) -> tuple[LatentModel, list[float]]:
    """The training arithmetic of the trainer before eval_every and devices (commit cfda25a),
    without its run folder: the model and the validation objective of every epoch."""
    data = read_sequences(cfg.data)
    record = run_record(cfg, data)
    norm = Normalizer.from_dict(record["normalizer"])
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(cfg.seed)
        model = LatentModel(from_json(ModelConfig, record["model"], "model"))
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, betas=cfg.betas,
                            weight_decay=cfg.weight_decay)
    gen = torch.Generator().manual_seed(cfg.seed)
    x, u = WindowDataset(data.split("train"), cfg.window, norm).tensors()
    xv, uv = WindowDataset(data.split("val"), cfg.window, norm).tensors()
    val = []
    for epoch in range(1, cfg.epochs + 1):
        order = torch.randperm(len(x), generator=gen)
        for b in range(0, len(x), cfg.batch_size):
            idx = order[b : b + cfg.batch_size]
            terms = model.loss(x[idx], u[idx], cfg.loss)
            opt.zero_grad(set_to_none=True)
            terms["total"].backward()
            opt.step()
        if cfg.prune_every and epoch % cfg.prune_every == 0:
            with torch.no_grad():
                model.dynamics.prune(cfg.prune_below)
                for key in ("exp_avg", "exp_avg_sq"):
                    opt.state[model.dynamics.psi][key].masked_fill_(~model.dynamics.mask, 0.0)
        with torch.no_grad():
            model.eval()
            val.append(float(model.loss(xv, uv, cfg.loss)["objective"].double()))
            model.train()
    return model, val


def test_eval_every_changes_the_metrics_only(data: Path, tmp_path: Path) -> None:
    """eval_every=1 gives the model and losses of the trainer as it was, bit for bit; other
    values leave val/* empty except every N-th and the last epoch, and the same model."""
    kw = {"epochs": 5, "prune_below": 3e-3, "prune_every": 2, "dynamics": {"init_scale": 3e-3},
          "batch_size": 20,  # one batch per epoch: the validation loss is one batch too
          "batching": "windows", "prune": "absolute"}
    every = train(config(data, tmp_path / "every", **kw))
    ref, ref_val = reference_model(config(data, tmp_path / "ref", **kw))
    states_equal(load_run(every, checkpoint=True).model, ref)  # the last epoch
    assert [r["val/objective"] for r in read_metrics(every)] == ref_val
    sparse = train(config(data, tmp_path / "sparse", eval_every=2, **kw))
    states_equal(load_run(sparse, checkpoint=True).model, ref)
    rows, full = read_metrics(sparse), read_metrics(every)
    evaluated = [r["epoch"] for r in rows if r["val/objective"] is not None]
    assert evaluated == [2, 4, 5]  # every 2nd and the last
    for a, b in zip(rows, full, strict=True):
        for k in METRIC_COLUMNS:
            if k != "time_s" and (not k.startswith("val/") or a["epoch"] in evaluated):
                assert a[k] == b[k], (a["epoch"], k)
            elif k.startswith("val/"):
                assert a[k] is None
    # Changing eval_every on resume is allowed: it does not change the model.
    more = dataclasses.replace(config(data, tmp_path / "sparse", eval_every=3, **kw),
                               epochs=6, resume=True)
    assert train(more) == sparse


def test_resume_with_another_thread_count_says_so(data: Path, tmp_path: Path) -> None:
    cfg = config(data, tmp_path / "run", epochs=2)
    train(cfg)
    progress = Recorder()
    torch.set_num_threads(2)
    try:
        train(dataclasses.replace(cfg, epochs=3, resume=True), progress)
    finally:
        torch.set_num_threads(1)
    notes = [c[1] for c in progress.calls if c[0] == "note"]
    assert any("with 2 thread(s) (batch) a run trained on cpu with 1 (ops)" in n
               for n in notes), notes


@pytest.mark.parametrize("batching", ["trajectories", "windows"])
@pytest.mark.parametrize("threads", [1, 2])
def test_same_seed_same_model_on_cpu(data: Path, tmp_path: Path, threads: int,
                                     batching: str) -> None:
    """Two trainings of the conv decoder (the CPU's own kernels included) from one seed give
    the same weights, bit for bit; another seed does not."""
    kw = {"autoencoder": {"decoder_kind": "conv"}, "epochs": 3, "prune_below": 3e-3,
          "prune_every": 2, "dynamics": {"init_scale": 3e-3}, "batching": batching}
    torch.set_num_threads(threads)
    try:
        a, b = (train(config(data, tmp_path / name, **kw)) for name in "ab")
        c = train(config(data, tmp_path / "c", seed=1, **kw))
    finally:
        torch.set_num_threads(1)
    states_equal(load_run(a).model, load_run(b).model)
    states_equal(load_run(a, checkpoint=True).model, load_run(b, checkpoint=True).model)
    assert losses(read_metrics(a)) == losses(read_metrics(b))
    with pytest.raises(AssertionError):
        states_equal(load_run(a).model, load_run(c).model)


# ----------------------------------------------------------------------------- batching
def test_batchings_see_the_same_predictions(data: Path, tmp_path: Path) -> None:
    """One batch per epoch: epoch 1's training terms are the initial model's loss on all the
    windows; trajectory batches give the same prediction terms and the per-frame
    reconstruction mean (each of the 4 x 4 frames once), then train another model."""
    kw = {"epochs": 2, "batch_size": 12}  # 4 trajectories of 3 pushes: 12 windows
    traj = read_metrics(train(config(data, tmp_path / "t", batching="trajectories", **kw)))
    win = read_metrics(train(config(data, tmp_path / "w", batching="windows", **kw)))
    auto = read_metrics(train(config(data, tmp_path / "a", **kw)))  # window 1: trajectories
    for term in ("pred_x", "pred_z", "l1"):
        assert math.isclose(traj[0][f"train/{term}"], win[0][f"train/{term}"], rel_tol=1e-5)
    d = read_sequences(data)
    cfg = config(data, tmp_path / "x")
    with torch.random.fork_rng(devices=[]):  # the trainer's initial model
        torch.manual_seed(cfg.seed)
        model = LatentModel(from_json(ModelConfig, run_record(cfg, d)["model"], "model"))
    x = Normalizer.from_trajectories(d).normalize(d.split("train").images)  # (4, 4, 1, 32, 32)
    with torch.no_grad():
        per_frame = float((model.decode(model.encode(x)) - x).square().mean())
    assert math.isclose(traj[0]["train/recon"], per_frame, rel_tol=1e-5)
    assert not math.isclose(win[0]["train/recon"], per_frame, rel_tol=1e-4)
    assert losses(auto) == losses(traj)
    assert traj[1]["train/objective"] != win[1]["train/objective"]


def test_a_run_batched_by_windows_resumes_only_by_windows(data: Path, tmp_path: Path) -> None:
    cfg = config(data, tmp_path / "run", epochs=2, batching="windows")
    run = train(cfg)
    assert load_run(run).config.batching == "windows"
    with pytest.raises(UserError, match=r"batching \(run 'windows', now 'trajectories'\)"):
        train(dataclasses.replace(cfg, batching="auto", epochs=3, resume=True))
    train(dataclasses.replace(cfg, epochs=3, resume=True))
    straight = train(config(data, tmp_path / "straight", epochs=3, batching="windows"))
    states_equal(load_run(run).model, load_run(straight).model)
    # auto at window 2 batches windows: a run of either setting is the other's
    two = config(data, tmp_path / "two", epochs=1, window=2, batching="windows")
    train(two)
    train(dataclasses.replace(two, batching="auto", epochs=2, resume=True))


def test_the_record_holds_what_auto_batching_resolved_to(data: Path, tmp_path: Path) -> None:
    """config.json keeps --batching as given and what it batched; the recorded value is the
    one a resume is checked against."""
    one = train(config(data, tmp_path / "one", epochs=1))
    two = train(config(data, tmp_path / "two", epochs=1, window=2))
    for run, want in ((one, "trajectories"), (two, "windows")):
        record = json.loads((run / "config.json").read_text())
        assert (record["train"]["batching"], record["batching"]) == ("auto", want)
        assert RunDir(run).batching() == want
        assert load_run(run).config.batching == "auto"
    train(config(data, one, epochs=2, resume=True))
    # a run whose auto had batched windows is not resumed by trajectory batches
    record = json.loads((one / "config.json").read_text())
    (one / "config.json").write_text(json.dumps({**record, "batching": "windows"}))
    with pytest.raises(UserError, match=r"batching \(run 'windows', now 'trajectories'\)"):
        train(config(data, one, epochs=3, resume=True))
    (one / "config.json").write_text(json.dumps({**record, "batching": "auto"}))
    with pytest.raises(UserError, match="batching 'auto' is not trajectories or windows"):
        RunDir(one).batching()


# ----------------------------------------------------------------------------- best validation
def scripted_validation(monkeypatch, objectives: list[float]) -> None:
    """The trainer's validation reports these objectives, one per evaluation in order (the
    other terms are the real ones); training itself is untouched."""
    from latent_sindy.training import fit_loop as fit_module

    real, values = fit_module.evaluate, iter(objectives)

    def scripted(*args, **kwargs):
        return {**real(*args, **kwargs), "objective": next(values)}

    monkeypatch.setattr(fit_module, "evaluate", scripted)


def test_the_best_validation_epoch_is_kept(data: Path, tmp_path: Path, monkeypatch) -> None:
    """The validation objective rises late: model.pt holds the earlier, lower epoch's weights
    (those of a run stopped there), the checkpoint the last epoch's."""
    scripted_validation(monkeypatch, [5.0, 4.0, 3.0, 3.5, 4.5, 6.0])
    progress = Recorder()
    run = train(config(data, tmp_path / "run", epochs=6), progress)
    monkeypatch.undo()
    stopped = train(config(data, tmp_path / "stopped", epochs=3, keep_best=False))
    last = train(config(data, tmp_path / "last", epochs=6, keep_best=False))
    states_equal(load_run(run).model, load_run(stopped).model)
    states_equal(load_run(run, checkpoint=True).model, load_run(last).model)
    with pytest.raises(AssertionError):  # the comparison can tell epochs 3 and 6 apart
        states_equal(load_run(run).model, load_run(last).model)
    kept = json.loads((run / "config.json").read_text())["kept"]
    assert kept == {"epoch": 3, "selection": "best validation", "val_objective": 3.0,
                    "candidates_from": 1}
    assert torch.load(run / "model.pt", weights_only=True)["epoch"] == 3
    assert ("note", "kept the weights of epoch 3 of 6: the lowest validation objective (3) "
            "since epoch 1") in progress.calls
    assert json.loads((last / "config.json").read_text())["kept"]["selection"] == "last epoch"


def test_only_epochs_with_the_final_mask_are_kept(data: Path, tmp_path: Path,
                                                   monkeypatch) -> None:
    """Pruning at epoch 2 removes every term (prune_below 10): epoch 1, the lowest, has another
    mask and is not kept; the prunings at 4 and 6 remove nothing and change no mask."""
    kw = {"prune_below": 10.0, "prune_every": 2}
    scripted_validation(monkeypatch, [1.0, 5.0, 4.0, 3.0, 3.5, 6.0])
    run = train(config(data, tmp_path / "run", epochs=6, **kw))
    monkeypatch.undo()
    every_term = load_run(run).model.dynamics.psi.numel()
    assert [r["sindy/pruned"] for r in read_metrics(run)][1::2] == [every_term, 0, 0]
    kept = json.loads((run / "config.json").read_text())["kept"]
    assert (kept["epoch"], kept["candidates_from"]) == (4, 2)
    stopped = train(config(data, tmp_path / "stopped", epochs=4, keep_best=False, **kw))
    states_equal(load_run(run).model, load_run(stopped).model)


def test_the_best_so_far_survives_a_resume(data: Path, tmp_path: Path, monkeypatch) -> None:
    """The best epoch (2) is before the checkpoint the run resumes from (4): only the
    checkpoint holds its weights."""
    scripted_validation(monkeypatch, [3.0, 2.0, 2.5, 4.0])
    cfg = config(data, tmp_path / "run", epochs=4, checkpoint_every=4)
    train(cfg)
    monkeypatch.undo()
    scripted_validation(monkeypatch, [5.0, 6.0])
    run = train(dataclasses.replace(cfg, epochs=6, resume=True))
    monkeypatch.undo()
    assert json.loads((run / "config.json").read_text())["kept"]["epoch"] == 2
    stopped = train(config(data, tmp_path / "stopped", epochs=2, keep_best=False))
    states_equal(load_run(run).model, load_run(stopped).model)


def test_resuming_a_checkpoint_without_selection_says_so(data: Path, tmp_path: Path) -> None:
    cfg = config(data, tmp_path / "run", epochs=2)
    train(cfg)
    ckpt = torch.load(cfg.out / "checkpoint.pt", weights_only=True)
    del ckpt["best"]  # as written before model selection existed
    torch.save(ckpt, cfg.out / "checkpoint.pt")
    progress = Recorder()
    train(dataclasses.replace(cfg, epochs=4, resume=True), progress)
    assert ("note", f"{cfg.out / 'checkpoint.pt'} is from before model selection: the kept "
            "weights are chosen among epochs 3 to 4") in progress.calls
    kept = json.loads((cfg.out / "config.json").read_text())["kept"]
    assert kept["candidates_from"] == 3 and kept["epoch"] in (3, 4)


# ----------------------------------------------------------------------------- devices
def test_device_cuda_without_cuda_is_one_line(data: Path, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_device("auto") == "cpu"
    with pytest.raises(UserError, match=r"--device cuda: .*no CUDA device") as e:
        train(config(data, tmp_path / "run", device="cuda"))
    assert "\n" not in str(e.value)
    assert not (tmp_path / "run").exists()  # refused before anything was written
    run = train(config(data, tmp_path / "auto", device="auto", epochs=1))
    assert load_run(run).config.device == "auto"


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_training_writes_cpu_files(data: Path, tmp_path: Path) -> None:
    kw = {"prune_below": 3e-3, "prune_every": 1, "dynamics": {"init_scale": 3e-3}}
    run = train(config(data, tmp_path / "run", device="cuda", epochs=2, **kw))
    ckpt = torch.load(run / "checkpoint.pt", weights_only=True)  # no map_location needed
    assert all(t.device.type == "cpu" for t in ckpt["model"].values())
    assert ckpt["device"] == "cuda"
    cpu = train(config(data, tmp_path / "cpu", epochs=2, **kw))
    a, b = load_run(run).model.state_dict(), load_run(cpu).model.state_dict()
    for k in a:  # the same mini-batches and initial weights: close, not bit-identical
        assert torch.allclose(a[k].float(), b[k].float(), atol=1e-4), k
    resumed = train(dataclasses.replace(config(data, run, device="cpu", epochs=3, **kw),
                                        resume=True))
    assert len(read_metrics(resumed)) == 3


def test_finished_run_is_not_overwritten(data: Path, tmp_path: Path) -> None:
    cfg = config(data, tmp_path / "run", epochs=1)
    train(cfg)
    stamp = (cfg.out / "model.pt").stat().st_mtime_ns
    with pytest.raises(UserError, match="already holds a trained model"):
        train(cfg)
    assert (cfg.out / "model.pt").stat().st_mtime_ns == stamp
    train(dataclasses.replace(cfg, overwrite=True, epochs=2))
    assert len(read_metrics(cfg.out)) == 2


# ----------------------------------------------------------------------------- failures
def test_nan_loss_stops_with_a_clear_error(data: Path, tmp_path: Path, monkeypatch) -> None:
    calls = {"n": 0}
    original = LatentModel.loss

    def poisoned(self, x, u, weights=None, poses=None, window=None):
        terms = original(self, x, u, weights, poses, window)
        calls["n"] += self.training  # validation runs in eval mode
        if calls["n"] > 3 and self.training:  # 1 batch per epoch: epoch 4 goes bad
            terms["pred_x"] = terms["pred_x"] * float("nan")
            terms["total"] = terms["total"] + terms["pred_x"]
        return terms

    monkeypatch.setattr(LatentModel, "loss", poisoned)
    cfg = config(data, tmp_path / "run", epochs=10, batch_size=500, checkpoint_every=2)
    progress = Recorder()
    with pytest.raises(TrainingDiverged, match=r"epoch 4: loss term pred_x \(nan\).*epoch 2\)"):
        train(cfg, progress)
    assert progress.calls[-1] == ("close",)
    monkeypatch.undo()
    model = load_run(cfg.out, checkpoint=True).model
    assert all(torch.isfinite(p).all() for p in model.parameters())
    assert torch.load(cfg.out / "checkpoint.pt", weights_only=True)["epoch"] == 2


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"epochs": 0}, "--epochs 0"),
        ({"batch_size": 0}, "--batch-size 0"),
        ({"window": 0}, "--window 0"),
        ({"lr": math.nan}, "--lr"),
        ({"weight_decay": math.inf}, "--weight-decay"),
        ({"lr": -1.0}, "--lr"),
        ({"prune_every": -1}, "--prune-every"),
        ({"resume": True, "overwrite": True}, "contradict"),
        ({"eval_every": 0}, "--eval-every 0"),
        ({"device": "tpu"}, "--device 'tpu' is unknown"),
    ],
)
def test_bad_settings(tmp_path: Path, kwargs: dict, message: str) -> None:
    with pytest.raises(UserError, match=message):
        TrainConfig(out=tmp_path, **kwargs)


def test_bad_inputs(data: Path, tmp_path: Path) -> None:
    with pytest.raises(UserError, match="--window 4 is longer"):
        train(config(data, tmp_path / "a", window=4))
    with pytest.raises(UserError, match="does not exist"):
        train(config(tmp_path / "missing.h5", tmp_path / "b"))
    with pytest.raises(UserError, match="channels is 3 but"):
        train(config(data, tmp_path / "c", autoencoder={"channels": 3}))
    (tmp_path / "file").write_text("x")
    with pytest.raises(UserError, match="is a file"):
        train(config(data, tmp_path / "file"))


def test_no_validation_split(data: Path, tmp_path: Path) -> None:
    d = read_sequences(data)
    d.split_ids = np.zeros_like(d.split_ids)
    path = tmp_path / "all_train.h5"
    write_sequences(path, d)
    progress = Recorder()
    run = train(config(path, tmp_path / "run", epochs=2), progress)
    assert any(c[0] == "note" and "no validation" in c[1] for c in progress.calls)
    assert all(r["val/objective"] is None for r in read_metrics(run))


def test_load_run_errors(data: Path, tmp_path: Path) -> None:
    with pytest.raises(UserError, match="does not exist"):
        load_run(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(UserError, match="not a run folder"):
        load_run(tmp_path / "empty")
    run = train(config(data, tmp_path / "run", epochs=1))
    (run / "model.pt").write_bytes(b"not a torch file")
    with pytest.raises(UserError, match=r"model\.pt is damaged"):
        load_run(run)
    (run / "config.json").write_text("{")
    with pytest.raises(UserError, match=r"config\.json is damaged"):
        load_run(run)


def test_batch_parallel_gradients_equal_one_thread_and_repeat_exactly() -> None:
    """--parallel batch: the slices' loss terms and gradients, weighted by their share and
    added, are those of the whole batch (to float rounding), the pose head's unused
    parameters stay without a gradient, and the same batch gives the same bits again."""
    from latent_sindy.training.fit_loop import Gradients as _Gradients
    from latent_sindy.training.fit_loop import Sequences

    torch.manual_seed(0)
    cfg = ModelConfig(observation=AutoencoderConfig(**TINY_AE), dynamics=DYNAMICS_KINDS["sindy"](),
                      pose_head="linear").resolve(1, 32, 3)
    model = LatentModel(cfg)
    g = torch.Generator().manual_seed(1)
    x, u = torch.randn(7, 4, 1, 32, 32, generator=g), torch.rand(7, 3, 3, generator=g)
    weights = LossWeights()

    def run(parts: int) -> tuple[dict, list]:
        grads = _Gradients(model, parts)
        try:
            terms = grads(Sequences(x, u), weights, 1)
        finally:
            grads.close()
        return terms, [None if p.grad is None else p.grad.clone() for p in model.parameters()]

    threads = torch.get_num_threads()
    one, split, again = run(1), run(3), run(3)
    assert torch.get_num_threads() == threads  # restored
    for k in one[0]:
        assert torch.allclose(one[0][k], split[0][k], rtol=1e-5, atol=1e-7), k
        assert torch.equal(split[0][k], again[0][k]), k
    named = [n for n, _ in model.named_parameters()]
    for name, a, b, c in zip(named, one[1], split[1], again[1], strict=True):
        if name.startswith("pose_head"):  # λ4 = 0: not in the total
            assert a is None and b is None, name
            continue
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-6), name
        assert torch.equal(b, c), name


def test_parallel_settings_resolve_by_device_and_threads(tmp_path: Path) -> None:
    from latent_sindy.training.config import resolve_parallel

    cfg = TrainConfig(data=tmp_path / "d.h5", out=tmp_path / "r")
    assert resolve_parallel(cfg, "cpu", 2) == "batch"
    assert resolve_parallel(cfg, "cpu", 1) == "ops"
    assert resolve_parallel(cfg, "cuda", 4) == "ops"
    assert resolve_parallel(dataclasses.replace(cfg, parallel="ops"), "cpu", 2) == "ops"
    with pytest.raises(UserError, match="--parallel 'threads' is unknown"):
        TrainConfig(parallel="threads")  # type: ignore[arg-type]


def test_a_batch_parallel_run_on_two_threads_is_reproducible(data: Path,
                                                             tmp_path: Path) -> None:
    """Two threads, batches split in two: the same seed gives the same model bit for bit,
    within float rounding of the one-thread-per-batch ("ops") run's."""
    torch.set_num_threads(2)
    try:
        runs = {}
        for name, parallel in (("a", "batch"), ("b", "batch"), ("ops", "ops")):
            out = train(config(data, tmp_path / name, parallel=parallel, batch_size=6,
                               batching="trajectories"))
            runs[name] = RunDir(out).load().model
            assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(1)
    states_equal(runs["a"], runs["b"])
    for k, v in runs["a"].state_dict().items():
        assert torch.allclose(v, runs["ops"].state_dict()[k], rtol=1e-3, atol=1e-5), k
    assert json.loads((tmp_path / "a" / "config.json").read_text())["train"]["parallel"] == \
        "batch"


def test_a_divergence_crosses_process_boundaries_whole() -> None:
    """The study's workers send a TrainingDiverged back to the parent: it must unpickle with
    its epoch, what diverged and the message (and stay a UserError, a ValueError)."""
    import pickle

    e = pickle.loads(pickle.dumps(TrainingDiverged(4, "loss term pred_x (nan)", "the text")))
    assert (e.epoch, e.what, str(e)) == (4, "loss term pred_x (nan)", "the text")
    assert isinstance(e, UserError) and isinstance(e, ValueError)
