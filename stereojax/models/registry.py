"""The shipped-model registry: where the pretrained weights live, which one fits an input,
and loading a checkpoint as a :class:`~stereojax.matching_cost.learned.LearnedModel`.

This is the inference side of the learned cost; it never imports the training module
(``stereojax.learning.train``), so ``predict``, ``evaluate`` and ``demo`` load neither optax nor the
training loop.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import threading
from pathlib import Path

import jax

from stereojax.config import StereoConfig, dataclass_from_dict, preset
from stereojax.errors import CheckpointError, ConfigError
from stereojax.models import checkpoint
from stereojax.models.nets import LearnedModel, NetConfig, init_params

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"

#: shipped models: name -> file stem in stereojax/models/weights (<stem>.msgpack, its card <stem>.json).
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


def check_weights_exist(weights) -> None:
    """Refuse a weights argument that is neither a shipped name nor an existing file, listing
    the shipped names (and the closest one to what was typed)."""

    if Path(weights).exists():          # a file, or a folder that the loader refuses by name
        return
    typed = str(weights)
    close = difflib.get_close_matches(Path(typed).stem, list(SHIPPED), n=1)
    hint = f"; did you mean {close[0]}?" if close else ""
    raise CheckpointError(f"weights {typed} does not exist: neither a file nor a shipped model (shipped: "
                          f"{', '.join(SHIPPED)}){hint}")


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


#: ``--scene``: the kind of input ``--method best`` picks a model for (auto: by shape)
SCENES = {"road": "kitti", "indoor": "middlebury"}
#: ``--scene auto``: a frame at least this many times wider than high is a road frame (KITTI is 3.3)
ROAD_ASPECT = 2.5


def best_kind(width: int, height: int, dataset: str | None = None, scene: str = "auto") -> tuple[str, str]:
    """(kind of input, why) for ``--method best``: "kitti" (road) or "middlebury" (indoor), from
    ``scene`` ("road", "indoor"), else the data set, else the shape (width >= ROAD_ASPECT x
    height: road)."""

    if scene not in ("auto", *SCENES):
        raise ConfigError(f"--scene must be auto, road or indoor, got {scene!r}")
    if scene != "auto":
        return SCENES[scene], f"--scene {scene}"
    if dataset is not None:
        kind = "kitti" if dataset.startswith("kitti") else "middlebury"
        return kind, f"data set {dataset}"
    if width >= ROAD_ASPECT * height:
        return "kitti", (f"{width}x{height} is at least {ROAD_ASPECT} times as wide as high: a road frame "
                         "(--scene indoor overrides)")
    return "middlebury", (f"{width}x{height} is less than {ROAD_ASPECT} times as wide as high: an indoor "
                          "scene (--scene road overrides)")


def weights_for_input(width: int, height: int, dataset: str | None = None, scene: str = "auto") -> Path | None:
    """The shipped model ``--method best`` runs for an input (:data:`BEST`, :func:`best_kind`):
    the KITTI choice for road frames, the Middlebury model for indoor scenes. None when that
    model is not shipped."""
    kind, _ = best_kind(width, height, dataset, scene)
    path = WEIGHTS_DIR / f"{SHIPPED[BEST[kind]]}.msgpack"
    return path if path.is_file() else None


def chain_settings(weights) -> dict:
    """The learned-chain settings that go with a model: the ``"chain"`` entry of the JSON card
    next to its weights (``NAME.json`` beside ``NAME.msgpack``), as StereoConfig overrides of
    ``preset("learned")`` (e.g. ``{"sgm": {"p1": 0.7}}``); {} when there is none."""

    card = Path(weights).with_suffix(".json")
    if not card.is_file():
        return {}
    try:
        return dict(json.loads(card.read_text()).get("chain") or {})
    except (OSError, ValueError, AttributeError):
        return {}


def write_card(weights, chain: dict, **info) -> Path:
    """Write (or update) the card beside ``weights`` (``NAME.json`` beside ``NAME.msgpack``): its
    ``"chain"`` entry (StereoConfig overrides of ``preset("learned")``) and ``info`` (e.g.
    ``chain_from``: where the settings come from). A shipped model's card is never written.
    Returns the card's path."""
    from stereojax.data.io import write_json

    weights = Path(weights)
    if shipped_name(weights):
        raise ConfigError(f"{weights.name} is a shipped model: its card is not changed (copy the weights first)")
    card = weights.with_suffix(".json")
    data = {}
    if card.is_file():
        try:
            data = json.loads(card.read_text())
        except ValueError:
            data = {}
    write_json(card, {**data, "chain": chain, **info})
    return card


