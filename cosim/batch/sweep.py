"""Sweeps of :class:`cosim.Scenario` fields: parsing values, the product of a sweep, the config file.

Names are the Scenario fields (``-`` may replace ``_``); values are converted to the field's type,
read from the dataclass's annotations (``int``, ``str``, ``float``, ``tuple[float, float]``), before
anything runs: a malformed value is a :class:`ConfigError`; a value the scenario rejects (a negative
radius...) is left to the run, which fails and is reported in the table.  No FMU, no dask here.
"""
from __future__ import annotations

import dataclasses
import itertools
import re
import tomllib
import typing
from pathlib import Path

import numpy as np

from cosim import Scenario

__all__ = ["SCENARIO_FIELDS", "DEFAULTS", "INT_FIELDS", "STR_FIELDS", "VEC_FIELDS", "BATCH_OPTIONS", "ConfigError",
           "field_name", "parse_value", "parse_sweep_arg", "expand", "load_config"]

#: The Scenario fields by name, their defaults and types (from the dataclass and its annotations).
SCENARIO_FIELDS = {f.name: f for f in dataclasses.fields(Scenario)}
DEFAULTS = {f.name: (f.default if f.default is not dataclasses.MISSING else f.default_factory())
            for f in dataclasses.fields(Scenario)}
_TYPES = typing.get_type_hints(Scenario)
#: fields of type int, of type str, and the tuple fields with their length (``tuple[float, float]``)
INT_FIELDS = frozenset(n for n in SCENARIO_FIELDS if _TYPES[n] is int)
STR_FIELDS = frozenset(n for n in SCENARIO_FIELDS if _TYPES[n] is str)
VEC_FIELDS = {n: len(typing.get_args(_TYPES[n])) for n in SCENARIO_FIELDS if typing.get_origin(_TYPES[n]) is tuple}
#: Runner options of a config file's ``[batch]`` table and their defaults.
BATCH_OPTIONS = {"fmu_dir": "build", "resolution": None, "out": "results/batch", "workers": None,
                 "scheduler": None, "fmu_transfer": "auto", "plot_x": None, "rms_from": 0.5}


class ConfigError(ValueError):
    """A malformed sweep, config file or option (the message names it)."""


def field_name(key: str) -> str:
    name = str(key).strip().replace("-", "_")
    if name not in SCENARIO_FIELDS:
        raise ConfigError(f"{key!r} is not a Scenario field; expected one of {sorted(SCENARIO_FIELDS)}")
    return name


def parse_value(key: str, value):
    """``value`` (a TOML value or a command-line string) converted to the type of field ``key``."""
    name = field_name(key)
    if name in VEC_FIELDS:
        n = VEC_FIELDS[name]
        if isinstance(value, str):
            parts = [p for p in re.split(r"[\s,;:()\[\]]+", value) if p]
        elif isinstance(value, (list, tuple)):
            parts = list(value)
        else:
            parts = [value]
        if len(parts) != n:
            raise ConfigError(f"{name}: expected {n} numbers, got {value!r}")
        return tuple(_to_float(name, p) for p in parts)
    if isinstance(value, (list, tuple, dict)):
        raise ConfigError(f"{name}: expected a single value, got {value!r}")
    if name in STR_FIELDS:
        return str(value).strip()
    if name in INT_FIELDS:
        f = _to_float(name, value)
        if not float(f).is_integer():
            raise ConfigError(f"{name}: expected an integer, got {value!r}")
        return int(f)
    return _to_float(name, value)


def _to_float(name, value) -> float:
    if isinstance(value, bool):
        raise ConfigError(f"{name}: expected a number, got {value!r}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}: expected a number, got {value!r}") from None


def _split_top(text: str) -> list[str]:
    """Split on commas outside brackets: ``"[1,2],[3,4]"`` -> ``["[1,2]", "[3,4]"]``."""
    out, depth, cur = [], 0, []
    for ch in text:
        if ch in "[(":
            depth += 1
        elif ch in "])":
            depth -= 1
        if ch == "," and depth == 0:
            out.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    out.append("".join(cur))
    return [s.strip() for s in out if s.strip()]


