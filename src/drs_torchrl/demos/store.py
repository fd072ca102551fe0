"""The demonstrations format: save, load, check against a task, relabel for a stage ablation.

On-disk format (a directory, e.g. ``demos/pick_cube-cube_2cm.demos``):

* ``states/``: a memory-mapped TensorDict (``TensorDict.load_memmap``) of batch ``[S]``, one row per
  state ``s'`` reached by the demonstrator, episodes concatenated in order. Entries:
  ``observation`` (float, the env's flat state), ``stage_indicators`` (float, monotone),
  ``stage`` (int64), every indicator of the family (bool), ``episode`` and ``step`` (int64); from the
  planner and from a policy also ``action`` (the action that led to the row's state) and ``state`` (a
  sub-TensorDict of the reward inputs and ``stage`` of the state it was taken in).
* ``meta.json``: ``format``, ``version``, ``family``, ``env_id``, ``variant``, ``variant_kwargs``,
  ``stage_keys``, ``shapes`` (entry -> trailing size), ``episodes``, ``lengths``, ``seeds``,
  ``solver`` (:func:`demo_meta`); from the planner and from a policy ``actions`` (``control_mode``,
  ``size``: whose controller the actions are for), from an ``.h5`` conversion ``replay``.

Episodes are cut at their first successful state (training episodes terminate there).
"""

from __future__ import annotations

import errno
import json
import os
import shutil
from pathlib import Path

import torch
from tensordict import TensorDict

from drs_torchrl.runtime.console import UserError
from drs_torchrl.data.persistence import load_memmap_checked
from drs_torchrl.runtime.rundir import check_writable, ensure_free, fsync_tree, nbytes, space_errors
from drs_torchrl.tasks import TaskFamily
from drs_torchrl.transforms.stages import StageIndicator, monotone_indicators

DEMO_FORMAT = "drs-torchrl/demos"
DEMO_VERSION = 1


class DemoError(UserError, ValueError):
    """A demonstrations file that cannot be used for this task."""


def cut_at_success(states: TensorDict, labeller, index: int) -> TensorDict | None:
    """A demonstration's states cut at its first successful state and stage-labelled, with its
    ``episode`` index and ``step`` numbers; ``None`` when it never succeeds."""
    succ = states["success"].reshape(-1).nonzero()
    if succ.numel() == 0:
        return None
    states = labeller(states[: int(succ[0]) + 1])
    states.set("episode", torch.full((states.shape[0],), index, dtype=torch.long))
    states.set("step", torch.arange(states.shape[0]))
    return states


def demo_meta(
    family: TaskFamily, data: TensorDict, *, env_id, variant, variant_kwargs, lengths, seeds, solver, **extra
) -> dict:
    """The ``meta.json`` fields every source writes (module docstring), then the source's own ``extra``."""
    keys = ("observation", "stage_indicators", family.task_observation_key)
    return {
        "format": DEMO_FORMAT,
        "version": DEMO_VERSION,
        "family": family.name,
        "env_id": env_id,
        "variant": variant,
        "variant_kwargs": variant_kwargs,
        "stage_keys": list(family.stage_keys),
        "shapes": {k: int(data[k].shape[-1]) for k in keys if k},
        "episodes": len(lengths),
        "lengths": lengths,
        "seeds": seeds,
        "solver": solver,
        **extra,
    }


def check_demos_out(path: str | Path, *, replace: bool = True) -> Path:
    """``path`` if demonstrations can be written there: new, or (with ``replace``) demonstrations to replace;
    never another folder."""
    path = check_writable(path, "--out", folder=True)
    if path.exists() and any(path.iterdir()) and not (path / "meta.json").is_file():
        raise DemoError(
            f"--out {path} is a folder that does not hold demonstrations; give a new path such as {path / 'my.demos'}"
        )
    if not replace and (path / "meta.json").is_file():
        raise DemoError(f"--out {path} already holds demonstrations; pass --force to replace them, or give a new path")
    return path


def free_demos_path(path: Path) -> Path:
    """``path``, or the first of ``NAME-2.demos``, ``NAME-3.demos``, ... that does not exist yet."""
    n, out = 1, path
    while out.exists():
        n += 1
        out = path.with_name(f"{path.name.removesuffix('.demos')}-{n}.demos")
    return out


