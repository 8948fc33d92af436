"""Load, validate and dump oacli configuration files.

A configuration is a YAML file read with PyYAML's safe loader (duplicate keys rejected) into the frozen pydantic
models of :mod:`oacli.config.models`. Every problem, whether the file is missing, the YAML is malformed or a value
is non-physical, raises :class:`oacli.errors.ConfigError` with one line per problem::

    <file>: <field.path>: <value, shortened>: <reason>
    configs/x.yaml: robot.mass_kg: -1.0: must be > 0

List indices appear as numbers (``environment.keep_out.0.center``). Problems with the file as a whole read
``<file>: <reason>`` (``<file>: line 3, column 7: invalid YAML: ...`` for syntax errors).

Examples
--------
>>> from oacli.config import load_config, dump_config
>>> cfg = load_config("configs/iss_reswarm.yaml")          # doctest: +SKIP
>>> cfg.robot.inertial_params().mass_kg                     # doctest: +SKIP
9.583788668
>>> text = dump_config(cfg)                                 # resolved, safe YAML; load_config reads it back
"""

from __future__ import annotations

import difflib
import os
import re
import reprlib
import stat
import typing
from collections.abc import Mapping
from typing import Any

import yaml
from pydantic import BaseModel, ValidationError

from oacli.config.models import (
    ControllerConfig,
    ControllerWeights,
    DisturbanceConfig,
    EnvironmentConfig,
    KeepInBox,
    KeepOutEllipsoid,
    OacliConfig,
    Pose,
    ReferenceConfig,
    RobotConfig,
    SensorsConfig,
    SimulationConfig,
    TruthConfig,
)
from oacli.config.sizes import BoundedComposer, ConfigSizeError
from oacli.errors import ConfigError

MAX_CONFIG_BYTES = 1024 * 1024
"""Largest config file accepted [bytes] (the presets are under 10 KB; PyYAML parses about 1 MB a few seconds)."""

VALUE_REPR_CHARS = 60
"""Values in messages are shortened to this many characters."""

_REPR = reprlib.Repr()
_REPR.maxlevel = 3
_REPR.maxlist = _REPR.maxtuple = 6
_REPR.maxdict = 4
_REPR.maxstring = VALUE_REPR_CHARS
_REPR.maxother = VALUE_REPR_CHARS

_MISSING = "<missing>"


# --------------------------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------------------------


def load_config(path: str | os.PathLike[str]) -> OacliConfig:
    """Read, validate and resolve a YAML configuration file.

    Parameters
    ----------
    path : str or os.PathLike
        The YAML file. Relative paths inside it (``reference.file``) are resolved against its folder.

    Returns
    -------
    OacliConfig
        The frozen, validated configuration with every default filled in.

    Raises
    ------
    ConfigError
        For a missing or unreadable file, a directory, non-UTF-8 text, malformed YAML, a top level that is not a
        mapping, an empty file, and every invalid or non-physical value (one line per problem, each starting with
        ``path``).
    """
    source = os.fspath(path)
    data = read_yaml_file(source)
    if data is None:
        raise ConfigError(f"{source}: file is empty (expected a mapping with at least a 'robot' section)")
    return config_from_dict(data, source=source, base_dir=os.path.dirname(os.path.abspath(source)))


def read_yaml_file(path: str | os.PathLike[str]) -> Any:
    """Read a YAML file as :func:`load_config` does, without validating it as an oacli config: a size-bounded read
    of a regular file, UTF-8, the strict loader (YAML 1.2 scalars, duplicate keys and size caps refused).

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    Any
        The parsed document (None for an empty file).

    Raises
    ------
    ConfigError
        One line naming the file and the reason.
    """
    source = os.fspath(path)
    raw = _read_bounded(source)
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{source}: not valid UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start})"
        ) from None
    return _parse_yaml(text, source)


