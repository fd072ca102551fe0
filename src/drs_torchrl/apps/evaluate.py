"""``drs-eval``: a trained policy's episodes on any split or variant, reported as ManiSkill evaluates.

    drs-eval RUN_DIR                                  # 10 deterministic episodes on the run's own split
    drs-eval RUN_DIR --split test --episodes 50       # the held-out variants
    drs-eval RUN_DIR --split cube_1_5cm --override cube_half_size=0.016
    drs-eval RUN_DIR --episodes 3 --video videos/     # and an mp4 per episode (software Vulkan renders it)
    drs-eval RUN_DIR --episode-seed 0                 # episode i starts from seed i: the same starts for every run

Per episode: ``success_once`` (success at any step), ``success_at_end`` (at the last step; the same
here because episodes end on success, as in the authors' code), the highest stage reached, the
length and the return under the run's own reward (its learned reward for a DrS run). Prints a table
and writes ``eval_<split>.json`` into the run directory (or ``--out``); ``--override`` values are part of
that name, and an earlier report made with other settings is kept (the new one takes the next free name).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
from pathlib import Path

import numpy as np
import torch

from drs_torchrl.runtime.checkpoint import atomic_write_text
from drs_torchrl.runtime.console import UserError, at_least, console_script
from drs_torchrl.apps.reward_registry import with_builders
from drs_torchrl.runtime.rundir import check_writable, load_run_config, lock_run_dir, unlock_run_dir


class EvalError(UserError, ValueError):
    """A run directory or option that cannot be evaluated."""


def _run_reward(run_dir: Path, cfg):
    """The reward transform the run trained with, for the episodes' return (None: the env's reward)."""
    from drs_torchrl.rewards import is_learned
    from drs_torchrl.transforms.reward import load_reward

    if not is_learned(cfg.reward) or cfg.phase != "learn":
        return None  # a reused learned reward is the setup's frozen transform
    path = run_dir / "checkpoints" / "reward.pt"
    if not path.is_file() and (run_dir / "reward.pt").is_file():
        path = run_dir / "reward.pt"  # a committed record (drs-study --report): checkpoints flattened beside the CSVs
    return load_reward(path)


def start_fingerprint(start) -> str:
    """12 hex digits naming an episode's start state, so that two reports can show they met the same episodes."""
    import hashlib

    obs = torch.cat(
        [
            start.get(k).detach().float().reshape(-1).cpu()
            for k in sorted(start.keys(True, True), key=str)
            if k not in ("done", "terminated", "truncated") and start.get(k).dtype.is_floating_point
        ]
    )
    return hashlib.sha1(obs.numpy().round(5).tobytes()).hexdigest()[:12]


