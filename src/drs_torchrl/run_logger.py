"""Run logging: one CSV per stream (wide format, one row per log step) and TensorBoard.

A researcher opens ``train.csv`` / ``eval.csv`` with pandas or looks at ``tb/`` in TensorBoard.
Columns that appear later are added by rewriting the header (rare: the first rows fix them).
"""
from __future__ import annotations

import csv
import math
from pathlib import Path


class RunLogger:
    """Write scalars to ``<run_dir>/<stream>.csv`` and to TensorBoard under ``<stream>/<name>``."""

    def __init__(self, run_dir: str | Path, tensorboard: bool = True, csv_files: bool = True, resume_step: int | None = None):
        """``resume_step``: continuing a run from a checkpoint at that step; rows logged after it
        (by the interrupted process) are dropped, so the logs have neither gaps nor duplicates."""
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.csv_files = csv_files
        self._columns: dict[str, list[str]] = {}
        self._tb = None
        if resume_step is not None:
            for path in self.run_dir.glob("*.csv"):
                self._truncate(path, resume_step)
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            purge = None if resume_step is None else int(resume_step) + 1
            self._tb = SummaryWriter(str(self.run_dir / "tb"), purge_step=purge)

    @staticmethod
    def _truncate(path: Path, step: int) -> None:
        with path.open() as f:
            reader = csv.DictReader(f)
            cols = reader.fieldnames
            rows = [r for r in reader if r.get("step") and float(r["step"]) <= step]
        if cols is None:
            return
        tmp = path.with_suffix(".csv.tmp")
        with tmp.open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=cols)
            w.writeheader()
            w.writerows(rows)
        tmp.replace(path)

    def log(self, stream: str, step: int, scalars: dict[str, float]) -> None:
        row = {"step": int(step)}
        for k, v in scalars.items():
            v = float(v)
            row[k] = v
            if self._tb is not None and math.isfinite(v):
                self._tb.add_scalar(f"{stream}/{k}", v, int(step))
        if self.csv_files:
            self._write_csv(stream, row)

    def _write_csv(self, stream: str, row: dict) -> None:
        path = self.run_dir / f"{stream}.csv"
        cols = self._columns.get(stream)
        if cols is None and path.exists():
            with path.open() as f:
                header = next(csv.reader(f), None)
            cols = header or None
        if cols is None:
            cols = list(row)
            with path.open("w", newline="") as f:
                csv.writer(f).writerow(cols)
        new = [k for k in row if k not in cols]
        if new:
            cols = cols + new
            with path.open() as f:
                rows = list(csv.DictReader(f))
            with path.open("w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=cols)
                w.writeheader()
                w.writerows(rows)
        self._columns[stream] = cols
        with path.open("a", newline="") as f:
            csv.DictWriter(f, fieldnames=cols).writerow(row)

    def flush(self) -> None:
        if self._tb is not None:
            self._tb.flush()

    def close(self) -> None:
        if self._tb is not None:
            self._tb.close()
