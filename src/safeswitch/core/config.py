"""Typed, frozen configuration dataclasses loaded from plain data, unknown keys rejected.

A configuration is a tree of frozen dataclasses. :func:`from_dict` builds one from nested
dicts (as read from YAML), converting lists to tuples, and refuses any key the dataclass does
not have — naming it and the place it was found — so a misspelt key can never be silently
ignored. Range checks live in each dataclass's ``__post_init__``.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import re
import types
import typing
from collections.abc import Mapping, Sequence
from typing import Any, TypeVar

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration value or key is invalid; the message names it."""


def from_dict(cls: type[T], data: Mapping[str, Any] | None, where: str = "") -> T:
    """Build the dataclass ``cls`` from ``data``; missing keys keep their defaults. A class
    attribute ``RENAMED`` (old key → new key) lets configurations written before a rename load;
    ``MOVED`` (``"section.key"`` → ``"other.key"``) those written before a key moved to another
    section.

    Raises:
        ConfigError: On an unknown key or a value of the wrong type (the message names it).
    """
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where or cls.__name__}: expected a mapping, got {data!r}")
    moved: Mapping[str, str] = getattr(cls, "MOVED", {})
    if moved:
        data = move_keys(data, moved, where)
    renamed: Mapping[str, str] = getattr(cls, "RENAMED", {})
    if renamed:  # a configuration written before a key was renamed still loads
        for old, new in renamed.items():
            if old in data and new in data:
                raise ConfigError(
                    f"{where + '.' if where else ''}{old} is the old name of {new}: give one"
                )
        data = {renamed.get(key, key): value for key, value in data.items()}
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(
            f"unknown configuration key {where + '.' if where else ''}{unknown[0]!r} "
            f"(valid keys: {', '.join(sorted(names))})"
        )
    kwargs = {
        key: _convert(hints[key], value, f"{where}.{key}" if where else key)
        for key, value in data.items()
    }
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where or cls.__name__}: {exc}") from exc


def move_keys(data: Mapping[str, Any], moved: Mapping[str, str], where: str) -> dict[str, Any]:
    """``data`` with each key of ``moved`` (``"section.key"`` → ``"other.key"``) moved to its
    new place.

    Raises:
        ConfigError: A key given in both places (named).
    """
    out = {k: dict(v) if isinstance(v, Mapping) else v for k, v in data.items()}
    for old, new in moved.items():
        (section, key), (target, new_key) = old.split("."), new.split(".")
        source = out.get(section)
        if not isinstance(source, dict) or key not in source:
            continue
        into = out.setdefault(target, {})
        if not isinstance(into, dict):
            continue  # a malformed section: from_dict names it
        if new_key in into:
            prefix = where + "." if where else ""
            raise ConfigError(f"{prefix}{old} moved to {prefix}{new}: give one")
        into[new_key] = source.pop(key)
        if not source:  # emptied by the move (an empty mapping would replace a base's whole)
            del out[section]
    return out


def _convert(hint: Any, value: Any, where: str) -> Any:
    origin = typing.get_origin(hint)
    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        return from_dict(hint, value, where)
    if origin is typing.Literal:
        if value not in typing.get_args(hint):
            raise ConfigError(
                f"{where}: invalid value {value!r}; expected one of {list(typing.get_args(hint))}"
            )
        return value
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(hint)
        if value is None and type(None) in args:
            return None
        given = [arg for arg in args if arg is not type(None)]
        if len(given) == 1:  # ``X | None``: X's own message names what is wrong
            return _convert(given[0], value, where)
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _convert(arg, value, where)
            except ConfigError:
                continue
        raise ConfigError(f"{where}: invalid value {value!r} for type {hint}")
    if origin is dict:
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a mapping, got {value!r}")
        key_type, value_type = typing.get_args(hint) or (Any, Any)
        return {
            _convert(key_type, k, where): _convert(value_type, v, f"{where}.{k}")
            for k, v in value.items()
        }
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        args = typing.get_args(hint)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, f"{where}[{i}]") for i, v in enumerate(value))
        if len(args) != len(value):
            raise ConfigError(f"{where}: expected {len(args)} values, got {len(value)}")
        return tuple(
            _convert(a, v, f"{where}[{i}]")
            for i, (a, v) in enumerate(zip(args, value, strict=True))
        )
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    return value


def to_dict(config: Any) -> Any:
    """Plain nested dicts/lists of a configuration tree (for YAML or JSON)."""
    if dataclasses.is_dataclass(config) and not isinstance(config, type):
        return {f.name: to_dict(getattr(config, f.name)) for f in dataclasses.fields(config)}
    if isinstance(config, Mapping):
        return {k: to_dict(v) for k, v in config.items()}
    if isinstance(config, tuple | list):
        return [to_dict(v) for v in config]
    return config


