"""Typer options generated from config dataclasses: an option's default and help are its field's default and
docstring, read from the dataclass's source, so the command line never restates them.

A command declares a config as one parameter whose default is a :class:`ConfigOptions`::

    TRAIN = ConfigOptions("nue.train.bc:TrainConfig", Opt("data", path=True), "model", Opt("steps", check=A.positive))

    @config_command
    def train_cmd(cfg: TrainConfig = TRAIN, resume: bool = typer.Option(False, help="...")): ...

``nue train --help`` then lists ``--data``, ``--model`` and ``--steps`` (in that place among the command's
parameters) with ``TrainConfig``'s defaults and field docstrings, and the command receives the built
``TrainConfig``: each option's check has run first (naming the option, so bad input is the usual one-line
error). An :class:`Opt` overrides only what is CLI-specific: another flag, a path typed as ``Path``, minutes
for a field in seconds, another default or help for one command, a check.

The fields are read with :mod:`ast` from the module's source file without importing it (the config modules
import torch; ``nue --help`` stays quick); the class is imported when the command runs. A field's docstring
is the string literal written after it; its default must be a literal (``3``, ``"fp32"``, ``()``, ``None``).
Why not tyro, which builds options from the imported classes: ``nue --help`` took 0.33 s of CPU this way and
``--help`` of ``TrainConfig`` alone 2.2 s with tyro (importing the config modules and torch; docs/cli.md, measured
with ``scripts/cli_startup.py``).
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import importlib
import importlib.machinery
import importlib.util
import inspect
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional

import typer

from nue import cli_args as A

_UNSET: Any = object()
_SIMPLE = {"str": str, "int": int, "float": float, "bool": bool}


# --- reading a config dataclass from its source --------------------------------------------------------
@dataclass(frozen=True)
class ConfigField:
    """A field of a config dataclass as its source declares it."""

    name: str
    kind: str
    """``scalar``, ``ints`` (``tuple[int, ...]``) or ``strs`` (``tuple[str, ...]``)."""
    type: type
    """``str``, ``int``, ``float`` or ``bool``: the scalar's type, or the tuple's items'."""
    optional: bool
    """The annotation allows None (``str | None``)."""
    default: Any
    """The default value (a literal), or ``_UNSET``."""
    doc: str
    """The field's docstring, white space folded and Sphinx markup shown as `x`."""


def plain_doc(doc: str) -> str:
    """A docstring as one line of help: white space folded, ````x```` and ``:role:`~a.b.x``` as `x`."""
    text = " ".join(inspect.cleandoc(doc).split())
    text = re.sub(r":[a-z]+:`~([^`]*?\.)?([^`.]+)`", r"`\2`", text)
    text = re.sub(r":[a-z]+:`([^`]+)`", r"`\1`", text)
    return re.sub(r"``([^`]+)``", r"`\1`", text)


def source_file(module: str) -> Path:
    """The source file of ``module`` ("nue.train.bc"), found without importing it or its packages."""
    loaded = sys.modules.get(module)
    if loaded is not None and getattr(loaded, "__file__", None):
        return Path(loaded.__file__)
    parts = module.split(".")
    spec = importlib.util.find_spec(parts[0])  # a top-level name is found without being imported
    for i in range(1, len(parts)):
        if spec is None:
            break
        spec = importlib.machinery.PathFinder.find_spec(".".join(parts[: i + 1]), spec.submodule_search_locations)
    if spec is None or not spec.origin or not spec.origin.endswith(".py"):
        raise ModuleNotFoundError(f"{module}: no Python source")
    return Path(spec.origin)


@functools.cache
def config_fields(ref: str) -> dict[str, ConfigField]:
    """The fields of the dataclass ``ref`` ("module:Class") with a CLI-readable annotation, read from its source
    (bases are not followed); fields of other types (a nested config, ``AgentSpec``) are left out."""
    module, _, name = ref.partition(":")
    cls = _class_node(source_file(module).read_text(), name)
    if cls is None:
        raise LookupError(f"{ref}: no class {name} in {module}")
    fields = {}
    body = cls.body
    for stmt, after in zip(body, [*body[1:], None]):
        if not (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name)):
            continue
        shape = _annotation(stmt.annotation)
        if shape is None:
            continue
        doc = ""
        if isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant) and isinstance(after.value.value, str):
            doc = plain_doc(after.value.value)
        fields[stmt.target.id] = ConfigField(stmt.target.id, *shape, default=_default(stmt.value), doc=doc)
    return fields


def _class_node(text: str, name: str) -> ast.ClassDef | None:
    """The top-level class ``name`` of a module's source: parsed alone (from its line to the next line that is
    not indented: a tenth of the time of the whole module), or with the whole module if that fails."""
    start = re.search(rf"^class {name}\b", text, re.M)
    if start is not None:
        end = re.compile(r"^[^\s#]", re.M).search(text, start.end())
        try:
            tree = ast.parse(text[start.start(): end.start() if end else len(text)])
        except SyntaxError:
            tree = None
        if tree and len(tree.body) == 1 and isinstance(tree.body[0], ast.ClassDef):
            return tree.body[0]
    tree = ast.parse(text)
    return next((n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == name), None)


