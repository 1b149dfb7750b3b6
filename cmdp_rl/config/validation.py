"""Declared config constraints, and the one-line error a violated one gives.

A component declares its options as an :func:`options` dataclass beside its code, each field's allowed range in
its type (``gamma: Annotated[float, Field(ge=0, lt=1)] = 0.99``). pydantic checks them; this module turns its report
into one line naming the field and everything it allows (``algo.gamma must be in [0, 1), got 1.0``), not the one
bound that failed. A rule across fields is the component's ``check(self, run)``, calling :func:`require`."""

from __future__ import annotations

import dataclasses
import math
from typing import Annotated, Any, Literal, Mapping, Sequence, TypeVar, Union, get_args, get_origin

from pydantic import AfterValidator, ConfigDict, Field, StrictBool, ValidationError
from pydantic.dataclasses import dataclass as _pydantic_dataclass


class ConfigError(ValueError):
    """A config value is missing, of the wrong type, or out of range."""


AUTO = "auto"  # batch-shape options that follow env.num_envs (config.resolve_auto)

# Unknown keys are reported by build() with the allowed names; strict bools refuse "yes" and 1.
_OPTIONS = ConfigDict(extra="forbid", validate_assignment=False)

T = TypeVar("T")


def options(cls: type[T]) -> type[T]:
    """Declare ``cls`` as a validated options dataclass (pydantic checks every field on creation,
    ``dataclasses.replace`` included). Plain ``dataclasses`` functions keep working on it."""
    return _pydantic_dataclass(cls, config=_OPTIONS)


def finite(**kw: Any) -> Any:
    """A ``Field`` of finite floats with the given bounds (``ge``, ``gt``, ``le``, ``lt``)."""
    return Field(allow_inf_nan=False, **kw)


# The shapes most options take, declared once.
PositiveInt = Annotated[int, Field(ge=1)]
NonNegativeInt = Annotated[int, Field(ge=0)]
PositiveFloat = Annotated[float, finite(gt=0)]
NonNegativeFloat = Annotated[float, finite(ge=0)]
Discount = Annotated[float, finite(ge=0, lt=1)]
UnitOpen = Annotated[float, finite(gt=0, lt=1)]  # (0, 1)
Bool = StrictBool
AutoInt = Annotated[Union[PositiveInt, Literal["auto"]], Field(description=f"a positive integer or {AUTO!r}")]
# Off, or the number of iterations a schedule spans ("auto": the run's; true means "auto").
AutoSpan = Annotated[
    Union[Annotated[StrictBool, AfterValidator(lambda on: AUTO if on else False)], PositiveInt, Literal["auto"]],
    Field(description=f"false, a positive integer or {AUTO!r} (true)"),
]


def _fmt(x: Any) -> str:
    return str(int(x)) if isinstance(x, float) and x.is_integer() else str(x)


def _describe(annotation: Any, metadata: list) -> str:
    """What a field allows, in words, from its type and its declared bounds."""
    for m in metadata:
        if getattr(m, "description", None):
            return m.description
    origin = get_origin(annotation)
    if origin is Annotated:
        base, *extra = get_args(annotation)
        return _describe(base, [*extra, *metadata])
    if origin is Literal:
        return f"one of {get_args(annotation)}"
    if origin is Union:
        opts = [a for a in get_args(annotation) if a is not type(None)]
        inner = " or ".join(_describe(a, metadata) for a in opts)
        return f"null or {inner}" if len(opts) < len(get_args(annotation)) else inner
    if origin is list:
        (item,) = get_args(annotation) or (Any,)
        return f"a list of {_describe(item, []).removeprefix('a ').removeprefix('an ')}s"
    # annotated_types' Ge, Gt, Le, Lt and Interval, each holding its bound under its own name
    bounds = {k: getattr(m, k) for m in metadata for k in ("ge", "gt", "le", "lt") if getattr(m, k, None) is not None}
    if hasattr(annotation, "__pydantic_fields__"):  # a nested node (build's _nodes)
        return f"a mapping of its options ({', '.join(annotation.__pydantic_fields__)})"
    if annotation is bool:
        return "true or false"
    if annotation is str:
        return "a string"
    noun = {int: "an integer", float: "a number"}.get(annotation)
    if noun is None:
        return f"a {getattr(annotation, '__name__', annotation)}"
    lo = ("[", bounds["ge"]) if "ge" in bounds else ("(", bounds["gt"]) if "gt" in bounds else None
    hi = (bounds["le"], "]") if "le" in bounds else (bounds["lt"], ")") if "lt" in bounds else None
    if lo and hi:
        return f"in {lo[0]}{_fmt(lo[1])}, {_fmt(hi[0])}{hi[1]}"
    if lo == ("(", 0) or (annotation is int and lo == ("[", 1)):
        return f"a positive {noun.split()[1]}"
    if lo:
        return f"{noun} {'>=' if lo[0] == '[' else '>'} {_fmt(lo[1])}"
    return f"{noun} {'<=' if hi[1] == ']' else '<'} {_fmt(hi[0])}" if hi else noun


