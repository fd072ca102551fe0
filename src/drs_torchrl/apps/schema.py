"""The type and range of every numeric setting, declared once: structured configs (dataclasses, registered in
Hydra's ConfigStore as ``schema/run`` and ``schema/maze``) and one check that reads them.

``check(cfg, RunSchema)`` validates a composed *or resumed* config against the schema with OmegaConf's own type
validation (``total_frames=abc`` is refused by OmegaConf), then applies each field's declared range. A field's
range, example and hint live in its metadata (``setting(gt=0, example=...)``), so a new setting is declared in
one line; rules between fields (``buffer_size >= batch_size``, the demonstrations' switches) stay in
``apps/validation.py`` and ``apps/maze.py:validate``.

Why the schema is not in the YAML defaults lists: a resumed run's ``config.yaml`` and ``drs-study --check`` never
pass Hydra's composition, and a schema there would close every config group to keys it does not declare; checked
here, every path gives the same one-line error (exit code 2).
"""

import dataclasses  # no `from __future__ import annotations`: the fields' types are read at run time
import re
import typing
from dataclasses import dataclass, field
from typing import Any, List, Optional

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING, DictConfig, OmegaConf
from omegaconf.errors import ValidationError

from drs_torchrl.runtime.errors import ConfigError

__all__ = ["setting", "check", "RunSchema", "MazeSchema"]


def setting(
    *,
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
    example: Any = None,
    noun: str = "",
    hint: str = "",
) -> Any:
    """A schema field: no default (the YAML files hold the defaults), its range and the example shown on a type
    error (``e.g. total_frames=200000``); ``noun`` names what the range is of ("a success rate"), ``hint`` is appended
    to a range error."""
    return field(default=MISSING, metadata=dict(gt=gt, ge=ge, lt=lt, le=le, example=example, noun=noun, hint=hint))


# ----------------------------------------------------------------------------- drs-learn / drs-reuse
@dataclass
class EvalSchema:
    interval: int = setting(gt=0, example=20000)
    episodes: int = setting(ge=0, example=20)
    episode_seed: Optional[int] = setting(ge=0, example=1000)
    stop_at_success: Optional[float] = setting(ge=0, le=1, example=0.8, noun="a success rate")
    stop_streak: int = setting(gt=0, example=2)


@dataclass
class LoggerSchema:
    interval: int = setting(gt=0, example=2000)
    episode_window: int = setting(gt=0, example=50)
    tensorboard: bool = setting(example=True)
    csv: bool = setting(example=True)
    wandb: bool = setting(example=False)


@dataclass
class OptimSchema:
    lr: float = setting(gt=0, example=0.0003)


@dataclass
class AlgoSchema:
    """The keys algorithms share; a key an algorithm does not use (``utd`` for PPO, ``epochs`` for SAC) is absent."""

    batch_size: int = setting(gt=0, example=256)
    frames_per_batch: int = setting(gt=0, example=64)
    learning_starts: int = setting(ge=0, example=4000)
    buffer_size: int = setting(gt=0, example=2000000)
    utd: float = setting(gt=0, example=0.5)
    epochs: int = setting(gt=0, example=4)
    gamma: float = setting(gt=0, le=1, example=0.8)
    tau: float = setting(gt=0, le=1, example=0.005)
    reward_updates_per_update: float = setting(gt=0, example=0.5, hint="(fractions allowed, e.g. 0.5)")
    compile: Any = setting(example="update")  # false | true (= loss) | loss | update: updaters.sac.compile_scope
    hidden: List[int] = setting(gt=0, example="[256,256,256]", noun="layer widths, each")
    optim: OptimSchema = field(default_factory=OptimSchema)


@dataclass
class DiscSchema:
    lr: float = setting(gt=0, example=0.0003)
    batch_size: int = setting(gt=0, example=256)
    window: int = setting(gt=0, example=100)
    early_stop_threshold: Optional[float] = setting(gt=0, le=1, example=0.95)
    latch: bool = setting(example=True)


