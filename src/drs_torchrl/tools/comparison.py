"""``drs-compare RUN_DIR ...``: success-rate curves of several runs, grouped and averaged over seeds.

The paper reports every method as the mean and standard deviation over seeds of the evaluation
success rate against env steps (Sec. 5, Fig. 4-6). This module groups ``drs-learn`` /
``drs-reuse`` run directories by keys of their resolved ``config.yaml`` (``reward.name`` by
default, e.g. ``drs`` vs ``semi_sparse``), and writes:

- ``compare.png``: success rate and the reach rate of each earlier stage, of evaluation episodes
  (deterministic policy) and of training episodes (rolling), each as mean and std over the runs of
  a group;
- ``compare.csv``: the aggregated curves (group, metric, step, number of runs, mean, std);
- ``compare.md``: per group the runs, the env steps the shortest run reached, the final evaluation
  success per run, its mean +- std, the mean over the last three evaluations, the area under the
  success curve up to the shortest run of the comparison (normalised: 1.0 is success throughout), and
  the first step at which the mean over all the group's seeds passes 0.5 (issue 15's table); and for
  training episodes, the first step each stage and success pass 0.5 (issue 12's table).

Runs of unequal length are averaged over the runs that reached each step (the ``n`` column).
Everything here reads files only: it works on finished, interrupted and still-running runs.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from drs_torchrl.runtime.console import console_script
from drs_torchrl.runtime.rundir import maze_run_message, read_run_csv
from drs_torchrl.runtime.errors import UserError

DEFAULT_GROUP_BY = ("reward.name",)


class CompareError(UserError, ValueError):
    """A run directory (or a grouping key) that cannot be compared; the message names it."""


@dataclass
class RunRecord:
    path: Path
    label: str
    seed: object
    eval: "object"  # pandas DataFrame (eval.csv), or None when no evaluation ran yet
    train: "object"  # pandas DataFrame (train.csv)
    stages: tuple | None = None  # the run's stage indicators, success last (None when its config does not say)
    stopped_at: int | None = None  # env steps at which a success rule ended it (eval.stop_at_success, stop_at_success)


@dataclass
class Group:
    label: str
    runs: list[RunRecord] = field(default_factory=list)


def _lookup(cfg: dict, dotted: str, run: Path):
    node = cfg
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            raise CompareError(
                f"{run}/config.yaml has no key {dotted!r} to group by "
                f"(keys at that level: {sorted(node) if isinstance(node, dict) else node!r})"
            )
        node = node[part]
    return node


def load_run(run: Path, group_by: tuple[str, ...] = DEFAULT_GROUP_BY, label: str | None = None) -> RunRecord:
    """One run directory: its CSVs and its group label (the values of ``group_by`` in its config, or
    ``label`` when given, e.g. a study's run name without its seed)."""
    from omegaconf import OmegaConf

    run = Path(run)
    if maze := maze_run_message(run):
        raise CompareError(maze)
    if not (run / "train.csv").exists():
        raise CompareError(f"{run} has no train.csv: is it a drs-learn/drs-reuse run directory?")
    cfg_path = run / "config.yaml"
    if not cfg_path.exists():
        cfg_path = run / ".hydra" / "config.yaml"
    if not cfg_path.exists():
        raise CompareError(
            f"{run} has neither config.yaml nor .hydra/config.yaml: cannot tell which group it belongs to"
        )
    cfg = OmegaConf.to_container(OmegaConf.load(cfg_path), resolve=False) or {}
    if label is None:
        label = " ".join(f"{_lookup(cfg, k, run)}" for k in group_by)
    ev = read_run_csv(run / "eval.csv") if (run / "eval.csv").exists() else None
    if ev is not None and ev.empty:
        ev = None
    return RunRecord(
        path=run,
        label=label,
        seed=cfg.get("seed"),
        eval=ev,
        train=read_run_csv(run / "train.csv"),
        stages=_run_stages(cfg),
        stopped_at=_stopped_at(run),
    )


def _stopped_at(run: Path) -> int | None:
    """The env steps at which a success rule ended the run (its ``summary.json``), or None."""
    import json

    try:
        summary = json.loads((run / "summary.json").read_text())
    except (OSError, ValueError):
        return None
    stop = summary.get("stopped_at_eval_success") or summary.get("stopped_at_success")
    return int(stop.get("frames", summary.get("frames", 0))) if isinstance(stop, dict) else None


def _run_stages(cfg: dict) -> tuple | None:
    """The stage indicators a run used: ``env.stages`` (an ablation), else its family's."""
    env = cfg.get("env") if isinstance(cfg.get("env"), dict) else {}
    if env.get("stages"):
        return tuple(env["stages"])
    try:
        from drs_torchrl.tasks import get_family

        return tuple(get_family(env.get("family")).stage_keys)
    except Exception:  # a custom family, or a config from elsewhere: the columns keep their numbers
        return None


def _stage_label(runs: list[RunRecord], column: str) -> str:
    """``reached stage k``, with the stage's name when every run names the same stages."""
    k = int(column.rsplit("_", 1)[1])
    names = {r.stages for r in runs}
    if len(names) == 1 and (only := next(iter(names))) is not None and k <= len(only):
        return f"reached stage {k} ({only[k - 1]})"
    return f"reached stage {k}"


def group_runs(runs: list[RunRecord]) -> list[Group]:
    groups: dict[str, Group] = {}
    for r in runs:
        groups.setdefault(r.label, Group(r.label)).runs.append(r)
    return list(groups.values())


def aggregate(frames: list, column: str) -> "object":
    """Mean and std over runs of ``column``, per step: a DataFrame with step, n, mean, std.

    Each run contributes at the steps it logged; a step is kept when at least one run has it.
    """
    import pandas as pd

    # a resumed run may log a step twice (the row before the interruption and after): keep the later one
    parts = [
        f[["step", column]].dropna().drop_duplicates("step", keep="last").set_index("step")[column]
        for f in frames
        if f is not None and column in f
    ]
    if not parts:
        return pd.DataFrame(columns=["step", "n", "mean", "std"])
    wide = pd.concat(parts, axis=1)
    out = pd.DataFrame(
        {
            "step": wide.index.to_numpy(),
            "n": wide.notna().sum(axis=1).to_numpy(),
            "mean": wide.mean(axis=1, skipna=True).to_numpy(),
            "std": wide.std(axis=1, skipna=True, ddof=0).fillna(0.0).to_numpy(),
        }
    )
    return out.sort_values("step").reset_index(drop=True)


def _stage_columns(frames: list) -> list[str]:
    cols: set[str] = set()
    for f in frames:
        if f is not None:
            cols.update(c for c in f.columns if c.startswith("reach_stage_"))
    return sorted(cols, key=lambda c: int(c.rsplit("_", 1)[1]))


def _eval_curve(run: RunRecord) -> tuple[np.ndarray, np.ndarray]:
    ev = run.eval.drop_duplicates("step", keep="last").sort_values("step")
    return ev["step"].to_numpy(dtype=float), ev["success_rate"].to_numpy(dtype=float)


def success_auc(steps: np.ndarray, success: np.ndarray, horizon: float) -> float:
    """Area under one run's evaluation success curve up to ``horizon`` env steps, divided by its width.

    Trapezoids over the evaluations at steps <= horizon, from the first one (no value is assumed at step
    0: a fine-tuned agent starts above 0); 1.0 is success from the first evaluation on. NaN when fewer
    than two evaluations fall in the range.
    """
    keep = steps <= horizon
    x, y = steps[keep], success[keep]
    if x.size < 2 or x[-1] <= x[0]:
        return float("nan")
    return float(np.sum((y[1:] + y[:-1]) * np.diff(x)) / 2.0 / (x[-1] - x[0]))


def first_step_over(
    groups_runs: list[RunRecord], threshold: float = 0.5, source: str = "eval", column: str = "success_rate"
) -> float | None:
    """The first evaluation step at which the mean success over all of a group's runs is >= threshold.

    Only steps every run of the group has evaluated count (a mean over the runs that got there
    would favour the luckiest seed); None when it never passes.
    """
    agg = aggregate([getattr(r, source) for r in groups_runs], column)
    full = agg[agg["n"] == len(groups_runs)]
    hit = full[full["mean"] >= threshold]
    return float(hit["step"].iloc[0]) if len(hit) else None


def _carried(run: RunRecord, horizon: float, steps) -> object:
    """The run's evaluations, and for a run a success rule ended early its last evaluation held at each of ``steps``
    after it, up to ``horizon`` (it had reached the rule's success; the rest of its budget would only have confirmed
    it)."""
    import pandas as pd

    if run.stopped_at is None or run.eval is None:
        return run.eval
    ev = run.eval.drop_duplicates("step", keep="last").sort_values("step")
    last_step = float(ev["step"].iloc[-1])
    later = sorted(
        {float(x) for x in steps if last_step < float(x) <= horizon} | ({horizon} if horizon > last_step else set())
    )
    if not later:
        return ev
    held = pd.concat([ev.iloc[[-1]]] * len(later), ignore_index=True)
    held["step"] = later
    return pd.concat([ev, held], ignore_index=True)


def summary_rows(groups: list[Group]) -> list[dict]:
    """Per group: final and last-3 evaluation success, the normalised AUC up to the shortest evaluated
    run of the whole comparison (so groups are compared over the same steps), and the first step at
    which the group's mean success passes 0.5. A run with a single evaluation has no curve to integrate
    (AUC NaN) and does not set the horizon: e.g. ORIL's phase 1, whose reward is fixed before its first step.
    Nor does a run that a success rule ended early (``eval.stop_at_success``, ``stop_at_success``): its last
    evaluation is held to the horizon (:func:`_carried`), for its AUC and its group's first step past 0.5."""
    evaluated = [r for g in groups for r in g.runs if r.eval is not None]
    curves = [_eval_curve(r)[0] for r in evaluated]
    ran = [_eval_curve(r)[0] for r in evaluated if r.stopped_at is None]
    horizon = min(
        (x[-1] for x in (ran or curves) if x.size >= 2), default=min((x[-1] for x in curves), default=float("nan"))
    )
    if not ran and curves:  # every run was ended by a success rule: the longest of them
        horizon = max(x[-1] for x in curves)
    steps = {x for c in curves for x in c}
    carried = {id(r): _carried(r, horizon, steps) for r in evaluated}
    rows = []
    for g in groups:
        finals, last3, aucs = [], [], []
        for r in g.runs:
            if r.eval is not None:
                _, s = _eval_curve(r)  # the evaluations that ran
                finals.append(float(s[-1]))
                last3.append(float(np.mean(s[-3:])))
                ev = carried[id(r)]
                aucs.append(success_auc(ev["step"].to_numpy(float), ev["success_rate"].to_numpy(float), horizon))
        full = [r for r in g.runs if r.eval is not None]
        held = [replace(r, eval=carried[id(r)]) for r in full]
        aucs = [a for a in aucs if a == a]
        rows.append(
            {
                "group": g.label,
                "runs": len(g.runs),
                "seeds": [r.seed for r in g.runs],
                "steps": int(min(int(r.train["step"].iloc[-1]) for r in g.runs)),
                "final": finals,
                "final_mean": float(np.mean(finals)) if finals else float("nan"),
                "final_std": float(np.std(finals)) if finals else float("nan"),
                "last3_mean": float(np.mean(last3)) if last3 else float("nan"),
                "auc_horizon": float(horizon),
                "auc_mean": float(np.mean(aucs)) if aucs else float("nan"),
                "auc_std": float(np.std(aucs)) if aucs else float("nan"),
                "first_step_0_5": first_step_over(held) if len(full) == len(g.runs) and full else None,
                "carried": [(r.path.name, r.stopped_at) for r in full if r.stopped_at is not None],
            }
        )
    return rows


def _steps_label(x, _pos=None) -> str:
    return f"{x / 1e6:.4g}M" if abs(x) >= 1e6 else f"{x / 1e3:.4g}k" if abs(x) >= 1e3 else f"{x:g}"


def group_style(i: int) -> dict:
    """Line style of the ``i``-th group: tab10's colours, then the same colours dashed, dotted, dash-dotted, so
    that up to 40 groups stay distinguishable (matplotlib's default cycle repeats its colours after 10)."""
    return {"color": f"C{i % 10}", "linestyle": ("-", "--", ":", "-.")[(i // 10) % 4]}


def compare(
    run_dirs: list[Path],
    out_dir: Path,
    group_by: tuple[str, ...] = DEFAULT_GROUP_BY,
    labels: list[str] | None = None,
    title: str = "",
) -> dict[str, Path]:
    """Group ``run_dirs`` (by ``group_by``, or by ``labels``, one per run), write ``compare.png``,
    ``compare.csv`` and ``compare.md`` into ``out_dir``; ``title`` heads the figure and the table."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pandas as pd
    from matplotlib.ticker import FuncFormatter

    if not run_dirs:
        raise CompareError("no run directories given")
    if labels is not None and len(labels) != len(run_dirs):
        raise CompareError(f"{len(labels)} labels for {len(run_dirs)} run directories")
    seen: dict[Path, Path] = {}
    for r in map(Path, run_dirs):  # a run counted twice would pass for two seeds in mean +- std
        first = seen.setdefault(r.resolve(), r)
        if first is not r:
            same = "twice" if first == r else f"twice (as {first} and {r})"
            raise CompareError(f"run directory {r.resolve()} is given {same}: give each run once")
    groups = group_runs(
        [load_run(Path(r), tuple(group_by), None if labels is None else labels[i]) for i, r in enumerate(run_dirs)]
    )
    title_key = ", ".join(group_by) if labels is None else "run name without its seed"
    # the last reach column is the success stage, already drawn as success_rate
    eval_stages = _stage_columns([r.eval for g in groups for r in g.runs])[:-1]
    train_stages = _stage_columns([r.train for g in groups for r in g.runs])[:-1]
    panels = [("eval", "success_rate", "evaluation success (deterministic policy)")]
    panels += [("eval", c, f"evaluation: reached stage {c.rsplit('_', 1)[1]}") for c in eval_stages]
    panels += [("train", "success_rate", "training episodes: success (rolling)")]
    every = [r for g in groups for r in g.runs]
    panels += [("train", c, f"training episodes: {_stage_label(every, c)} (rolling)") for c in train_stages]
    ncols = min(3, len(panels))
    nrows = -(-len(panels) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(5.2 * ncols, 3.8 * nrows), squeeze=False)
    records, legend = [], {}  # one legend for the figure, outside the panels, in group order
    for ax, (source, column, panel_title) in zip(axes.ravel(), panels):
        for i, g in enumerate(groups):
            frames = [getattr(r, source) for r in g.runs]
            agg = aggregate(frames, column)
            if agg.empty:
                continue
            style = group_style(i)
            (line,) = ax.plot(
                agg["step"],
                agg["mean"],
                **style,
                marker="o" if source == "eval" else None,
                ms=3,
                label=f"{g.label} (n={len(g.runs)})",
            )
            legend.setdefault(i, line)
            ax.fill_between(
                agg["step"], agg["mean"] - agg["std"], agg["mean"] + agg["std"], color=style["color"], alpha=0.2
            )
            for row in agg.itertuples(index=False):
                records.append(
                    {
                        "group": g.label,
                        "source": source,
                        "metric": column,
                        "step": int(row.step),
                        "n": int(row.n),
                        "mean": float(row.mean),
                        "std": float(row.std),
                    }
                )
        ax.set_title(panel_title, fontsize=10)
        ax.set_xlabel("env steps")
        ax.xaxis.set_major_formatter(FuncFormatter(_steps_label))
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[len(panels) :]:
        ax.set_visible(False)
    fig.suptitle(
        (f"{title}\n" if title else "") + f"mean and std over the runs of each group ({title_key})", fontsize=10
    )
    fig.tight_layout()
    if legend:
        handles = [legend[i] for i in sorted(legend)]
        fig.legend(
            handles,
            [h.get_label() for h in handles],
            loc="center left",
            bbox_to_anchor=(1.0, 0.5),
            fontsize=9,
            frameon=False,
        )
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"png": out_dir / "compare.png", "csv": out_dir / "compare.csv", "md": out_dir / "compare.md"}
    fig.savefig(paths["png"], dpi=110, bbox_inches="tight")
    plt.close(fig)
    pd.DataFrame.from_records(records, columns=["group", "source", "metric", "step", "n", "mean", "std"]).to_csv(
        paths["csv"], index=False
    )
    rows = summary_rows(groups)
    horizon = rows[0]["auc_horizon"] if rows else float("nan")
    h = _steps_label(horizon) if horizon == horizon else "-"
    lines = [f"**{title}**", ""] if title else []
    lines += [
        f"| {' / '.join(group_by) if labels is None else 'runs'} | runs (seeds) | env steps (shortest run) | final eval success per run | "
        f"mean +- std | mean of the last 3 evals | success AUC to {h} (mean +- std) | mean success >= 0.5 first at |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        finals = ", ".join(f"{x:.2f}" for x in row["final"]) or "(no eval yet)"
        ms = f"{row['final_mean']:.2f} +- {row['final_std']:.2f}" if row["final"] else "-"
        l3 = f"{row['last3_mean']:.2f}" if row["final"] else "-"
        auc = f"{row['auc_mean']:.3f} +- {row['auc_std']:.3f}" if row["auc_mean"] == row["auc_mean"] else "-"
        first = (
            _steps_label(row["first_step_0_5"])
            if row["first_step_0_5"] is not None
            else (f"not by {_steps_label(row['steps'])}" if row["final"] else "-")
        )
        seeds = ", ".join(str(s) for s in row["seeds"])
        lines.append(
            f"| {row['group']} | {row['runs']} ({seeds}) | {row['steps']} | {finals} | {ms} | {l3} | {auc} | {first} |"
        )
    held = [f"`{name}` at {_steps_label(at)}" for row in rows for name, at in row.get("carried", [])]
    if held:
        lines += [
            "",
            "Ended early by a success rule (`eval.stop_at_success` or `stop_at_success`), their last evaluation held to "
            f"{h} for the AUC and the first step past 0.5: " + ", ".join(held) + ".",
        ]
    if train_stages:  # when each stage is first reached in half the training episodes (issue 12's table)
        cols = [*train_stages, "success_rate"]
        lines += [
            "",
            "Training episodes (rolling window), mean over each group's runs: the first step at which it passes 0.5",
            "",
            "| group | " + " | ".join(_stage_label(every, c) for c in train_stages) + " | success |",
            "|---|" + "---|" * len(cols),
        ]
        for g in groups:
            firsts = [first_step_over(g.runs, source="train", column=c) for c in cols]
            end = _steps_label(min(int(r.train["step"].iloc[-1]) for r in g.runs))
            lines.append(
                f"| {g.label} | "
                + " | ".join(_steps_label(f) if f is not None else f"not by {end}" for f in firsts)
                + " |"
            )
    lines.append("")
    lines.append("Runs: " + ", ".join(f"`{r.path}`" for g in groups for r in g.runs))
    paths["md"].write_text("\n".join(lines) + "\n")
    return paths


@console_script("drs-compare")
def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="drs-compare",
        description="success-rate curves of drs-learn/drs-reuse runs, grouped by config keys, mean +- std over seeds",
    )
    p.add_argument("runs", nargs="+", type=Path, help="run directories (each with train.csv, eval.csv, config.yaml)")
    p.add_argument(
        "--group-by",
        nargs="+",
        default=list(DEFAULT_GROUP_BY),
        metavar="KEY",
        help="dotted config keys whose values name a group (default: reward.name), e.g. env.split reward.name",
    )
    p.add_argument("--out", type=Path, default=Path("."), help="folder for compare.png / .csv / .md (default: .)")
    a = p.parse_args(argv)
    try:
        paths = compare(a.runs, a.out, tuple(a.group_by))
    except CompareError as exc:
        print(f"drs-compare: error: {exc}", file=sys.stderr)
        return 2
    for v in paths.values():
        print(v)
    return 0


if __name__ == "__main__":
    sys.exit(main())
