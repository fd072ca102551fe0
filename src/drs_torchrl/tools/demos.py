"""``drs-demos``: record demonstrations (motion planner, a trained policy) or convert ManiSkill's."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from drs_torchrl.runtime.console import UserError, at_least, console_script
from drs_torchrl.demos import (
    DemosOutTakenError,
    check_demos_out,
    free_demos_path,
    leftover_notes,
    load_maniskill_h5,
    record_demos,
    record_policy_demos,
    save_demos,
)
from drs_torchrl.tasks import get_family, with_task_observation


@console_script("drs-demos")
def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="drs-demos",
        description="generate demonstrations with ManiSkill's motion planners, "
        "record a trained policy's successful episodes (--from-policy), "
        "or convert a ManiSkill trajectory file (--from-h5)",
    )
    p.add_argument("--family", default="pick_cube")
    p.add_argument(
        "--variant",
        default=None,
        help="variant name, or train/test (default: train; with --from-policy, the split the run trained on)",
    )
    p.add_argument(
        "--num", type=at_least(1), default=None, help="default: 100 recorded; all successful ones of --from-h5"
    )
    p.add_argument(
        "--from-h5",
        type=Path,
        default=None,
        metavar="PATH.h5",
        help="convert ManiSkill's trajectory file PATH.h5 (+ PATH.json) by replaying it in the family's env",
    )
    p.add_argument(
        "--from-policy",
        default=None,
        metavar="RUN_DIR",
        help="roll out a drs-learn/drs-reuse run's policy (RUN_DIR or its policy.pt) and keep its successful "
        "episodes, as the paper's demonstrations (any family; the family comes from the checkpoint)",
    )
    p.add_argument("--stochastic", action="store_true", help="--from-policy: sample actions instead of the mean action")
    p.add_argument(
        "--max-episodes",
        type=at_least(1),
        default=None,
        help="--from-policy: give up after this many (default 20 x --num)",
    )
    p.add_argument(
        "--override",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a variant parameter for every recorded episode, e.g. placed_thresh=0.05 (the placed-threshold "
        "ablations) or max_steps=150 (repeatable; not with --from-h5)",
    )
    p.add_argument(
        "--control-mode",
        default=None,
        help="solver demonstrations: replay them in this controller "
        "(e.g. pd_ee_delta_pos, the agent's; default: the family's) with ManiSkill's converter; "
        "pd_joint_pos keeps the planner's own",
    )
    p.add_argument(
        "--task-observation",
        action="store_true",
        help="also record the env's robot-agnostic task state "
        "(key task_observation), for rewards learned with env.task_observation=true "
        "reward.in_keys=[task_observation,stage_indicators]",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="default: demos/<family>-<variant>.demos (-policy.demos with --from-policy; -2.demos, -3.demos, ... "
        "when that exists)",
    )
    p.add_argument("--force", action="store_true", help="replace the demonstrations already at --out")
    a = p.parse_args(argv)
    if a.from_policy is not None and a.from_h5 is not None:
        p.error("--from-policy and --from-h5 are two different sources; give one")
    import yaml

    overrides = {}
    for item in a.override:
        key, eq, value = item.partition("=")
        if not eq or not key:
            p.error(f"--override takes KEY=VALUE, got {item!r}")
        overrides[key] = yaml.safe_load(value)
    if overrides and a.from_h5 is not None:
        p.error("--override applies to recording (the planner or --from-policy), not to --from-h5")
    try:
        if a.out is not None:
            check_demos_out(a.out, replace=a.force)  # now, not after minutes of recording
        if a.from_policy is not None:  # a bad checkpoint raises PolicyCheckpointError, a ValueError
            states, meta = record_policy_demos(
                a.from_policy,
                a.variant,
                a.num or 100,
                seed=a.seed,
                variant_overrides=overrides,
                deterministic=not a.stochastic,
                max_episodes=a.max_episodes,
                task_observation=a.task_observation,
            )
            fam = get_family(meta["family"])
        else:
            fam = with_task_observation(get_family(a.family), a.task_observation)
            if a.from_h5 is not None:
                states, meta = load_maniskill_h5(a.from_h5, fam, a.variant or "train", num=a.num)
            else:
                states, meta = record_demos(
                    fam,
                    a.variant or "train",
                    a.num or 100,
                    seed=a.seed,
                    variant_overrides=overrides or None,
                    control_mode=a.control_mode or fam.control_mode or "pd_joint_pos",
                )
        named = a.out or Path("demos") / f"{fam.name}-{meta['variant']}{'-policy' if a.from_policy else ''}.demos"
        out = a.out or free_demos_path(named)
    except (KeyError, UserError, RuntimeError, ValueError, TypeError) as exc:
        print(f"drs-demos: error: {exc.args[0] if isinstance(exc, KeyError) else exc}", file=sys.stderr)
        return 2
    try:  # not replacing what another process wrote at --out meanwhile, unless --force
        out = save_demos(states, meta, out, replace=a.force)
    except DemosOutTakenError as exc:
        if a.out is not None:  # the error names where the new demonstrations are
            print(f"drs-demos: error: {exc}", file=sys.stderr)
            return 2
        out = exc.kept  # the default --out takes the next free name
    for note in leftover_notes(named):  # kept, never deleted: a whole one may be a recording's only copy
        print(f"drs-demos: note: {note}", file=sys.stderr)
    lengths = meta["lengths"]
    print(f"{meta['episodes']} demonstrations ({sum(lengths)} states, length {min(lengths)}-{max(lengths)}) -> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