def _annotation(node: ast.expr) -> tuple[str, type, bool] | None:
    """(kind, item type, optional) of an annotation the command line can give, else None."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):  # a quoted annotation
        return _annotation(ast.parse(node.value, mode="eval").body)
    if isinstance(node, ast.Name) and node.id in _SIMPLE:
        return "scalar", _SIMPLE[node.id], False
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.BitOr):  # X | Y: the one simple member (+ None)
        members = _union_members(node)
        optional = any(isinstance(m, ast.Constant) and m.value is None for m in members)
        simple = [_SIMPLE[m.id] for m in members if isinstance(m, ast.Name) and m.id in _SIMPLE]
        return ("scalar", simple[0], optional) if len(simple) == 1 else None
    if isinstance(node, ast.Subscript) and isinstance(node.value, ast.Name):
        if node.value.id == "Optional":
            inner = _annotation(node.slice)
            return (inner[0], inner[1], True) if inner and inner[0] == "scalar" else None
        elts = node.slice.elts if isinstance(node.slice, ast.Tuple) else []
        if (node.value.id == "tuple" and len(elts) == 2 and isinstance(elts[1], ast.Constant)
                and elts[1].value is Ellipsis and isinstance(elts[0], ast.Name) and elts[0].id in ("int", "str")):
            return ("ints" if elts[0].id == "int" else "strs"), _SIMPLE[elts[0].id], False
    return None


def _union_members(node: ast.expr) -> list[ast.expr]:
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.BitOr):
        return _union_members(node.left) + _union_members(node.right)
    return [node]


def _default(node: ast.expr | None) -> Any:
    """A field's default: the literal after ``=`` or in ``field(default=...)``; ``_UNSET`` otherwise."""
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "field":
        node = next((k.value for k in node.keywords if k.arg == "default"), None)
    if node is None:
        return _UNSET
    try:
        return ast.literal_eval(node)
    except ValueError:
        return _UNSET


# --- options ------------------------------------------------------------------------------------------
Check = Callable[[str, Any], None]


@dataclass(frozen=True)
class Opt:
    """How one config field is a command-line option; everything but ``field`` overrides what the field gives."""

    field: str
    flag: str = ""
    """Default: ``--`` and the field name with dashes."""
    help: str = ""
    """Default: the field's docstring (+ "Comma-separated integers." / "Repeatable." for tuples)."""
    default: Any = _UNSET
    """Default: the field's default (on the command line: minutes for ``minutes``, a ``Path`` for ``path``)."""
    check: Optional[Check] = None
    """``check(flag, value)`` raises a :class:`~nue.errors.ConfigError` for a bad value (e.g. ``A.positive``)."""
    path: bool = False
    """A ``str`` field holding a path: typed ``Path`` (its default ``""`` is no default: the option is optional)."""
    minutes: bool = False
    """A field in seconds given in minutes (needs its own help)."""
    panel: Optional[str] = None
    """The ``--help`` panel it is listed in (default: Options)."""

    @property
    def option(self) -> str:
        return self.flag or "--" + self.field.replace("_", "-")