def parse_setting(spec: str, option: str = "--set", prefix: str = "") -> tuple[str, Any]:
    """``KEY=VALUE`` → ``(KEY, VALUE)``: a dotted configuration key and a YAML value
    (``[30, 45]``, ``heavy``, ``null``, ``0.5``).

    Raises:
        ConfigError: Not ``KEY=VALUE``, or a value YAML cannot read (the message quotes it).
    """
    import yaml

    key, sep, text = spec.partition("=")
    if not sep or not key.strip() or not text.strip():
        raise ConfigError(
            f"{option} {prefix + spec!r}: expected KEY=VALUE (a dotted configuration key, e.g. "
            "env.scenarios.north_speed_kmh=[30,44])"
        )
    try:
        return key.strip(), yaml.safe_load(text)
    except yaml.YAMLError as exc:
        first = str(exc).splitlines()[0]
        raise ConfigError(
            f"{option} {prefix + spec!r}: {text!r} is not a YAML value ({first})"
        ) from exc


def set_key(
    data: dict[str, Any], key: str, value: Any, option: str = "--set", prefix: str = ""
) -> None:
    """Set the dotted ``key`` of the configuration dict ``data`` (every part must exist, as
    :func:`to_dict` writes them) to ``value``, in place; messages name the key with
    ``prefix`` (the section ``data`` is of a larger configuration).

    Raises:
        ConfigError: A part of ``key`` that is no key there (the message lists the keys).
    """
    node: Any = data
    parts = key.split(".")
    for i, part in enumerate(parts):
        if not isinstance(node, dict) or part not in node:
            where = prefix + ".".join(parts[:i])
            if not isinstance(node, dict):
                raise ConfigError(f"{option} {prefix}{key}: {where} is {node!r}, not a section")
            known = ", ".join(sorted(node))
            what = where.rstrip(".") or "the configuration"
            raise ConfigError(
                f"{option} {prefix}{key}: {what} has no key {part!r} (its keys: {known})"
            )
        if i == len(parts) - 1:
            node[part] = value
        else:
            node = node[part]


def with_settings(config: T, specs: Sequence[str], option: str = "--set", prefix: str = "") -> T:
    """``config`` with each ``KEY=VALUE`` of ``specs`` set (see :func:`parse_setting`),
    validated as a configuration file is (``prefix``: see :func:`set_key`).

    Raises:
        ConfigError: A malformed setting, an unknown key or a bad value (one line, naming it).
    """
    if not specs:
        return config
    data = to_dict(config)
    for spec in specs:
        key, value = parse_setting(spec, option, prefix)
        set_key(data, key, value, option, prefix)
    return from_dict(type(config), data, prefix.rstrip("."))


