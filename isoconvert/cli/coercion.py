"""Option values turned into Python values without importing pydantic.

typer (0.2x) coerces every option value, the defaults included, through a
pydantic ``TypeAdapter`` built per parameter: importing pydantic and building the
adapters of ``convert``'s sixty options costs about 0.1 s of every run, more
than reading and meshing a small volume. Our options are plain (``str``,
``int``, ``float``, ``Path``, ``bool``, a few enums, ``list[str]``; no parsers,
no ranges), so :func:`plain_coercion` gives each such parameter a coercion that
does what typer's adapter does for the common values (a word, a plain decimal
number, a path, an enum member or its name) and hands every other value (a
malformed number, for instance) to typer's own adapter, which then gives its
usual result or error message. The tests compare both on many values.

It relies on typer's internals (``_runtime_param``, ``_coercion.RuntimeParam``,
``_param_types``); with a typer that lacks them it does nothing and typer
coerces as it always did.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

try:  # typer's internals of the pydantic-based coercion (typer 0.2x)
    from typer._coercion import RuntimeParam, build_runtime_param
    from typer._param_types import coerce_cli_choice, coerce_cli_path
except ImportError:  # another typer: it coerces as it does
    RuntimeParam = None  # type: ignore[assignment,misc]

#: Numbers written plainly, which int() / float() and pydantic read alike.
_INT = re.compile(r"[+-]?[0-9]{1,18}")
_FLOAT = re.compile(r"[+-]?([0-9]{1,30}(\.[0-9]{0,30})?|\.[0-9]{1,30})([eE][+-]?[0-9]{1,2})?")

#: What a plain coercion cannot decide (the value goes to typer's adapter).
_UNDECIDED = object()


def _leaf(annotation: Any, value: Any, param: Any, ctx: Any) -> Any:
    """``value`` as ``annotation``, or ``_UNDECIDED``."""
    kind = type(value)
    if annotation is str:
        return value if kind is str else _UNDECIDED
    if annotation is int:
        if kind is int:
            return value
        return int(value) if kind is str and _INT.fullmatch(value) else _UNDECIDED
    if annotation is float:
        if kind is float or kind is int:
            return float(value)
        return float(value) if kind is str and _FLOAT.fullmatch(value) else _UNDECIDED
    if annotation is bool:
        return value if kind is bool else _UNDECIDED
    if isinstance(annotation, type) and issubclass(annotation, Enum):
        info = param.type_descriptor.parameter_info
        try:
            return coerce_cli_choice(
                value, choices=list(annotation), case_sensitive=info.case_sensitive, ctx=ctx
            )
        except ValueError:  # not a choice: typer's message
            return _UNDECIDED
    if annotation is Path:
        info = param.type_descriptor.parameter_info
        if kind is str and value:
            value = Path(value)
        if not isinstance(value, Path) or info.path_type not in (None, Path):
            return _UNDECIDED
        return coerce_cli_path(value, info, path_type=Path, param=param, ctx=ctx)
    return _UNDECIDED


def _plain(annotation: Any) -> bool:
    """Whether :func:`_leaf` knows ``annotation`` (a list of one is a list of it)."""
    if getattr(annotation, "__origin__", None) is list:
        (annotation,) = annotation.__args__
    if annotation in (str, int, float, bool, Path):
        return True
    return isinstance(annotation, type) and issubclass(annotation, Enum)


if RuntimeParam is not None:

    @dataclass(frozen=True)
    class PlainRuntimeParam(RuntimeParam):
        """typer's coercion of one parameter, without pydantic for plain values."""

        def _coerce_value(self, value: Any, param: Any, ctx: Any) -> Any:
            annotation = self.annotation
            if getattr(annotation, "__origin__", None) is list:  # as typer: a list
                if isinstance(value, (list, tuple)):
                    items = [_leaf(annotation.__args__[0], v, param, ctx) for v in value]
                    if not any(item is _UNDECIDED for item in items):
                        return items
                return self._typer(value, param, ctx)
            out = _leaf(annotation, value, param, ctx)
            return self._typer(value, param, ctx) if out is _UNDECIDED else out

        def _typer(self, value: Any, param: Any, ctx: Any) -> Any:
            # typer's own adapter (imports pydantic): its result, or its error message
            own = build_runtime_param(param.type_descriptor)
            return own._coerce_value(value, param=param, ctx=ctx)


def plain_coercion(params: list) -> None:
    """Give each of ``params`` (a command's typer parameters) whose type is plain
    and that has no parser, range or file mode a coercion without pydantic."""
    if RuntimeParam is None:
        return
    for param in params:
        desc = getattr(param, "type_descriptor", None)
        if desc is None or getattr(param, "_runtime_param", False) is not None:
            continue
        info = desc.parameter_info
        if info.parser is not None or desc.is_file or desc.is_ranged:
            continue
        if not _plain(desc.annotation):
            continue
        param._runtime_param = PlainRuntimeParam(parameter_info=info, annotation=desc.annotation)
