"""The ``--help`` of every console script, as JSON on the last line of stdout (used by ``reference.py``).

Usage: ``python docs/hooks/cli_help.py '{"drs-learn": "drs_torchrl.apps.cli:learn_main", ...}'``.

Nothing is run: an argparse script's entry point is called with ``ArgumentParser.parse_args`` replaced by a
function that records the parser's help and stops the call; a Hydra app prints Hydra's ``--help``, which
composes the config without calling the app; any other entry point is described by its docstring.
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import importlib
import importlib.util
import inspect
import json
import subprocess
import sys


class _Captured(BaseException):  # BaseException: a script's own `except Exception` must not swallow it
    def __init__(self, text: str):
        super().__init__(text)
        self.text = text


def _kind(module: str, func: str) -> str:
    spec = importlib.util.find_spec(module)
    source = open(spec.origin).read()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.FunctionDef) and node.name == func:
            for dec in node.decorator_list:
                target = dec.func if isinstance(dec, ast.Call) else dec
                if ast.unparse(target) in ("hydra.main", "main") and "hydra" in source:
                    return "Hydra app"
    if "ArgumentParser" in source:
        return "argparse"
    # an entry point assigned rather than defined (``main = wrap(_main)``) in a module of Hydra apps
    return "Hydra app" if "@hydra.main" in source else "no options"


def _argparse_help(name: str, module: str, func: str) -> str:
    def capture(self, *args, **kwargs):
        raise _Captured(self.format_help())

    saved = argparse.ArgumentParser.parse_args, argparse.ArgumentParser.parse_known_args, sys.argv
    argparse.ArgumentParser.parse_args = capture
    argparse.ArgumentParser.parse_known_args = capture
    sys.argv = [name]
    try:
        fn = getattr(importlib.import_module(module), func)
        with contextlib.redirect_stdout(sys.stderr):
            try:
                fn([]) if inspect.signature(fn).parameters else fn()
            except _Captured as cap:
                return cap.text
        raise RuntimeError("the entry point returned without building its parser")
    finally:
        argparse.ArgumentParser.parse_args, argparse.ArgumentParser.parse_known_args, sys.argv = saved


def main() -> None:
    scripts = json.loads(sys.argv[1])
    out: dict[str, dict] = {}
    procs = {}
    for name, target in scripts.items():
        module, func = target.split(":")
        try:
            kind = _kind(module, func)
        except Exception as exc:  # noqa: BLE001 - reported per script
            out[name] = {"kind": "?", "error": f"{type(exc).__name__}: {exc}"}
            continue
        out[name] = {"kind": kind}
        if kind == "Hydra app":  # Hydra's --help composes the config and returns; the app never runs
            code = f"import sys; sys.argv = [{name!r}, '--help']; from {module} import {func} as f; f()"
            procs[name] = subprocess.Popen(
                [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
            )
    for name, target in scripts.items():
        info = out[name]
        module, func = target.split(":")
        try:
            if info["kind"] == "argparse":
                info["help"] = _argparse_help(name, module, func)
            elif info["kind"] == "no options":
                doc = inspect.getdoc(getattr(importlib.import_module(module), func)) or ""
                info["help"] = f"usage: {name}\n\n{doc}\n(takes no options)"
        except BaseException as exc:  # noqa: BLE001 - a SystemExit of a script is reported, not fatal
            info["error"] = f"{type(exc).__name__}: {exc}"
    for name, proc in procs.items():
        try:
            stdout, stderr = proc.communicate(timeout=180)
        except subprocess.TimeoutExpired:
            proc.kill()
            out[name]["error"] = "--help timed out"
            continue
        if proc.returncode == 0 and stdout.strip():
            out[name]["help"] = stdout
        else:
            out[name]["error"] = f"exit {proc.returncode}: {stderr[-1500:]}"
    print(json.dumps(out))


if __name__ == "__main__":
    main()
