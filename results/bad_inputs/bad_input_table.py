#!/usr/bin/env python
"""Run every console script on bad inputs and write the table of what each got.

    .venv/bin/python results/bad_inputs/bad_input_table.py               # writes results/bad_inputs/README.md
    .venv/bin/python results/bad_inputs/bad_input_table.py --out T.md    # elsewhere (tests/test_bad_input_table.py)

Each case runs in a fresh temporary directory, cases side by side (one per core); a case that damages
or reuses a run works on its own copy of one real run. The table records the exit code, the error
line, whether that line is all the user got (no traceback) and whether the files of an existing run
are unchanged (``.drs-lock``, the run directory's lock, is not a run file and is left out).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import torch
import yaml

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
TINY = [
    "total_frames=256",
    "algo.learning_starts=128",
    "algo.batch_size=32",
    "eval.episodes=0",
    "logger.progress_bar=false",
    "logger.tensorboard=false",
]
LOCK = ".drs-lock"


def digest(d: Path) -> dict:
    return {
        str(p.relative_to(d)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in d.rglob("*")
        if p.is_file() and p.name != LOCK
    }


@dataclass
class Case:
    name: str
    cmd: list[str]  # "{good}": this case's copy of the good run; "{d}": its directory; "{work}": the shared inputs
    env: dict = field(default_factory=dict)
    damage: Callable[[Path], None] | None = None  # applied to the copy of the good run before the command
    # a special case: (exit code, stderr, untouched), or (None, "not run: why", None) where it cannot run
    run: Callable[["Case", Path], tuple[int | None, str, bool | None]] | None = None


def _fill(args: list[str], d: Path, work: Path) -> list[str]:
    return [a.replace("{good}", str(d / "good")).replace("{d}", str(d)).replace("{work}", str(work)) for a in args]


def _exe(cmd: list[str]) -> list[str]:
    return [cmd[0] if cmd[0].startswith("/") else str(BIN / cmd[0]), *cmd[1:]]


def two_writers(case: Case, d: Path) -> tuple[int, str, bool]:
    """Two drs-learn started at once into one directory: the second is refused while the first writes."""
    run = d / "run"
    first = subprocess.Popen(
        _exe(["drs-learn", *TINY, f"hydra.run.dir={run}"]),
        cwd=d,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    t0 = time.time()
    while not ((run / LOCK).is_file() and (run / LOCK).read_text().strip()) and time.time() - t0 < 120:
        time.sleep(0.1)
    second = subprocess.run(
        _exe(["drs-learn", *TINY, "seed=1", f"hydra.run.dir={run}"]), cwd=d, capture_output=True, text=True, timeout=600
    )
    first.communicate(timeout=600)
    rows = (run / "train.csv").read_text().splitlines() if (run / "train.csv").is_file() else []
    one_run = (
        first.returncode == 0
        and yaml.safe_load((run / "config.yaml").read_text())["seed"] == 0
        and "seed=1" not in (run / ".hydra" / "overrides.yaml").read_text()
        and sum(r.startswith("step,") for r in rows) == 1
        and not list(run.glob(".hydra-*-*"))
    )
    return second.returncode, second.stderr, one_run


def disk_full(case: Case, d: Path) -> tuple[int, str, bool]:
    """drs-learn on a 3 MB filesystem (a tmpfs in a private mount namespace): the state at 2048 env steps fits,
    the one at 3072 does not."""
    mnt, out = d / "small", d / "out"
    mnt.mkdir()
    out.mkdir()
    args = [
        "total_frames=4096",
        "algo.learning_starts=4096",
        "algo.batch_size=32",
        "algo.hidden=[32,32]",
        "eval.episodes=0",
        "checkpoint_interval=1024",
        "logger.interval=512",
        "stop_at_success=null",
        "logger.progress_bar=false",
        "logger.tensorboard=false",
        f"hydra.run.dir={mnt / 'run'}",
    ]
    script = (
        f"mount -t tmpfs -o size=3m tmpfs {mnt} || exit 99; {' '.join(map(repr, _exe(['drs-learn', *args])))}; "
        f"rc=$?; cp -a {mnt / 'run'} {out}/; exit $rc"
    )
    ns = ["unshare", "--mount"] if os.geteuid() == 0 else ["unshare", "--user", "--map-root-user", "--mount"]
    p = subprocess.run([*ns, "sh", "-c", script], cwd=d, capture_output=True, text=True, timeout=600)
    if p.returncode == 99 or "unshare:" in p.stderr:  # a container without CAP_SYS_ADMIN, no user namespaces
        return None, f"not run: no small filesystem could be mounted here ({' '.join(p.stderr.split())[:120]})", None
    state = out / "run" / "checkpoints"
    kept = (state / "state" / "COMPLETE").is_file() and not list(state.glob("state.tmp-*"))
    return p.returncode, p.stderr, kept


def maze_run(case: Case, d: Path) -> tuple[int, str, bool]:
    """A case on a copy of a committed drs-quickstart maze run (``{maze}``), with a Hydra record of its own."""
    maze = d / "maze"
    shutil.copytree(ROOT / "results" / "quickstart" / "seed1" / "learn", maze)
    (maze / ".hydra").mkdir()
    (maze / ".hydra" / "config.yaml").write_text("the maze run's own record\n")
    before = digest(maze)
    args = [a.replace("{maze}", str(maze)).replace("{d}", str(d)) for a in case.cmd]
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    p = subprocess.run(_exe(args), cwd=d, env=env, capture_output=True, text=True, timeout=600)
    return p.returncode, p.stderr, digest(maze) == before


def damage_config(run: Path) -> None:
    with open(run / "config.yaml", "a") as f:
        f.write("env: [unclosed\n")


def damage_csv(run: Path) -> None:
    (run / "train.csv").write_text('frames,success_rate\n1,"unterminated\n')


def damage_state(run: Path) -> None:
    f = run / "checkpoints" / "state" / "trainer.pt"
    f.write_bytes(f.read_bytes()[:100])


class _Payload:
    """Unpickling it creates ``RAN`` inside the run: a loader that ran the file's code shows as "files touched"."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))  # an empty file: the run's digest changes