def settings_note(weights) -> str | None:
    """Where a learned model's chain settings come from, for the first printed line: None for a
    shipped model (its own searched card); else its card's ``chain_from``, or a note that it runs
    the learned preset's settings, never searched for it."""
    if weights is None or shipped_name(weights):
        return None
    card = Path(weights).with_suffix(".json")
    if card.is_file():
        try:
            data = json.loads(card.read_text())
        except ValueError:
            data = {}
        if data.get("chain_from"):
            return f"chain settings {data['chain_from']}"
        if "chain" in data:
            return f"chain settings from its card {card.name}"
    return ("the learned preset's default chain settings, never searched for these weights "
            "(stereojax tune searches them)")


def learned_config(weights=None, max_disp: int = 228):
    """``preset("learned", max_disp)`` with the chain settings stored with ``weights`` (a path,
    or a shipped name such as "kitti2015" / "kitti2015_compact"; None: the preset alone). This is the
    configuration ``--method best`` runs for that model."""

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


    stored = checkpoint.read_config(path)
    net = dataclass_from_dict(NetConfig, stored["net"]).validate()
    if expect_net is not None and net != expect_net:
        raise CheckpointError(f"checkpoint {path} is for network {dataclasses.asdict(net)}, "
                              f"expected {dataclasses.asdict(expect_net)}")
    variables = init_params(net, jax.random.PRNGKey(0))
    # restores only these two entries (a training checkpoint also holds opt_state and step)
    template = {"params": variables["params"], "batch_stats": variables["batch_stats"]}
    state, _ = checkpoint.load(path, template)
    return LearnedModel(net, state)


@dataclasses.dataclass(frozen=True)
class Resolved:
    """What runs for an input (:func:`resolve`): the cost method ("learned" or a classical
    one), the weights file of a learned cost, the chain configuration, and a description."""

    method: str
    weights: Path | None
    config: object
    exact_head: bool = False
    from_file: bool = False
    #: why this method and model run (e.g. the ``--method best`` rule that picked them)
    reason: str = ""
    #: the cascade (:mod:`stereojax.matching_cost.cascade`): (the full network's weights file,
    #: the share q of pixels it re-scores, its candidates per pixel); ``weights`` is then the
    #: student's. None: one network
    cascade: tuple | None = None

    @property
    def description(self) -> str:
        """One line that says what runs, e.g. "learned cost, shipped model kitti2015"."""
        if self.method != "learned":
            return f"{self.method} cost"
        label = _model_label(self.weights)
        if self.cascade is not None:
            full, share, k = self.cascade
            return (f"cascade q = {100 * share:g} %: learned cost, {label} everywhere, {_model_label(full)} at the "
                    f"{100 * share:g} % least confident pixels ({k} candidates each)")
        head = ", exact head (every disparity)" if self.exact_head and not self.from_file else ""
        return f"learned cost, {label}{head}"

    @property
    def label(self) -> str:
        """The short name of a results table's row, e.g. "stereojax kitti2015", "stereojax census"."""
        if self.method != "learned":
            return f"stereojax {self.method}"
        name = shipped_name(self.weights)
        if self.cascade is not None:
            full = shipped_name(self.cascade[0]) or Path(self.cascade[0]).name
            return f"stereojax cascade {name or Path(self.weights).name} + {full} at q = {100 * self.cascade[1]:g} %"
        head = ", exact head" if self.exact_head and not self.from_file else ""
        return f"stereojax {name or Path(self.weights).name}{head}"

    @property
    def chosen_line(self) -> str:
        """What runs and why, in one line (the first line ``predict`` prints); for weights that are
        not shipped, where their chain settings come from (:func:`settings_note`)."""
        line = f"{self.description} ({self.reason})" if self.reason else self.description
        note = settings_note(self.weights) if self.method == "learned" and not self.from_file else None
        return f"{line}; {note}" if note else line

    def with_max_disp(self, max_disp: int) -> "Resolved":
        return dataclasses.replace(self, config=self.config.with_max_disp(max_disp))

    def model(self):
        """The :class:`~stereojax.matching_cost.learned.LearnedModel` of a learned cost (loaded once per
        process and weights file), None for a classical one."""
        if self.method != "learned":
            return None
        return _load_once(self.weights)


    def cascade_arg(self):
        """The :class:`~stereojax.matching_cost.cascade.Cascade` for
        :class:`~stereojax.inference.predictor.Predictor` (the full network loaded once per
        process), or None for one network."""
        if self.cascade is None:
            return None
        from stereojax.matching_cost.cascade import Cascade
        full, share, k = self.cascade
        return Cascade(_load_once(full), share, k)


def _model_label(weights) -> str:
    name = shipped_name(weights)
    return f"shipped model {name}" if name else f"weights {Path(weights).name}"


