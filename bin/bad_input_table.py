#!/usr/bin/env python
"""Run drs-learn / drs-reuse on each bad input of issue 5 and write the table of what each got.

    .venv/bin/python bin/bad_input_table.py   # writes results/bad_inputs/README.md

Each case runs in a fresh temporary directory; the table records the exit code, the error line
and whether files that existed before the command are unchanged.
"""
from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
TINY = ["total_frames=256", "algo.learning_starts=128", "algo.batch_size=32", "eval.episodes=0",
        "logger.progress_bar=false", "logger.tensorboard=false"]


def digest(d: Path) -> dict:
    return {str(p.relative_to(d)): hashlib.sha256(p.read_bytes()).hexdigest() for p in d.rglob("*") if p.is_file()}


def main() -> int:
    sys.path.insert(0, str(ROOT / "src"))
    from drs_torchrl.demos import save_demos
    from drs_torchrl.transforms import DrSReward
    from tensordict import TensorDict

    work = Path(tempfile.mkdtemp(prefix="drs-bad-"))
    # a real reward and a real run to damage
    good_run = work / "good"
    subprocess.run([str(BIN / "drs-learn"), *TINY, f"hydra.run.dir={good_run}"], check=True, capture_output=True)
    good = good_run / "checkpoints" / "reward.pt"
    r = DrSReward.from_checkpoint(good)
    other_family = DrSReward(3, r.reward_in_keys, r.in_shapes, metadata={**r.metadata, "family": "stack_cube"})
    other_family.save(work / "other_family.pt")
    DrSReward(3, ["observation"], {"observation": 48}, metadata=r.metadata).save(work / "other_layout.pt")
    DrSReward(2, r.reward_in_keys, r.in_shapes, metadata=r.metadata).save(work / "two_stages.pt")
    data = good.read_bytes()
    (work / "truncated.pt").write_bytes(data[: len(data) // 3])
    payload = torch.load(good, weights_only=True)
    payload["version"] = 99
    torch.save(payload, work / "future.pt")
    states = TensorDict({"observation": torch.zeros(4, 40), "stage_indicators": torch.zeros(4, 3),
                         "episode": torch.zeros(4, dtype=torch.long)}, [4])
    save_demos(states, {"format": "drs-torchrl/demos", "version": 1, "family": "pick_cube", "stage_keys": ["is_grasped", "is_obj_placed", "success"],
                        "shapes": {"observation": 40, "stage_indicators": 3}}, work / "wrong.demos")
    # a study whose second run has a typo in an override: refused before any run starts
    (work / "typo_study.yaml").write_text(
        f"root: {work / 'typo_study_runs'}\napp: learn\ncommon: [{', '.join(TINY)}]\n"
        "runs:\n  - {name: good, args: [seed=0]}\n  - {name: typo, args: [algo.batchsize=64]}\n")

    R = ["drs-reuse", *TINY]
    L = ["drs-learn", *TINY]
    cases = [
        ("reward checkpoint from another family", [*R, f"reward.checkpoint={work / 'other_family.pt'}"], {}),
        ("reward checkpoint with another observation layout", [*R, f"reward.checkpoint={work / 'other_layout.pt'}"], {}),
        ("reward checkpoint with another number of stages", [*R, f"reward.checkpoint={work / 'two_stages.pt'}"], {}),
        ("truncated reward checkpoint", [*R, f"reward.checkpoint={work / 'truncated.pt'}"], {}),
        ("reward checkpoint from a newer format version", [*R, f"reward.checkpoint={work / 'future.pt'}"], {}),
        ("a policy checkpoint passed as the reward", [*R, f"reward.checkpoint={good_run / 'checkpoints' / 'policy.pt'}"], {}),
        ("no reward checkpoint for reward=drs", [*R], {}),
        ("unknown task family", [*L, "env.family=pick_banana"], {}),
        ("unknown variant", [*L, "env.split=cube_9cm"], {}),
        ("unknown reward", [*L, "reward=vice"], {}),
        ("unknown override key", [*L, "algo.batchsize=64"], {}),
        ("negative budget", [*L, "total_frames=-1"], {}),
        ("alpha >= 1/2", [*L, "reward.alpha=0.5"], {}),
        ("batch larger than the buffer can supply", [*L, "algo.buffer_size=16"], {}),
        ("missing ManiSkill asset (env that needs YCB)", [sys.executable, "-c",
          "from drs_torchrl.envs import ManiSkillEnv; ManiSkillEnv('PickSingleYCB-v1', ['success'])"], {}),
        ("no usable Vulkan device", [*L], {"VK_ICD_FILENAMES": str(work / "none.json")}),
        ("CUDA asked for, none present", [*L, "device=cuda"], {}),
        ("GPU simulation asked for, no CUDA", [*L, "env.sim_backend=physx_cuda", "env.num_envs=64"], {}),
        ("demonstrations that do not match the task", [*L, f"demos.path={work / 'wrong.demos'}"], {}),
        ("demonstrations path that is not a demos directory", [*L, f"demos.path={work}"], {}),
        ("resume of a directory that is not a run", ["drs-learn", f"resume={work / 'nowhere'}"], {}),
        ("resume switching a config group", ["drs-learn", f"resume={good_run}", "algo=sac_paper"], {}),
        ("resume with drs-reuse of a drs-learn run", ["drs-reuse", f"resume={good_run}"], {}),
        ("a value of the wrong type", [*L, "total_frames=abc"], {}),
        ("a new run in a directory that holds one (no resume=)", [*L, f"hydra.run.dir={good_run}"], {}),
        ("an unknown learner precision", [*L, "algo.precision=fp8"], {}),
        ("fp16 learner on a CPU", [*L, "algo.precision=fp16"], {}),
        ("config-defined family with a stage key the env does not report",
         [*L, "env=custom", "env.family=mine", "env.env_id=PushCube-v1", "env.stage_keys=[is_grasped,success]"], {}),
        ("config-defined family named like a built-in one", [*L, "env=custom", "env.family=pick_cube"], {}),
        ("drs-eval of a directory that is not a run", ["drs-eval", str(work / "nowhere")], {}),
        ("drs-eval on an unknown variant", ["drs-eval", str(good_run), "--split", "cube_9cm"], {}),
        ("drs-study with a malformed study file", ["drs-study", str(work / "other_family.pt")], {}),
        ("drs-study with a typo in one run's overrides (nothing may start)", ["drs-study", str(work / "typo_study.yaml")], {}),
    ]
    rows = []
    for name, cmd, extra_env in cases:
        before = digest(good_run)
        d = work / f"case{len(rows)}"
        d.mkdir()
        exe = cmd[0] if cmd[0].startswith("/") else str(BIN / cmd[0])
        args = list(cmd[1:])
        if cmd[0] in ("drs-learn", "drs-reuse") and not any(a.startswith(("resume=", "hydra.run.dir=")) for a in args):
            args.append(f"hydra.run.dir={d / 'run'}")
        env = dict(os.environ, PYTHONWARNINGS="ignore", **extra_env)
        p = subprocess.run([exe, *args], cwd=d, env=env, capture_output=True, text=True, timeout=600)
        lines = [ln for ln in p.stderr.splitlines() if ln.strip() and "WARNING" not in ln and "warn" not in ln.lower()]
        msg = (next((ln for ln in lines if ln.startswith("drs-") and "error:" in ln), None)
               or " ".join(ln.strip() for ln in lines if ln.strip().startswith(("Could not", "Available options", "Key '")))
               or next((ln for ln in reversed(lines) if "Error:" in ln), None)
               or (lines[-1] if lines else ""))
        untouched = digest(good_run) == before and not (work / "typo_study_runs").exists()
        rows.append((name, p.returncode, msg.strip()[:300], untouched))
        print(f"{p.returncode:3d}  {name}: {msg.strip()[:160]}", flush=True)
    out = ROOT / "results" / "bad_inputs" / "README.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    md = ["# Bad inputs and what they get", "",
          "Produced by `.venv/bin/python bin/bad_input_table.py` (each case in a fresh directory; "
          "\"files untouched\" compares the hashes of every file of an existing run directory before and after).", "",
          "| bad input | exit code | message | existing run files untouched |", "|---|---|---|---|"]
    for name, rc, msg, untouched in rows:
        md.append(f"| {name} | {rc} | {msg.replace('|', '/')} | {'yes' if untouched else 'NO'} |")
    out.write_text("\n".join(md) + "\n")
    print(out)
    return 0 if all(rc != 0 for _, rc, _, _ in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