def craft(f: Path, marker: Path) -> None:
    """``f`` as it was, plus a pickled call (a file from elsewhere that would run code)."""
    torch.save({**torch.load(f, weights_only=True), "extra": _Payload(marker)}, f)


def craft_policy(run: Path) -> None:
    craft(run / "checkpoints" / "policy.pt", run / "RAN")


def craft_state(run: Path) -> None:
    craft(run / "checkpoints" / "state" / "trainer.pt", run / "RAN")


def craft_config_target(run: Path) -> None:
    cfg = yaml.safe_load((run / "config.yaml").read_text())
    cfg["algo"]["optim"]["_target_"] = "os.system"
    (run / "config.yaml").write_text(yaml.safe_dump(cfg))


def eval_beside_a_writer(case: Case, d: Path) -> tuple[int, str, bool]:
    """drs-eval of a run another process holds the lock of: refused before its episodes, the run untouched."""
    run = d / "good"
    before = digest(run)
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            f"from drs_torchrl.runtime.rundir import lock_run_dir; lock_run_dir({str(run)!r}); input()",
        ],
        stdin=subprocess.PIPE,
        env=dict(os.environ, PYTHONPATH=str(ROOT / "src")),
    )
    t0 = time.time()
    while not ((run / LOCK).is_file() and (run / LOCK).read_text().strip()) and time.time() - t0 < 60:
        time.sleep(0.1)
    p = subprocess.run(_exe(_fill(case.cmd, d, d)), cwd=d, capture_output=True, text=True, timeout=600)
    holder.communicate(b"\n", timeout=60)
    return p.returncode, p.stderr, digest(run) == before


def damage_demos(demos: Path) -> None:
    (demos / "meta.json").write_text("{not json")