@dataclass
class RewardSchema:
    name: str = setting()
    alpha: float = setting(example=0.3333)
    stage_buffer_size: int = setting(gt=0, example=1000000)
    hidden: List[int] = setting(gt=0, example="[32]", noun="layer widths, each")
    disc: Optional[DiscSchema] = None  # learned rewards only


@dataclass
class DemosSchema:
    num: Optional[int] = setting(gt=0, example=100, hint="(null: all in the file)")


@dataclass
class EnvSchema:
    num_envs: int = setting(gt=0, example=1)
    max_episode_steps: Optional[int] = setting(gt=0, example=50, hint="(null: the family's)")


@dataclass
class RunSchema:
    """drs-learn / drs-reuse (``conf/learn.yaml``, ``conf/reuse.yaml`` and their groups)."""

    total_frames: int = setting(gt=0, example=200000)
    seed: int = setting(ge=0, example=0, hint="(it seeds numpy, torch and the simulator)")
    overwrite: bool = setting(example=True)
    checkpoint_interval: int = setting(gt=0, example=20000)
    torch_threads: Optional[int] = setting(gt=0, example=1)
    stop_at_success: Optional[float] = setting(ge=0, le=1, example=0.8, noun="a success rate")
    env: EnvSchema = field(default_factory=EnvSchema)
    eval: EvalSchema = field(default_factory=EvalSchema)
    logger: LoggerSchema = field(default_factory=LoggerSchema)
    algo: AlgoSchema = field(default_factory=AlgoSchema)
    reward: RewardSchema = field(default_factory=RewardSchema)
    demos: DemosSchema = field(default_factory=DemosSchema)


# ----------------------------------------------------------------------------- drs-maze
@dataclass
class MazeDQNSchema:
    gamma: float = setting(gt=0, le=1, example=0.99)
    lr: float = setting(gt=0, example=0.001)
    batch_size: int = setting(gt=0, example=256)
    frames_per_batch: int = setting(gt=0, example=256)
    utd: float = setting(gt=0, example=0.25)
    learning_starts: int = setting(ge=0, example=5000)
    buffer_size: int = setting(gt=0, example=200000)
    n_steps: int = setting(ge=1, example=5)
    reward_scale: float = setting(gt=0, example=0.1, hint="(it multiplies the reward the agent trains on)")
    eps_init: float = setting(ge=0, le=1, example=1.0)
    eps_end: float = setting(ge=0, le=1, example=0.05)
    eps_anneal_frac: float = setting(gt=0, le=1, example=0.5)
    hidden: List[int] = setting(gt=0, example="[64,64]", noun="layer widths, each")
    reward_updates_per_update: float = setting(gt=0, example=1, hint="(fractions allowed, e.g. 0.5)")


@dataclass
class MazePPOSchema:
    gamma: float = setting(gt=0, le=1, example=0.99)
    lmbda: float = setting(ge=0, le=1, example=0.95)
    lr: float = setting(gt=0, example=0.0003)
    frames_per_batch: int = setting(gt=0, example=2048)
    batch_size: int = setting(gt=0, example=256)
    epochs: int = setting(gt=0, example=4)
    reward_scale: float = setting(gt=0, example=1.0)
    hidden: List[int] = setting(gt=0, example="[64,64]", noun="layer widths, each")
    reward_updates_per_update: float = setting(gt=0, example=1, hint="(fractions allowed, e.g. 0.5)")


@dataclass
class MazeDiscSchema:
    lr: float = setting(gt=0, example=0.001)
    batch_size: int = setting(gt=0, example=256)
    window: int = setting(gt=0, example=100)
    early_stop_threshold: Optional[float] = setting(gt=0, le=1, example=0.95)


@dataclass
class MazeRewardSchema:
    name: str = setting()
    alpha: float = setting(example=0.3333)
    reuse_alpha: Optional[float] = setting(ge=0, lt=0.5, example=0.0, hint="(0 keeps only DrS's constant part)")
    stage_buffer_size: int = setting(gt=0, example=20000)
    dense_coef: float = setting(ge=0, example=1.0)
    hidden: List[int] = setting(gt=0, example="[32]", noun="layer widths, each")
    disc: MazeDiscSchema = field(default_factory=MazeDiscSchema)


