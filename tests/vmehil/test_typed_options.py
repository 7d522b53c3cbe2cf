"""The command line is read once (issue 27, "typed run options"): each command's parser names the
one step that reads the parsed namespace into frozen, typed options (``options=<Dataclass>.from_args``),
and everything below receives those options. No function of ``vmehil`` or ``servo`` takes the
argparse namespace but that step, none reads an option with ``getattr(args, name, default)``
below it, and none keeps private ``args._x`` fields on the namespace.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import importlib.util
from collections.abc import Iterator
from pathlib import Path

import pytest

#: Where the namespace may be handled: ``vmehil.cli.main`` parses the line and hands it to the
#: command's parse step; each parse step is a classmethod named ``from_args`` (checked below).
ALLOWED = {("vmehil/cli.py", "main")}
PARSE_STEP = "from_args"


def _package_files(name: str) -> Iterator[tuple[str, ast.Module]]:
    spec = importlib.util.find_spec(name)
    assert spec is not None and spec.submodule_search_locations
    root = Path(next(iter(spec.submodule_search_locations)))
    for path in sorted(root.rglob("*.py")):
        rel = f"{name}/{path.relative_to(root).as_posix()}"
        yield rel, ast.parse(path.read_text(encoding="utf-8"), filename=rel)


def _functions(tree: ast.Module) -> Iterator[tuple[ast.FunctionDef | ast.AsyncFunctionDef, bool]]:
    """Every function (nested ones too), with whether it is part of a parse step: a classmethod
    ``from_args`` of a class, or a function nested in one."""
    def walk(node: ast.AST, in_class: bool, in_step: bool) -> Iterator[tuple[ast.FunctionDef | ast.AsyncFunctionDef,
                                                                             bool]]:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                is_step = in_step or (in_class and child.name == PARSE_STEP and any(
                    isinstance(d, ast.Name) and d.id == "classmethod" for d in child.decorator_list))
                yield child, is_step
                yield from walk(child, False, is_step)
            elif isinstance(child, ast.ClassDef):
                yield from walk(child, True, in_step)
            else:
                yield from walk(child, in_class, in_step)

    yield from walk(tree, False, False)


def _takes_namespace(arg: ast.arg) -> bool:
    """A parameter annotated as the argparse namespace, or named ``args`` without a type that says
    otherwise (a console request's ``args: list[Arg]`` is not the namespace)."""
    if arg.annotation is None:
        return arg.arg == "args"
    return "Namespace" in ast.unparse(arg.annotation) and "SimpleNamespace" not in ast.unparse(arg.annotation)


def _namespace_uses(fn: ast.FunctionDef | ast.AsyncFunctionDef, names: set[str]) -> Iterator[str]:
    """``getattr(<namespace>, ...)`` and ``<namespace>._private`` in ``fn``'s own body."""
    for node in ast.walk(fn):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("getattr", "hasattr",
                                                                                                "setattr")
                and node.args and isinstance(node.args[0], ast.Name) and node.args[0].id in names):
            yield f"line {node.lineno}: {ast.unparse(node)}"
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in names
                and node.attr.startswith("_") and not node.attr.startswith("__")):
            yield f"line {node.lineno}: private field {ast.unparse(node)}"


def violations(packages: tuple[str, ...] = ("vmehil", "servo")) -> tuple[list[str], int]:
    """What breaks the rule, one line each; and how many parse steps were seen."""
    out: list[str] = []
    steps = 0
    for rel, tree in (item for name in packages for item in _package_files(name)):
        for fn, is_step in _functions(tree):
            params = [*fn.args.posonlyargs, *fn.args.args, *fn.args.kwonlyargs]
            ns = {a.arg for a in params if _takes_namespace(a)}
            where = f"{rel}:{fn.lineno} {fn.name}"
            if is_step:
                steps += fn.name == PARSE_STEP
                # the parse step may read an option some parsers lack (getattr with a default);
                # it must not park private state on the namespace
                out += [f"{where}: {u}" for u in _namespace_uses(fn, ns) if "private" in u]
                continue
            if ns and (rel, fn.name) not in ALLOWED:
                out.append(f"{where}: takes the argparse namespace ({', '.join(sorted(ns))})")
            out += [f"{where}: {u}" for u in _namespace_uses(fn, ns | {"args"}) if (rel, fn.name) not in ALLOWED]
    return out, steps


