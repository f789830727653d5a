"""Strict conversion of nested mappings (parsed YAML) into frozen, typed dataclasses.

Every problem found (unknown key, missing key, wrong type, value out of range) is collected and
raised as one :class:`~pipeline.errors.ConfigError` that names the source file, the dotted key,
the bad value and what is allowed.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar

import yaml

from pipeline.errors import MISSING, ConfigError, ConfigProblem

T = TypeVar("T")


def setting(
    default: Any = dataclasses.MISSING,
    *,
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
    lt: float | None = None,
    min_len: int | None = None,
    max_len: int | None = None,
    allow_empty: bool = False,
    optional: bool = False,
) -> Any:
    """A dataclass field with numeric bounds (inclusive `ge`/`le`, exclusive `gt`/`lt`).

    Strings must be non-empty unless `allow_empty`. Every key must be given unless `optional`: an
    optional key that is absent takes its default.
    """
    if optional and default is dataclasses.MISSING:
        raise TypeError("an optional setting needs a default")
    meta = {
        "ge": ge,
        "gt": gt,
        "le": le,
        "lt": lt,
        "min_len": min_len,
        "max_len": max_len,
        "allow_empty": allow_empty,
        "optional": optional,
    }
    if default is dataclasses.MISSING:
        return dataclasses.field(metadata=meta)
    if isinstance(default, (list, dict)):
        raise TypeError("mutable defaults are not allowed; use a tuple")
    return dataclasses.field(default=default, metadata=meta)


def _describe(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin is tuple:
        return f"a list of {_describe(typing.get_args(tp)[0])}"
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_describe(a) for a in typing.get_args(tp))
    if tp is type(None):
        return "null"
    if dataclasses.is_dataclass(tp):
        return "a mapping with keys " + ", ".join(f.name for f in dataclasses.fields(tp))
    return {int: "an integer", float: "a number", str: "a string", bool: "true or false"}.get(tp, str(tp))


def in_bounds(value: float, meta: Mapping[str, Any]) -> bool:
    """Whether `value` lies inside the bounds of a setting's metadata (`ge`, `gt`, `le`, `lt`)."""
    return not (
        (meta.get("ge") is not None and not value >= meta["ge"])
        or (meta.get("gt") is not None and not value > meta["gt"])
        or (meta.get("le") is not None and not value <= meta["le"])
        or (meta.get("lt") is not None and not value < meta["lt"])
    )


def bounds_text(meta: Mapping[str, Any]) -> str:
    """The bounds of a setting's metadata in words (">= 0.0 and <= 1.0")."""
    parts = []
    if meta.get("ge") is not None:
        parts.append(f">= {meta['ge']}")
    if meta.get("gt") is not None:
        parts.append(f"> {meta['gt']}")
    if meta.get("le") is not None:
        parts.append(f"<= {meta['le']}")
    if meta.get("lt") is not None:
        parts.append(f"< {meta['lt']}")
    return " and ".join(parts)


