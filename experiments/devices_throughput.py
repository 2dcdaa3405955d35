"""Training throughput of the data-parallel step on 1 and N devices (patches/s, warm).

Command:  XLA_FLAGS=--xla_force_host_platform_device_count=2 .venv/bin/python experiments/devices_throughput.py
          [--augment]   (with the MC-CNN patch augmentation of ``train --augment``)
Running time here: about a minute. Uses the ``cpu`` preset's network and batch (150 references
+ 150 positives + 150 negatives per step) on KITTI 2015 000001 (or a synthetic pair without
../shared/data); prints one line per device count. On forced host devices of a 2-core CPU the
numbers show that the sharded step runs, not a speed-up (the devices share the same cores).
"""

import sys
import time
from pathlib import Path


import jax  # noqa: E402
from jax.sharding import NamedSharding, PartitionSpec  # noqa: E402

from stereojax.data.datasets import DEFAULT_DATA
from stereojax.learning.sampling import build_patch_data  # noqa: E402
from stereojax.learning.train import init_state, make_mesh, train_preset, train_step  # noqa: E402


def main(steps: int = 30, augment: bool = False, data: str = DEFAULT_DATA):
    root = Path(data) / "kitti2015" / "training"
    if not root.is_dir():
        sys.exit(f"KITTI 2015 not found under {data} (give the shared data root with --data)")
    from stereojax.data import load_kitti2015
    samples = [load_kitti2015(root, "000001")]
    cfg = train_preset("cpu")
    if augment:
        from stereojax.learning.train import with_augmentation

        cfg = with_augmentation(cfg)
    data = build_patch_data(samples, cfg.net.patch_size, cfg.sampler)
    for n in range(1, len(jax.devices()) + 1):
        mesh = make_mesh(n)
        state = init_state(cfg)
        d = data
        if mesh is not None:
            every = NamedSharding(mesh, PartitionSpec())
            state, d = jax.device_put(state, every), jax.device_put(data, every)
        state, _ = train_step(state, d, cfg, mesh)                    # compile
        jax.block_until_ready(state)
        t0 = time.perf_counter()
        for _ in range(steps):
            state, m = train_step(state, d, cfg, mesh)
        jax.block_until_ready(state)
        secs = time.perf_counter() - t0
        print(f"{n} device(s) ({jax.default_backend()}{', augmented' if augment else ''}): "
              f"{steps * 3 * cfg.batch / secs:.0f} patches/s "
              f"({steps / secs:.1f} steps/s)", flush=True)


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--augment", action="store_true")
    ap.add_argument("--data", default=DEFAULT_DATA, help=f"shared data root (default {DEFAULT_DATA})")
    args = ap.parse_args()
    main(augment=args.augment, data=args.data)
