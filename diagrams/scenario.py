"""Scenarios: YAML files in scenarios/ loaded into typed dataclasses, with command-line overrides.

A scenario file names the diagram that runs it (`diagram:`) and sets any field of that diagram's
scenario dataclass; fields it leaves out keep their defaults. A file may start from another scenario
(`base: deck-landing`): its mappings are laid over that one's key by key, and any other value (a list
too) replaces the base's whole. Loading goes through
`pydrake.common.yaml.yaml_load_typed` (Drake's scenario idiom) after a check that names any
unknown key by its full dotted path.
"""

import dataclasses
import difflib
import math
import re
import sys
import typing
from collections.abc import Hashable
from pathlib import Path

import yaml
from pydrake.common.yaml import yaml_load_typed

from systems.config import ConfigError

SCENARIO_DIR = Path(__file__).resolve().parent.parent / "scenarios"


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader with YAML 1.2's (core schema's) numbers in place of YAML 1.1's, which PyYAML
    follows: `1e9` and `1E-3` are floats (1.1 reads a float without a dot as text), `045` is 45 (1.1:
    octal, 37), and `1:30` (1.1: sexagesimal, 90), `0b11` and `1_000` are text. A key given twice in one
    mapping is an error, as YAML says (PyYAML keeps the last)."""

    def construct_mapping(self, node, deep=False) -> dict:
        """The mapping; a ConstructorError naming a key it repeats and the lines of both."""
        lines = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # `<<: *base`: keys given here override the merged ones
                continue
            key = self.construct_object(key_node, deep=deep)
            if not isinstance(key, Hashable):  # PyYAML's construct_mapping refuses it
                continue
            line = key_node.start_mark.line + 1
            if key in lines:
                raise yaml.constructor.ConstructorError(
                    None, None, f"key {key!r} is given twice in one mapping (lines {lines[key]} and {line})")
            lines[key] = line
        return super().construct_mapping(node, deep)

    def construct_yaml_int(self, node) -> int:
        """A YAML 1.2 core integer: decimal (leading zeros included), 0o octal or 0x hexadecimal."""
        text = self.construct_scalar(node)
        try:
            if text[:2] in ("0o", "0x"):
                return int(text[2:], 8 if text[1] == "o" else 16)
            return int(text, 10)
        except ValueError:  # text tagged !!int by hand, which the resolver would have left as text
            raise yaml.constructor.ConstructorError(None, None, f"{text!r} is not a YAML 1.2 integer",
                                                    node.start_mark) from None


_NUMBER_TAGS = ("tag:yaml.org,2002:int", "tag:yaml.org,2002:float")
_Loader.yaml_implicit_resolvers = {first: [(tag, regexp) for tag, regexp in resolvers if tag not in _NUMBER_TAGS]
                                   for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}
_Loader.add_implicit_resolver("tag:yaml.org,2002:int", re.compile(r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$"),
                              list("-+0123456789"))
_Loader.add_implicit_resolver("tag:yaml.org,2002:float",  # after the int resolver: `3` is an int
                              re.compile(r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
                                         r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"),
                              list("-+.0123456789"))
_Loader.add_constructor("tag:yaml.org,2002:int", _Loader.construct_yaml_int)


def parse_yaml(text: str):
    """YAML text as plain data, numbers read as YAML 1.2 reads them."""
    return yaml.load(text, Loader=_Loader)


@dataclasses.dataclass
class RunSettings:
    """Fields every scenario has, whatever its diagram."""

    diagram: str = "stewart_scene"
    description: str = ""
    duration_s: float = 20.0


def scenario_names() -> list[str]:
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml"))


def scenario_path(name: str) -> Path:
    path = SCENARIO_DIR / f"{name}.yaml"
    if not path.is_file():
        known = ", ".join(scenario_names())
        raise ConfigError(f"unknown scenario '{name}' (known: {known}; or pass --config FILE)")
    return path


def _field_types(schema) -> dict[str, type]:
    hints = typing.get_type_hints(schema)
    return {f.name: hints[f.name] for f in dataclasses.fields(schema)}


_SCALAR_KINDS = {float: ((int, float), "a number"), int: ((int,), "a whole number"), str: ((str,), "text"),
                 bool: ((bool,), "true or false")}
INT_RANGE = (-2**31, 2**31 - 1)  # a C++ int's, which the bindings (Drake's, OpenCV's) take a whole number as


def _check_scalar(value, kind, dotted: str) -> None:
    """A ConfigError naming the field when a YAML scalar has the wrong type for it, or when the field's type is
    none a scenario sets (not in _SCALAR_KINDS: Drake's loader would refuse it with an assertion)."""
    if kind not in _SCALAR_KINDS:
        raise ConfigError(f"{dotted} cannot be set: its type, {getattr(kind, '__name__', kind)}, is none a scenario "
                          "sets (a number, whole number, text, true or false, a list of them, or a group)")
    accepted, description = _SCALAR_KINDS[kind]
    if not isinstance(value, accepted) or (kind is not bool and isinstance(value, bool)):
        raise ConfigError(f"{dotted} must be {description}, got {value!r}")
    # No setting means NaN (every comparison with it is false) or infinity (every quantity here is a
    # physical one, and a range check of x > 0 lets .inf through).
    if kind is float and isinstance(value, int) and abs(value) > sys.float_info.max:
        raise ConfigError(f"{dotted} must be a finite number, got a whole number of {len(str(abs(value)))} digits")
    if kind is float and not math.isfinite(value):
        raise ConfigError(f"{dotted} must be a finite number, got {'.nan' if math.isnan(value) else f'{value:+}'}")
    seed = dotted == "seed" or dotted.endswith((".seed", "_seed"))
    if kind is int and seed and value < 0:
        raise ConfigError(f"{dotted} must not be negative (a seed, as numpy's generators take them), got {value}")
    if kind is int and not seed and not INT_RANGE[0] <= value <= INT_RANGE[1]:  # a seed goes to numpy, of any size
        raise ConfigError(f"{dotted} must lie in {INT_RANGE[0]} to {INT_RANGE[1]} (a 32-bit int, as C++ takes it), "
                          f"got {value}")


def _check_item(item, kind, dotted: str) -> None:
    """`_check_scalar` for an item of a list field, into nested lists (list[list[float]])."""
    if typing.get_origin(kind) is not list:
        _check_scalar(item, kind, dotted)
        return
    if not isinstance(item, list):
        raise ConfigError(f"{dotted} must be a list of lists, got {item!r} in it")
    for inner in item:
        _check_item(inner, typing.get_args(kind)[0], dotted)


def normalise(raw: dict, schema, path: str = "") -> dict:
    """Checks `raw` (plain YAML data) against a dataclass schema: an unknown key or a value of the
    wrong type is a ConfigError naming its dotted path; a scalar given for a list field becomes a
    one-element list. `path` is the dotted name of `raw` itself ("" at the top)."""
    if not isinstance(raw, dict):
        raise ConfigError(f"{path or 'the scenario'} must be a group of settings (key: value), got {raw!r}")
    prefix = f"{path}." if path else ""
    types = _field_types(schema)
    out = {}
    for key, value in raw.items():
        dotted = f"{prefix}{key}"
        if key not in types:
            close = difflib.get_close_matches(str(key), types, n=1)
            hint = f" (did you mean '{prefix}{close[0]}'?)" if close else ""
            raise ConfigError(f"unknown key '{dotted}'{hint}")
        kind = types[key]
        if dataclasses.is_dataclass(kind):
            value = normalise(value, kind, dotted)
        elif typing.get_origin(kind) is list:
            value = value if isinstance(value, list) else [value]
            item_kind = typing.get_args(kind)[0]
            if dataclasses.is_dataclass(item_kind):  # a list of groups: each checked as its own
                value = [normalise(item, item_kind, f"{dotted}[{i}]") for i, item in enumerate(value)]
            else:
                for item in value:
                    _check_item(item, item_kind, dotted)
        else:
            _check_scalar(value, kind, dotted)
        out[key] = value
    return out


def set_override(raw: dict, assignment: str) -> None:
    """Applies one `--set a.b.c=value` to the raw data; the value is parsed as YAML. A mapping given for a group
    is laid over the group key by key, as a file's over its base's (`merged`); any other value replaces it."""
    key, sep, text = assignment.partition("=")
    if not sep or not key:
        raise ConfigError(f"--set expects key=value, got '{assignment}'")
    try:
        value = parse_yaml(text)
    except yaml.YAMLError as e:
        raise ConfigError(f"--set {key}: cannot parse the value '{text}': {yaml_problem(e)}") from None
    node = raw
    parts = key.split(".")
    for part in parts[:-1]:
        node = node.setdefault(part, {})
        if not isinstance(node, dict):
            raise ConfigError(f"--set {key}: '{part}' is not a group of settings")
    node.update(merged(node, {parts[-1]: value}))


def load_typed(raw: dict, schema, source: str):
    """The dataclass for `raw` data (already normalised), with Drake's typed YAML loader."""
    try:
        return yaml_load_typed(schema=schema, data=yaml.safe_dump(raw) if raw else "{}")
    except (RuntimeError, ValueError, TypeError) as e:
        raise ConfigError(f"{source}: {e}") from None


def merged(base: dict, over: dict) -> dict:
    """`over` laid on `base`: mappings merged key by key (recursively), any other value replacing the base's."""
    out = dict(base)
    for key, value in over.items():
        out[key] = merged(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


def read_scenario(path: Path, _from: tuple = ()) -> dict:
    """A scenario file's data over the scenario it names as `base` (and that one's base, ...). ConfigError
    for a file that is not a mapping, an unknown base or bases that lead back to the file."""
    raw = read_yaml(path)
    if not isinstance(raw, dict):
        raise ConfigError(f"{path} must hold a mapping of keys to values")
    if "base" not in raw:
        return raw
    base = raw.pop("base")
    if not isinstance(base, str):
        raise ConfigError(f"{path}: base must be a scenario name, got {base!r}")
    base_path = scenario_path(base)
    if base_path.resolve() in (*_from, path.resolve()):
        raise ConfigError(f"{path}: base '{base}' leads back to this file")
    return merged(read_scenario(base_path, (*_from, path.resolve())), raw)


def read_yaml(path: Path):
    """A scenario file's YAML data (UTF-8 text), {} for an empty file; ConfigError for one that cannot be read
    or parsed."""
    try:
        raw = parse_yaml(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise ConfigError(f"cannot read scenario file {path}: {e.strerror}") from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path} is not UTF-8 text (byte {e.start}: {e.object[e.start:e.start + 1]!r})") from None
    except yaml.YAMLError as e:
        raise ConfigError(f"{path} is not valid YAML: {yaml_problem(e)}") from None
    return {} if raw is None else raw


def yaml_problem(error: yaml.YAMLError) -> str:
    """PyYAML's error in one line: what is wrong and where (its first line alone can be only the context, as
    "while constructing a mapping")."""
    problem, mark = getattr(error, "problem", None), getattr(error, "problem_mark", None)
    if not problem:
        return str(error).splitlines()[0]
    return f"{problem} (line {mark.line + 1}, column {mark.column + 1})" if mark else problem
