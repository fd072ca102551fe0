"""PREREGISTRATION.md's decision rules on the seed-5-9 record (test/seed<S>/summary.json), written as decision.md.

usage: python results/first_command/decide.py [RECORD_DIR]   (default: results/first_command)
"""

import json
import sys
from pathlib import Path

SEEDS = [5, 6, 7, 8, 9]
BAR = 0.9


def main(root: Path) -> str:
    got = {}
    for s in SEEDS:
        p = root / "test" / f"seed{s}" / "summary.json"
        if not p.is_file():
            raise SystemExit(f"seed {s} has no summary.json under {root / 'test'}: the rules apply once all five have")
        got[s] = {k: v["success_last3"] for k, v in json.loads(p.read_text())["phase2"].items()}
    drs = [got[s]["drs"] for s in SEEDS]
    sparse = [got[s]["sparse"] for s in SEEDS]
    semi = [got[s]["semi_sparse"] for s in SEEDS]
    rules = [
        ("1. the first command holds on new seeds: DrS >= 0.9", sum(d >= BAR for d in drs)),
        ("2. DrS beats sparse: DrS - sparse >= 0.2", sum(d - p >= 0.2 for d, p in zip(drs, sparse))),
        (
            "3. DrS matches semi-sparse: abs(DrS - semi-sparse) <= 0.1",
            sum(abs(d - m) <= 0.1 for d, m in zip(drs, semi)),
        ),
    ]
    lines = [
        "# Decision (PREREGISTRATION.md's rules on seeds 5-9; written by decide.py)",
        "",
        "| seed | DrS | sparse | semi-sparse |",
        "|---|---|---|---|",
        *[f"| {s} | {got[s]['drs']:.2f} | {got[s]['sparse']:.2f} | {got[s]['semi_sparse']:.2f} |" for s in SEEDS],
        f"| mean +- std | {_ms(drs)} | {_ms(sparse)} | {_ms(semi)} |",
        "",
        "| rule (holds if true in at least 4 of 5 seeds) | seeds where true | verdict |",
        "|---|---|---|",
        *[f"| {name} | {n} of 5 | {'**holds**' if n >= 4 else '**does not hold**'} |" for name, n in rules],
    ]
    text = "\n".join(lines) + "\n"
    (root / "decision.md").write_text(text)
    return text


def _ms(xs):
    m = sum(xs) / len(xs)
    return f"{m:.2f} +- {(sum((x - m) ** 2 for x in xs) / len(xs)) ** 0.5:.2f}"


if __name__ == "__main__":
    print(main(Path(sys.argv[1] if len(sys.argv) > 1 else "results/first_command")))
