"""Training of the matching network on patch pairs (no pmap: one device, or data-parallel over a
mesh with sharded ``jax.jit``; see :func:`train_step`).

``train_step`` and ``eval_step`` are the jit boundaries. The batch of step t is drawn with
``fold_in(PRNGKey(seed), t)``, so a run resumed from a checkpoint at step t sees exactly the
batches an uninterrupted run would, and ends with the same parameters. ``fit`` adds a
progress bar (loss, accuracy, samples/s), TensorBoardX logs, atomic checkpoints every N
steps and at the end (with the resolved config), and stops on a NaN loss keeping the last
good checkpoint.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from tensorboardX import SummaryWriter
from tqdm import tqdm

from stereojax.chain import learned_cost
from stereojax.config import dataclass_from_dict
from stereojax.data.datasets import load_dataset, parse_frames
from stereojax.data.images import as_grey
from stereojax.data.io import colorize_disparity, write_json
from stereojax.devices import count
from stereojax.errors import ConfigError, TrainingError
from stereojax.interrupt import Interrupted, stop_on_signals
from stereojax.learning import losses
from stereojax.learning.dense_distill import dense_loss
from stereojax.learning.sampling import (AUGMENT_MCCNN, PatchData, SamplerConfig, build_patch_data,
                                         sample_batch, sample_distill_batch)
from stereojax.models import checkpoint
from stereojax.models.nets import MatchNet, NetConfig, init_params, net_preset, similarity
from stereojax.models.registry import load_model, weights_path

LOSSES = ("bce", "relaxed", "hinge")


@dataclass(frozen=True)
class TrainConfig:
    """Everything that determines a training run (hashable; stored in every checkpoint).

    loss: "bce", "relaxed" (paper Eq. 3.6 with margin ``delta``) or "hinge" (cosine head).
    batch: reference patches per step; each has one positive and one negative pair.
    lr, momentum: SGD; the learning rate is multiplied by ``decay`` after ``decay_from`` of
      the steps ("decay in the late epochs").
    distill: weight of the distillation term (0 = off): the cross-entropy between the network's
      similarity and a teacher network's, on the positive, the negative and a fourth right
      patch at a near-miss offset U[-distill_range, distill_range] px from the true match
      (:func:`stereojax.learning.sampling.sample_distill_batch`), added to the loss on the labels. The
      teacher is given to :func:`fit`; dense heads only, without augmentation.
    dense: weight of dense distillation (0 = off): the cross-entropy to a teacher's similarities
      at every disparity of the band of ``dense_batch`` cached target pixels per step
      (:mod:`stereojax.learning.dense_distill`; the targets are given to :func:`fit`).
    """

    net: NetConfig = field(default_factory=NetConfig)
    sampler: SamplerConfig = field(default_factory=SamplerConfig)
    loss: str = "relaxed"
    delta: float = 0.05
    hinge_margin: float = 0.2
    batch: int = 150
    lr: float = 0.02
    momentum: float = 0.9
    steps: int = 6000
    decay_from: float = 0.75
    decay: float = 0.1
    seed: int = 0
    checkpoint_every: int = 500
    log_every: int = 25
    val_every: int = 1000
    val_pairs: int = 3000
    distill: float = 0.0
    distill_range: float = 6.0
    dense: float = 0.0
    dense_batch: int = 64

    def validate(self) -> "TrainConfig":
        self.net.validate()
        self.sampler.validate()
        if self.loss not in LOSSES:
            raise ConfigError(f"loss must be one of {LOSSES}, got {self.loss!r}")
        if (self.loss == "hinge") != (self.net.head == "cosine"):
            raise ConfigError(f"loss {self.loss!r} does not fit head {self.net.head!r}: "
                              "the cosine head trains with 'hinge', dense heads with 'bce'/'relaxed'")
        if not 0 <= self.delta < 1 / 3:
            raise ConfigError(f"delta must be in [0, 1/3), got {self.delta}")
        for name in ("batch", "steps", "checkpoint_every", "log_every", "val_every", "val_pairs"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.distill < 0 or not 0 < self.distill_range <= self.sampler.z_high:
            raise ConfigError(f"need distill >= 0 and 0 < distill_range <= sampler.z_high, got "
                              f"{self.distill}, {self.distill_range}")
        if self.distill and (self.net.head == "cosine" or self.sampler.augment.enabled):
            raise ConfigError("distillation trains a dense head without patch augmentation")
        if self.dense < 0 or self.dense_batch < 1 or (self.dense and self.net.head == "cosine"):
            raise ConfigError(f"need dense >= 0, dense_batch >= 1 and a dense head for dense distillation, got "
                              f"{self.dense}, {self.dense_batch}, head {self.net.head!r}")
        if self.lr <= 0 or not 0 <= self.momentum < 1 or not 0 < self.decay <= 1 or not 0 <= self.decay_from <= 1:
            raise ConfigError("need lr > 0, 0 <= momentum < 1, 0 < decay <= 1, 0 <= decay_from <= 1")
        return self

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data) -> "TrainConfig":
        return dataclass_from_dict(cls, data).validate()

    @classmethod
    def from_file(cls, path) -> "TrainConfig":
        """The training config of a JSON file (``stereojax train --config FILE``)."""
        try:
            return cls.from_dict(json.loads(Path(path).read_text()))
        except (OSError, json.JSONDecodeError) as exc:
            raise ConfigError(f"cannot read training config {path}: {exc}") from None

    @classmethod
    def from_stored(cls, stored: dict) -> "TrainConfig":
        """The training config of a checkpoint's or shipped model's stored config
        (``checkpoint.read_config``), which also carries the run's facts that are not settings
        (the CLI's "data" frames, the "init" weights of a fine-tune)."""
        return cls.from_dict({k: v for k, v in stored.items() if k in cls.__dataclass_fields__})


def train_preset(name: str, head: str = "downsize", loss: str | None = None, **overrides) -> TrainConfig:
    """``cpu``: trains in under an hour on 2 cores; ``paper``: the paper's schedule (18 epochs
    of the full KITTI 2015 training GT, 112 feature maps), for a long run or a GPU;
    ``tiny``: seconds, for tests."""

    loss = loss or ("hinge" if head == "cosine" else "relaxed")
    base = {
        # v_pos = 1 (MC-CNN's positive jitter) instead of the paper's 4: with 4 px positives the
        # network learns to accept 4 px-off matches, which the disparity search then cannot resolve
        "cpu": dict(net=net_preset(head, 64), sampler=SamplerConfig(v_pos=1.0), steps=50000,
                    checkpoint_every=1000, val_every=5000),
        "paper": dict(net=net_preset(head, 112), steps=18 * 2_000_000 // 150, checkpoint_every=2000,
                      val_every=5000),
        "tiny": dict(net=dataclasses.replace(net_preset(head, 8), widths=tuple(
            8 for _ in net_preset(head, 8).widths)), steps=12, batch=16, checkpoint_every=4,
            log_every=2, val_every=6, val_pairs=64),
    }
    if name not in base:
        raise ConfigError(f"unknown training preset {name!r}; choose one of {sorted(base)}")
    return TrainConfig(loss=loss, **{**base[name], **overrides}).validate()


def with_augmentation(cfg: TrainConfig, augment=None) -> TrainConfig:
    """``cfg`` with patch augmentation (default: ``sampling.AUGMENT_MCCNN``, what
    ``stereojax train --augment`` uses)."""

    aug = AUGMENT_MCCNN if augment is None else augment
    return dataclasses.replace(cfg, sampler=dataclasses.replace(cfg.sampler, augment=aug)).validate()


# ---- the jitted steps ------------------------------------------------------------------------

def _optimizer(cfg: TrainConfig):
    boundary = int(cfg.steps * cfg.decay_from)
    schedule = optax.piecewise_constant_schedule(cfg.lr, {boundary: cfg.decay})
    return optax.sgd(schedule, momentum=cfg.momentum), schedule


def init_state(cfg: TrainConfig) -> dict[str, Any]:
    """Fresh training state: params, batch_stats, opt_state, step."""
    variables = init_params(cfg.net, jax.random.PRNGKey(cfg.seed))
    opt, _ = _optimizer(cfg)
    return {"params": variables["params"], "batch_stats": variables["batch_stats"],
            "opt_state": opt.init(variables["params"]), "step": jnp.int32(0)}


def _pair_losses(cfg: TrainConfig, s_pos, s_neg):
    if cfg.loss == "hinge":
        return losses.hinge(s_pos, s_neg, cfg.hinge_margin)
    fn = losses.bce if cfg.loss == "bce" else functools.partial(losses.relaxed, delta=cfg.delta)
    return 0.5 * (fn(s_pos, jnp.ones_like(s_pos)) + fn(s_neg, jnp.zeros_like(s_neg)))


def _scores(model, variables, ref, *rights, train):
    """Scores of ``ref`` against each patch batch of ``rights`` (one tower call for all), and
    the batch-norm updates when ``train``."""
    b = ref.shape[0]
    patches = jnp.concatenate([ref, *rights])
    if train:
        feats, updates = model.apply(variables, patches, True, method=MatchNet.features,
                                     mutable=["batch_stats"])
    else:
        feats, updates = model.apply(variables, patches, False, method=MatchNet.features), None
    f = feats[:, 0, 0]
    scores = [model.apply(variables, f[:b], f[(i + 1) * b:(i + 2) * b], method=MatchNet.compare)
              for i in range(len(rights))]
    return (*scores, updates)


def _errors(cfg, s_pos, s_neg):
    """Share of misclassified pairs: similarity of a positive <= 0.5 or of a negative >= 0.5."""
    return 0.5 * ((similarity(cfg.net, s_pos) <= 0.5).mean() + (similarity(cfg.net, s_neg) >= 0.5).mean())


def make_mesh(devices: int | None = None):
    """A one-axis ``("data",)`` mesh of the first ``devices`` devices (None: every device of
    every process), or None for a single device (the plain, unsharded step)."""


    have = jax.devices()
    n = count(devices, have)
    if n == 1:
        return None
    return Mesh(np.array(have[:n]), ("data",))


def _check_batch(cfg: TrainConfig, mesh) -> None:
    n = 1 if mesh is None else mesh.size
    if cfg.batch % n:
        raise ConfigError(f"batch {cfg.batch} does not divide evenly over {n} devices; use a batch "
                          f"that is a multiple of {n} or another --devices")


@functools.partial(jax.jit, static_argnames=("cfg", "mesh", "teacher_net"))
def train_step(state, data: PatchData, cfg: TrainConfig, mesh=None, teacher=None, teacher_net=None, dense=None):
    """One SGD step on the batch of ``state["step"]``; returns (new state, metrics).

    mesh: None (one device) or a ``("data",)`` mesh (:func:`make_mesh`): the global batch is
    drawn exactly as on one device and split along the mesh, parameters and optimiser state
    are replicated, and XLA reduces the gradients and the batch-norm statistics over the
    whole batch, so N devices compute the step of one device (up to float rounding).

    teacher, teacher_net: the variables and (static) NetConfig of the teacher network when
    ``cfg.distill > 0``: its similarities on the batch's pairs are the soft targets.
    dense: :class:`~stereojax.learning.dense_distill.DenseTargets` when ``cfg.dense > 0``.
    """
    model = MatchNet(cfg.net)
    key = jax.random.fold_in(jax.random.PRNGKey(cfg.seed), state["step"])
    distill = cfg.distill > 0
    if distill:
        if teacher is None or teacher_net is None:
            raise ConfigError("distill > 0 needs a teacher network")
        patches = sample_distill_batch(key, data, cfg.batch, cfg.net.patch_size, cfg.sampler,
                                       cfg.distill_range)
    else:
        patches = sample_batch(key, data, cfg.batch, cfg.net.patch_size, cfg.sampler)
    if mesh is not None:
        split = NamedSharding(mesh, PartitionSpec("data"))
        patches = tuple(jax.lax.with_sharding_constraint(x, split) for x in patches)
    targets = None
    if distill:   # the teacher's similarities, constants of the step
        t = _scores(MatchNet(teacher_net), teacher, *patches, train=False)[:-1]
        targets = [jax.lax.stop_gradient(jax.nn.sigmoid(x)) for x in t]

    def loss_fn(params):
        variables = {"params": params, "batch_stats": state["batch_stats"]}
        *scores, updates = _scores(model, variables, *patches, train=True)
        s_pos, s_neg = scores[0], scores[1]
        loss = _pair_losses(cfg, s_pos, s_neg).mean()
        if distill:
            loss = loss + cfg.distill * jnp.mean(jnp.stack(
                [losses.bce(s, t).mean() for s, t in zip(scores, targets)]))
        if cfg.dense > 0:
            loss = loss + cfg.dense * dense_loss(model, variables, dense, jax.random.fold_in(key, 11),
                                                 cfg.dense_batch, cfg.net.patch_size)
        return loss, (updates, s_pos, s_neg)

    (loss, (updates, s_pos, s_neg)), grads = jax.value_and_grad(loss_fn, has_aux=True)(state["params"])
    opt, schedule = _optimizer(cfg)
    upd, opt_state = opt.update(grads, state["opt_state"], state["params"])
    new = {"params": optax.apply_updates(state["params"], upd), "batch_stats": updates["batch_stats"],
           "opt_state": opt_state, "step": state["step"] + 1}
    metrics = {"loss": loss, "error": _errors(cfg, s_pos, s_neg), "grad_norm": optax.tree.norm(grads),
               "lr": schedule(state["step"])}
    return new, metrics


@functools.partial(jax.jit, static_argnames=("cfg", "pairs"))
def eval_step(state, data: PatchData, cfg: TrainConfig, pairs: int):
    """Patch-level validation: (mean loss, share of misclassified pairs) on a fixed sample."""
    model = MatchNet(cfg.net)
    key = jax.random.PRNGKey(cfg.seed + 7919)
    ref, pos, neg = sample_batch(key, data, pairs, cfg.net.patch_size, cfg.sampler, augment=False)
    variables = {"params": state["params"], "batch_stats": state["batch_stats"]}
    s_pos, s_neg, _ = _scores(model, variables, ref, pos, neg, train=False)
    return _pair_losses(cfg, s_pos, s_neg).mean(), _errors(cfg, s_pos, s_neg)


# ---- the loop --------------------------------------------------------------------------------

def _state_config(cfg: TrainConfig, extra: dict | None = None) -> dict[str, Any]:
    return {**cfg.to_dict(), **(extra or {})}


def _flat(d: dict, prefix: str = "") -> dict:
    """{"net": {"head": "x"}} -> {"net.head": "x"}"""
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _start_state(cfg: TrainConfig, ckpt: Path, resume: bool, init) -> dict:
    """The state training starts from: fresh (from ``init``'s weights when given), or the
    checkpoint's when resuming, which must have been made with the same config (fields of
    :data:`_FREE_ON_RESUME` may differ)."""
    state = init_state(cfg)
    if init is not None and not (resume and ckpt.exists()):
        if init.net != cfg.net:
            raise ConfigError(f"--init model has network {dataclasses.asdict(init.net)}, the training "
                              f"config {dataclasses.asdict(cfg.net)}")
        state = {**state, "params": init.variables["params"], "batch_stats": init.variables["batch_stats"]}
    if resume and ckpt.exists():
        stored = checkpoint.read_config(ckpt)
        wanted = json.loads(json.dumps(cfg.to_dict()))          # tuples -> lists, as stored
        # a checkpoint from before a config field existed has that field's default
        there = {**_flat(json.loads(json.dumps(TrainConfig().to_dict()))), **_flat(stored)}
        here = _flat(wanted)
        # how often to write and log does not change what is learned: it may differ on resume
        differ = sorted(k for k in here if there.get(k) != here[k] and k not in _FREE_ON_RESUME)
        if differ:
            shown = ", ".join(f"{k} = {there.get(k)!r} there, {here[k]!r} here" for k in differ[:3])
            raise ConfigError(f"cannot resume {ckpt}: it was made with another training config ({shown}"
                              f"{', ...' if len(differ) > 3 else ''}); use another --out or the same settings")
        state, _ = checkpoint.load(ckpt, state, expect_net=wanted["net"])
    return state


def _check_fit_inputs(cfg: TrainConfig, teacher, dense) -> None:
    """The config is valid, and a teacher / dense targets are given exactly when it distils."""
    cfg.validate()
    if (cfg.distill > 0) != (teacher is not None):
        raise ConfigError("a teacher network is needed exactly when distill > 0 "
                          f"(distill {cfg.distill}, teacher {'given' if teacher else 'none'})")
    if (cfg.dense > 0) != (dense is not None):
        raise ConfigError("dense distillation targets are needed exactly when dense > 0 "
                          f"(dense {cfg.dense}, targets {'given' if dense is not None else 'none'})")


def _teacher_args(teacher, dense, mesh) -> dict:
    """The distillation inputs of :func:`_steps`: the teacher's variables (on every device of
    ``mesh``) and network, and the dense targets."""
    args = {}
    if teacher is not None:
        variables = teacher.variables
        if mesh is not None:
            variables = jax.device_put(variables, NamedSharding(mesh, PartitionSpec()))
        args = {"teacher": variables, "teacher_net": teacher.net}
    if dense is not None:
        args["dense"] = dense
    return args


def _keep_on_stop(stop: Interrupted, state, cfg: TrainConfig, info, ckpt: Path, start: int,
                  last_good: int, main_process: bool) -> None:
    """A signal stopped training: checkpoint the last completed step (if not yet written) and
    tell ``stop`` what was kept and how to continue."""
    done = int(state["step"])
    if main_process and done > last_good:
        checkpoint.save(ckpt, state, _state_config(cfg, info))
    kept = (f"the checkpoint of step {done} is kept in {ckpt}" if done > start or ckpt.exists()
            else "no step was completed, nothing kept")
    stop.summary = {"steps": done, "of": cfg.steps, "checkpoint": str(ckpt) if ckpt.exists() else None}
    stop.note = f"stopped at step {done} of {cfg.steps}; {kept}; run the same command with --resume to continue"


def fit(cfg: TrainConfig, train_samples: Sequence, val_samples: Sequence | None, out_dir,
        resume: bool = False, progress: bool = True, stop_after: int | None = None,
        info: dict | None = None, devices: int | None = 1, init=None, teacher=None, dense=None) -> dict[str, Any]:
    """Train, checkpointing to ``out_dir/checkpoint.msgpack``; returns a summary dict.

    init: a :class:`~stereojax.matching_cost.learned.LearnedModel` (same network) to start from instead
    of random weights (fine-tuning; the optimiser and the schedule start afresh). A resumed run
    continues from its checkpoint and ignores ``init``.

    resume: continue from the checkpoint in ``out_dir`` (it must have been made with the same
    config). stop_after: return after this many steps of this call (for tests). devices: data
    parallelism over this many devices (None: all; see :func:`train_step`); only process 0
    of a multi-process run writes checkpoints, logs and TensorBoard. teacher: the
    :class:`~stereojax.matching_cost.learned.LearnedModel` whose scores ``cfg.distill`` distils.
    dense: the :class:`~stereojax.learning.dense_distill.DenseTargets` that ``cfg.dense`` distils.
    """

    _check_fit_inputs(cfg, teacher, dense)
    mesh = make_mesh(devices)
    _check_batch(cfg, mesh)
    main_process = jax.process_index() == 0
    out = Path(out_dir)
    ckpt = out / "checkpoint.msgpack"
    data = build_patch_data(train_samples, cfg.net.patch_size, cfg.sampler)
    val = build_patch_data(val_samples, cfg.net.patch_size, cfg.sampler) if val_samples else None
    state = _start_state(cfg, ckpt, resume, init)
    if mesh is not None:   # parameters, optimiser state and the patch data on every device
        every = NamedSharding(mesh, PartitionSpec())
        state, data = jax.device_put(state, every), jax.device_put(data, every)
    if main_process:
        write_json(out / "config.json", _state_config(cfg, info))
    writer = SummaryWriter(str(out / "tb")) if main_process else _NoWriter()
    start = int(state["step"])
    end = cfg.steps if stop_after is None else min(cfg.steps, start + stop_after)
    bar = tqdm(range(start, end), initial=start, total=cfg.steps, desc="train", unit="step",
               disable=not progress, dynamic_ncols=True)
    history, t0, last_val = [], time.perf_counter(), None
    samples_per_step = (4 if cfg.distill else 3) * cfg.batch + (cfg.dense_batch if cfg.dense else 0)
    teacher_args = _teacher_args(teacher, dense, mesh)
    last_good = start
    latest = {"state": state}        # the last completed step's state, kept if a signal stops the loop
    try:
        with stop_on_signals():
            state, history, last_val, last_good = _steps(
                bar, latest, data, val, val_samples, cfg, mesh, teacher_args, writer, ckpt, info, main_process,
                start, end, t0, samples_per_step, history, last_val, last_good)
    except Interrupted as stop:
        bar.close()
        writer.close()
        _keep_on_stop(stop, latest["state"], cfg, info, ckpt, start, last_good, main_process)
        raise
    writer.close()
    elapsed = time.perf_counter() - t0
    summary = {"steps": int(state["step"]), "seconds": elapsed,
               "samples_per_s": (end - start) * samples_per_step / max(elapsed, 1e-9),
               "final_train": history[-1] if history else None, "validation": last_val,
               "train_pixels": data.size, "val_pixels": val.size if val is not None else 0,
               "devices": 1 if mesh is None else mesh.size}
    if main_process:
        write_json(out / "train_summary.json", summary)
    return summary


def _steps(bar, latest, data, val, val_samples, cfg, mesh, teacher_args, writer, ckpt, info, main_process,
           start, end, t0, samples_per_step, history, last_val, last_good):
    """The steps of :func:`fit`; ``latest["state"]`` always holds the last completed step's state."""
    state = latest["state"]
    for step in bar:
        new_state, m = train_step(state, data, cfg, mesh, **teacher_args)
        loss = float(m["loss"])
        if not math.isfinite(loss):
            writer.close()
            raise TrainingError(f"loss became {loss} at step {step}; stopped, the last good checkpoint "
                                f"(step {last_good}) is kept in {ckpt}")
        state = new_state
        latest["state"] = state
        done = step + 1
        if done % cfg.log_every == 0 or done == end:
            rate = (done - start) * samples_per_step / max(time.perf_counter() - t0, 1e-9)
            for k in ("loss", "error", "grad_norm", "lr"):
                writer.add_scalar(f"train/{k}", float(m[k]), done)
            writer.add_scalar("train/samples_per_s", rate, done)
            bar.set_postfix(loss=f"{loss:.4f}", acc=f"{1 - float(m['error']):.3f}", samples_s=f"{rate:.0f}")
            history.append({"step": done, "loss": loss, "error": float(m["error"])})
        if val is not None and (done % cfg.val_every == 0 or done == cfg.steps):
            vl, ve = eval_step(state, val, cfg, cfg.val_pairs)
            last_val = {"step": done, "loss": float(vl), "error": float(ve)}
            writer.add_scalar("val/loss", float(vl), done)
            writer.add_scalar("val/patch_error", float(ve), done)
            if main_process:
                writer.add_image("val/disparity_wta", _preview(cfg, state, val_samples[0]), done,
                                 dataformats="HWC")
        if done % cfg.checkpoint_every == 0 or done == end:
            if main_process:
                checkpoint.save(ckpt, state, _state_config(cfg, info))
            last_good = done
    return state, history, last_val, last_good


#: TrainConfig fields that a resumed run may change (they do not change what is learned)
_FREE_ON_RESUME = ("checkpoint_every", "log_every")


class _NoWriter:
    """TensorBoard writer of the processes other than 0 of a multi-process run: writes nothing."""

    def add_scalar(self, *a, **k):
        pass

    def add_image(self, *a, **k):
        pass

    def close(self):
        pass


def maybe_initialize_distributed() -> bool:
    """``jax.distributed.initialize`` when the standard variables are set:
    ``JAX_COORDINATOR_ADDRESS`` (host:port of process 0), ``JAX_NUM_PROCESSES`` and
    ``JAX_PROCESS_ID``. Returns whether it did. Called by ``stereojax train``."""

    names = ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID")
    found = [n for n in names if os.environ.get(n)]
    if not found:
        return False
    if len(found) != len(names):
        missing = ", ".join(n for n in names if n not in found)
        raise ConfigError(f"multi-process training needs {', '.join(names)}; {missing} not set")
    try:
        n, pid = int(os.environ["JAX_NUM_PROCESSES"]), int(os.environ["JAX_PROCESS_ID"])
    except ValueError:
        raise ConfigError("JAX_NUM_PROCESSES and JAX_PROCESS_ID must be integers") from None
    # cross-process collectives of the CPU backend (GPUs use NCCL whatever this says)
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator_address=os.environ["JAX_COORDINATOR_ADDRESS"],
                               num_processes=n, process_id=pid)
    return True


