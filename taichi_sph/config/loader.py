"""Config loading: YAML (+ `extends:`) -> `--set` overrides -> typed, frozen dataclasses (schema.py) -> validated."""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from pathlib import Path
from typing import Any, Union

import yaml

from taichi_sph.config.schema import AUTO, Config
from taichi_sph.config.validate import validate
from taichi_sph.errors import ConfigError, UsageError


def is_dataclass_type(tp: Any) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def _allowed(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin in (Union, types.UnionType):
        return " or ".join(_allowed(a) for a in typing.get_args(tp))
    if tp is type(None):
        return "null"
    if origin is tuple:
        return f"a list of {_allowed(typing.get_args(tp)[0])}"
    if is_dataclass_type(tp):
        return "a mapping"
    if tp is Any:
        return "a value"
    return {float: "a number", int: "an integer", bool: "true/false", str: "a string"}.get(tp, str(tp))


def _convert(value: Any, tp: Any, key: str, source: str) -> Any:
    """Convert a YAML value to the annotated type or raise ConfigError naming the key."""
    origin = typing.get_origin(tp)
    if origin in (Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        if isinstance(value, str) and str in args:
            if value == AUTO or args == (str,):
                return value
        errors = []
        for a in args:
            if a is type(None) or a is str:
                continue
            try:
                return _convert(value, a, key, source)
            except ConfigError as e:
                errors.append(e)
        allowed = _allowed(tp).replace("a string", f"'{AUTO}'")
        raise ConfigError(f"got {value!r}; allowed: {allowed}", source=source, key=key)
    if tp is Any:
        return value
    if is_dataclass_type(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"expected a mapping, got {value!r}", source=source, key=key)
        return build_dataclass(tp, value, source, prefix=key)
    if origin is tuple:
        (item_tp, *_rest) = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"expected a list, got {value!r}", source=source, key=key)
        return tuple(_convert(v, item_tp, f"{key}[{i}]", source) for i, v in enumerate(value))
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"expected true or false, got {value!r}", source=source, key=key)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"expected an integer, got {value!r}", source=source, key=key)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"expected a number, got {value!r}", source=source, key=key)
        try:
            number = float(value)
        except OverflowError:
            raise ConfigError(f"number too large, got {value!r}", source=source, key=key) from None
        if not math.isfinite(number):
            raise ConfigError(f"expected a finite number, got {value!r}", source=source, key=key)
        return number
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"expected a string, got {value!r}", source=source, key=key)
        return value
    raise TypeError(f"unsupported schema type {tp}")  # a bug in the schema, not the user's


def _check_field_rules(f: dataclasses.Field, value: Any, key: str, source: str) -> None:
    meta = f.metadata
    if value is None or isinstance(value, str) and value == AUTO and meta.get("choices") is None:
        return
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        allowed = ", ".join(str(c) for c in choices)
        raise ConfigError(f"unknown value {value!r}; allowed: {allowed}", source=source, key=key)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if meta.get("positive") and not value > 0:
            raise ConfigError(f"must be > 0, got {value!r}", source=source, key=key)
        if meta.get("minimum") is not None and value < meta["minimum"]:
            raise ConfigError(f"must be >= {meta['minimum']}, got {value!r}", source=source, key=key)


