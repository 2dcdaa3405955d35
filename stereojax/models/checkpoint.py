"""Checkpoints: network variables (+ optimiser state and step when training) with the
configuration that made them, in one msgpack file written atomically (temp name + rename).

Loading checks the architecture recorded in the file against the one asked for, and turns
every kind of damage (missing, truncated, not msgpack, other architecture) into a one-line
:class:`CheckpointError`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import flax.serialization as ser
import jax

from stereojax.data.io import atomic_output
from stereojax.errors import CheckpointError

FORMAT = "stereojax-checkpoint-1"


def save(path, state: dict[str, Any], config: dict[str, Any]) -> None:
    """Write ``state`` (a pytree of arrays and numbers) and ``config`` (JSON-able) atomically."""

    payload = {"format": FORMAT, "config": json.dumps(config, sort_keys=True),
               "state": ser.to_state_dict(state)}
    data = ser.msgpack_serialize(payload)
    with atomic_output(Path(path)) as tmp:
        Path(tmp).write_bytes(data)


def read_config(path) -> dict[str, Any]:
    """The configuration stored in a checkpoint (without restoring the arrays)."""
    return json.loads(_read(path)["config"])


def load(path, template: dict[str, Any], expect_net: dict[str, Any] | None = None):
    """Restore a checkpoint into the structure of ``template``; returns (state, config).

    expect_net: the ``net`` section the caller's model has; a checkpoint of another
    architecture raises :class:`CheckpointError` naming both.
    """
    payload = _read(path)
    config = json.loads(payload["config"])
    if expect_net is not None and config.get("net") != expect_net:
        raise CheckpointError(f"checkpoint {path} is for network {config.get('net')}, "
                              f"but the model is {expect_net}")
    try:
        state = ser.from_state_dict(template, payload["state"])
    except (KeyError, ValueError, TypeError) as exc:
        raise CheckpointError(f"checkpoint {path} does not match the model's parameters: {exc}") from None
    _check_shapes(template, state, path)
    return state, config


def _read(path) -> dict[str, Any]:
    p = Path(path)
    if not p.is_file():
        raise CheckpointError(f"checkpoint {p} does not exist" if not p.exists() else f"checkpoint {p} is not a file")
    try:
        payload = ser.msgpack_restore(p.read_bytes())
    except Exception as exc:  # msgpack raises many unrelated types (ValueError, ExtraData, ...) on damage
        raise CheckpointError(f"checkpoint {p} is corrupt or truncated ({type(exc).__name__})") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT or "state" not in payload:
        raise CheckpointError(f"{p} is not a stereojax checkpoint")
    return payload


def _check_shapes(template, state, path) -> None:

    t_leaves, t_tree = jax.tree_util.tree_flatten(template)
    s_leaves, s_tree = jax.tree_util.tree_flatten(state)
    if t_tree != s_tree:
        raise CheckpointError(f"checkpoint {path} has a different parameter structure")
    for a, b in zip(t_leaves, s_leaves):
        if getattr(a, "shape", None) != getattr(b, "shape", None):
            raise CheckpointError(f"checkpoint {path} has a parameter of shape {getattr(b, 'shape', None)} "
                                  f"where the model has {getattr(a, 'shape', None)}")