def evaluate_run(
    run_dir: str | Path,
    *,
    episodes: int = 10,
    split: str | None = None,
    overrides: dict | None = None,
    deterministic: bool = True,
    seed: int = 12345,
    video_dir: str | Path | None = None,
    keep_episodes: bool = False,
    episode_seed: int | None = None,
) -> dict:
    """Roll out the policy of ``run_dir`` for ``episodes`` episodes; returns per-episode rows and means
    (and, with ``keep_episodes``, each episode's stage and reward per step under ``"episodes"``).

    ``episode_seed=S`` resets episode i with seed S + i (the trainer's ``eval.episode_seed``): episode i then
    starts from the same state whatever the number of episodes or the policy, so two runs' reports pair up.
    Without it only the first reset is seeded (``seed``) and later starts follow torch's global RNG."""
    from omegaconf import OmegaConf
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from drs_torchrl.envs.factory import make_family_env
    from drs_torchrl.models import PolicyCheckpointError, load_policy
    from drs_torchrl.rewards import dense_offset, reward_setup
    from drs_torchrl.tasks import family_from_config

    run_dir = Path(run_dir)
    if run_dir.is_file() and run_dir.parent.name == "checkpoints":  # RUN_DIR/checkpoints/policy.pt
        run_dir = run_dir.parent.parent
    if not (run_dir / "config.yaml").is_file():
        raise EvalError(f"{run_dir} is not a drs-learn/drs-reuse run directory (no config.yaml)")
    if episodes < 1:
        raise EvalError(f"--episodes must be >= 1, got {episodes}")
    if episode_seed is not None and episode_seed < 0:
        raise EvalError(f"--episode-seed must be >= 0, got {episode_seed}")
    cfg = load_run_config(run_dir)
    with_builders(cfg.reward)  # a config saved before the reward registry named its builders
    family = family_from_config(cfg.env)
    split = split or cfg.env.split
    family.split_variants(split)  # unknown names raise the KeyError listing the variants
    from drs_torchrl.tools.study import RecordError, pinned_reward

    try:  # a committed record names the reward it reused in reward.json (drs-study --report), pinned by hash
        pinned = pinned_reward(run_dir)
    except RecordError as exc:
        raise EvalError(str(exc)) from None
    if pinned is not None:
        cfg.reward.checkpoint = str(pinned)
    setup = reward_setup(cfg.reward, cfg.phase)
    variant_overrides = {**(OmegaConf.to_container(cfg.env.variant_overrides) or {}), **(overrides or {})}
    env = make_family_env(
        family,
        split,
        seed=seed,
        variant_overrides=variant_overrides or None,
        reward_mode=setup.env_reward_mode,
        semi_sparse_reward=setup.semi_sparse,
        semi_sparse_offset=setup.semi_sparse_offset,
        reward_offset=dense_offset(setup, family),
        control_mode=cfg.env.control_mode,
        max_episode_steps=cfg.env.max_episode_steps,
        render_mode="rgb_array" if video_dir else None,
    )
    try:
        actor, meta = load_policy(run_dir, env.observation_spec, env.action_spec, family=family.name)
    except PolicyCheckpointError as exc:
        env.close()
        raise EvalError(str(exc)) from exc
    reward = _run_reward(run_dir, cfg) or setup.frozen
    if video_dir:
        video_dir = check_writable(video_dir, "--video", folder=True)
        video_dir.mkdir(parents=True, exist_ok=True)
    rows, kept = [], []
    mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    try:
        for i in range(episodes):
            frames = []
            callback = (lambda e, td: frames.append(e.base_env.render_frame())) if video_dir else None
            if episode_seed is not None:
                env.set_seed(episode_seed + i, static_seed=True)
            start = env.reset()
            if video_dir:
                frames.append(env.base_env.render_frame())  # the start state
            with set_exploration_type(mode), torch.no_grad():
                # the callback runs after every step but the last one
                ep = env.rollout(
                    100_000, actor, break_when_any_done=True, callback=callback, auto_reset=False, tensordict=start
                )
            if video_dir:
                frames.append(env.base_env.render_frame())  # the final state
            nxt = ep.get("next")
            success = nxt.get("success").reshape(-1)
            if reward is None:
                r = nxt.get("reward")
            else:  # DrS reads next states; a classifier reward may read (s, a) and takes the transitions
                from drs_torchrl.transforms.classifier_reward import ClassifierReward

                r = reward.reward(ep if isinstance(reward, ClassifierReward) else nxt)
            row = {
                "episode": i,
                **({"seed": episode_seed + i} if episode_seed is not None else {}),
                "start": start_fingerprint(start),
                "success_once": bool(success.any()),
                "success_at_end": bool(success[-1]),
                "stage": int(nxt.get("stage").max()),
                "length": int(ep.shape[-1]),
                "return": float(r.sum()),
            }
            if video_dir and frames:
                import imageio

                path = video_dir / f"{run_dir.name}-{split}-ep{i}.mp4"
                imageio.mimsave(path, [np.asarray(f) for f in frames], fps=20, macro_block_size=1)
                row["video"] = str(path)
            rows.append(row)
            if keep_episodes:
                kept.append({"stage": nxt.get("stage").reshape(-1).tolist(), "reward": r.reshape(-1).tolist()})
    finally:
        env.close()
    n = family.num_stages
    summary = {
        "run_dir": str(run_dir),
        "family": family.name,
        "split": split,
        "overrides": overrides or {},
        "episodes": episodes,
        "episode_seed": episode_seed,
        "seed": seed,
        "deterministic": deterministic,
        "policy_frames": meta.get("frames"),
        "success_once": float(np.mean([r["success_once"] for r in rows])),
        "success_at_end": float(np.mean([r["success_at_end"] for r in rows])),
        "return": float(np.mean([r["return"] for r in rows])),
        "length": float(np.mean([r["length"] for r in rows])),
        **{f"reach_stage_{k}": float(np.mean([r["stage"] >= k for r in rows])) for k in range(1, n + 1)},
        "rows": rows,
    }
    if keep_episodes:
        summary["episodes_data"] = kept
        summary["reward"] = reward.description() if reward is not None else {"name": cfg.reward.name}
    return summary


# what decides which episodes a report measures: a report that differs in one of them is another measurement
REPORT_SETTINGS = ("split", "overrides", "episodes", "episode_seed", "seed", "deterministic", "policy_frames")