class DemosOutTakenError(DemoError):
    """:func:`save_demos` without ``replace`` found its path taken meanwhile; the new demonstrations are at ``kept``."""

    def __init__(self, message: str, kept: Path):
        super().__init__(message)
        self.kept = kept


def save_demos(states: TensorDict, meta: dict, path: str | Path, *, replace: bool = True) -> Path:
    """Write demonstrations to ``path`` (a folder, swapped in by renames) and return it.

    Without ``replace``, demonstrations that another process wrote there meanwhile are kept: the new ones go
    to the next free name instead and :class:`DemosOutTakenError` names it.
    """
    path = check_demos_out(path)  # no replace check yet: the states are saved in any case, below
    tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")  # this process's own: two saves never share one
    shutil.rmtree(tmp, ignore_errors=True)
    ensure_free(tmp, nbytes(states), "the demonstrations")  # a memory map on a full disk faults (SIGBUS)
    try:
        with space_errors(tmp, "the demonstrations"):
            tmp.mkdir(parents=True)
            states.memmap(tmp / "states", num_threads=0)
            (tmp / "meta.json").write_text(json.dumps(meta, indent=2))
            fsync_tree(tmp)  # on the disk before it takes the name
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = path.with_name(f"{path.name}.old-{os.getpid()}")  # replace by renames: a crash midway leaves one whole
    while not _rename_if_free(tmp, path):
        demos = (path / "meta.json").is_file()
        if not replace or not demos:  # never replace anything but demonstrations, and those only when told
            kept = _keep_elsewhere(tmp, path)
            what = "demonstrations" if demos else "files that are not demonstrations"
            raise DemosOutTakenError(
                f"--out {path} already holds {what} (written by another process while these were recorded?); "
                f"the new demonstrations are saved at {kept} instead: use that path"
                + (", pass --force to replace the earlier ones," if demos else "")
                + " or give another --out",
                kept,
            )
        shutil.rmtree(old, ignore_errors=True)
        try:
            path.rename(old)
        except FileNotFoundError:  # another process moved it meanwhile: try again
            pass
    shutil.rmtree(old, ignore_errors=True)
    return path


def _rename_if_free(src: Path, dst: Path) -> bool:
    """Rename the folder ``src`` to ``dst`` unless something (other than an empty folder) is there: one atomic
    rename, so no other process can write ``dst`` between a check and the rename."""
    try:
        src.rename(dst)
    except OSError as exc:
        if exc.errno in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR):
            return False
        raise
    return True


def _keep_elsewhere(tmp: Path, path: Path) -> Path:
    """Give the finished folder ``tmp`` the first free name after ``path`` (``NAME-2.demos``, ...)."""
    while True:
        kept = free_demos_path(path)
        if _rename_if_free(tmp, kept):
            return kept


def leftover_saves(path: str | Path) -> list[tuple[Path, bool]]:
    """Folders that a :func:`save_demos` to ``path`` stopped midway (killed, power cut) left beside it, each with
    whether it holds whole demonstrations: ``NAME.tmp-<pid>`` (the new ones before their swap) and
    ``NAME.old-<pid>`` (the earlier ones moved aside by a replace). Folders of a process still running here
    are not listed. Nothing is deleted: a whole one may be the only copy of a recording."""
    path = Path(path)
    out = []
    for p in sorted(path.parent.glob(f"{path.name}.tmp-*")) + sorted(path.parent.glob(f"{path.name}.old-*")):
        pid = p.name.rpartition("-")[2]
        if not p.is_dir() or not pid.isdigit() or _running(int(pid)):
            continue
        out.append((p, _whole(p)))
    return out


