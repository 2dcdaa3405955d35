"""Copy a trained model into the package as shipped weights (variables only, no optimiser state).

Command:  .venv/bin/python experiments/ship_weights.py RUN_DIR NAME [--chain SETTINGS.json]
          e.g. runs/kitti2015_downsize kitti2015_downsize_relaxed
--chain: the learned-chain settings for this model (StereoConfig overrides of
preset("learned"), e.g. the "changes" that experiments/search_chain.py found), stored in
NAME.json under "chain"; ``--method best`` and ``models.learned_config`` apply them.
Writes stereojax/models/weights/NAME.msgpack (params + batch_stats + the training config) and
stereojax/models/weights/NAME.json (config and training summary). Takes a second.
"""

import json
import sys
from pathlib import Path


from stereojax.models import checkpoint  # noqa: E402
from stereojax.data.io import write_json  # noqa: E402
from stereojax.models.registry import WEIGHTS_DIR, load_model  # noqa: E402


def main():
    run, name = Path(sys.argv[1]), sys.argv[2]
    chain = json.loads(Path(sys.argv[sys.argv.index("--chain") + 1]).read_text()) if "--chain" in sys.argv else {}
    model = load_model(run / "checkpoint.msgpack")
    config = checkpoint.read_config(run / "checkpoint.msgpack")
    out = WEIGHTS_DIR / f"{name}.msgpack"
    checkpoint.save(out, dict(model.variables), config)
    summary = json.loads((run / "train_summary.json").read_text())
    card = {"config": config, "training": summary}
    if chain:
        card["chain"] = chain
    write_json(WEIGHTS_DIR / f"{name}.json", card)
    print(f"-> {out} ({out.stat().st_size / 2**20:.1f} MiB)")


if __name__ == "__main__":
    main()