def report_path(res: dict) -> tuple[Path, Path | None]:
    """Where ``drs-eval`` writes ``res`` by default, and the earlier report it keeps instead of replacing.

    ``RUN_DIR/eval_<split>[_<k>=<v>...].json``. The same measurement again (every ``REPORT_SETTINGS`` equal)
    replaces its report; a report with other settings, or one that cannot be read, is kept and the new one
    takes the next free name (``..._2.json``)."""
    name = "_".join([f"eval_{res['split']}", *(f"{k}={v}" for k, v in sorted(res["overrides"].items()))])
    name = "".join(c if c.isalnum() or c in "._=-" else "-" for c in name)
    run_dir = Path(res["run_dir"])
    kept = None
    for n in itertools.count(1):
        path = run_dir / (f"{name}.json" if n == 1 else f"{name}_{n}.json")
        if not path.exists():
            return path, kept
        try:
            old = json.loads(path.read_text())
            same = all(old.get(k) == res.get(k) for k in REPORT_SETTINGS)
        except (OSError, ValueError):
            same = False
        if same:
            return path, kept
        kept = kept or path


@console_script("drs-eval")
def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="drs-eval", description=__doc__.split("\n")[0])
    p.add_argument("run_dir", help="a drs-learn / drs-reuse run directory (or its checkpoints/policy.pt)")
    p.add_argument("--episodes", type=at_least(1), default=10)
    p.add_argument("--split", default=None, help="train | test | a variant name (default: the run's split)")
    p.add_argument(
        "--override", action="append", default=[], metavar="K=V", help="a variant parameter, e.g. cube_half_size=0.016"
    )
    p.add_argument("--stochastic", action="store_true", help="sample actions instead of the deterministic policy")
    p.add_argument("--seed", type=int, default=12345, help="the env's seed (its first reset)")
    p.add_argument(
        "--episode-seed",
        type=at_least(0),
        default=None,
        metavar="S",
        help="reset episode i with seed S+i: the same starts in every call and every run (as eval.episode_seed)",
    )
    p.add_argument("--video", metavar="DIR", help="record each episode to DIR/*.mp4")
    p.add_argument(
        "--out",
        help="where to write the JSON report (default RUN_DIR/eval_<split>[_K=V].json; an earlier one with other "
        "settings is kept)",
    )
    a = p.parse_args(argv)
    try:
        return _evaluate_and_report(a)
    finally:
        unlock_run_dir(a.run_dir)  # the lock taken below, if any (the process may go on: tests, notebooks)


def _evaluate_and_report(a: argparse.Namespace) -> int:
    import yaml

    try:  # the places it writes, before minutes of episodes
        if a.video:
            check_writable(a.video, "--video", folder=True)
        if a.out:
            check_writable(a.out, "--out")
        elif Path(a.run_dir).is_dir() and not os.access(a.run_dir, os.W_OK | os.X_OK):
            raise EvalError(f"{a.run_dir} cannot be written (no permission): pass --out FILE for the report")
        elif Path(a.run_dir).is_dir():  # the report goes into the run directory: not while another process writes it
            lock_run_dir(a.run_dir, elsewhere="pass --out FILE for the report")
        overrides = {}
        for o in a.override:
            k, sep, v = o.partition("=")
            if not sep:
                raise EvalError(f"--override takes K=V, got {o!r}")
            overrides[k] = yaml.safe_load(v)
        res = evaluate_run(
            a.run_dir,
            episodes=a.episodes,
            split=a.split,
            overrides=overrides,
            deterministic=not a.stochastic,
            seed=a.seed,
            video_dir=a.video,
            episode_seed=a.episode_seed,
        )
    except (EvalError, KeyError, ValueError, FileNotFoundError) as exc:
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"drs-eval: error: {msg}", file=sys.stderr)
        return 2
    out, kept = (Path(a.out), None) if a.out else report_path(res)
    atomic_write_text(out, json.dumps(res, indent=2))
    reach = "  ".join(f"stage>={k} {res[f'reach_stage_{k}']:.2f}" for k in range(1, 99) if f"reach_stage_{k}" in res)
    print(
        f"drs-eval: {res['family']} {res['split']}, {res['episodes']} {'deterministic' if res['deterministic'] else 'stochastic'} "
        f"episodes of the policy at {res['policy_frames']} env steps"
    )
    print(
        f"  success_once {res['success_once']:.2f}  success_at_end {res['success_at_end']:.2f}  {reach}  "
        f"return {res['return']:.2f}  length {res['length']:.1f}"
    )
    if a.video:
        print(f"  videos in {a.video}")
    print(f"  report: {out}")
    if kept:
        print(f"  (kept {kept.name}: an earlier report with other settings)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
