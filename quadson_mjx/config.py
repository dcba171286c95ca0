"""Configs: built by factory functions, overridden with dotted keys, frozen, saved with every run.

A config is an `ml_collections.ConfigDict` (a brax dependency already). Factories return it locked,
so a typo can never add a new key silently; `apply_overrides` parses command-line style
`--env.reward.forward_target=0.4` and raises on an unknown key or a value of the wrong type.
"""

from __future__ import annotations

import ast
import difflib
import json
from collections.abc import Iterable, Mapping

import ml_collections

ConfigDict = ml_collections.ConfigDict


def _flat_keys(cfg: Mapping, prefix: str = "") -> list[str]:
    keys = []
    for k, v in cfg.items():
        name = f"{prefix}{k}"
        if isinstance(v, Mapping | ConfigDict):
            keys.extend(_flat_keys(v, name + "."))
        else:
            keys.append(name)
    return keys


# Keys whose value is a list of layer sizes: any depth may replace the default's.
LAYER_SIZE_KEYS = ("policy_hidden", "value_hidden")


def _parse_value(text: str, current, key: str):
    """Parses `text` into the type of the current value; raises naming `key` on a mismatch."""
    if isinstance(current, str):
        return text
    try:
        value = ast.literal_eval(text)
    except (ValueError, SyntaxError):
        if text.lower() in ("true", "false"):
            value = text.lower() == "true"
        else:
            raise ValueError(
                f"config key '{key}': cannot parse {text!r} as {type(current).__name__}"
            ) from None
    if current is None:
        return value
    if isinstance(current, bool):
        if not isinstance(value, bool):
            raise ValueError(f"config key '{key}' takes true/false, got {text!r}")
        return value
    if isinstance(current, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(value, int) and key.rsplit(".", 1)[-1] in LAYER_SIZE_KEYS:
        value = (value,)  # one hidden layer, written without a trailing comma
    if isinstance(current, tuple | list) and isinstance(value, tuple | list):
        if key.rsplit(".", 1)[-1] in LAYER_SIZE_KEYS:
            if not value or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in value):
                raise ValueError(f"config key '{key}' takes layer sizes (positive integers), got {text!r}")
            return type(current)(value)
        if len(value) != len(current):
            raise ValueError(f"config key '{key}' takes {len(current)} values, got {len(value)}")
        return type(current)(
            float(v) if isinstance(c, float) else v for v, c in zip(value, current, strict=True)
        )
    if type(value) is not type(current):
        raise ValueError(f"config key '{key}' takes a {type(current).__name__}, got {text!r}")
    return value


def apply_overrides(cfg: ConfigDict, overrides: Iterable[str], prefix: str = "") -> ConfigDict:
    """Returns a copy of `cfg` with `key.sub=value` overrides applied (leading dashes allowed).

    Raises ValueError naming the key for an unknown key (with the closest known ones), a missing
    '=', or a value that does not parse as the type of the default. `prefix` (e.g. "env.") is put
    before key names in messages, to name them as the user typed them.
    """
    out = ml_collections.ConfigDict(cfg.to_dict())
    known = _flat_keys(out)
    for item in overrides:
        body = item.lstrip("-")
        if "=" not in body:
            raise ValueError(f"override {item!r} must look like key.sub=value")
        key, text = body.split("=", 1)
        if key not in known:
            close = difflib.get_close_matches(key, known, n=3)
            hint = f"; did you mean {', '.join(prefix + c for c in close)}?" if close else ""
            raise ValueError(f"unknown config key '{prefix}{key}'{hint}")
        *path, leaf = key.split(".")
        node = out
        for p in path:
            node = node[p]
        node[leaf] = _parse_value(text, node[leaf], prefix + key)
    out.lock()
    return out


def conform(data: Mapping, reference: ConfigDict, prefix: str, source: str) -> ConfigDict:
    """`data` (e.g. a section of a run's config.json) checked against `reference` (the factory's
    config): every key present, none unknown, each value of the reference's type (an int where a
    float is expected is accepted; lists become tuples). Raises ValueError naming `source` (the
    file) and the key as `prefix + key`. Returns a locked ConfigDict.
    """
    if not isinstance(data, Mapping):
        raise ValueError(f"{source}: '{prefix.rstrip('.')}' must be an object, got {type(data).__name__}")
    out = {}
    unknown = [prefix + k for k in sorted(set(data) - set(reference.keys()))]
    if unknown:
        raise ValueError(f"{source}: unknown config keys {unknown} (written by another version?)")
    for key, ref in reference.items():
        name = prefix + key
        if key not in data:
            raise ValueError(f"{source}: config key '{name}' is missing (the file is incomplete or damaged)")
        value = data[key]
        if isinstance(ref, ConfigDict | Mapping):
            out[key] = conform(value, ml_collections.ConfigDict(ref), name + ".", source).to_dict()
            continue
        if isinstance(ref, tuple | list) and isinstance(value, list):
            value = tuple(value)
        ok = type(value) is type(ref)
        if isinstance(ref, float) and type(value) is int:
            value, ok = float(value), True
        if isinstance(ref, tuple) and ok:
            if key in LAYER_SIZE_KEYS:
                ok = bool(value) and all(type(v) is int and v > 0 for v in value)
            else:
                ok = len(value) == len(ref) and all(
                    type(v) is type(r) or (type(r) is float and type(v) is int)
                    for v, r in zip(value, ref, strict=True)
                )
                if ok:
                    value = tuple(
                        float(v) if type(r) is float else v for v, r in zip(value, ref, strict=True)
                    )
        if not ok:
            raise ValueError(f"{source}: config key '{name}' should be like {ref!r}, got {data[key]!r}")
        out[key] = value
    cfg = ml_collections.ConfigDict(out)
    cfg.lock()
    return cfg


def freeze(cfg: ConfigDict) -> ml_collections.FrozenConfigDict:
    return ml_collections.FrozenConfigDict(cfg)


def to_json(cfg) -> str:
    """The resolved config as JSON, for saving beside checkpoints and inside MCAP files."""
    data = cfg.to_dict() if hasattr(cfg, "to_dict") else dict(cfg)
    return json.dumps(data, indent=2, sort_keys=True, default=list)


def from_json(text: str) -> ConfigDict:
    cfg = ml_collections.ConfigDict(json.loads(text))
    cfg.lock()
    return cfg
