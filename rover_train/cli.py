"""Command lines generated from argument dataclasses, in the CleanRL way.

Each field of an arguments dataclass becomes ``--field-name`` with the field's type, its
default, and the docstring written under it as help text. ``bool`` fields become
``--x/--no-x``; ``choices``, ``parse`` (the argparse type), ``nargs``/``const`` (an option
whose value may be left out) come from the field's metadata::

    @dataclass
    class Args:
        env: str = field(default="lidar", metadata={"choices": ("lidar", "fused")})
        \"\"\"Which env.\"\"\"
        slots: int = shared_field(Connection, "slots")   # roverav_cli's --slots

A field taken from a group of :mod:`roverav_cli` (``shared_field``) is that group's flag: its
type, default, choices and help, the same in every command.

Artefact recipes are frozen dataclasses of the same kind, stored in the artefact
(:func:`recipe_dict` / :func:`recipe_from_dict`); a maker's command line is the recipe's fields
plus its run options (:func:`build_parser` takes several classes), ``--recipe FILE`` starts
from the recipe stored in an artefact (:func:`recipe_defaults`) and ``--log-level`` is
always there.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import logging
import sys
import textwrap
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

from roverav_cli import LOG_LEVEL_ENV_VAR, LOG_LEVELS, Connection, add_group, default_log_level

T = TypeVar("T")
U = TypeVar("U")


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


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows each option's default, unless its help already says it (a shared flag's)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        return text if "(default" in text else super()._get_help_string(action)


def _field_default(f: dataclasses.Field[Any], defaults: Any) -> Any:
    if defaults is not None:
        return getattr(defaults, f.name)
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None


def build_parser(cls: type | Sequence[type], prog: str, description: str,
                 epilog: str | None = None, *,
                 defaults: Mapping[type, Any] | None = None,
                 positional: Sequence[str] = ()) -> argparse.ArgumentParser:  # fmt: skip
    """An ``ArgumentParser`` with one option per field of each dataclass in ``cls``, and
    ``--log-level`` unless a class has a ``log_level`` field.

    :param defaults: an instance per class whose values replace the fields' defaults (a
        recipe read from an artefact).
    :param positional: field names taken as positional arguments instead of options.
    """
    classes = [cls] if isinstance(cls, type) else list(cls)
    parser = argparse.ArgumentParser(
        prog=prog, description=description, epilog=epilog,
        formatter_class=_HelpFormatter,
    )  # fmt: skip
    has_log_level = False
    for c in classes:
        docs = field_docs(c)
        hints = typing.get_type_hints(c)
        instance = (defaults or {}).get(c)
        for f in dataclasses.fields(c):
            if not f.init or f.metadata.get("cli") is False:
                continue
            has_log_level |= f.name == "log_level"
            tp, _optional = _base_type(hints[f.name])
            default = _field_default(f, instance)
            # a shared flag's help is its group's; argparse expands %-formats in help: a
            # docstring's "70 %" must reach it as "%%"
            text = (f.metadata["help"] if f.metadata.get("shared") else
                    docs.get(f.name, f.metadata.get("help", ""))).replace("%", "%%")  # fmt: skip
            kwargs: dict[str, Any] = {"default": default, "help": text}
            if "choices" in f.metadata:
                kwargs["choices"] = tuple(f.metadata["choices"])
            if "nargs" in f.metadata:  # e.g. an optional value: --ray [ADDRESS]
                kwargs["nargs"] = f.metadata["nargs"]
                kwargs["const"] = f.metadata.get("const")
            if tp is bool and f.name not in positional:
                kwargs["action"] = argparse.BooleanOptionalAction
            else:
                kwargs["type"] = f.metadata.get(
                    "parse", tp if tp in (int, float, str, Path) else str
                )
                if "choices" not in kwargs:
                    kwargs["metavar"] = f.metadata.get("metavar", f.name.upper())
            if f.name in positional:
                kwargs.pop("default")
                parser.add_argument(f.name, **kwargs)
                continue
            flag = "--" + f.name.replace("_", "-")
            parser.add_argument(flag, dest=f.name, **kwargs)
    if not has_log_level:
        add_group(parser, Connection, only=("log_level",))
    return parser


def parse_into(cls: type[T], parser: argparse.ArgumentParser,
               argv: Sequence[str] | None = None) -> T:  # fmt: skip
    """Parse ``argv`` with ``parser`` (from :func:`build_parser`) into an instance of ``cls``."""
    ns = parser.parse_args(argv)
    return instance_from(cls, ns)


def instance_from(cls: type[T], ns: argparse.Namespace) -> T:
    """The instance of dataclass ``cls`` made of the same-named attributes of ``ns``."""
    names = {f.name for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
    return cls(**{k: v for k, v in vars(ns).items() if k in names})


def recipe_dict(recipe: Any) -> dict[str, Any]:
    """A recipe dataclass as plain data (lists for tuples, strings for paths; nested
    dataclasses as dicts) that ``torch.load(weights_only=True)`` and JSON can hold."""

    def conv(v: Any) -> Any:
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return {f.name: conv(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, Path):
            return str(v)
        if isinstance(v, tuple | list):
            return [conv(x) for x in v]
        if isinstance(v, dict):
            return {str(k): conv(x) for k, x in v.items()}
        return v

    return typing.cast(dict[str, Any], conv(recipe))


def _coerce(tp: Any, value: Any) -> Any:
    if value is None:
        return None
    tp, _ = _base_type(tp)
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp) and isinstance(value, dict):
        return recipe_from_dict(typing.cast(type, tp), value)
    if tp is Path:
        return Path(value)
    if origin is tuple:
        args = typing.get_args(tp)
        inner = args[0] if args else Any
        return tuple(_coerce(inner, v) for v in value)
    if origin is dict:
        _, vt = typing.get_args(tp) or (Any, Any)
        return {k: _coerce(vt, v) for k, v in value.items()}
    if tp is float and isinstance(value, int):
        return float(value)
    return value


def recipe_from_dict(cls: type[T], data: Mapping[str, Any]) -> T:
    """The recipe ``cls`` from :func:`recipe_dict`'s output; raises ``ValueError`` naming
    the fields it does not know (a recipe from a newer version)."""
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ValueError(f"{cls.__name__} has no field(s) {unknown}: the recipe was written "
                         "by another version of roverav")  # fmt: skip
    hints = typing.get_type_hints(cls)
    return cls(**{k: _coerce(hints[k], v) for k, v in data.items()})


def recipe_defaults(argv: Sequence[str] | None,
                    read: Callable[[Path], Any]) -> tuple[Any, list[str]]:  # fmt: skip
    """``(recipe, rest of argv)``: the recipe stored in the artefact named by ``--recipe
    FILE`` (``read(path)`` returns it), or ``(None, argv)`` without that option. Exits with
    a usage error naming the file when it holds no readable recipe."""
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--recipe", type=Path, default=None)
    ns, rest = pre.parse_known_args(list(sys.argv[1:] if argv is None else argv))
    if ns.recipe is None:
        return None, rest
    try:
        return read(ns.recipe), rest
    except (OSError, ValueError, KeyError, RuntimeError) as exc:
        print(f"--recipe {ns.recipe}: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


def add_recipe_option(parser: argparse.ArgumentParser, what: str) -> None:
    """Document ``--recipe FILE`` (read before parsing by :func:`recipe_defaults`)."""
    parser.add_argument("--recipe", type=Path, metavar="FILE",
                        help=f"start from the recipe stored in {what} (the command that "
                        "remakes it); options given beside it override its values")


def parse_recipe_command(
    recipe_cls: type[T], run_cls: type[U], prog: str, description: str,
    read: Callable[[Path], T], argv: Sequence[str] | None = None, what: str = "the artefact",
) -> tuple[T, U, argparse.Namespace]:  # fmt: skip
    """A maker's command line: ``recipe_cls``'s fields (their defaults, or the recipe stored
    in the file of ``--recipe FILE``, read by ``read``), ``run_cls``'s, ``--recipe`` and
    ``--log-level``. Returns the recipe, the run options and the namespace (for extra
    checks), with logging set up at the chosen level. A recipe with a ``problem()`` method
    that returns a message is a usage error."""
    stored, rest = recipe_defaults(argv, read)
    parser = build_parser((recipe_cls, run_cls), prog, description,
                          defaults={recipe_cls: stored} if stored is not None else None)
    add_recipe_option(parser, what)
    ns = parser.parse_args(rest)
    recipe, run = instance_from(recipe_cls, ns), instance_from(run_cls, ns)
    problem = getattr(recipe, "problem", lambda: None)()
    if problem:
        parser.error(problem)
    setup_logging(ns.log_level)
    return recipe, run, ns


def setup_logging(level: str) -> None:
    """Root logging at ``level`` for a command line (library code never calls this)."""
    logging.basicConfig(level=level.upper(), format="%(levelname)s %(name)s: %(message)s")


def plain(obj: Any) -> dict[str, Any]:
    """A dataclass as a JSON-ready dict (paths as strings)."""
    return {k: str(v) if isinstance(v, Path) else v for k, v in dataclasses.asdict(obj).items()}


__all__ = [
    "LOG_LEVELS",
    "LOG_LEVEL_ENV_VAR",
    "add_recipe_option",
    "build_parser",
    "default_log_level",
    "field_docs",
    "instance_from",
    "parse_into",
    "parse_recipe_command",
    "plain",
    "recipe_defaults",
    "recipe_dict",
    "recipe_from_dict",
    "setup_logging",
]