def parse_sweep_arg(text: str) -> tuple[str, list]:
    """``"KEY=V1,V2"`` -> ``(field, [values])``; ``lo:hi:n`` gives n values (linspace)."""
    if "=" not in text:
        raise ConfigError(f"{text!r}: expected KEY=V1,V2,...")
    key, rhs = text.split("=", 1)
    name = field_name(key)
    values = []
    for item in _split_top(rhs):
        m = re.fullmatch(r"([^:\[\]]+):([^:\[\]]+):(\d+)", item)
        if m and name not in STR_FIELDS and name not in VEC_FIELDS:
            lo, hi, n = _to_float(name, m[1]), _to_float(name, m[2]), int(m[3])
            if n < 1:
                raise ConfigError(f"{name}: {item!r} asks for no value")
            values.extend(parse_value(name, float(v)) for v in np.linspace(lo, hi, n))
        else:
            values.append(parse_value(name, item))
    if not values:
        raise ConfigError(f"{text!r}: no value")
    return name, values


def _dimension(key, spec) -> tuple[tuple[str, ...], list[tuple]]:
    """One dimension of the product: a list of values of one field, or a table of equal lists."""
    if isinstance(spec, dict):
        names = tuple(field_name(k) for k in spec)
        lists = [spec[k] if isinstance(spec[k], list) else [spec[k]] for k in spec]
        if not lists or len({len(v) for v in lists}) != 1:
            raise ConfigError(f"sweep group {key!r}: expected lists of equal length, got "
                              f"{ {k: len(v) for k, v in zip(spec, lists)} }")
        rows = [tuple(parse_value(n, v) for n, v in zip(names, vals)) for vals in zip(*lists)]
        return names, rows
    name = field_name(key)
    values = spec if isinstance(spec, list) else [spec]
    if name in VEC_FIELDS and values and not isinstance(values[0], (list, tuple)):
        values = [values]                     # center = [0.45, 0.3]: a single value
    if not values:
        raise ConfigError(f"sweep {key!r}: no value")
    return (name,), [(parse_value(name, v),) for v in values]


def expand(base: dict | None = None, sweep: dict | None = None, cases: list | None = None) -> list[dict]:
    """Parameter dicts (every Scenario field) of the runs: ``base`` x product(``sweep``) + ``cases``.

    ``sweep``: ``{field: [values]}`` (one dimension each) or ``{group: {field: [values], ...}}``
    (the lists of a group vary together).  ``cases``: extra ``{field: value}`` runs on ``base``.
    Values are converted with :func:`parse_value`; no run is validated here (the worker does it).
    """
    fixed = dict(DEFAULTS)
    for k, v in (base or {}).items():
        fixed[field_name(k)] = parse_value(k, v)
    dims = [_dimension(k, v) for k, v in (sweep or {}).items()]
    seen: dict[str, str] = {}
    for names, _ in dims:
        for n in names:
            if n in seen:
                raise ConfigError(f"{n!r} is swept twice")
            seen[n] = n
    runs = []
    for combo in itertools.product(*(rows for _, rows in dims)):
        p = dict(fixed)
        for (names, _), vals in zip(dims, combo):
            p.update(zip(names, vals))
        runs.append(p)
    for case in cases or []:
        if not isinstance(case, dict):
            raise ConfigError(f"cases: expected tables of Scenario fields, got {case!r}")
        p = dict(fixed)
        for k, v in case.items():
            p[field_name(k)] = parse_value(k, v)
        runs.append(p)
    return runs


def load_config(path) -> dict:
    """Read a TOML sweep file: ``{"batch": {...}, "base": {...}, "sweep": {...}, "cases": [...]}``."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            cfg = tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such config file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    unknown = set(cfg) - {"batch", "base", "sweep", "cases"}
    if unknown:
        raise ConfigError(f"{path}: unknown sections {sorted(unknown)} (expected batch, base, sweep, cases)")
    batch = cfg.get("batch", {})
    bad = set(batch) - set(BATCH_OPTIONS)
    if bad:
        raise ConfigError(f"{path}: unknown [batch] options {sorted(bad)}; expected {sorted(BATCH_OPTIONS)}")
    return {"batch": batch, "base": cfg.get("base", {}), "sweep": cfg.get("sweep", {}),
            "cases": cfg.get("cases", [])}