def parse_yaml_value(text: str, source: str) -> Any:
    """Parse one YAML value (e.g. of ``--set KEY=VALUE``) with the strict loader of config files.

    Parameters
    ----------
    text : str
    source : str
        Named in an error message (e.g. ``--set seed``).

    Returns
    -------
    Any

    Raises
    ------
    ConfigError
    """
    return _parse_yaml(text, source)


def _read_bounded(source: str) -> bytes:
    """Read a config file through a size-bounded read: a regular file only (no FIFO, device or folder), at most
    :data:`MAX_CONFIG_BYTES` bytes read whatever its size claims."""
    try:
        # O_NONBLOCK: opening a FIFO must not wait for a writer (it is refused right after).
        fd = os.open(source, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise ConfigError(f"{source}: file not found") from None
    except IsADirectoryError:
        raise ConfigError(f"{source}: is a directory, expected a YAML file") from None
    except OSError as exc:
        raise ConfigError(f"{source}: cannot read: {exc.strerror or exc}") from None
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):
            raise ConfigError(f"{source}: is a directory, expected a YAML file")
        if not stat.S_ISREG(mode):
            kind = "a FIFO" if stat.S_ISFIFO(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) \
                else "a socket" if stat.S_ISSOCK(mode) else "not a regular file"
            raise ConfigError(f"{source}: is {kind}, expected a regular YAML file")
        with os.fdopen(fd, "rb", closefd=False) as handle:
            raw = handle.read(MAX_CONFIG_BYTES + 1)
    except OSError as exc:
        raise ConfigError(f"{source}: cannot read: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{source}: file is too large (more than {MAX_CONFIG_BYTES} bytes)")
    return raw


def config_from_dict(
    data: Mapping[str, Any], source: str = "<dict>", base_dir: str | os.PathLike[str] | None = None
) -> OacliConfig:
    """Validate a configuration given as nested plain data (what ``yaml.safe_load`` returns).

    Parameters
    ----------
    data : Mapping
        The configuration; lists may also be tuples or 1-D/2-D numpy arrays.
    source : str
        Name used at the start of every problem line (normally the file path).
    base_dir : str or os.PathLike, optional
        Folder relative paths are resolved against (default: the current working directory).

    Returns
    -------
    OacliConfig
        The validated configuration.

    Raises
    ------
    ConfigError
        One line per problem, ``<source>: <field.path>: <value>: <reason>``.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: the top level must be a mapping of config sections, got {type(data).__name__}")
    context = {"base_dir": None if base_dir is None else os.fspath(base_dir)}
    try:
        return OacliConfig.model_validate(dict(data), context=context)
    except ValidationError as exc:
        raise ConfigError(format_validation_errors(exc, source)) from None
    except RecursionError:
        raise ConfigError(f"{source}: the data is nested too deeply") from None


def dump_config(cfg: OacliConfig) -> str:
    """The resolved configuration as safe YAML text that :func:`load_config` reads back into an equal model.

    Parameters
    ----------
    cfg : OacliConfig
        A validated configuration.

    Returns
    -------
    str
        YAML with every field explicit (defaults included), vectors in flow style, in field order.
    """
    data = cfg.model_dump(mode="json")
    body = yaml.dump(data, Dumper=_DUMPER, sort_keys=False, default_flow_style=False, allow_unicode=True)
    return (
        "# oacli resolved configuration: every default filled in (lengths m, times s, forces N, torques N·m)\n" + body
    )


def format_validation_errors(exc: ValidationError, source: str) -> list[str]:
    """Turn a pydantic ``ValidationError`` into ``<source>: <path>: <value>: <reason>`` lines, one per error."""
    lines = []
    for err in exc.errors(include_url=False):
        loc = tuple(part for part in err["loc"] if not _is_union_tag(part))
        path = ".".join(_loc_part(part) for part in loc) or "<top level>"
        value = _MISSING if err["type"] == "missing" else _short_repr(err.get("input"))
        lines.append(f"{source}: {path}: {value}: {_reason(err, loc)}")
    return lines


# --------------------------------------------------------------------------------------------------------------
# YAML
# --------------------------------------------------------------------------------------------------------------


class _FlowVectorDumper(yaml.SafeDumper):
    """Safe dumper writing lists of scalars (vectors) on one line and everything else in block style."""


def _represent_list(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
    flow = all(not isinstance(item, list | dict) for item in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_FlowVectorDumper.add_representer(list, _represent_list)

if hasattr(yaml, "CSafeDumper"):  # libyaml's emitter: the same text (same representers and resolvers), faster

    class _CFlowVectorDumper(yaml.CSafeDumper):  # type: ignore[misc,name-defined]
        """:class:`_FlowVectorDumper` with libyaml's C emitter (our own validated data only)."""

    _CFlowVectorDumper.add_representer(list, _represent_list)
    _DUMPERS: tuple[Any, ...] = (_FlowVectorDumper, _CFlowVectorDumper)
