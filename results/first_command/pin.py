"""Pin the reward each reuse record of this folder reused (reward.json: the committed file and its sha256), as every
committed reuse record does (tests/test_records.py). The record was run in a worktree whose RUN_ROOT held the runs;
the file it ran with must have the committed copy's hash.

usage: python results/first_command/pin.py WORKTREE RUN_ROOT RECORD_DIR
  e.g. python results/first_command/pin.py ../fc-test-wt runs/first_command/test results/first_command/test
"""

import sys
from pathlib import Path

import yaml

from drs_torchrl.tools.study import pin_reward, sha256_file


def main(worktree: Path, run_root: str, record: Path) -> None:
    for cfg in sorted(record.rglob("config.yaml")):
        ran_with = (yaml.safe_load(cfg.read_text()).get("reward") or {}).get("checkpoint")
        if not ran_with:
            continue
        if ran_with.startswith("results/"):  # a reward committed before the run (seeds 0-2 of the quickstart)
            committed = Path(ran_with)
        else:
            committed = record / Path(ran_with).relative_to(run_root)
        original = worktree / ran_with
        assert committed.is_file(), f"{cfg.parent}: {committed} is not in the record"
        assert sha256_file(original) == sha256_file(committed), f"{cfg.parent}: {committed} differs from {original}"
        print(pin_reward(cfg.parent, committed, ran_with))


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2], Path(sys.argv[3]))