def _running(pid: int) -> bool:
    """Whether process ``pid`` runs on this machine (a writer on another machine of a shared disk is not seen)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # e.g. another user's process
        return True
    return True


def _whole(path: Path) -> bool:
    """Whether ``path`` holds demonstrations that load: a meta.json of this format and every state file whole."""
    try:
        meta = json.loads((path / "meta.json").read_text())
        load_memmap_checked(path / "states")
    except Exception:
        return False
    return isinstance(meta, dict) and meta.get("format") == DEMO_FORMAT


def _role(p: Path) -> str:
    return "new demonstrations that had not taken the name yet" if ".tmp-" in p.name else "the ones it replaced"


def leftover_notes(path: str | Path) -> list[str]:
    """One line per :func:`leftover_saves` folder beside ``path``: what it holds and what to do with it."""
    return [
        f"{p} holds {_role(p)}, left whole by a save to {Path(path).name} that stopped midway; "
        f"use them (mv {p} OTHER.demos) or delete the folder"
        if whole
        else f"{p} is what a stopped save to {Path(path).name} left half written; delete it (rm -r {p})"
        for p, whole in leftover_saves(path)
    ]


def load_demos(path: str | Path) -> tuple[list[TensorDict], dict]:
    """Episodes (each a ``(T,)`` TensorDict of states) and the file's metadata."""
    path = Path(path)
    if not (path / "meta.json").is_file():
        whole = [p for p, ok in leftover_saves(path) if ok]
        if whole and not path.exists():  # a replace stopped between its two renames (or a save before its one)
            raise DemoError(
                f"{path} does not exist, but a drs-demos save to it stopped midway and left "
                + " and ".join(f"{_role(p)} at {p}" for p in whole)
                + f": move the one you want into place (mv {whole[0]} {path}), or record them again"
            )
        if path.is_file() and path.suffix == ".h5":
            raise DemoError(
                f"{path} is a ManiSkill trajectory file, not drs-torchrl demonstrations; convert it first: "
                f"drs-demos --family FAMILY --from-h5 {path} --out {path.with_suffix('.demos')}"
            )
        raise DemoError(f"{path} is not a drs-torchrl demonstrations directory (no meta.json); make one with drs-demos")
    try:
        meta = json.loads((path / "meta.json").read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise DemoError(
            f"{path / 'meta.json'} is damaged ({exc.__class__.__name__}: {exc}); record the "
            "demonstrations again with drs-demos"
        ) from None
    if not isinstance(meta, dict) or meta.get("format") != DEMO_FORMAT:
        found = meta.get("format") if isinstance(meta, dict) else f"a JSON {type(meta).__name__}"
        raise DemoError(f"{path}: unknown format {found!r}; make demonstrations with drs-demos")
    if int(meta.get("version", 99)) > DEMO_VERSION:
        raise DemoError(
            f"{path} has demo format version {meta['version']}, newer than this drs-torchrl reads ({DEMO_VERSION})"
        )
    try:
        states = load_memmap_checked(path / "states").clone()
    except Exception as exc:
        raise DemoError(f"{path}: the states cannot be read (corrupt or truncated?): {exc}") from exc
    missing = [k for k in ("family", "stage_keys", "shapes") if k not in meta]
    if missing:
        raise DemoError(
            f"{path / 'meta.json'} is damaged: it lacks {missing}; record the demonstrations again with drs-demos"
        )
    ep = states["episode"]
    bounds = torch.cat([torch.tensor([0]), (ep[1:] != ep[:-1]).nonzero().reshape(-1) + 1, torch.tensor([ep.numel()])])
    episodes = [states[int(a) : int(b)] for a, b in zip(bounds[:-1], bounds[1:])]
    return episodes, meta


def restage_demos(episodes: list[TensorDict], meta: dict, stage_keys) -> tuple[list[TensorDict], dict]:
    """The same demonstrations under a subset of their stage indicators (a stage ablation, ``env.stages``).

    Every recorded indicator is kept per state, so each state's stage and monotone indicators are
    recomputed from ``stage_keys``, and so are those of ``"state"`` (the state each action was taken
    in: the previous row's; the first row's from its recorded indicators' columns of ``stage_keys``).
    """
    stage_keys, recorded = list(stage_keys), list(meta["stage_keys"])
    missing = [k for k in stage_keys if k not in recorded]
    if missing:
        raise DemoError(f"the demonstrations record the stage indicators {recorded}; {missing} are not among them")
    labeller = StageIndicator(stage_keys)
    cols = [recorded.index(k) for k in stage_keys]
    out = []
    for ep in episodes:
        ep = labeller(ep.clone())
        prev = ep.get("state", None)
        if prev is not None and "stage_indicators" in prev.keys():
            head = monotone_indicators(prev.get("stage_indicators")[:1, cols])
            prev.set("stage_indicators", torch.cat([head.to(torch.float32), ep.get("stage_indicators")[:-1]], 0))
            if "stage" in prev.keys():
                prev.set(
                    "stage",
                    torch.cat([head.sum(-1, keepdim=True), ep.get("stage")[:-1]], 0).to(prev.get("stage").dtype),
                )
        out.append(ep)
    shapes = {**meta["shapes"], "stage_indicators": len(stage_keys)}
    return out, {**meta, "stage_keys": stage_keys, "shapes": shapes}


def variant_mismatches(meta: dict, overrides: dict | None) -> list[str]:
    """The run's variant overrides (``env.variant_overrides``) that the demonstrations were recorded without.

    Their stage labels follow the recording's task definition (e.g. a "placed" threshold of 2.5 cm,
    where the run's is 5 cm), so such a mismatch relabels nothing and is worth a warning.
    """
    recorded = meta.get("variant_kwargs") or {}
    variants = recorded.get("variants") if isinstance(recorded.get("variants"), list) else [recorded]
    out = []
    for key, value in (overrides or {}).items():
        have = sorted({repr(v[key]) if key in v else "the variant's default" for v in variants})
        if have != [repr(value)]:
            out.append(f"{key}={value!r} (recorded with {', '.join(have)})")
    return out


def check_demos(meta: dict, family: TaskFamily, in_shapes: dict[str, int], path: str | Path = "") -> None:
    """Raise :class:`DemoError` naming every way the demonstrations do not fit this task."""
    problems = []
    if meta["family"] != family.name:
        problems.append(f"they are from family {meta['family']!r}, the run is family {family.name!r}")
    if list(meta["stage_keys"]) != list(family.stage_keys):
        problems.append(f"their stage indicators are {meta['stage_keys']}, the family's are {list(family.stage_keys)}")
    for k, d in in_shapes.items():
        have = meta["shapes"].get(k)
        if have is None:
            problems.append(f"they lack the reward input {k!r}")
        elif int(have) != int(d):
            problems.append(f"their {k!r} has size {have}, the env's has size {d}")
    if problems:
        raise DemoError(f"demonstrations {path} do not match the task: " + "; ".join(problems))


def demos_for_run(
    path: str | Path,
    family: TaskFamily,
    *,
    num: int | None,
    in_sizes: dict[str, int],
    variant_overrides: dict | None = None,
    reward_name: str = "drs",
    use_action: bool = False,
    action_size: int | None = None,
    control_mode: str | None = None,
) -> tuple[list[TensorDict], list[str]]:
    """The first ``num`` (None: all) episodes of ``path`` for a run of ``family`` (Algorithm 1, line 3), checked:
    relabelled under the run's stages for a stage ablation; their shapes against ``in_sizes`` (the reward's inputs);
    for a reward that reads (s, a), their actions against the agent's ``action_size`` and ``control_mode``.
    Returns ``(episodes, warnings)``: a warning names variant overrides they were recorded without."""
    episodes, meta = load_demos(path)
    if list(meta["stage_keys"]) != list(family.stage_keys) and set(family.stage_keys) <= set(meta["stage_keys"]):
        episodes, meta = restage_demos(episodes, meta, family.stage_keys)  # a stage ablation (env.stages)
    warnings = []
    if mismatched := variant_mismatches(meta, variant_overrides):
        overrides = " ".join(f"--override {k}={v}" for k, v in (variant_overrides or {}).items())
        warnings.append(
            f"{path} were recorded without this run's env.variant_overrides {'; '.join(mismatched)}: their stages "
            f"follow the recording's task. To match, record them with drs-demos --family {family.name} {overrides} "
            "--out NEW.demos"
        )
    check_demos(meta, family, in_sizes, path)
    n = len(episodes) if num is None else int(num)
    if n > len(episodes):
        raise DemoError(f"demos.num={n} but {path} holds only {len(episodes)} demonstrations")
    if use_action:  # (s, a) rewards need the agent's own actions
        acts = meta.get("actions")
        if acts is None:
            raise DemoError(
                f"reward={reward_name} reads (s, a), but {path} holds states only (planner demonstrations, or "
                "recorded before actions were kept); record demonstrations with drs-demos --from-policy RUN_DIR, "
                "or use reward.use_action=false"
            )
        if acts["control_mode"] != control_mode or int(acts["size"]) != int(action_size):
            raise DemoError(
                f"the actions in {path} are {acts['size']}-dimensional {acts['control_mode']} commands; this run "
                f"acts with {int(action_size)}-dimensional {control_mode}"
            )
    return episodes[:n], warnings