@dataclasses.dataclass(frozen=True)
class Bounds:
    """A number's allowed range, declared on its field: ``x: Annotated[float, Bounds(0, 1)]``
    (``None`` passes when the type allows it; a finite number is required). On a field that
    holds a ``(low, high)`` range, each end must be in the bounds and ``low <= high``.

    Attributes:
        low: Smallest allowed value (``None``: no lower bound).
        high: Largest allowed value (``None``: no upper bound).
        low_open: ``low`` itself is not allowed.
        high_open: ``high`` itself is not allowed.
        unit: Shown after the range in messages and the reference (e.g. ``"s"``).
    """

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    unit: str = ""

    def accepts(self, value: Any) -> bool:
        """``value`` (a number, or a ``(low, high)`` range) is within the bounds."""
        if isinstance(value, tuple):
            return len(value) == 2 and all(self.accepts(v) for v in value) and value[0] <= value[1]
        number = isinstance(value, int | float) and not isinstance(value, bool)
        return number and self.holds(value)

    def holds(self, value: float) -> bool:
        if not math.isfinite(value):
            return False
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            return False
        return self.high is None or (value < self.high if self.high_open else value <= self.high)

    def describe(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        if self.high is None:
            return f"must be {'>' if self.low_open else '>='} {self.low:g}{unit}"
        if self.low is None:
            return f"must be {'<' if self.high_open else '<='} {self.high:g}{unit}"
        return (
            f"must be in {'(' if self.low_open else '['}{self.low:g}, {self.high:g}"
            f"{')' if self.high_open else ']'}{unit}"
        )


_DECLARED: dict[type, dict[str, Bounds]] = {}


def _declared(cls: type) -> dict[str, Bounds]:
    """Every field of ``cls`` that declares :class:`Bounds`, read once per class."""
    if cls not in _DECLARED:
        hints = typing.get_type_hints(cls, include_extras=True)
        _DECLARED[cls] = {
            name: found[0]
            for name, hint in hints.items()
            if (found := [m for m in getattr(hint, "__metadata__", ()) if isinstance(m, Bounds)])
        }
    return _DECLARED[cls]


def bounds_of(cls: type, name: str) -> Bounds | None:
    """The :class:`Bounds` declared on field ``name`` of ``cls``, if any."""
    return _declared(cls).get(name)


def check_bounds(config: Any, owner: str) -> None:
    """Check every field of ``config`` that declares :class:`Bounds` (in a ``__post_init__``).

    Raises:
        ConfigError: Naming ``owner.field``, its value and the range.
    """
    for name, bounds in _declared(type(config)).items():
        value = getattr(config, name)
        if value is None:
            continue
        requirement = bounds.describe()
        if isinstance(value, tuple):
            requirement = f"must be (low, high) with low <= high, each {requirement[8:]}"
        check(bounds.accepts(value), owner, name, value, requirement)


def check(condition: bool, owner: str, name: str, value: Any, requirement: str) -> None:
    """Raise :class:`ConfigError` naming ``owner.name`` and its value unless ``condition``."""
    if not condition:
        raise ConfigError(f"{owner}.{name} {requirement}, got {value!r}")


# -- the reference --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Field:
    """One key of a configuration class, as the reference documents it."""

    name: str
    type: str
    default: str
    description: str


def _attributes(cls: type) -> dict[str, str]:
    """The ``Attributes:`` section of a Google-style class docstring: name → description
    (continuation lines joined)."""
    doc = inspect.cleandoc(cls.__doc__ or "")
    described: dict[str, str] = {}
    inside, name, indent = False, "", 0
    for line in doc.splitlines():
        if line.strip() == "Attributes:":
            inside, indent = True, len(line) - len(line.lstrip())
            continue
        if not inside:
            continue
        if line.strip() and len(line) - len(line.lstrip()) <= indent:
            break  # the next section
        entry = re.match(r"\s+(\w+)(?: \([^)]*\))?: (.*)", line)
        if entry and len(line) - len(line.lstrip()) == indent + 4:
            name = entry.group(1)
            described[name] = entry.group(2).strip()
        elif name and line.strip():
            described[name] += " " + line.strip()
    return described


def _type_name(hint: Any) -> str:
    text = hint if isinstance(hint, str) else getattr(hint, "__name__", None) or str(hint)
    return re.sub(r"\b(?:typing|safeswitch(?:\.\w+)*)\.", "", str(text))


def fields_of(cls: type) -> list[Field]:
    """Every key of the configuration class ``cls`` with its type, default and the
    description its docstring gives (or, for a key a subclass inherits, its base class's;
    empty when none gives one)."""
    described: dict[str, str] = {}
    for base in reversed(cls.__mro__):
        if dataclasses.is_dataclass(base):
            described |= _attributes(base)
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        if f.default is not dataclasses.MISSING:
            default = to_dict(f.default)
        elif f.default_factory is not dataclasses.MISSING:
            made = f.default_factory()
            default = "(section)" if dataclasses.is_dataclass(made) else to_dict(made)
        else:
            default = "(required)"
        shown = default if isinstance(default, str) and default.startswith("(") else repr(default)
        shown = {"None": "null", "True": "true", "False": "false"}.get(shown, shown)
        description = described.get(f.name, "")
        bounds = bounds_of(cls, f.name)
        if bounds is not None:
            description = f"{description} ({bounds.describe().removeprefix('must be ')})"
        out.append(Field(f.name, _type_name(hints[f.name]), shown, description))
    return out


def _nested(hint: Any) -> tuple[type, str] | None:
    """The configuration class a field's type holds — itself, ``X | None`` or
    ``dict[str, X]`` — and the key suffix it is written under (``""``, or ``".<name>"`` for a
    mapping's entries)."""
    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        return hint, ""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        given = [a for a in args if a is not type(None)]
        return _nested(given[0]) if len(given) == 1 else None
    if origin is dict and len(args) == 2:
        inner = _nested(args[1])
        return (inner[0], ".<name>") if inner else None
    return None


def sections(cls: type, prefix: str = "") -> list[tuple[str, type]]:
    """``cls`` and every configuration class nested in it (directly, as ``X | None`` or as the
    values of a ``dict[str, X]``), depth first, each with the dotted key it is found under
    (``""`` for ``cls`` itself)."""
    found = [(prefix, cls)]
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        nested = _nested(hints[f.name])
        if nested is not None:
            key = f"{prefix}.{f.name}" if prefix else f.name
            found += sections(nested[0], key + nested[1])
    return found


def _markdown(text: str) -> str:
    """reStructuredText roles and literals of a docstring as Markdown code."""
    text = re.sub(r":\w+:`~?([^`]+)`", lambda m: f"`{m.group(1).split('.')[-1]}`", text)
    return text.replace("``", "`")


def reference(cls: type, title: str) -> str:
    """A Markdown reference of the configuration tree under ``cls``: one table per class (key,
    type, default, description), read from the dataclasses and their docstrings."""
    lines = [f"## {title}", ""]
    keys: dict[type, list[str]] = {}  # a class nested under several keys gets one table
    for key, section in sections(cls):
        keys.setdefault(section, []).append(key)
    for section, under in keys.items():
        names = ", ".join(f"`{key or '(top level)'}`" for key in under)
        lines += [f"### {names} — `{section.__name__}`", ""]
        summary = _markdown(inspect.cleandoc(section.__doc__ or "").split("\n\n")[0])
        summary = summary.replace("\n", " ")
        lines += [summary, "", "| key | type | default | description |", "|---|---|---|---|"]
        for f in fields_of(section):
            cells = (f"`{f.name}`", f"`{f.type}`", f"`{f.default}`", _markdown(f.description))
            lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
        lines.append("")
    return "\n".join(lines)