def test_no_function_below_the_parse_step_takes_the_argparse_namespace() -> None:
    found, steps = violations()
    assert not found, "the argparse namespace below the parse step:\n  " + "\n  ".join(found)
    assert steps >= 10, f"only {steps} from_args parse steps found: is the walk looking at the packages?"


def test_the_check_finds_a_function_that_takes_the_namespace(tmp_path, monkeypatch) -> None:
    """The walk is not blind: a package with today's shape (a helper taking ``args`` and reading
    ``getattr(args, "x", 0)``, an extension parking ``args._state``) is refused, line by line."""
    pkg = tmp_path / "oldshape"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "cmd.py").write_text(
        "import argparse\n"
        "from dataclasses import dataclass\n\n"
        "def helper(args: argparse.Namespace) -> int:\n"
        "    return getattr(args, 'x', 0)\n\n"
        "def prepare(args, rig):\n"
        "    args._state = rig\n\n"
        "@dataclass(frozen=True)\n"
        "class Options:\n"
        "    x: int\n"
        "    @classmethod\n"
        "    def from_args(cls, args: argparse.Namespace) -> 'Options':\n"
        "        return cls(getattr(args, 'x', 0))\n\n"
        "def console_request(args: list[str]) -> int:\n"
        "    return len(args)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    found, steps = violations(("oldshape",))
    assert steps == 1
    assert found == [
        "oldshape/cmd.py:4 helper: takes the argparse namespace (args)",
        "oldshape/cmd.py:4 helper: line 5: getattr(args, 'x', 0)",
        "oldshape/cmd.py:7 prepare: takes the argparse namespace (args)",
        "oldshape/cmd.py:7 prepare: line 8: private field args._state",
    ]


def _leaf_parsers(parser: argparse.ArgumentParser, path: str = "vmehil",
                  inherited: dict | None = None) -> Iterator[tuple[str, dict]]:
    """Each command's parser with the defaults it sets or inherits (``crate`` sets them above its actions)."""
    defaults = {**(inherited or {}), **{k: v for k, v in parser._defaults.items() if k in ("func", "options")}}
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield path, defaults
        return
    for action in subs:
        for name, sub in action.choices.items():
            yield from _leaf_parsers(sub, f"{path} {name}", defaults)


def test_every_command_names_its_parse_step_into_frozen_options() -> None:
    from vmehil.cli import build_parser

    leaves = dict(_leaf_parsers(build_parser()))
    assert {"vmehil run", "vmehil tune bode", "vmehil crate read", "vmehil coordinate"} <= set(leaves)
    for name, defaults in leaves.items():
        func, step = defaults.get("func"), defaults.get("options")
        assert func is not None, name
        assert step is not None and step.__name__ == PARSE_STEP, f"{name}: no options=<Options>.from_args default"
        cls = step.__self__
        assert dataclasses.is_dataclass(cls) and cls.__dataclass_params__.frozen, f"{name}: {cls} is not frozen"


@pytest.mark.parametrize(("argv", "expected"), [
    (["run", "--console", "pty"], True),  # a person at the console: the wall clock's pace
    (["run", "--console", "pty", "--lockstep"], False),
    (["run"], False),
    (["console"], True),
    (["console", "--lockstep"], False),
])
def test_the_pacing_default_is_decided_once_at_the_parse_step(argv, expected) -> None:
    from vmehil.cli import build_parser

    args = build_parser().parse_args(argv)
    options = args.options(args)
    assert options.pacing.realtime is expected
    with pytest.raises(dataclasses.FrozenInstanceError):
        options.seed = 1


def test_run_options_carry_the_parsed_gains_and_the_switch_off_override() -> None:
    from vmehil.cli import build_parser

    args = build_parser().parse_args(["run", "--gains", "kp=120,kv=40", "--no-integrator-switch-off"])
    options = args.options(args)
    assert options.gains == {"kp": 120.0, "kv": 40.0}
    assert options.integrator_switch_off is False
    default = build_parser().parse_args(["run"])
    assert default.options(default).integrator_switch_off is None  # the rig's setting