def build_dataclass(cls: type, data: dict, source: str, prefix: str = "") -> Any:
    """Validate a mapping against dataclass `cls` (unknown keys refused) and build it."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = [k for k in data if k not in fields]
    if unknown:
        k = unknown[0]
        full = f"{prefix}.{k}" if prefix else str(k)
        raise ConfigError(f"unknown key; allowed keys here: {', '.join(fields)}", source=source, key=full)
    kwargs = {}
    for name, value in data.items():
        full = f"{prefix}.{name}" if prefix else name
        if name == "bodies":
            value = [_body(v, f"{full}[{i}]", source) for i, v in enumerate(value or [])]
        converted = _convert(value, hints[name], full, source)
        _check_field_rules(fields[name], converted, full, source)
        kwargs[name] = converted
    return cls(**kwargs)


def _body(value: Any, key: str, source: str) -> Any:
    if not isinstance(value, dict):
        raise ConfigError(f"each body is a mapping with a 'type', got {value!r}", source=source, key=key)
    return value


class _YamlLoader(yaml.SafeLoader):
    """SafeLoader that also reads `1e-3` as a float (YAML 1.1 insists on `1.0e-3`)."""


_YamlLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"))


def _read_yaml(path: Path) -> dict:
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ConfigError("file not found; `taichi-sph list` shows the bundled configs", source=str(path)) from None
    except OSError as e:
        raise ConfigError(f"cannot read file ({e.strerror})", source=str(path)) from None
    except UnicodeDecodeError:
        raise ConfigError("cannot read file (not UTF-8 text; a config is a YAML text file)", source=str(path)) from None
    try:
        data = yaml.load(text, Loader=_YamlLoader)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(e, "problem", None) or "invalid YAML"
        raise ConfigError(f"invalid YAML{where}: {problem}", source=str(path)) from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError("the top level must be a mapping of keys", source=str(path))
    return data


def _deep_merge(base: dict, top: dict) -> dict:
    out = dict(base)
    for k, v in top.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _deep_merge(out[k], v)
        else:
            out[k] = v
    return out


def load_raw(path: Path, _seen: tuple[Path, ...] = ()) -> dict:
    """Read a YAML config, resolving `extends:` (relative to the file) recursively."""
    path = Path(path)
    if path.resolve() in _seen:
        raise ConfigError("circular 'extends'", source=str(path), key="extends")
    data = _read_yaml(path)
    parent = data.pop("extends", None)
    if parent is not None:
        if not isinstance(parent, str):
            raise ConfigError(f"expected a file name, got {parent!r}", source=str(path), key="extends")
        parent_path = (path.parent / parent)
        if not parent_path.exists():
            raise ConfigError(f"extended file '{parent}' not found next to this config", source=str(path), key="extends")
        data = _deep_merge(load_raw(parent_path, _seen + (path.resolve(),)), data)
    return data


def parse_override(text: str) -> tuple[list[str], Any]:
    """`a.b.c=value` -> (['a','b','c'], typed value parsed as YAML)."""
    if "=" not in text:
        raise ConfigError(f"override '{text}' must look like KEY=VALUE, e.g. particles.dx=0.01", source="--set")
    key, _, raw = text.partition("=")
    key = key.strip()
    if not key or any(not part for part in key.split(".")):
        raise ConfigError(f"override '{text}' has an empty key", source="--set")
    try:
        value = yaml.load(raw, Loader=_YamlLoader) if raw.strip() else None
    except yaml.YAMLError:
        value = raw
    return key.split("."), value


def apply_overrides(data: dict, overrides: list[str]) -> dict:
    """Apply `--set a.b=value` overrides; keys must exist in the schema. An item of a list of sections is named by
    its index, `bodies[1].hi=[2.0, 0.3]` (the item must exist: an override changes a scene, it does not add bodies)."""
    data = _deep_merge({}, data)
    for text in overrides:
        parts, value = parse_override(text)
        _set_key(data, Config, parts, 0, value)
    return data


_INDEXED = re.compile(r"^(\w+)\[(\d+)\]$")


def section_type(tp: Any) -> Any:
    """The dataclass of a section field (Optional[section] included), else None."""
    if is_dataclass_type(tp):
        return tp
    args = [a for a in typing.get_args(tp) if a is not type(None)]
    return args[0] if len(args) == 1 and is_dataclass_type(args[0]) and type(None) in typing.get_args(tp) else None


def list_item_type(tp: Any) -> Any:
    """The dataclass of the items of a list-of-sections field (tuple[Body, ...]), else None."""
    args = typing.get_args(tp)
    return args[0] if typing.get_origin(tp) is tuple and args and is_dataclass_type(args[0]) else None


def _name_an_item(name: str, count: int) -> str:
    """The error for a list item that is not named, or not there."""
    if count == 0:
        return f"'{name}' has no items to change"
    return f"'{name}' has {count} item(s): name one by its index, {name}[0]" + (f" to {name}[{count - 1}]" if count > 1 else "")


def _set_key(node: dict, cls: Any, parts: list[str], i: int, value: Any) -> None:
    """node[parts[i]]...[parts[-1]] = value (copying every dict and list it changes), each part checked against the
    schema class of its level."""
    key = ".".join(parts)
    match = _INDEXED.match(parts[i])
    name = match.group(1) if match else parts[i]
    names = {f.name: f for f in dataclasses.fields(cls)} if is_dataclass_type(cls) else {}
    if name not in names:
        where = ".".join(parts[:i]) or "top level"
        raise ConfigError(f"unknown key '{key}'; allowed at {where}: {', '.join(names)}", source="--set", key=key)
    tp = typing.get_type_hints(cls)[name]
    item_cls = list_item_type(tp)
    if match or item_cls is not None and i < len(parts) - 1:
        if item_cls is None:
            raise ConfigError(f"'{name}' is not a list of sections", source="--set", key=key)
        _set_item(node, name, item_cls, int(match.group(2)) if match else None, parts, i, value)
        return
    if i == len(parts) - 1:
        node[name] = value
        return
    section = section_type(tp)
    if section is None:
        raise ConfigError(f"'{name}' is not a section", source="--set", key=key)
    child = node.get(name)
    node[name] = child = dict(child) if isinstance(child, dict) else {}
    _set_key(child, section, parts, i + 1, value)


def _set_item(node: dict, name: str, item_cls: Any, index: int | None, parts: list[str], i: int, value: Any) -> None:
    """node[name][index] (an existing item of a list of sections), or a key inside it, = value."""
    key = ".".join(parts)
    items = node.get(name)
    count = len(items) if isinstance(items, list) else 0
    if index is None or index >= count:
        raise ConfigError(_name_an_item(name, count), source="--set", key=key)
    node[name] = items = list(items)
    if i == len(parts) - 1:
        items[index] = value
        return
    if not isinstance(items[index], dict):
        raise ConfigError(f"'{parts[i]}' is not a section", source="--set", key=key)
    items[index] = child = dict(items[index])
    _set_key(child, item_cls, parts, i + 1, value)


def load_config(path: str | Path, overrides: list[str] | None = None) -> Config:
    """Load, merge, override and validate a config file."""
    path = Path(path)
    data = load_raw(path)
    data = apply_overrides(data, overrides or [])
    data.setdefault("name", path.stem)
    return config_from_dict(data, str(path))


def config_from_dict(data: dict, source: str = "<config>") -> Config:
    """Validate a plain mapping (already merged) into a Config."""
    data = dict(data)
    bodies = data.get("bodies")
    if bodies is not None and not isinstance(bodies, list):
        raise ConfigError("expected a list of bodies", source=source, key="bodies")
    cfg = build_dataclass(Config, data, source)
    validate(cfg, source)
    return cfg


def to_dict(cfg: Any) -> Any:
    """Plain data (lists, dicts) for config.yaml."""
    if dataclasses.is_dataclass(cfg):
        return {f.name: to_dict(getattr(cfg, f.name)) for f in dataclasses.fields(cfg)}
    if isinstance(cfg, tuple):
        return [to_dict(v) for v in cfg]
    return cfg


def bundled_configs_dir() -> Path:
    """configs/ of a source checkout, else the copy installed with the package."""
    package = Path(__file__).resolve().parent.parent
    for cand in (package.parent / "configs", package / "data" / "configs"):
        if cand.is_dir():
            return cand
    return package.parent / "configs"


def config_from_args(args) -> Config:
    """The config a command's arguments name: CONFIG with --set, --solver, --arch and --t-end applied."""
    overrides = list(args.overrides)
    if getattr(args, "solver", None) and not isinstance(args.solver, list):
        overrides.append(f"solver={args.solver}")
    if getattr(args, "arch", None):
        overrides.append(f"arch={args.arch}")
    if getattr(args, "t_end", None) is not None:
        if args.t_end <= 0:
            raise UsageError(f"--t-end must be > 0, got {args.t_end}")
        overrides.append(f"time.t_end={args.t_end}")
    return load_config(args.config, overrides)