@dataclass
class MazeEvalSchema:
    interval: int = setting(gt=0, example=10000)
    episodes: int = setting(gt=0, example=64)


@dataclass
class MazeSchema:
    """drs-maze (``conf/maze.yaml``)."""

    total_frames: int = setting(gt=0, example=200000)
    seed: int = setting(ge=0, example=0, hint="(it seeds numpy, torch and the simulator)")
    overwrite: bool = setting(example=True)
    save_state: bool = setting(example=False)
    num_threads: int = setting(gt=0, example=1)
    num_envs: int = setting(gt=0, example=32)
    max_steps: int = setting(gt=0, example=200)
    demos: int = setting(ge=0, example=100)
    reward: MazeRewardSchema = field(default_factory=MazeRewardSchema)
    dqn: MazeDQNSchema = field(default_factory=MazeDQNSchema)
    ppo: MazePPOSchema = field(default_factory=MazePPOSchema)
    eval: MazeEvalSchema = field(default_factory=MazeEvalSchema)


_store = ConfigStore.instance()
_store.store(group="schema", name="run", node=RunSchema)
_store.store(group="schema", name="maze", node=MazeSchema)


# ----------------------------------------------------------------------------- the check
def check(cfg: DictConfig, schema: type, error: type[Exception] = ConfigError) -> None:
    """Raise ``error`` with one line naming the first setting of ``cfg`` whose type or range ``schema`` refuses.

    Keys the schema does not declare pass; a declared key absent from ``cfg`` (a setting its algorithm or reward
    does not have) is not checked."""
    _check_sections(cfg, schema, error)
    view = OmegaConf.create(_project(cfg, schema))
    try:
        typed = OmegaConf.merge(OmegaConf.structured(schema), view)
    except ValidationError as exc:
        key = exc.full_key
        base = re.sub(r"\[\d+\]$", "", key)  # an element of a list setting: the list's field
        f = _field(schema, base)
        if f is None:  # not one setting: say what OmegaConf said rather than fail on it
            raise error(f"{key or 'the config'}: {exc.msg}") from None
        value = OmegaConf.select(view, key)
        value = OmegaConf.to_container(value) if OmegaConf.is_config(value) else value
        raise error(
            f"{key} must be {_kind(f, element=base != key)}, got {value!r} ({type(value).__name__}); "
            f"e.g. {base}={_example(f)}"
        ) from None
    for key, f in _leaves(schema):
        if OmegaConf.select(typed, key, default=None) is None or OmegaConf.is_missing(typed, key):
            continue
        given = OmegaConf.select(view, key)
        given = OmegaConf.to_container(given) if OmegaConf.is_config(given) else given
        if f.type is bool and not isinstance(given, bool):  # OmegaConf reads "no", "off", 0 as false; Python as true
            raise error(
                f"{key} must be true or false, got {given!r} ({type(given).__name__}); e.g. {key}={_example(f)}"
            )
        value = OmegaConf.select(typed, key)
        bad = next(
            filter(None, (_out_of_range(v, f.metadata) for v in (value if OmegaConf.is_list(value) else [value]))), None
        )
        if bad:
            m = f.metadata
            what = ("null or " if type(None) in typing.get_args(f.type) else "") + (
                m["noun"] + " " if m["noun"] else ""
            )
            hint = f" {m['hint']}" if m["hint"] else f"; e.g. {key}={_example(f)}"
            raise error(f"{key} must be {what}{bad}, got {given}{hint}")


