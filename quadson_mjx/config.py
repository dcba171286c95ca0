"""Configs: built by factory functions, overridden with dotted keys, frozen, saved with every run.

A config is an `ml_collections.ConfigDict` (a brax dependency already). Factories return it locked,
so a typo can never add a new key silently; `apply_overrides` parses command-line style
`--env.reward.forward_target=0.4` with ml_collections' config_flags (absl flags) and raises on an
unknown key or a value of the wrong type.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import re
from collections.abc import Iterable, Mapping

import ml_collections
import numpy as np
from absl import flags
from ml_collections import config_flags

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

# name of the one config flag apply_overrides defines: `key.sub=value` is parsed as --_cfg.key.sub=value
_FLAG = "_cfg"


def _check_value(value, current, key: str, text: str):
    """`value` (as config_flags parsed it) checked against the field's `current` value: the checks
    config_flags leaves out. Returns the value to store (tuple elements as the default's types)."""
    if not isinstance(current, tuple | list):
        return value
    if key.rsplit(".", 1)[-1] in LAYER_SIZE_KEYS:  # any depth; `64` means (64,)
        if not value or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in value):
            raise ValueError(f"config key '{key}' takes layer sizes (positive integers), got {text!r}")
        return type(current)(value)
    if len(value) != len(current):  # config_flags takes a tuple of any length
        raise ValueError(f"config key '{key}' takes {len(current)} values, got {len(value)}")
    out = []
    for v, c in zip(value, current, strict=True):
        ok = type(v) is type(c) or (type(c) is float and type(v) is int)
        if not ok:
            raise ValueError(f"config key '{key}' takes values like {tuple(current)!r}, got {text!r}")
        out.append(float(v) if type(c) is float else v)
    return type(current)(out)


def apply_overrides(cfg: ConfigDict, overrides: Iterable[str], prefix: str = "") -> ConfigDict:
    """Returns a copy of `cfg` with `key.sub=value` overrides applied (leading dashes allowed).

    Values are parsed by ml_collections' config_flags (absl flags) as the type of the default: a
    bool takes true/false (also 1/0), a tuple `(0, 2)` or `0,2`. Raises ValueError naming the key for
    an unknown key (with the closest known ones), a missing '=', a value that does not parse as the
    type of the default, or a tuple of another length (layer-size keys, LAYER_SIZE_KEYS, take any
    depth of positive integers; `64` is (64,)). Non-finite floats parse; the env and PPO config
    checks refuse them. `prefix` (e.g. "env.") is put before key names in messages, to name them as
    the user typed them. `cfg` itself is left as it is.
    """
    known = _flat_keys(cfg)
    parsed = []  # (key, text)
    for item in overrides:
        body = item.lstrip("-")
        if "=" not in body:
            raise ValueError(f"override {item!r} must look like key.sub=value")
        key, text = body.split("=", 1)
        if key not in known:
            close = difflib.get_close_matches(key, known, n=3)
            hint = f"; did you mean {', '.join(prefix + c for c in close)}?" if close else ""
            raise ValueError(f"unknown config key '{prefix}{key}'{hint}")
        parsed.append((key, text))
    data = cfg.to_dict()
    current = {}
    for key, _ in parsed:
        *path, leaf = key.split(".")
        node = data
        for p in path:
            node = node[p]
        current[key] = node[leaf]
        if node[leaf] is None:
            raise ValueError(f"config key '{prefix}{key}' is None: no type to parse the value as")
        if isinstance(node[leaf], list):  # config_flags overrides tuples, not lists
            node[leaf] = tuple(node[leaf])
    # DEFINE_config_dict keeps (and mutates) the ConfigDict it is given: a copy, never cfg
    out = ml_collections.ConfigDict(data)
    argv = ["apply_overrides", *(f"--{_FLAG}.{key}={text}" for key, text in parsed)]
    fv = flags.FlagValues()
    config_flags.DEFINE_config_dict(_FLAG, out, flag_values=fv, lock_config=True, sys_argv=argv)
    try:
        fv(argv)
    except flags.Error as e:  # IllegalFlagValueError: "flag --_cfg.KEY=TEXT: why"
        message = str(e)
        match = re.search(rf"--{_FLAG}\.([^=\s]+)=", message)
        key = match.group(1) if match else None
        if key not in current:
            raise ValueError(f"config keys {[prefix + k for k, _ in parsed]}: {message}") from None
        text = dict(parsed)[key]
        if isinstance(current[key], bool):
            raise ValueError(f"config key '{prefix}{key}' takes true/false, got {text!r}") from None
        why = message.split(": ", 1)[-1]
        like = f"{type(current[key]).__name__} like {current[key]!r}"
        raise ValueError(f"config key '{prefix}{key}' takes a {like}, got {text!r} ({why})") from None
    out = fv[_FLAG].value
    for key, text in parsed:
        *path, leaf = key.split(".")
        node = out
        for p in path:
            node = node[p]
        value = _check_value(node[leaf], current[key], prefix + key, text)
        if type(value) is not type(node[leaf]):  # a list field: unlock to store it as a list again
            with node.unlocked():
                node[leaf] = None
                node[leaf] = value
        else:
            node[leaf] = value
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