def _preview(cfg: TrainConfig, state, sample, rows: int = 64, cols: int = 320, max_disp: int = 64):
    """``u8[h, w, 3]``: winner-takes-all disparity of the raw network cost on a crop of the
    bottom centre of a validation frame (road and cars), for TensorBoard."""

    h, w = sample.left.shape[:2]
    y0, x0 = max(h - rows, 0), max((w - cols) // 2, 0)
    crop = (slice(y0, y0 + rows), slice(x0, x0 + cols))
    gl = jnp.asarray(as_grey(sample.left, "left")[crop])
    gr = jnp.asarray(as_grey(sample.right, "right")[crop])
    variables = {"params": state["params"], "batch_stats": state["batch_stats"]}
    md = min(max_disp, gl.shape[1] - 1)
    vol = learned_cost(cfg.net, variables, gl, gr, md, 16)
    return colorize_disparity(np.asarray(jnp.argmin(vol, -1)).astype(np.float32), md)



def parse_widths(text: str) -> tuple[int, ...]:
    """Hidden widths of a dense head from ``--widths`` ("64,32")."""
    try:
        widths = tuple(int(w) for w in text.split(","))
    except ValueError:
        raise ConfigError(f"--widths must be comma-separated integers such as 64,32, got {text!r}") from None
    if not widths or min(widths) < 1:
        raise ConfigError(f"--widths must be positive integers, got {text!r}")
    return widths


def config_from_options(preset: str = "cpu", head: str = "downsize", loss: str | None = None,
                        features: int | None = None, widths: Sequence[int] | str | None = None,
                        distill_weight: float | None = None, augment: bool = False,
                        **overrides) -> TrainConfig:
    """The TrainConfig of ``stereojax train``'s options: the preset, its network narrowed to
    ``features`` maps and hidden ``widths`` when given, distillation with ``distill_weight``,
    augmentation, and the plain ``overrides`` (steps, seed, delta, lr) that are not None.
    ``widths`` may be the text of ``--widths`` (:func:`parse_widths`)."""

    if isinstance(widths, str):
        widths = parse_widths(widths)
    over = {k: v for k, v in overrides.items() if v is not None}
    if features or widths:
        net = net_preset(head, features or train_preset(preset, head=head).net.features)
        if widths:
            net = dataclasses.replace(net, widths=tuple(widths)).validate()
        over["net"] = net
    if distill_weight is not None:
        over["distill"] = distill_weight
    cfg = train_preset(preset, head=head, loss=loss, **over)
    return with_augmentation(cfg) if augment else cfg


def inherit_card(init, checkpoint) -> Path | None:
    """The chain settings of the model a run starts from (``--init``), written as the card of its
    checkpoint, saying where they come from: a fine-tuned model then runs with its parent's
    searched settings, and the first printed line says they were not searched for it. None when
    ``init`` has no card."""
    from stereojax.models.registry import chain_settings, write_card

    chain = chain_settings(weights_path(init))
    if not chain:
        return None
    Path(checkpoint).parent.mkdir(parents=True, exist_ok=True)
    name = init if isinstance(init, str) and "/" not in init else Path(init).name
    return write_card(checkpoint, chain, chain_from=f"inherited from {name} (searched for it, not for these "
                      "weights; stereojax tune searches them)")


def net_from_init(cfg: "TrainConfig", init, features: int | None, widths, head: str | None) -> "TrainConfig":
    """``train --init MODEL``: the network of MODEL (its tower's maps, its head and widths), unless
    the options name another (a one-line error that names the flags)."""
    net = load_model(weights_path(init)).net
    if isinstance(widths, str):
        widths = parse_widths(widths)
    asked = {"--features": (features, net.features), "--widths": (tuple(widths) if widths else None, net.widths),
             "--head": (head, net.head)}
    wrong = [f"{flag} {','.join(map(str, got)) if isinstance(got, tuple) else got}"
             for flag, (got, has) in asked.items() if got is not None and got != has]
    if wrong:
        raise ConfigError(f"--init {init} has a tower of {net.features} maps and a {net.head} head "
                          f"{','.join(map(str, net.widths))}; {' '.join(wrong)} do not fit it (drop them: --init "
                          "takes the network from the model)")
    return dataclasses.replace(cfg, net=net).validate()


def train_on_dataset(cfg: TrainConfig, data, dataset: str, frames: str, val_frames: str | None, out_dir,
                     resume: bool = False, devices: int | None = None, init: str | None = None,
                     distill: str | None = None) -> dict:
    """:func:`fit` on frames of a dataset (``frames``/``val_frames``: specs such as
    000001-000020 or a comma list of scenes), starting from the weights ``init`` and distilling
    from ``distill`` (checkpoint paths or shipped names) when given. Returns fit's summary."""

    gt = "occ" if dataset == "middlebury" else "noc"

    def load(spec):
        return [ld() for _, ld in load_dataset(data, dataset, parse_frames(spec), gt=gt)]

    train_samples = load(frames)
    val_samples = load(val_frames) if val_frames else None
    info = {"data": {"dataset": dataset, "frames": [s.name for s in train_samples],
                     "val_frames": [s.name for s in val_samples or []]}}
    print(f"training {cfg.net.head} head ({cfg.loss}, delta {cfg.delta}) on {len(train_samples)} "
          f"{dataset} images, {cfg.steps} steps -> {out_dir}", flush=True)
    model = teacher = None
    if init:
        model = load_model(weights_path(init))
        info["init"] = init
        inherit_card(init, Path(out_dir) / "checkpoint.msgpack")
    if cfg.distill:
        if not distill:
            raise ConfigError("the training config distils (distill > 0): name the teacher with --distill")
        teacher = load_model(weights_path(distill))
        info["distill_from"] = distill
    return fit(cfg, train_samples, val_samples, out_dir, resume=resume, info=info, devices=devices,
               init=model, teacher=teacher)
