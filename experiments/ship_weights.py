"""Copy a trained model into the package as shipped weights (variables only, no optimiser state).

Command:  .venv/bin/python experiments/ship_weights.py RUN_DIR NAME
          e.g. runs/kitti2015_downsize kitti2015_downsize_relaxed
Writes stereojax/weights/NAME.msgpack (params + batch_stats + the training config) and
stereojax/weights/NAME.json (config and training summary). Takes a second.
"""

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from stereojax import checkpoint  # noqa: E402
from stereojax.data.io import write_json  # noqa: E402
from stereojax.train import WEIGHTS_DIR, load_model  # noqa: E402


def main():
    run, name = Path(sys.argv[1]), sys.argv[2]
    model = load_model(run / "checkpoint.msgpack")
    config = checkpoint.read_config(run / "checkpoint.msgpack")
    out = WEIGHTS_DIR / f"{name}.msgpack"
    checkpoint.save(out, dict(model.variables), config)
    summary = json.loads((run / "train_summary.json").read_text())
    write_json(WEIGHTS_DIR / f"{name}.json", {"config": config, "training": summary})
    print(f"-> {out} ({out.stat().st_size / 2**20:.1f} MiB)")


if __name__ == "__main__":
    main()