@dataclasses.dataclass(frozen=True)
class Rule:
    """What one config key may hold. kind: "number" (one value in [lo, hi]; lo_open: lo itself
    excluded), "int" (an integer in [lo, hi]), "pair" (a (low, high) range, low <= high, both in
    [lo, hi]), "vector" (a tuple of values each in [lo, hi]), "bool", "name" (a string the
    structural checks of check_env_config / check_ppo_config test against their lists)."""

    kind: str
    lo: float = -math.inf
    hi: float = math.inf
    unit: str = ""
    lo_open: bool = False

    def describe(self) -> str:
        if self.kind in ("bool", "name"):
            return "true/false" if self.kind == "bool" else "a known name"
        left = "(" if self.lo_open else "["
        span = f"{left}{_num(self.lo)}, {_num(self.hi)}]" + (f" {self.unit}" if self.unit else "")
        return {
            "pair": f"a (low, high) range with low <= high, both in {span}",
            "vector": f"values in {span}",
        }.get(self.kind, f"{'an integer' if self.kind == 'int' else 'a number'} in {span}")

    def check(self, name: str, value) -> None:
        """Raises ValueError naming `name` when `value` breaks the rule. Numbers are also checked
        in float32, the dtype training runs in (1e300 is finite in float64 and inf in float32)."""
        if self.kind == "bool":
            if not isinstance(value, bool):
                raise ValueError(f"{name} must be true or false, got {value!r}")
            return
        if self.kind == "name":
            if not isinstance(value, str):
                raise ValueError(f"{name} must be a name (a string), got {value!r}")
            return
        many = self.kind in ("pair", "vector")
        values = tuple(value) if many and isinstance(value, tuple | list) else (value,)
        if many != isinstance(value, tuple | list) or (self.kind == "pair" and len(values) != 2):
            raise ValueError(f"{name} must be {self.describe()}, got {value!r}")
        for v in values:
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise ValueError(f"{name} must be {self.describe()}, got {value!r}")
            if self.kind == "int" and not isinstance(v, int):
                raise ValueError(f"{name} must be {self.describe()}, got {value!r}")
            if isinstance(v, float) and not math.isfinite(v):
                raise ValueError(f"{name} must be finite, got {value!r}")
            with np.errstate(over="ignore"):
                overflows = isinstance(v, float) and not math.isfinite(float(np.float32(v)))
            if overflows:
                raise ValueError(
                    f"{name} must be finite in float32, the dtype training runs in: {v!r} overflows to inf"
                )
            low_ok = v > self.lo if self.lo_open else v >= self.lo
            if not (low_ok and v <= self.hi):
                raise ValueError(f"{name} must be {self.describe()}, got {value!r}")
        if self.kind == "pair" and not values[0] <= values[1]:
            raise ValueError(f"{name} must be {self.describe()}, got {value!r}")


def rule_for(rules: dict[str, Rule], key: str) -> Rule | None:
    """The rule of dotted `key` in `rules` (exact name first, then a `group.*` entry), or None."""
    if key in rules:
        return rules[key]
    head = key.rsplit(".", 1)[0] if "." in key else None
    return rules.get(f"{head}.*") if head else None


def _num(x: float) -> str:
    """A bound as written: whole numbers in full (2147483647, not 2.14748e+09), others as %g."""
    return str(int(x)) if math.isfinite(x) and float(x).is_integer() and abs(x) < 1e13 else f"{x:g}"