else:  # pragma: no cover - PyYAML built without libyaml
    _DUMPERS = (_FlowVectorDumper,)


class _NoDuplicateKeys:
    """Loader mixin rejecting duplicate keys in a mapping (PyYAML keeps the last silently)."""

    def construct_mapping(self, node: yaml.Node, deep: bool = False) -> dict:
        if isinstance(node, yaml.MappingNode):
            seen: set = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)  # type: ignore[attr-defined]
                try:
                    duplicate = key in seen
                    seen.add(key)
                except TypeError:  # unhashable key: the base class reports it
                    continue
                if duplicate:
                    raise yaml.constructor.ConstructorError(
                        "while constructing a mapping",
                        node.start_mark,
                        f"found duplicate key {key!r}",
                        key_node.start_mark,
                    )
        return super().construct_mapping(node, deep=deep)  # type: ignore[misc]


class _StrictSafeLoader(BoundedComposer, _NoDuplicateKeys, yaml.SafeLoader):
    """PyYAML's safe loader that also rejects duplicate keys in a mapping (PyYAML keeps the last silently) and
    lists, mappings or documents too large (:class:`oacli.config.sizes.BoundedComposer`)."""


if hasattr(yaml, "CSafeLoader"):  # libyaml's parser and composer: the same document, ~10x faster

    class _CStrictSafeLoader(_NoDuplicateKeys, yaml.CSafeLoader):  # type: ignore[misc,name-defined]
        """:class:`_StrictSafeLoader` with libyaml's scanner, parser and composer (the same resolvers and
        constructors, in Python); the size caps are checked on the composed document (:func:`_within_size_caps`)
        instead of while composing."""

    _LOADERS: tuple[Any, ...] = (_StrictSafeLoader, _CStrictSafeLoader)
else:  # pragma: no cover - PyYAML built without libyaml
    _CStrictSafeLoader = None  # type: ignore[misc,assignment]
    _LOADERS = (_StrictSafeLoader,)


# YAML 1.2 core schema scalars instead of PyYAML's YAML 1.1 ones: ``1:30`` (sexagesimal 90), ``0777`` (octal),
# ``1_000``, ``yes``/``no``/``on``/``off`` and dates stay text (refused where a number or a flag is expected);
# ``1e3`` / ``1.0e3`` are numbers (PyYAML 1.1 needs ``1.0e+3``).
_YAML11_SCALAR_TAGS = {"tag:yaml.org,2002:int", "tag:yaml.org,2002:float", "tag:yaml.org,2002:bool",
                       "tag:yaml.org,2002:timestamp"}
