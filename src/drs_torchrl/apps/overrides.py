"""Checks of what a Hydra command line adds to a config, which neither Hydra nor the schema refuses:

- ``+key=value`` (or ``++key=value``) adds a key the config lacks. Hydra accepts it, nothing reads it and the run
  silently does without it (``+algo.lr=1e-3``). :func:`check_added_settings` allows an added key only where keys are
  free-form: a variant parameter, an argument of a constructed object, a config group (``+ablation=one_stage``).
- A mapping with ``_target_`` is built by ``hydra.utils.instantiate``: a key its target does not take, or a target
  that cannot be imported, was a ``TypeError``/``ImportError`` deep in the build (reported as a bug).
  :func:`check_constructor_arguments` names it before anything is built.
"""

from __future__ import annotations

import difflib
import inspect
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from drs_torchrl.config_dir import conf_dir
from drs_torchrl.runtime.errors import ConfigError

__all__ = ["FREE_FORM", "check_added_settings", "check_constructor_arguments"]

# mappings whose keys are passed on as they are (to a task variant, torch.compile, a custom family's variants), each
# checked by what receives it
FREE_FORM = ("env.variant_overrides", "env.variants", "algo.compile_kwargs")


def check_added_settings(
    cfg: DictConfig, overrides: list[str], config_name: str, app: str, error: type[Exception] = ConfigError
) -> None:
    """Refuse a ``+key=value`` / ``++key=value`` of ``overrides`` that adds a key nothing reads, naming the closest
    existing setting. ``cfg`` is the composed config; ``config_name`` composes it again without the additions
    (only for ``++``, which may also set an existing key). Call inside an initialized Hydra (an app, ``compose``)."""
    added = []
    for o in overrides:
        key = o.partition("=")[0]
        if not key.startswith("+"):
            continue
        key = key.lstrip("+")
        if key.split(".")[0].split("/")[0] == "hydra" or Path(conf_dir(), *key.split(".")).is_dir():
            continue  # Hydra's own settings; a config group (+ablation=one_stage)
        if any(key == f or key.startswith(f + ".") for f in FREE_FORM):
            continue
        parent = OmegaConf.select(cfg, key.rpartition(".")[0], default=None) if "." in key else None
        if isinstance(parent, DictConfig) and "_target_" in parent:
            continue  # an argument of a constructed object: check_constructor_arguments checks it
        added.append((o, key))
    if not added:
        return
    base = None
    if any(o.startswith("++") for o, _ in added):  # ++ also sets a key that exists: compose without the additions
        from hydra import compose

        skip = {o for o, _ in added}
        base = compose(config_name, overrides=[o for o in overrides if o not in skip and not o.startswith("hydra")])
    for o, key in added:
        if base is not None and OmegaConf.select(base, key, default=_ABSENT) is not _ABSENT:
            continue
        near = _closest(key, [k for k in _leaves(OmegaConf.to_container(cfg, resolve=False)) if k != key])
        hint = f"; did you mean {near}=...?" if near else ""
        raise error(
            f"{o.partition('=')[0]}: drs-{app} has no setting {key!r} ('+' adds a key that nothing reads, so the run "
            f"would silently do without it){hint}"
        )


def check_constructor_arguments(cfg: DictConfig, error: type[Exception] = ConfigError) -> None:
    """Every mapping of ``cfg`` with a ``_target_``: the target imports and takes each of the mapping's keys."""
    for path, node in _targets(OmegaConf.to_container(cfg, resolve=False)):
        target = node["_target_"]
        if not isinstance(target, str) or "${" in target:
            continue
        try:
            obj = _locate(target)
        except Exception:  # noqa: BLE001 (ImportError, AttributeError, ...: _not_importable says which)
            raise error(f"{path}._target_={target} cannot be imported: {_not_importable(target)}") from None
        takes = _arguments(obj)
        if takes is None:
            continue
        unknown = [k for k in node if not str(k).startswith("_") and k not in takes]
        if unknown:
            near = difflib.get_close_matches(unknown[0], sorted(takes), n=1)
            hint = f"; did you mean {path}.{near[0]}?" if near else ""
            names = ", ".join(sorted(takes)) if len(takes) <= 12 else f"{len(takes)} arguments: help({target})"
            raise error(f"{path}.{unknown[0]}: {target} takes no argument {unknown[0]!r}{hint} (it takes {names})")


_ABSENT = object()


def _locate(target: str):
    """The object at a dotted path (own code: ``hydra.utils.get_object`` also logs a failure to the console)."""
    import importlib

    parts = target.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ModuleNotFoundError:
            continue
        for name in parts[i:]:
            obj = getattr(obj, name)
        return obj
    raise ImportError(target)


def _not_importable(target: str) -> str:
    """Why ``target`` (``module.name``) does not import, in one clause, with the nearest name where one is near."""
    import importlib

    module, _, name = target.rpartition(".")
    try:
        mod = importlib.import_module(module) if module else None
    except Exception as exc:  # noqa: BLE001
        return f"module {module!r} does not import ({type(exc).__name__}: {' '.join(str(exc).split())[:120]})"
    if mod is None:
        return "give the full path, e.g. torch.optim.Adam"
    near = difflib.get_close_matches(name, [n for n in dir(mod) if not n.startswith("_")], n=1)
    return f"{module} has no {name!r}" + (f"; did you mean {module}.{near[0]}?" if near else "")


def _arguments(obj) -> set[str] | None:
    """The keyword arguments ``obj`` takes; a class that passes ``**kwargs`` on to its base also takes the base's.
    None where that cannot be told (a callable taking ``**kwargs`` it does not pass to a known base)."""
    if inspect.isclass(obj):
        names: set[str] = set()
        for cls in obj.__mro__:
            if cls is object:
                return None
            if "__init__" not in vars(cls):
                continue
            params = _parameters(vars(cls)["__init__"])
            if params is None:
                return None
            names |= {p.name for p in params if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)} - {"self"}
            if not any(p.kind is p.VAR_KEYWORD for p in params):
                return names
        return None
    params = _parameters(obj)
    if params is None or any(p.kind is p.VAR_KEYWORD for p in params):
        return None
    return {p.name for p in params if p.kind is not p.VAR_POSITIONAL}


def _parameters(fn) -> list[inspect.Parameter] | None:
    try:
        return list(inspect.signature(fn).parameters.values())
    except (TypeError, ValueError):  # a builtin without a signature
        return None


def _targets(tree, path: str = ""):
    """(dotted path, mapping) for every mapping with ``_target_`` in a plain container tree."""
    if isinstance(tree, dict):
        if "_target_" in tree:
            yield path, tree
        for k, v in tree.items():
            yield from _targets(v, f"{path}.{k}" if path else str(k))
    elif isinstance(tree, list):
        for i, v in enumerate(tree):
            yield from _targets(v, f"{path}[{i}]")


def _leaves(tree, path: str = ""):
    if isinstance(tree, dict) and tree:
        for k, v in tree.items():
            yield from _leaves(v, f"{path}.{k}" if path else str(k))
    elif path:
        yield path


def _closest(key: str, settings: list[str]) -> str | None:
    """The existing setting ``key`` most likely meant: the same last name elsewhere, else the nearest spelling."""
    last = key.rpartition(".")[2]
    same = [s for s in settings if s.rpartition(".")[2] == last]
    if same:
        return min(same, key=lambda s: (s.split(".")[0] != key.split(".")[0], len(s)))
    near = difflib.get_close_matches(key, settings, n=1, cutoff=0.75)
    return near[0] if near else None
