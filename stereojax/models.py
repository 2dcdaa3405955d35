"""The shipped-model registry: where the pretrained weights live, which one fits an input,
and loading a checkpoint as a :class:`~stereojax.learned_cost.LearnedModel`.

This is the inference side of the learned cost; it never imports the training module
(``stereojax.train``), so ``predict``, ``evaluate`` and ``demo`` load neither optax nor the
training loop.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from .errors import CheckpointError

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"

#: shipped models: name -> file stem in stereojax/weights (<stem>.msgpack, its card <stem>.json).
#: "kitti2015" and "middlebury" are the paper's network (tower of 64 maps, downsize head
#: 512-384-256-128); "kitti2015_compact" is the compressed network distilled from "kitti2015"
#: (experiments/results/compressed.md).
SHIPPED = {"kitti2015": "kitti2015_downsize_relaxed", "middlebury": "middlebury_downsize_relaxed",
           "kitti2015_compact": "kitti2015_compact"}

#: the shipped model that ``--method best`` runs for each kind of input, chosen by the rules of
#: experiments/PROTOCOL.md ("A compressed network")
BEST = {"kitti": "kitti2015", "middlebury": "middlebury"}


def shipped_weights(name: str = "kitti2015") -> Path:
    """Path of the pretrained weights shipped in the package under ``name`` (see SHIPPED)."""
    if name not in SHIPPED:
        raise CheckpointError(f"no shipped model named {name!r}; shipped: {', '.join(SHIPPED)}")
    path = WEIGHTS_DIR / f"{SHIPPED[name]}.msgpack"
    if not path.is_file():
        have = sorted(p.name for p in WEIGHTS_DIR.glob("*.msgpack")) if WEIGHTS_DIR.is_dir() else []
        raise CheckpointError(f"no shipped weights for {name} ({path.name}); shipped: {have or 'none'}")
    return path


def weights_path(weights) -> Path:
    """The file of ``weights``: a shipped model's name (see SHIPPED) or a path."""
    return shipped_weights(weights) if weights in SHIPPED else Path(weights)


def shipped_name(path) -> str | None:
    """The shipped name of a weights file (None for any other file)."""
    stem = Path(path).resolve()
    for name, s in SHIPPED.items():
        if stem == (WEIGHTS_DIR / f"{s}.msgpack").resolve():
            return name
    return None


def weights_for_input(width: int, height: int, dataset: str | None = None) -> Path | None:
    """The shipped model ``--method best`` runs for an input (:data:`BEST`): by data set when
    ``dataset`` is given (KITTI 2012 and 2015 -> the KITTI choice), else by shape: KITTI-like
    wide road frames (width >= 2.5 x height, KITTI is 3.3) -> the KITTI choice, other pairs ->
    the Middlebury model. None when that model is not shipped."""
    if dataset is not None:
        kind = "kitti" if dataset.startswith("kitti") else "middlebury"
    else:
        kind = "kitti" if width >= 2.5 * height else "middlebury"
    path = WEIGHTS_DIR / f"{SHIPPED[BEST[kind]]}.msgpack"
    return path if path.is_file() else None


def chain_settings(weights) -> dict:
    """The learned-chain settings that go with a model: the ``"chain"`` entry of the JSON card
    next to its weights (``NAME.json`` beside ``NAME.msgpack``), as StereoConfig overrides of
    ``preset("learned")`` (e.g. ``{"sgm": {"p1": 0.7}}``); {} when there is none."""
    import json

    card = Path(weights).with_suffix(".json")
    if not card.is_file():
        return {}
    try:
        return dict(json.loads(card.read_text()).get("chain") or {})
    except (OSError, ValueError, AttributeError):
        return {}


def learned_config(weights=None, max_disp: int = 228):
    """``preset("learned", max_disp)`` with the chain settings stored with ``weights`` (a path,
    or a shipped name such as "kitti2015" / "kitti2015_compact"; None: the preset alone). This is the
    configuration ``--method best`` runs for that model."""
    from .config import StereoConfig, preset

    base = preset("learned", max_disp)
    if weights is None:
        return base
    over = chain_settings(weights_path(weights))
    if not over:
        return base
    merged = base.to_dict()
    for section, values in over.items():
        merged[section] = {**merged[section], **values} if isinstance(values, dict) else values
    return StereoConfig.from_dict(merged)


def load_model(path, expect_net=None):
    """:class:`LearnedModel` (architecture + variables) from a checkpoint file (training
    checkpoint or shipped weights). ``expect_net``: a NetConfig the checkpoint must match."""
    import jax

    from . import checkpoint
    from .config import _from_dict
    from .learned_cost import LearnedModel
    from .nets import NetConfig, init_params

    stored = checkpoint.read_config(path)
    net = _from_dict(NetConfig, stored["net"]).validate()
    if expect_net is not None and net != expect_net:
        raise CheckpointError(f"checkpoint {path} is for network {dataclasses.asdict(net)}, "
                              f"expected {dataclasses.asdict(expect_net)}")
    variables = init_params(net, jax.random.PRNGKey(0))
    # restores only these two entries (a training checkpoint also holds opt_state and step)
    template = {"params": variables["params"], "batch_stats": variables["batch_stats"]}
    state, _ = checkpoint.load(path, template)
    return LearnedModel(net, state)