_YAML12_RESOLVERS = (
    ("tag:yaml.org,2002:bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"), list("tTfF")),
    ("tag:yaml.org,2002:int", re.compile(r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$"), list("-+0123456789")),
    ("tag:yaml.org,2002:float",
     re.compile(r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
                r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"),
     list("-+.0123456789")),
)
# The dumper uses the same rules, so that text such as "1e3" or "1:30" is quoted and reads back as text.
for _cls in (*_LOADERS, *_DUMPERS):
    _cls.yaml_implicit_resolvers = {
        first: [(tag, regexp) for tag, regexp in resolvers if tag not in _YAML11_SCALAR_TAGS]
        for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
    }
    for _tag, _regexp, _first in _YAML12_RESOLVERS:
        _cls.add_implicit_resolver(_tag, _regexp, _first)


def _construct_yaml12_int(loader: yaml.SafeLoader, node: yaml.Node) -> int:
    text = str(loader.construct_scalar(node))
    if text.startswith(("0o", "0x")):
        return int(text, 0)
    return int(text, 10)  # YAML 1.2: 0777 is 777, not octal


for _cls in _LOADERS:
    _cls.add_constructor("tag:yaml.org,2002:int", _construct_yaml12_int)

#: The dumper :func:`dump_config` uses (the C emitter when PyYAML has libyaml; ``tests/test_config.py`` checks both
#: write the same text).
_DUMPER: Any = _DUMPERS[-1]


def _within_size_caps(root: yaml.Node) -> bool:
    """Whether a composed document keeps :class:`oacli.config.sizes.BoundedComposer`'s caps: no list of more than
    ``MAX_CONFIG_LIST_ITEMS`` items, no mapping of more than ``MAX_CONFIG_MAPPING_KEYS`` keys, at most
    ``MAX_CONFIG_NODES`` nodes with every alias counting the nodes it repeats (False also for a recursive
    document: the pure-Python loader decides it)."""
    from oacli.config.sizes import MAX_CONFIG_LIST_ITEMS, MAX_CONFIG_MAPPING_KEYS, MAX_CONFIG_NODES

    sizes: dict[int, int] = {}
    open_nodes: set[int] = set()

    def size(node: yaml.Node) -> int | None:  # nodes under and including ``node``; None: over a cap or recursive
        key = id(node)
        if key in sizes:
            return sizes[key]
        if key in open_nodes:
            return None
        if isinstance(node, yaml.SequenceNode):
            if len(node.value) > MAX_CONFIG_LIST_ITEMS:
                return None
            children = list(node.value)
        elif isinstance(node, yaml.MappingNode):
            if len(node.value) > MAX_CONFIG_MAPPING_KEYS:
                return None
            children = [n for pair in node.value for n in pair]
        else:
            children = []
        open_nodes.add(key)
        total = 1
        for child in children:
            n = size(child)
            if n is None:
                return None
            total += n
            if total > MAX_CONFIG_NODES:
                return None
        open_nodes.discard(key)
        sizes[key] = total
        return total

    try:
        return size(root) is not None
    except RecursionError:
        return False


_FAST_FAILED = object()

FAST_PATH_MAX_SEPARATORS = 20_000
"""Documents with more commas and line breaks than this go straight to the pure-Python loader: libyaml composes the
whole document before the size caps are checked (a 1 MiB list of half a million items: 2 s), where the pure-Python
loader refuses it after :data:`oacli.config.sizes.MAX_CONFIG_LIST_ITEMS` items (the shipped configs: ~300 lines)."""


def _load_fast(text: str) -> Any:
    """The document through :class:`_CStrictSafeLoader`, or :data:`_FAST_FAILED` when libyaml is missing, the text
    is not a valid config document for it, or it breaks a size cap (then :func:`_parse_yaml` parses it with the
    pure-Python loader, which gives the one-line error the user sees: the same message either way)."""
    if _CStrictSafeLoader is None:  # pragma: no cover - PyYAML built without libyaml
        return _FAST_FAILED
    if text.count(",") + text.count("\n") > FAST_PATH_MAX_SEPARATORS:
        return _FAST_FAILED
    loader = _CStrictSafeLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        if not _within_size_caps(node):
            return _FAST_FAILED
        return loader.construct_document(node)
    except (yaml.YAMLError, RecursionError, ValueError, TypeError):
        return _FAST_FAILED
    finally:
        loader.dispose()


def _parse_yaml(text: str, source: str) -> Any:
    """``yaml.safe_load`` (plus duplicate-key detection) with every error turned into a one-line ConfigError.

    A document is parsed by libyaml (:func:`_load_fast`) and, when that fails or the document is too large, again
    by the pure-Python loader, whose error is the one raised: a valid config reads ~10x faster (``oacli report``
    reads a mission's stage configs), an invalid one is refused exactly as before."""
    data = _load_fast(text)
    if data is not _FAST_FAILED:
        return data
    try:
        return yaml.load(text, Loader=_StrictSafeLoader)  # a SafeLoader subclass: as safe as yaml.safe_load
    except ConfigSizeError as exc:
        raise ConfigSizeError(f"{source}: {exc}") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        what = " ".join(str(x) for x in (exc.problem, f"({exc.context})" if exc.context else None) if x)
        raise ConfigError(f"{source}: {where}invalid YAML: {_one_line(what or str(exc))}") from None
    except yaml.reader.ReaderError as exc:
        line = text.count("\n", 0, exc.position) + 1
        column = exc.position - (text.rfind("\n", 0, exc.position) + 1) + 1
        raise ConfigError(
            f"{source}: line {line}, column {column}: invalid YAML: unacceptable character "
            f"#x{exc.character if isinstance(exc.character, int) else ord(exc.character):04x}"
        ) from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: invalid YAML: {_one_line(str(exc))}") from None
    except RecursionError:
        raise ConfigError(f"{source}: invalid YAML: nested too deeply") from None


# --------------------------------------------------------------------------------------------------------------
# Message formatting
# --------------------------------------------------------------------------------------------------------------


def _one_line(text: str) -> str:
    return " ".join(text.split())


def _is_union_tag(part: str | int) -> bool:
    return isinstance(part, str) and len(part) > 2 and part.startswith("<") and part.endswith(">")


def _loc_part(part: str | int) -> str:
    text = str(part)
    if text and text.isprintable() and not any(c.isspace() for c in text):
        return text
    return repr(part)


def _short_repr(value: Any) -> str:
    try:
        text = _REPR.repr(value)
    except Exception:  # a value whose repr fails must not hide the real problem
        text = f"<{type(value).__name__}>"
    text = _one_line(text)
    return text if len(text) <= VALUE_REPR_CHARS else text[: VALUE_REPR_CHARS - 3] + "..."


_PRIOR_VARIANCE = ("give the prior's variances as one list variance: [m kg², Ixx, Iyy, Izz (kg·m²)²] in the same "
                   "section")
MOVED_KEYS: dict[tuple[str, str], str] = {
    ("disturbance", "mass_std_kg"): "W's σ_m is the robot model's: set robot.variance: [m kg², Ixx, Iyy, Izz "
    "(kg·m²)²] (σ_m = sqrt(robot.variance[0])); mass_sigmas stays here",
    ("margin", "mass_std_kg"): "a design's σ_m is its model's: robot.variance[0] for the planner, "
    "excitation.prior.variance[0] for the excitation [kg²]; margin.mass_sigmas: 0 for no mass derating",
    ("prior", "mass_variance_kg2"): _PRIOR_VARIANCE,
    ("prior", "inertia_variance_kg2m4"): _PRIOR_VARIANCE,
    ("prior", "mass_std_kg"): "give the model's variances as one list variance: [m kg², Ixx, Iyy, Izz (kg·m²)²] "
    "(the unit of robot.variance)",
    ("prior", "inertia_std_kgm2"): "give the model's variances as one list variance: [m kg², Ixx, Iyy, Izz "
    "(kg·m²)²] (the unit of robot.variance)",
}
"""Keys of earlier config versions and where their value lives now (issue 28: one robot model carries θ and its
covariance): ``(parent section, key)`` → the message of the exit-2 line."""


def _reason(err: Mapping[str, Any], loc: tuple[str | int, ...]) -> str:
    kind = err["type"]
    ctx = err.get("ctx") or {}
    if kind == "missing":
        return "required key is missing"
    if kind == "extra_forbidden":
        moved = MOVED_KEYS.get((str(loc[-2]), str(loc[-1]))) if len(loc) >= 2 else None
        if moved is not None:
            return f"no longer a key: {moved}"
        allowed = _allowed_keys(loc[:-1])
        if not allowed:
            return "unknown key"
        close = _suggest(str(loc[-1]), allowed)
        if close:
            return f"unknown key (did you mean '{close}'?)"
        return f"unknown key (allowed: {', '.join(allowed)})"
    simple = {
        "greater_than": lambda: f"must be > {ctx['gt']}",
        "greater_than_equal": lambda: f"must be >= {ctx['ge']}",
        "less_than": lambda: f"must be < {ctx['lt']}",
        "less_than_equal": lambda: f"must be <= {ctx['le']}",
        "literal_error": lambda: f"must be {ctx['expected']}",
        "string_pattern_mismatch": lambda: (
            "must contain only letters, digits, '_', '.' and '-' (not starting with '.' or '-')"
        ),
        "string_too_long": lambda: f"must be at most {ctx['max_length']} characters",
        "string_type": lambda: "must be a string",
        "int_type": lambda: "must be an integer",
        "int_from_float": lambda: "must be an integer",
        "int_parsing": lambda: "must be an integer",
        "model_type": lambda: "must be a mapping",
        "model_attributes_type": lambda: "must be a mapping",
        "dict_type": lambda: "must be a mapping",
        "tuple_type": lambda: "must be a list",
        "list_type": lambda: "must be a list",
        "recursion_loop": lambda: "refers to itself (recursive YAML alias)",
    }
    if kind in simple:
        try:
            return simple[kind]()
        except KeyError:
            pass
    return _one_line(str(err.get("msg", kind)))


def _suggest(key: str, allowed: list[str]) -> str | None:
    """The allowed key the user most likely meant: a prefix/extension of ``key`` or a close spelling."""
    lowered = key.lower()
    if len(lowered) >= 3:
        for name in allowed:
            if name.startswith(lowered) or lowered.startswith(name):
                return name
    close = difflib.get_close_matches(key, allowed, n=1, cutoff=0.7)
    return close[0] if close else None


def _models_in(annotation: Any) -> tuple[type[BaseModel] | None, bool]:
    """The model class inside a field annotation and whether it sits in a container (list/tuple/dict)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation, False
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin is typing.Annotated:
        return _models_in(args[0])
    container = origin in (tuple, list, dict)
    for arg in args:
        model, nested = _models_in(arg)
        if model is not None:
            return model, container or nested
    return None, False


def _allowed_keys(loc: tuple[str | int, ...]) -> list[str]:
    """Field names of the model at ``loc`` (for 'did you mean' hints); empty when it cannot be determined."""
    model: type[BaseModel] = OacliConfig
    i = 0
    while i < len(loc):
        field = model.model_fields.get(str(loc[i]))
        if field is None:
            return []
        sub, in_container = _models_in(field.annotation)
        if sub is None:
            return []
        i += 2 if in_container else 1
        model = sub
    return list(model.model_fields)


__all__ = [
    "ConfigError",
    "ControllerConfig",
    "ControllerWeights",
    "DisturbanceConfig",
    "EnvironmentConfig",
    "KeepInBox",
    "KeepOutEllipsoid",
    "OacliConfig",
    "Pose",
    "ReferenceConfig",
    "RobotConfig",
    "SensorsConfig",
    "SimulationConfig",
    "TruthConfig",
    "config_from_dict",
    "dump_config",
    "format_validation_errors",
    "load_config",
]
