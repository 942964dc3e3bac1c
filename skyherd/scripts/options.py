"""Command-line options generated from a frozen dataclass: one field, one option.

A command declares its options once, as the fields of a frozen dataclass: the field's name gives
the flag (`dqn_steps` → `--dqn-steps`), its default and type the option's, and the comment beside
it (or, when longer, the docstring under it) its help; `opt(default, **kw)` hands more keywords
to `add_argument` (choices, metavar, nargs, action) but for `aliases`, more flags of the same
option, and `flag`, the option's flag when it is not the field's name (`dest` its attribute). A command showing a lower
layer's parameters (which carry no argparse) gives the same keywords to `add_options` instead. A tuple field takes one or more values (`nargs="+"`, its default given as a list); a bool
field whose default is False is a flag (`store_true`), one whose default is True a `--x/--no-x`
pair. The help shows the default (scripts.cli.DefaultsFormatter).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import functools
import inspect
import sys
import textwrap
import types
import typing


def opt(default, **kw) -> dataclasses.Field:
    """A field whose option gets `kw` as `add_argument` keywords besides the generated ones."""
    return dataclasses.field(default=default, metadata=kw)


@functools.cache
def _module_classes(module: str) -> tuple[list[str], dict[str, ast.ClassDef]]:
    """A module's source lines and its top-level classes, parsed once per process (each
    command's parser reads several dataclasses of one module; `inspect.getsource` parsed the
    whole module again for each class)."""
    src = inspect.getsource(sys.modules[module])
    classes = {n.name: n for n in ast.parse(src).body if isinstance(n, ast.ClassDef)}
    return src.splitlines(), classes


def _class_body(cls: type) -> tuple[list[str], list[ast.stmt]]:
    """The source lines holding `cls` and the statements of its body (line numbers index the
    lines): its module's, for a top-level class; else its own source."""
    lines, classes = _module_classes(cls.__module__)
    if cls.__qualname__ in classes:
        return lines, classes[cls.__qualname__].body
    src = textwrap.dedent(inspect.getsource(cls))
    return src.splitlines(), ast.parse(src).body[0].body


def field_docs(cls: type) -> dict[str, str]:
    """Each field's help text: the docstring under the field, else the comment beside it."""
    lines, body = _class_body(cls)
    docs = {}
    for a, b in zip(body, [*body[1:], None]):
        if not isinstance(a, ast.AnnAssign):
            continue
        if isinstance(b, ast.Expr) and isinstance(b.value, ast.Constant):
            docs[a.target.id] = " ".join(str(b.value.value).split())
        elif "  # " in lines[a.end_lineno - 1]:
            docs[a.target.id] = lines[a.end_lineno - 1].split("  # ", 1)[1]
    return docs


def values(cls: type, args: argparse.Namespace, **more):
    """The dataclass `cls` made of the options `add_options` generated from its fields (a field
    with no option keeps its default) and of `more`."""
    names = [f.name for f in dataclasses.fields(cls) if hasattr(args, f.name)]
    return cls(**{n: getattr(args, n) for n in names}, **more)


def _value_type(hint) -> tuple[type, bool]:
    """The type of one value of an option (`int` for `int`, `int | None`, `tuple[int, ...]`) and
    whether the option takes several."""
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        hint = next(a for a in typing.get_args(hint) if a is not type(None))
    if typing.get_origin(hint) is tuple:
        return typing.get_args(hint)[0], True
    return hint, False


def add_options(
    parser: argparse.ArgumentParser,
    cls: type | tuple[type, ...],
    skip: tuple[str, ...] = (),
    only: tuple[str, ...] | None = None,
    **given: dict,
) -> None:
    """One option of `parser` per field of the dataclass `cls` (or of each of several, in turn;
    a name two have is the first's) but those in `skip`, or those named in `only`, in its order
    (see the module's docstring); `given[name]`: more keywords for that option, as `opt`'s."""
    classes = cls if isinstance(cls, tuple) else (cls,)
    fields: dict[str, tuple] = {}
    for c in classes:
        for f in dataclasses.fields(c):
            fields.setdefault(f.name, (f, c))
    helps = {c: field_docs(c) for c in classes}
    hints = {c: typing.get_type_hints(c) for c in classes}
    for name in only if only is not None else fields:
        f, c = fields[name]
        if name in skip:
            continue
        kw = {**f.metadata, **given.get(name, {})}
        if "flag" in kw and "choices" not in kw:  # its value named after the flag, as before
            kw.setdefault("metavar", kw["flag"].lstrip("-").replace("-", "_").upper())
        flags = [kw.pop("flag", "--" + name.replace("_", "-")), *kw.pop("aliases", ())]
        kw.setdefault("help", helps[c].get(name, ""))
        typ, several = _value_type(hints[c][name])
        default = list(f.default) if isinstance(f.default, tuple) else f.default
        if several and kw.get("action") != "append":
            kw.setdefault("nargs", "+")
        if typ is bool and default:  # a --x/--no-x pair: its help shows no default by itself
            kw.setdefault("action", argparse.BooleanOptionalAction)
            kw["help"] += " (default: on)"
        elif typ is bool:
            kw.setdefault("action", "store_true")
        elif typ is not str:
            kw.setdefault("type", typ)
        parser.add_argument(*flags, dest=kw.pop("dest", name), default=default, **kw)