def _check_sections(cfg: DictConfig, schema: type, error: type[Exception], prefix: str = "") -> None:
    """A section given one value (``eval=5``: Hydra accepts it) is named as a section; OmegaConf's merge error
    names no key."""
    for f in dataclasses.fields(schema):
        sub = _dataclass_of(f)
        if sub is None or f.name not in cfg or OmegaConf.is_missing(cfg, f.name):
            continue
        value = cfg[f.name]
        if value is None and type(None) in typing.get_args(f.type):
            continue
        if not isinstance(value, DictConfig):
            first = dataclasses.fields(sub)[0]
            given = "null" if value is None else OmegaConf.to_container(value) if OmegaConf.is_config(value) else value
            raise error(
                f"{prefix}{f.name} is a section of settings, not one value (got {given}); set one of its settings, "
                f"e.g. {prefix}{f.name}.{first.name}={_example(first)}"
            )
        _check_sections(value, sub, error, f"{prefix}{f.name}.")


def _project(cfg: DictConfig, schema: type) -> dict:
    """The values of ``cfg`` at the schema's keys (interpolations resolved), nothing else."""
    out = {}
    for f in dataclasses.fields(schema):
        if f.name not in cfg:
            continue
        sub = _dataclass_of(f)
        value = cfg[f.name] if not OmegaConf.is_missing(cfg, f.name) else MISSING
        if sub is not None and isinstance(value, DictConfig):
            out[f.name] = _project(value, sub)
        elif isinstance(value, DictConfig) or OmegaConf.is_list(value):
            out[f.name] = OmegaConf.to_container(value, resolve=True)
        else:
            out[f.name] = value
    return out


def _dataclass_of(f: dataclasses.Field) -> type | None:
    """The schema of a nested section (``eval: EvalSchema``, ``disc: Optional[DiscSchema]``), else None."""
    return next((t for t in (f.type, *typing.get_args(f.type)) if dataclasses.is_dataclass(t)), None)


def _leaves(schema: type, prefix: str = ""):
    for f in dataclasses.fields(schema):
        sub = _dataclass_of(f)
        if sub is not None:
            yield from _leaves(sub, f"{prefix}{f.name}.")
        else:
            yield prefix + f.name, f


def _field(schema: type | None, key: str) -> dataclasses.Field | None:
    """The schema field at the dotted ``key``; ``None`` where the schema has none (e.g. ``""``, ``hidden[0]``)."""
    head, _, rest = key.partition(".")
    f = next((f for f in dataclasses.fields(schema) if f.name == head), None) if schema is not None else None
    return _field(_dataclass_of(f), rest) if rest and f is not None else f


def _kind(f: dataclasses.Field, element: bool = False) -> str:
    """What ``f`` holds, in words (``element``: what one entry of a list setting holds)."""
    ann = f.type
    args = [a for a in typing.get_args(ann) if a is not type(None)] or [ann]
    words = {int: "an integer", float: "a number", str: "a string", bool: "true or false"}
    if typing.get_origin(ann) is list:
        return words[args[0]] if element else f"a list of {words[args[0]].split(' ', 1)[1]}s"
    kind = words.get(args[0], str(args[0]))
    return kind + (" or null" if type(None) in typing.get_args(ann) else "")


def _example(f: dataclasses.Field) -> Any:
    ex = f.metadata.get("example")
    return 1 if ex is None else str(ex).lower() if isinstance(ex, bool) else ex


def _out_of_range(v: float, m: dict) -> str | None:
    lo = (m.get("gt"), "(") if m.get("gt") is not None else (m.get("ge"), "[")
    hi = (m.get("lt"), ")") if m.get("lt") is not None else (m.get("le"), "]")
    too_low = lo[0] is not None and (v <= lo[0] if lo[1] == "(" else v < lo[0])
    too_high = hi[0] is not None and (v >= hi[0] if hi[1] == ")" else v > hi[0])
    if not (too_low or too_high):
        return None
    if lo[0] is not None and hi[0] is not None:
        return f"in {lo[1]}{lo[0]:g}, {hi[0]:g}{hi[1]}"
    if lo[0] is not None:
        return f"{'>' if lo[1] == '(' else '>='} {lo[0]:g}"
    return f"{'<' if hi[1] == ')' else '<='} {hi[0]:g}"