class _Converter:
    def __init__(self) -> None:
        self.problems: list[ConfigProblem] = []

    def fail(self, key: str, value: object, allowed: str) -> None:
        self.problems.append(ConfigProblem(key, value, allowed))

    def convert(self, tp: Any, value: Any, key: str, meta: Mapping[str, Any]) -> Any:
        origin = typing.get_origin(tp)
        if dataclasses.is_dataclass(tp) and isinstance(tp, type):
            return self.dataclass(tp, value, key)
        if origin in (typing.Union, types.UnionType):
            args = typing.get_args(tp)
            if value is None and type(None) in args:
                return None
            inner = [a for a in args if a is not type(None)]
            if len(inner) == 1:
                return self.convert(inner[0], value, key, meta)
            for arm in inner:  # the first arm the value fits (e.g. a number or the word "auto")
                trial = _Converter()
                converted = trial.convert(arm, value, key, meta)
                if not trial.problems:
                    return converted
            arms = [_describe(a) + (self._suffix(meta) if a in (int, float) else "") for a in inner]
            self.fail(key, value, " or ".join(arms))
            return None
        if origin is Literal:
            choices = typing.get_args(tp)
            if value not in choices or isinstance(value, bool) != isinstance(choices[0], bool):
                self.fail(key, value, _describe(tp))
                return None
            return value
        if origin is tuple:
            (item_tp, *_rest) = typing.get_args(tp)
            if not isinstance(value, (list, tuple)):
                self.fail(key, value, _describe(tp))
                return None
            min_len, max_len = meta.get("min_len"), meta.get("max_len")
            if min_len is not None and len(value) < min_len:
                self.fail(key, value, f"a list with at least {min_len} item(s)")
            if max_len is not None and len(value) > max_len:
                self.fail(key, value, f"a list with at most {max_len} item(s)")
            return tuple(self.convert(item_tp, item, f"{key}[{i}]", meta) for i, item in enumerate(value))
        if tp is bool:
            if not isinstance(value, bool):
                self.fail(key, value, "true or false")
            return value
        if tp is int:
            if isinstance(value, bool) or not isinstance(value, int):
                self.fail(key, value, "an integer" + self._suffix(meta))
                return None
            return self.bounded(value, key, meta)
        if tp is float:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                self.fail(key, value, "a number" + self._suffix(meta))
                return None
            if not math.isfinite(value):
                self.fail(key, value, "a finite number" + self._suffix(meta))
                return None
            return self.bounded(float(value), key, meta)
        if tp is str:
            if not isinstance(value, str):
                self.fail(key, value, "a string")
            elif not value and not meta.get("allow_empty"):
                self.fail(key, value, "a non-empty string")
            return value
        raise TypeError(f"unsupported settings type {tp!r} at {key}")

    @staticmethod
    def _suffix(meta: Mapping[str, Any]) -> str:
        text = bounds_text(meta)
        return f" {text}" if text else ""

    def bounded(self, value: float, key: str, meta: Mapping[str, Any]) -> Any:
        if not in_bounds(value, meta):
            self.fail(key, value, "a value " + bounds_text(meta))
        return value

    def dataclass(self, cls: type, value: Any, key: str) -> Any:
        if not isinstance(value, Mapping):
            self.fail(key or "<top>", value, _describe(cls))
            return None
        hints = typing.get_type_hints(cls)
        fields = {f.name: f for f in dataclasses.fields(cls)}
        prefix = f"{key}." if key else ""
        for extra in sorted(set(map(str, value)) - set(fields)):
            self.fail(prefix + extra, value[extra], "unknown key; allowed keys: " + ", ".join(fields))
        kwargs: dict[str, Any] = {}
        before = len(self.problems)
        for name, f in fields.items():
            if name not in value:
                if f.metadata.get("optional"):
                    kwargs[name] = f.default
                    continue
                self.fail(prefix + name, MISSING, "required: " + _describe(hints[name]))
                continue
            kwargs[name] = self.convert(hints[name], value[name], prefix + name, f.metadata)
        if len(self.problems) != before:
            return None
        obj = cls(**kwargs)
        check = getattr(obj, "check", None)
        if check is not None:
            for sub, bad, allowed in check():
                self.fail(prefix + sub, bad, allowed)
        return obj


def from_mapping(cls: type[T], data: Any, source: str, key: str = "") -> T:
    """Build `cls` from a parsed mapping; raises ConfigError listing every problem."""
    conv = _Converter()
    obj = conv.dataclass(cls, data, key)
    if conv.problems:
        raise ConfigError(source, conv.problems)
    return typing.cast(T, obj)


def to_mapping(obj: Any) -> Any:
    """The inverse of :func:`from_mapping`: plain dicts, lists and scalars."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_mapping(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, tuple):
        return [to_mapping(v) for v in obj]
    return obj


def merge(base: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """Deep-merge `overrides` into a copy of `base` (mappings merge, everything else replaces)."""
    out = dict(base)
    for k, v in overrides.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = merge(out[k], v)
        else:
            out[k] = v
    return out


def read_yaml(path: str | Path) -> Any:
    """Parse a YAML file; a missing or malformed file raises ConfigError naming it."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(str(p), [ConfigProblem("<file>", str(p), f"a readable file ({exc.strerror})")]) from exc
    except UnicodeDecodeError as exc:
        problem = ConfigProblem("<file>", str(p), f"UTF-8 text (byte {exc.start}: {exc.reason})")
        raise ConfigError(str(p), [problem]) from exc
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(str(p), [ConfigProblem("<file>", str(p), f"valid YAML ({exc})")]) from exc