class ConfigOptions:
    """Command-line options of chosen fields of a config dataclass ``ref`` ("module:Class"), in the order given;
    a field given by name is an :class:`Opt` with no overrides."""

    def __init__(self, ref: str, *opts: Opt | str, as_dict: bool = False):
        self.ref = ref
        self.opts = tuple(Opt(o) if isinstance(o, str) else o for o in opts)
        self.as_dict = as_dict
        """The command receives ``{field: value}`` instead of the built class (when which class to build, or
        whether to build it at all, depends on other options, as for ``nue view``'s live run or replay)."""
        fields = config_fields(ref)
        for o in self.opts:
            f = fields.get(o.field)
            if f is None:
                raise TypeError(f"{ref} has no field {o.field!r} of a type the command line can give")
            if f.default is _UNSET and o.default is _UNSET:
                raise TypeError(f"{ref}.{o.field}: its default is not a literal; give the option a default")
            if o.minutes and not o.help:
                raise TypeError(f"{ref}.{o.field}: an option in minutes needs its own help (the field's is in seconds)")

    def but(self, *drop: str, **changes: dict) -> ConfigOptions:
        """These options without the fields ``drop``, and with ``changes[field]`` overriding an option's settings
        (``out={"default": "runs/x", "help": "..."}``)."""
        unknown = {*drop, *changes} - {o.field for o in self.opts}
        if unknown:
            raise TypeError(f"{self.ref}: no options {sorted(unknown)}")
        return ConfigOptions(self.ref, *(dataclasses.replace(o, **changes.get(o.field, {}))
                                         for o in self.opts if o.field not in drop), as_dict=self.as_dict)

    def field(self, name: str) -> ConfigField:
        return config_fields(self.ref)[name]

    def parameters(self, prefix: str) -> list[inspect.Parameter]:
        """One typer parameter per option, named ``<prefix>__<field>``."""
        return [inspect.Parameter(f"{prefix}__{o.field}", inspect.Parameter.KEYWORD_ONLY, default=self._typer_option(o),
                                  annotation=self._cli_type(o)) for o in self.opts]

    def build(self, values: dict[str, Any]):
        """The config from the options' values (by field name): every check first, then the class (imported now);
        with ``as_dict`` the fields' values instead."""
        for o in self.opts:
            if o.check is not None:
                o.check(o.option, values[o.field])
        fields = {o.field: self._to_field(o, values[o.field]) for o in self.opts}
        if self.as_dict:
            return fields
        module, _, name = self.ref.partition(":")
        cls = getattr(importlib.import_module(module), name)
        return cls(**fields)

    # -- one option
    def _cli_type(self, o: Opt) -> Any:
        f = self.field(o.field)
        item = Path if o.path else f.type
        if f.kind == "ints":
            return str
        if f.kind == "strs":
            return list[item]
        return Optional[item] if f.optional or self._cli_default(o) is None else item

    def _cli_default(self, o: Opt) -> Any:
        f = self.field(o.field)
        value = f.default if o.default is _UNSET else o.default
        if o.default is _UNSET and o.minutes:
            value = value / 60
        if f.kind == "ints":
            return value if isinstance(value, str) else ",".join(map(str, value))
        if f.kind == "strs":
            return [Path(v) if o.path else v for v in value]
        if o.path:
            return Path(value) if value not in ("", None) else None
        return value

    def _typer_option(self, o: Opt):
        f = self.field(o.field)
        help = o.help or f.doc
        if not o.help:
            help += {"ints": " Comma-separated integers.", "strs": " Repeatable."}.get(f.kind, "")
        flags = {p.field: p.option for p in self.opts if p.field != o.field}  # `another_field`: its flag
        help = re.sub(r"`([a-z_0-9]+)`", lambda m: f"`{flags[m[1]]}`" if m[1] in flags else m[0], help)
        if getattr(typer.core, "HAS_RICH", False):  # help is rich markup then: keep [...] as written
            help = _escape_markup(help)
        flag = o.option
        decls = [f"{flag}/--no-{flag[2:]}"] if f.kind == "scalar" and f.type is bool else [flag]
        return typer.Option(self._cli_default(o), *decls, help=help, rich_help_panel=o.panel)

    def _to_field(self, o: Opt, value: Any) -> Any:
        f = self.field(o.field)
        if f.kind == "ints":
            return A.ints(o.option, value)
        if f.kind == "strs":
            return tuple(str(v) for v in value)
        if value is None:
            return f.default if f.default is not _UNSET else None
        if o.minutes:
            return 60 * value
        return str(value) if o.path else value


def _escape_markup(text: str) -> str:
    """``rich.markup.escape`` (without importing rich, which costs the command line's start-up a third of a second):
    a backslash before each ``[`` that would open a markup tag."""
    text = re.sub(r"(\\*)(\[[a-z#/@][^[]*?])", lambda m: f"{m[1]}{m[1]}\\{m[2]}", text)
    return text + "\\" if text.endswith("\\") and not text.endswith("\\\\") else text


# --- options that are no config's field: where a run happens, not what it computes --------------------
WORKERS = typer.Option(1, help="Parallel local worker processes.")
RAY_ADDRESS = typer.Option(None, help="Run episodes as tasks on this Ray cluster (`local`: one of the driver's own).")


# --- commands -----------------------------------------------------------------------------------------
def config_command(fn: Callable) -> Callable:
    """``fn`` as a typer command: each parameter whose default is a :class:`ConfigOptions` becomes that config's
    options (in its place in ``--help``), and the call passes the built config under the parameter's name."""
    sig = inspect.signature(fn)
    params, groups = [], {}
    for p in sig.parameters.values():
        if isinstance(p.default, ConfigOptions):
            groups[p.name] = p.default
            params += p.default.parameters(p.name)
        else:
            # a postponed annotation ("Optional[Path]") evaluated in the command's module, as typing.get_type_hints
            # does; the config parameters' own annotations are never evaluated (their classes are imported late)
            annotation = eval(p.annotation, fn.__globals__) if isinstance(p.annotation, str) else p.annotation
            params.append(p.replace(kind=inspect.Parameter.KEYWORD_ONLY, annotation=annotation))
    _refuse_repeated_flags(fn.__name__, params)

    @functools.wraps(fn)
    def command(**kwargs):
        for name, group in groups.items():
            kwargs[name] = group.build({o.field: kwargs.pop(f"{name}__{o.field}") for o in group.opts})
        return fn(**kwargs)

    command.__signature__ = inspect.Signature(params)
    command.config_options = groups  # {parameter name: ConfigOptions}, for tests and tools
    command.__annotations__ = {p.name: p.annotation for p in params}
    return command


def _refuse_repeated_flags(name: str, params: list[inspect.Parameter]) -> None:
    seen: dict[str, str] = {}
    for p in params:
        if not isinstance(p.default, typer.models.OptionInfo):
            continue
        for decl in p.default.param_decls or ("--" + p.name.replace("_", "-"),):
            for flag in decl.split("/"):
                if flag in seen:
                    raise TypeError(f"{name}: {flag} is both {seen[flag]} and {p.name}")
                seen[flag] = p.name