def allowed(cls: type, name: str) -> str:
    """What field ``name`` of the options class ``cls`` allows, in words."""
    info = cls.__pydantic_fields__[name]
    return _describe(info.annotation, [info, *info.metadata])


def require(ok: bool, name: str, allowed_values: str, value: Any) -> None:
    """Raise the toolkit's one-line :class:`ConfigError` unless ``ok``."""
    if not ok:
        raise ConfigError(f"{name} must be {allowed_values}, got {value!r}")


def _dotted(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else name


def build(cls: type[T], data: Mapping[str, Any], prefix: str) -> T:
    """``cls(**data)``, or a :class:`ConfigError` naming the first bad field (``prefix.field``)."""
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(data) - set(names))
    if unknown:
        raise ConfigError(f"{prefix or 'config'}: unknown option(s) {unknown}; allowed: {sorted(names)}")
    data = {**data, **_nodes(cls, data, prefix)}
    try:
        return cls(**data)
    except ValidationError as exc:
        err = exc.errors()[0]
        field = str(err["loc"][0]) if err["loc"] else ""
        if field not in names:  # not a field's value: pass pydantic's own words on
            raise ConfigError(f"{prefix or 'config'}: {err['msg']}") from None
        raise ConfigError(f"{_dotted(prefix, field)} must be {allowed(cls, field)}, got {data.get(field)!r}") from None


def _node_classes(info: Any) -> tuple[str | None, dict[Any, type]] | None:
    """A field's nested option classes: ``(None, {None: cls})`` for an :func:`options` class, ``(key, {value: cls})``
    for a union of them told apart by the field ``key`` (``algo.multiplier``'s ``kind``); None for any other field."""
    node = info.annotation
    if isinstance(node, type) and hasattr(node, "__pydantic_fields__"):
        return None, {None: node}
    key = getattr(info, "discriminator", None)
    if key and get_origin(node) is Union:
        return key, {c.__pydantic_fields__[key].default: c for c in get_args(node)}
    return None


def _nodes(cls: type, data: Mapping[str, Any], prefix: str) -> dict[str, Any]:
    """The nested option nodes among ``data`` (a field whose type is itself an :func:`options` class, or a union of
    them chosen by a key, e.g. ``algo.multiplier`` by its ``kind``) built first, so that an error names the nested field
    (``algo.multiplier.lr``). A mapping fills in only what it names: the rest are the values of the field's default
    where that is of the same class (the algorithm's own defaults of the node, as Hydra's merge of a YAML node gives),
    else the class's own; an instance is validated again (:func:`recheck`)."""
    out = {}
    for f in dataclasses.fields(cls):
        classes = _node_classes(cls.__pydantic_fields__[f.name])
        if f.name not in data or classes is None:
            continue
        key, by_key = classes
        value, where = data[f.name], _dotted(prefix, f.name)
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else None
        if isinstance(value, tuple(by_key.values())):
            value = {g.name: getattr(value, g.name) for g in dataclasses.fields(value)}
        if not isinstance(value, Mapping):
            continue
        chosen = value.get(key, getattr(default, key, None)) if key else None
        if chosen not in by_key:
            raise ConfigError(f"{_dotted(where, key)} must be one of {tuple(by_key)}, got {chosen!r}")
        node = by_key[chosen]
        unknown = sorted(set(value) - {g.name for g in dataclasses.fields(node)})
        if key and unknown:  # e.g. another kind's step, set by the algorithm's config for its default kind
            own = [g.name for g in dataclasses.fields(node)]
            raise ConfigError(
                f"{where}: {key} {chosen} has no option(s) {unknown}; its options: {own} "
                f"(drop one the algorithm's config sets for another {key} with ~{_dotted(where, unknown[0])})"
            )
        if isinstance(default, node):
            value = {**{g.name: getattr(default, g.name) for g in dataclasses.fields(default)}, **value}
        out[f.name] = build(node, value, where)
    return out


def recheck(obj: T, prefix: str) -> T:
    """``obj`` validated again (after its fields were assigned directly); returns a new instance."""
    return build(type(obj), {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}, prefix)


def is_finite(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def per_constraint(value: float | Sequence[float], field: str, cost_names: Sequence[str]) -> list[float]:
    """``value`` (a number, or a list of K numbers) as K numbers, one per cost of ``cost_names``; a list of another
    length is a config error naming ``field`` and K. Only the env tells K, so this runs where the env is known (the
    algorithm built on the agent, the early-terminated env), before the run writes anything."""
    k = len(cost_names)
    # None is "the task's budget", which config.validate fills in before anything is built.
    require(value is not None, field, "a number or a list of numbers (config.validate fills in the task's)", value)
    if isinstance(value, (int, float)):
        return [float(value)] * k
    values = list(value)
    require(
        len(values) == k,
        field,
        f"a number or a list of {k} numbers, one per cost of the env ({', '.join(cost_names)})",
        values,
    )
    return [float(v) for v in values]