def cases(work: Path, good_run: Path) -> list[Case]:
    R = ["drs-reuse", *TINY]
    L = ["drs-learn", *TINY]
    ck = "{good}/checkpoints"
    return [
        Case("reward checkpoint from another family", [*R, f"reward.checkpoint={work / 'other_family.pt'}"]),
        Case(
            "reward checkpoint with another observation layout", [*R, f"reward.checkpoint={work / 'other_layout.pt'}"]
        ),
        Case("reward checkpoint with another number of stages", [*R, f"reward.checkpoint={work / 'two_stages.pt'}"]),
        Case(
            "reward checkpoint learned with other stages (as many)",
            [*R, f"reward.checkpoint={work / 'other_stages.pt'}"],
        ),
        Case("truncated reward checkpoint", [*R, f"reward.checkpoint={work / 'truncated.pt'}"]),
        Case("reward checkpoint from a newer format version", [*R, f"reward.checkpoint={work / 'future.pt'}"]),
        Case("a policy checkpoint passed as the reward", [*R, f"reward.checkpoint={ck}/policy.pt"]),
        Case("no reward checkpoint for reward=drs", [*R]),
        Case("a folder passed as the reward checkpoint", [*R, "reward.checkpoint={good}"]),
        Case("unknown task family", [*L, "env.family=pick_banana"]),
        Case("unknown variant", [*L, "env.split=cube_9cm"]),
        Case("unknown reward", [*L, "reward=vice"]),
        Case("unknown override key", [*L, "algo.batchsize=64"]),
        Case("negative budget", [*L, "total_frames=-1"]),
        Case("alpha >= 1/2", [*L, "reward.alpha=0.5"]),
        Case("batch larger than the buffer can supply", [*L, "algo.buffer_size=16"]),
        Case("missing ManiSkill asset (env that needs YCB)", [*L, "env=pick_ycb"], {"MS_ASSET_DIR": "{d}/no_assets"}),
        Case("no usable Vulkan device", [*L], {"VK_ICD_FILENAMES": "{d}/none.json"}),
        # no CUDA device visible, on a GPU machine too (there these would be runs, not bad inputs)
        Case("CUDA asked for, none present", [*L, "device=cuda"], {"CUDA_VISIBLE_DEVICES": ""}),
        Case(
            "GPU simulation asked for, no CUDA",
            [*L, "env.sim_backend=physx_cuda", "env.num_envs=64"],
            {"CUDA_VISIBLE_DEVICES": ""},
        ),
        Case("demonstrations that do not match the task", [*L, f"demos.path={work / 'wrong.demos'}"]),
        Case("demonstrations path that is not a demos directory", [*L, f"demos.path={work}"]),
        Case("demonstrations whose meta.json is damaged", [*L, "demos.path={d}/damaged.demos"]),
        Case("a negative number of demonstrations", [*L, f"demos.path={work / 'wrong.demos'}", "demos.num=-1"]),
        Case("resume of a directory that is not a run", ["drs-learn", "resume={d}/nowhere"]),
        Case("resume switching a config group", ["drs-learn", "resume={good}", "algo=sac_paper"]),
        Case(
            "resume changing a setting the saved state was made with",
            ["drs-learn", "resume={good}", "reward.hidden=[64]"],
        ),
        Case("resume with drs-reuse of a drs-learn run", ["drs-reuse", "resume={good}"]),
        Case(
            "resume of a run whose config.yaml is not valid YAML", ["drs-learn", "resume={good}"], damage=damage_config
        ),
        Case("resume of a run whose training state is truncated", ["drs-learn", "resume={good}"], damage=damage_state),
        Case("a value of the wrong type", [*L, "total_frames=abc"]),
        Case("a new run in a directory that holds one (no resume=)", [*L, "hydra.run.dir={good}"]),
        Case("overwrite=no (a switch given as a word)", [*L, "hydra.run.dir={good}", "overwrite=no"]),
        Case(
            "overwrite=true refused by a later check (a missing demonstrations file): the old run stays",
            [*L, "hydra.run.dir={good}", "overwrite=true", "demos.path={d}/none.demos"],
        ),
        Case(
            "drs-reuse overriding what its reward checkpoint was learned with",
            [*R, "reward.checkpoint={good}/checkpoints/reward.pt", "reward.alpha=0.2"],
        ),
        Case("resume changing the task family", ["drs-learn", "resume={good}", "env.family=stack_cube"]),
        Case("a misspelt variant parameter", [*L, "+env.variant_overrides.cube_half_sze=0.018"]),
        Case("two runs started at once into one directory", [], run=two_writers),
        Case("a full disk while saving the training state (3 MB filesystem)", [], run=disk_full),
        Case("a run directory under a file", [*L, f"hydra.run.dir={work / 'a_file'}/run"]),
        Case("an unknown learner precision", [*L, "algo.precision=fp8"]),
        Case("fp16 learner on a CPU", [*L, "algo.precision=fp16"]),
        Case(
            "config-defined family with a stage key the env does not report",
            [*L, "env=custom", "env.family=mine", "env.env_id=PushCube-v1", "env.stage_keys=[is_grasped,success]"],
        ),
        Case("config-defined family named like a built-in one", [*L, "env=custom", "env.family=pick_cube"]),
        Case(
            "config-defined family whose last stage is not success",
            [*L, "env=custom", "env.family=mine", "env.env_id=PushCube-v1", "env.stage_keys=[is_grasped,done]"],
        ),
        Case(
            "config-defined family with an env id ManiSkill does not know",
            [*L, "env=custom", "env.family=mine", "env.env_id=PushCub-v1"],
        ),
        Case("drs-eval of a directory that is not a run", ["drs-eval", "{d}/nowhere"]),
        Case("drs-eval on an unknown variant", ["drs-eval", "{good}", "--split", "cube_9cm"]),
        Case("drs-eval of a run whose config.yaml is not valid YAML", ["drs-eval", "{good}"], damage=damage_config),
        Case("drs-eval --video naming a file", ["drs-eval", "{good}", "--video", f"{work / 'a_file'}"]),
        Case("drs-eval --out naming a folder", ["drs-eval", "{good}", "--out", "{d}"]),
        Case(
            "drs-demos --out naming a folder that is not demonstrations", ["drs-demos", "--num", "1", "--out", "{good}"]
        ),
        Case(
            "drs-demos --out naming earlier demonstrations (no --force)",
            ["drs-demos", "--num", "1", "--out", "{d}/earlier.demos"],
        ),
        Case("drs-demos --from-policy of a folder that is not a run", ["drs-demos", "--from-policy", "{d}"]),
        Case("drs-demos --from-h5 of a missing file", ["drs-demos", "--from-h5", "{d}/none.h5"]),
        Case("drs-study with a malformed study file", ["drs-study", str(work / "other_family.pt")]),
        Case(
            "drs-study with a typo in one run's overrides (nothing may start)",
            ["drs-study", str(work / "typo_study.yaml")],
        ),
        Case(
            "drs-study --report into a file",
            ["drs-study", str(work / "typo_study.yaml"), "--report", f"{work / 'a_file'}"],
        ),
        Case(
            "drs-compare of a run whose train.csv is damaged",
            ["drs-compare", "{good}", "--out", "{d}/cmp"],
            damage=damage_csv,
        ),
        Case("drs-compare --out naming a file", ["drs-compare", "{good}", "--out", f"{work / 'a_file'}"]),
        Case(
            "drs-plot of a run whose train.csv is damaged",
            ["drs-plot", "{good}", "--out", "{d}/p.png"],
            damage=damage_csv,
        ),
        Case("drs-plot --out under a file", ["drs-plot", "{good}", "--out", f"{work / 'a_file'}/p.png"]),
        Case(
            "drs-maze with a missing reward checkpoint",
            ["drs-maze", "phase=reuse", "reward.name=drs", "reward.checkpoint={d}/none.pt", "hydra.run.dir={d}/m"],
        ),
        Case("drs-maze with a value of the wrong type", ["drs-maze", "dqn.lr=fast", "hydra.run.dir={d}/m"]),
        Case("drs-learn env=maze with a ManiSkill algorithm", ["drs-learn", "env=maze", "algo=sac_cpu"]),
        Case(
            "drs-maze report of a folder without runs",
            ["drs-maze", "phase=report", "report.root={d}", "report.out={d}/r"],
        ),
        Case("drs-quickstart into a file", ["drs-quickstart", f"out={work / 'a_file'}"]),
        Case("drs-quickstart into a folder of other files", ["drs-quickstart", "out={good}"]),
        Case("drs-bench of an unknown task family", ["drs-bench", "--family", "pick_banana"]),
        Case("drs-doctor with no usable Vulkan device", ["drs-doctor"], {"VK_ICD_FILENAMES": "{d}/none.json"}),
        Case("a section given one value", [*L, "eval=5"]),
        Case("a network width that is not a number", [*L, "algo.hidden=[abc,16]"]),
        Case("demonstrations path naming a ManiSkill .h5 file", [*L, f"demos.path={work / 'trajectory.h5'}"]),
        Case("drs-eval of a drs-maze run", ["drs-eval", "{maze}"], run=maze_run),
        Case("drs-learn resume= of a drs-maze run", ["drs-learn", "resume={maze}"], run=maze_run),
        Case("drs-maze into a directory holding a maze run", ["drs-maze", "hydra.run.dir={maze}"], run=maze_run),
        Case("drs-maze resume= of a finished maze run", ["drs-maze", "resume={maze}"], run=maze_run),
        Case("drs-learn algo=dqn on a continuous-action family", [*L, "algo=dqn"]),
        Case("drs-maze with another family's env", ["drs-maze", "env=pick_cube", "hydra.run.dir={d}/m"]),
        Case("a config group set to null", [*L, "algo=null"]),
        Case("drs-compare naming one run twice", ["drs-compare", "{good}", "{good}/", "--out", "{d}/cmp"]),
        Case("drs-study with two runs of the same settings", ["drs-study", str(work / "twin_study.yaml")]),
        Case("drs-study --jobs 0", ["drs-study", str(work / "typo_study.yaml"), "--jobs", "0"]),
        Case("a negative seed", [*L, "seed=-1"]),
        Case(
            "config-defined family with its stage keys as one string",
            [*L, "env=custom", "env.family=mine", "env.env_id=PushCube-v1", "env.stage_keys=success"],
        ),
        Case("drs-quickstart with a setting that is not a list", ["drs-quickstart", "learn=5", "out={d}/q"]),
        Case("a '+' override adding a setting nothing reads", [*L, "+algo.lr=1e-3"]),
        Case(
            "drs-maze with a '+' override adding a setting nothing reads",
            ["drs-maze", "+dqn.lr2=1e-3", "hydra.run.dir={d}/m"],
        ),
        Case("a constructor argument the built object does not take", [*L, "+algo.loss.alpha_int=0.5"]),
        Case("a _target_ that does not import", [*L, "algo.collector._target_=torchrl.collectors.AsyncColector"]),
        Case("an empty run directory (hydra.run.dir=$RUN, RUN unset)", [*L, "hydra.run.dir="]),
        Case("drs-quickstart with an empty out=", ["drs-quickstart", "out="]),
        Case("a number of demonstrations without demonstrations", [*L, "demos.num=5"]),
        Case(
            "a reward checkpoint given to a static reward (drs-reuse reward=dense)",
            ["drs-reuse", *TINY, "reward=dense", "reward.checkpoint={good}/checkpoints/reward.pt"],
        ),
        # files from elsewhere run no code (each carries a pickled call that would create RAN in the run)
        Case("drs-eval of a run whose policy.pt carries pickled code", ["drs-eval", "{good}"], damage=craft_policy),
        Case(
            "init_from= a run whose policy.pt carries pickled code",
            ["drs-reuse", *TINY, "reward=dense", "init_from={good}"],
            damage=craft_policy,
        ),
        Case(
            "resume= of a run whose training state carries pickled code",
            ["drs-learn", "resume={good}"],
            damage=craft_state,
        ),
        Case(
            "a reward.pt that carries pickled code",
            [*R, "reward.checkpoint={good}/checkpoints/reward.pt"],
            damage=lambda run: craft(run / "checkpoints" / "reward.pt", run / "RAN"),
        ),  # fmt: skip
        Case(
            "drs-eval of a run whose config.yaml names code outside the library",
            ["drs-eval", "{good}"],
            damage=craft_config_target,
        ),
        Case(
            "resume= of a run whose config.yaml names code outside the library",
            ["drs-learn", "resume={good}"],
            damage=craft_config_target,
        ),  # fmt: skip
        Case("a non-ASCII path left unquoted", [*R, "reward.checkpoint={d}/müde/reward.pt"]),
        Case("drs-eval of a run another process is writing", ["drs-eval", "{good}"], run=eval_beside_a_writer),
    ]


