"""Run by tests/test_devices.py in a subprocess with XLA_FLAGS=--xla_force_host_platform_device_count=2
(the flag must be set before jax starts): trains the tiny model on 1 and on 2 forced host
devices, and with a resume on 2, and prints the comparisons as one JSON line."""

import dataclasses
import json
import sys
from pathlib import Path

import jax
import numpy as np


def leaves(path):
    from stereojax.models import checkpoint
    from stereojax.learning.train import TrainConfig, init_state

    cfg = TrainConfig.from_dict(checkpoint.read_config(path))
    state, _ = checkpoint.load(path, init_state(cfg))
    return [np.asarray(x) for x in jax.tree_util.tree_leaves(state)]


def main(out: Path) -> None:
    from stereojax.errors import ConfigError
    from stereojax.learning.train import fit, train_preset
    from tests.helpers import tiny_sampler as stereojax_sampler, training_samples as _samples

    cfg = train_preset("tiny", sampler=stereojax_sampler(), steps=6, checkpoint_every=2, val_every=6)
    samples, val = _samples(), _samples(1)
    one = fit(cfg, samples, val, out / "n1", progress=False, devices=1)
    two = fit(cfg, samples, val, out / "n2", progress=False, devices=2)
    fit(cfg, samples, val, out / "r2", progress=False, devices=2, stop_after=4)      # killed at 4 ...
    fit(cfg, samples, val, out / "r2", progress=False, devices=2, resume=True)       # ... resumed
    a, b, r = (leaves(out / n / "checkpoint.msgpack") for n in ("n1", "n2", "r2"))
    try:
        fit(dataclasses.replace(cfg, batch=15), samples, val, out / "odd", devices=2)
        odd = "accepted"
    except ConfigError as exc:
        odd = str(exc)
    print(json.dumps({
        "devices": len(jax.devices()),
        "summary_devices": [one["devices"], two["devices"]],
        "max_diff_n1_n2": max(float(np.abs(x - y).max()) for x, y in zip(a, b)),
        "max_param": max(float(np.abs(x).max()) for x in a),
        "resume_exact": all(np.array_equal(x, y) for x, y in zip(b, r)),
        "val_n1_n2": [one["validation"]["loss"], two["validation"]["loss"]],
        "odd_batch": odd,
        "samples_per_s": [one["samples_per_s"], two["samples_per_s"]],
    }))




def multihost(out: Path) -> None:
    """One process of a two-process run (JAX_COORDINATOR_ADDRESS, JAX_NUM_PROCESSES and
    JAX_PROCESS_ID set by the test): data-parallel over both processes' devices."""
    from stereojax.learning.train import fit, maybe_initialize_distributed, train_preset
    from tests.helpers import tiny_sampler as stereojax_sampler, training_samples as _samples

    assert maybe_initialize_distributed()
    cfg = train_preset("tiny", sampler=stereojax_sampler(), steps=4, checkpoint_every=2, val_every=4)
    s = fit(cfg, _samples(), _samples(1), out, progress=False, devices=None)
    print(json.dumps({"process": jax.process_index(), "devices": s["devices"], "val": s["validation"]["loss"]}))


if __name__ == "__main__":
    if sys.argv[1] == "multihost":
        multihost(Path(sys.argv[2]))
    else:
        main(Path(sys.argv[1]))