def _load_once(weights):
    key = str(weights)
    with _LOADED_LOCK:                  # map_frames workers may ask at the same time
        if key not in _LOADED:
            _LOADED[key] = load_model(weights)
        return _LOADED[key]


_LOADED: dict = {}
_LOADED_LOCK = threading.Lock()


def resolve(method: str = "best", weights=None, config=None, width: int = 0, height: int = 0,
            dataset: str | None = None, max_disp: int = 228, exact_head: bool = False,
            scene: str = "auto", cascade: float | None = None, cascade_weights=None,
            cascade_candidates: int = 16) -> Resolved:
    """What runs for an input, as values (nothing is changed in place).

    method: "best" (the default: the shipped model that fits the input, :func:`weights_for_input`,
    or census when it is not shipped), "learned", "census" or "sad". weights: a checkpoint path
    or a shipped name (learned and best only). config: a StereoConfig that replaces the chain
    settings (a classical one turns best into that method). width, height, dataset: the input,
    for best; scene: "auto" (by shape or data set), "road" or "indoor" (:func:`best_kind`).
    exact_head: the learned head at every disparity instead of the candidates. ``reason`` of the
    result says why that method and model run. cascade: the share q in (0, 1] of pixels that the
    full network (``cascade_weights``; default: the model ``best`` picks for the input) re-scores
    where the student (``weights``; default :data:`CASCADE_STUDENT`) is least confident, at
    ``cascade_candidates`` candidates each (:mod:`stereojax.matching_cost.cascade`).
    """
    if cascade is not None:
        return _resolve_cascade(method, weights, config, width, height, dataset, max_disp, scene, cascade,
                                cascade_weights, cascade_candidates)
    if cascade_weights:
        raise ConfigError("--cascade-weights needs --cascade Q (the share of pixels the full network re-scores)")

    if weights in SHIPPED:
        weights = shipped_weights(weights)
    elif weights:
        check_weights_exist(weights)
    reason = f"--method {method}"
    if method == "best":
        if config is not None and config.cost.method != "learned":
            method = config.cost.method          # a classical chain from the config
            reason = f"--method best with a --config of cost.method {method}"
        elif weights:
            method = "learned"
            reason = "--method best with --weights"
        else:
            # the same model and chain settings on every backend (the exact head only on request)
            kind, why = best_kind(width, height, dataset, scene)
            path = weights_for_input(width, height, dataset, scene)
            method, weights = ("learned", path) if path else ("census", None)
            reason = f"--method best: {why}" + ("" if path else f"; the {BEST[kind]} model is not shipped")
    if method != "learned" and weights:
        raise ConfigError(f"--weights needs --method learned or best (got --method {method})")
    if method == "learned" and not weights:
        weights = shipped_weights("kitti2015")
        reason = "--method learned without --weights: the shipped kitti2015 model"
    if config is not None:
        cfg = config.with_max_disp(max_disp)
    elif method == "learned":
        # the chain settings searched for this model travel with it (NAME.json beside the weights)
        cfg = learned_config(weights, max_disp)
        if exact_head:
            cfg = dataclasses.replace(cfg, cost=dataclasses.replace(cfg.cost, candidates=0)).validate()
    else:
        cfg = preset(method, max_disp)
    return Resolved(method, Path(weights) if weights else None, cfg, bool(exact_head), config is not None, reason)


#: the student a cascade runs everywhere when no --weights are given
CASCADE_STUDENT = "kitti2015_compact"


def _resolve_cascade(method, weights, config, width, height, dataset, max_disp, scene, share, full,
                     candidates) -> Resolved:
    if method not in ("best", "learned"):
        raise ConfigError(f"--cascade needs --method best or learned (got --method {method})")
    if config is not None:
        raise ConfigError("--cascade runs its student's own chain settings; it takes no --config")
    if not 0.0 < float(share) <= 1.0:
        raise ConfigError(f"--cascade takes the share of pixels re-scored, in (0, 1] (e.g. 0.2), got {share}")
    student = resolve("learned", weights or CASCADE_STUDENT, None, width, height, dataset, max_disp)
    if not student.config.cost.candidates:
        raise ConfigError("the cascade's student needs a pruned head (cost.candidates > 0 in its card)")
    if full:
        full_path = weights_path(full)
        check_weights_exist(full_path)
        why = "--cascade-weights"
    else:
        kind, why = best_kind(width, height, dataset, scene)
        full_path = weights_for_input(width, height, dataset, scene)
        if full_path is None:
            raise ConfigError(f"no shipped {BEST[kind]} model for the cascade's full network; give --cascade-weights")
    reason = f"--cascade {share:g}; full network by {why}"
    return dataclasses.replace(student, cascade=(Path(full_path), float(share), int(candidates)), reason=reason)