def prepare(work: Path) -> Path:
    """The inputs the cases share: a real run (its reward and policy), damaged and mismatched files."""
    sys.path.insert(0, str(ROOT / "src"))
    from tensordict import TensorDict

    from drs_torchrl.demos import save_demos
    from drs_torchrl.transforms import DrSReward

    good_run = work / "good"
    subprocess.run([str(BIN / "drs-learn"), *TINY, f"hydra.run.dir={good_run}"], check=True, capture_output=True)
    good = good_run / "checkpoints" / "reward.pt"
    r = DrSReward.from_checkpoint(good)
    other_family = DrSReward(3, r.reward_in_keys, r.in_shapes, metadata={**r.metadata, "family": "stack_cube"})
    other_family.save(work / "other_family.pt")
    DrSReward(3, ["observation"], {"observation": 48}, metadata=r.metadata).save(work / "other_layout.pt")
    DrSReward(2, r.reward_in_keys, r.in_shapes, metadata=r.metadata).save(work / "two_stages.pt")
    swapped = {**r.metadata, "stage_keys": ["is_obj_placed", "is_grasped", "success"]}
    DrSReward(3, r.reward_in_keys, r.in_shapes, metadata=swapped).save(work / "other_stages.pt")
    data = good.read_bytes()
    (work / "truncated.pt").write_bytes(data[: len(data) // 3])
    payload = torch.load(good, weights_only=True)
    payload["version"] = 99
    torch.save(payload, work / "future.pt")
    states = TensorDict(
        {
            "observation": torch.zeros(4, 40),
            "stage_indicators": torch.zeros(4, 3),
            "episode": torch.zeros(4, dtype=torch.long),
        },
        [4],
    )
    save_demos(
        states,
        {
            "format": "drs-torchrl/demos",
            "version": 1,
            "family": "pick_cube",
            "stage_keys": ["is_grasped", "is_obj_placed", "success"],
            "shapes": {"observation": 40, "stage_indicators": 3},
        },
        work / "wrong.demos",
    )
    (work / "a_file").write_text("not a folder\n")
    # a study whose second run has a typo in an override: refused before any run starts
    (work / "typo_study.yaml").write_text(
        f"root: {work / 'typo_study_runs'}\napp: learn\ncommon: [{', '.join(TINY)}]\n"
        "runs:\n  - {name: good, args: [seed=0]}\n  - {name: typo, args: [algo.batchsize=64]}\n"
    )
    # a study whose second run is the first one copied with its seed unchanged
    (work / "twin_study.yaml").write_text(
        f"root: {work / 'typo_study_runs'}\napp: learn\ncommon: [{', '.join(TINY)}]\n"
        "runs:\n  - {name: a_s0, args: [seed=0]}\n  - {name: a_s1, args: [seed=0]}\n"
    )
    (work / "trajectory.h5").write_bytes(b"\x89HDF\r\n\x1a\n")  # the start of an HDF5 file
    return good_run


def run_case(case: Case, d: Path, work: Path, good_run: Path) -> tuple[int, str, bool]:
    d.mkdir()
    uses_good = any("{good}" in a for a in case.cmd)
    if uses_good:
        shutil.copytree(good_run, d / "good", ignore=shutil.ignore_patterns(LOCK))
        if case.damage is not None:
            case.damage(d / "good")
    if "earlier.demos" in " ".join(case.cmd):
        shutil.copytree(work / "wrong.demos", d / "earlier.demos")
    if "damaged.demos" in " ".join(case.cmd):
        shutil.copytree(work / "wrong.demos", d / "damaged.demos")
        damage_demos(d / "damaged.demos")
    if case.run is not None:
        return case.run(case, d)
    before = digest(d / "good") if uses_good else {}
    args = _fill(case.cmd, d, work)
    if args[0] in ("drs-learn", "drs-reuse") and not any(a.startswith(("resume=", "hydra.run.dir=")) for a in args):
        args.append(f"hydra.run.dir={d / 'run'}")
    env = dict(os.environ, PYTHONWARNINGS="ignore", **{k: v.replace("{d}", str(d)) for k, v in case.env.items()})
    p = subprocess.run(_exe(args), cwd=d, env=env, capture_output=True, text=True, timeout=600)
    untouched = (digest(d / "good") == before if uses_good else True) and not (work / "typo_study_runs").exists()
    return p.returncode, p.stderr, untouched


def error_line(stderr: str) -> str:
    lines = [ln for ln in stderr.splitlines() if ln.strip() and "WARNING" not in ln and "warn" not in ln.lower()]
    msg = (
        next((ln for ln in lines if ln.startswith(("drs-", "not run:")) and ("error:" in ln or "not run:" in ln)), None)
        or " ".join(ln.strip() for ln in lines if ln.strip().startswith(("Could not", "Available options", "Key '")))
        or next((ln for ln in reversed(lines) if "Error:" in ln), None)
        or (lines[-1] if lines else "")
    )
    return msg.strip()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "bad_inputs" / "README.md")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="cases side by side (default: one per core)")
    a = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="drs-bad-"))
    good_run = prepare(work)
    todo = cases(work, good_run)
    with ThreadPoolExecutor(a.jobs) as pool:
        results = list(pool.map(lambda ic: run_case(ic[1], work / f"case{ic[0]}", work, good_run), enumerate(todo)))
    rows = []
    for case, (rc, stderr, untouched) in zip(todo, results):
        msg = error_line(stderr)
        clean = "Traceback" not in stderr and msg.startswith("drs-") and "internal error" not in msg
        rows.append((case.name, rc, msg[:300], clean, untouched))
        print(
            f"{rc if rc is not None else '-':>3}  {'one line' if clean else 'NO      '}  {case.name}: {msg[:150]}",
            flush=True,
        )
    md = [
        "# Bad inputs and what they get",
        "",
        'Produced by `.venv/bin/python results/bad_inputs/bad_input_table.py` (each case in a fresh directory; "one line": the '
        'error line is all the user got, no traceback; "files untouched" compares the hashes of every file of an '
        "existing run directory before and after, the run directory's lock `.drs-lock` aside; for two runs started "
        "at once it means the directory holds the first run's files only, for a full disk that the last complete "
        "training state is kept and no temporary files are left).",
        "",
        "| bad input | exit code | message | one line | existing run files untouched |",
        "|---|---|---|---|---|",
    ]
    for name, rc, msg, clean, untouched in rows:
        if rc is None:
            md.append(f"| {name} | - | {msg.replace('|', '/')} | - | - |")
            continue
        md.append(
            f"| {name} | {rc} | {msg.replace('|', '/')} | {'yes' if clean else 'NO'} | {'yes' if untouched else 'NO'} |"
        )
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text("\n".join(md) + "\n")
    print(a.out)
    shutil.rmtree(work, ignore_errors=True)
    return 0 if all(rc != 0 and untouched is not False for _, rc, _, _, untouched in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
