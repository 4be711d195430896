"""Command lines generated from argument dataclasses, in the CleanRL way.

Each field of an arguments dataclass becomes ``--field-name`` with the field's type, its
default, and the docstring written under it as help text. ``bool`` fields become
``--x/--no-x``; ``choices`` and hidden old spellings come from the field's metadata::

    @dataclass
    class Args:
        env: str = field(default="lidar", metadata={"choices": ("lidar", "fused")})
        \"\"\"Which env.\"\"\"
        slots: int = field(default=1, metadata={"aliases": ("--n-envs",)})
        \"\"\"Parallel envs.\"\"\"

An alias is accepted and not shown in ``--help`` (kept for one release after a rename).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import os
import textwrap
import types
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")

LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")
LOG_LEVEL_ENV_VAR = "ROVERAV_LOG_LEVEL"
"""Set by ``rover-pair --log-level`` for its trainer."""


def default_log_level(fallback: str = "INFO") -> str:
    """``$ROVERAV_LOG_LEVEL`` (set by rover-pair) when it names a level, else ``fallback``."""
    level = os.environ.get(LOG_LEVEL_ENV_VAR, "").upper()
    return level if level in LOG_LEVELS else fallback


def field_docs(cls: type) -> dict[str, str]:
    """The docstring under each annotated attribute of ``cls`` (``{}`` if no source)."""
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    body = ast.parse(source).body[0]
    assert isinstance(body, ast.ClassDef)
    docs: dict[str, str] = {}
    items = body.body
    for node, nxt in zip(items, items[1:], strict=False):
        if (
            isinstance(node, ast.AnnAssign)
            and isinstance(node.target, ast.Name)
            and isinstance(nxt, ast.Expr)
            and isinstance(nxt.value, ast.Constant)
            and isinstance(nxt.value.value, str)
        ):
            docs[node.target.id] = " ".join(nxt.value.value.split())
    return docs


def _base_type(tp: Any) -> tuple[Any, bool]:
    """(the type to parse with, whether None is allowed) of an annotation."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0], True
    return tp, False


def build_parser(cls: type, prog: str, description: str, epilog: str | None = None
                 ) -> argparse.ArgumentParser:  # fmt: skip
    """An ``ArgumentParser`` with one option per field of dataclass ``cls``."""
    parser = argparse.ArgumentParser(
        prog=prog, description=description, epilog=epilog,
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )  # fmt: skip
    docs = field_docs(cls)
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if not f.init or f.metadata.get("cli") is False:
            continue
        tp, _optional = _base_type(hints[f.name])
        flag = "--" + f.name.replace("_", "-")
        default = (
            f.default if f.default is not dataclasses.MISSING
            else f.default_factory() if f.default_factory is not dataclasses.MISSING
            else None
        )  # fmt: skip
        kwargs: dict[str, Any] = {"dest": f.name, "default": default,
                                  "help": docs.get(f.name, f.metadata.get("help", ""))}
        if "choices" in f.metadata:
            kwargs["choices"] = tuple(f.metadata["choices"])
        if tp is bool:
            kwargs["action"] = argparse.BooleanOptionalAction
        else:
            kwargs["type"] = f.metadata.get("parse", tp if tp in (int, float, str, Path) else str)
            if "choices" not in kwargs:
                kwargs["metavar"] = f.metadata.get("metavar", f.name.upper())
        parser.add_argument(flag, **kwargs)
        for alias in f.metadata.get("aliases", ()):
            hidden = dict(kwargs, help=argparse.SUPPRESS, default=argparse.SUPPRESS)
            hidden.pop("metavar", None)
            parser.add_argument(alias, **hidden)
    return parser


def parse_into(cls: type[T], parser: argparse.ArgumentParser,
               argv: Sequence[str] | None = None) -> T:  # fmt: skip
    """Parse ``argv`` with ``parser`` (from :func:`build_parser`) into an instance of ``cls``."""
    ns = parser.parse_args(argv)
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    return cls(**{k: v for k, v in vars(ns).items() if k in names})


def plain(obj: Any) -> dict[str, Any]:
    """A dataclass as a JSON-ready dict (paths as strings)."""
    return {k: str(v) if isinstance(v, Path) else v for k, v in dataclasses.asdict(obj).items()}


__all__ = [
    "LOG_LEVELS",
    "LOG_LEVEL_ENV_VAR",
    "build_parser",
    "default_log_level",
    "field_docs",
    "parse_into",
    "plain",
]
