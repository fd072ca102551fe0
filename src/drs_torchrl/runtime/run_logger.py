"""Run logging through TorchRL's ``Logger`` interface: wide CSV files, TensorBoard and (optionally) wandb.

A researcher opens ``train.csv`` / ``eval.csv`` with pandas, looks at ``tb/`` in TensorBoard, or
follows the run in wandb. Each backend is a :class:`torchrl.record.loggers.Logger`, so any TorchRL
logger can be added to :class:`RunLogger`, and :class:`WideCSVLogger` can serve other TorchRL code.

* :class:`WideCSVLogger` is our own because TorchRL's ``CSVLogger`` writes one long file per
  scalar; a row per log step with one column per metric is what pandas users and ``drs-plot`` read.
* :class:`ResumableTensorboardLogger` is TorchRL's ``TensorboardLogger`` with a purge step, so a
  resumed run's curves have no duplicate tail (TorchRL's logger cannot pass ``purge_step``).
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Sequence
from pathlib import Path

import torch
from torchrl.record.loggers import Logger, TensorboardLogger

from drs_torchrl.runtime.errors import UserError

__all__ = ["WideCSVLogger", "ResumableTensorboardLogger", "RunLogger", "LoggerConfigError"]


def _scalar(value) -> int | float:
    """Integers (counts, steps) stay integers in the CSV; everything else is a float."""
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    return float(value)


class LoggerConfigError(UserError, ValueError):
    """A logger setting that cannot work, with the fix in its message."""


class _WideCSVFiles:
    """The experiment object of :class:`WideCSVLogger`: ``<log_dir>/<stream>.csv``, one row per step.
    Columns that appear later are added by rewriting the header (rare: the first rows fix them)."""

    def __init__(self, log_dir: Path):
        self.log_dir = log_dir
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self._columns: dict[str, list[str]] = {}

    @staticmethod
    def _rewrite(path: Path, cols: list[str], rows: list[dict]) -> None:
        """Replace ``path`` by ``cols`` and ``rows`` at once (a kill or a full disk midway keeps the old file)."""
        tmp = path.with_suffix(".csv.tmp")
        try:
            with tmp.open("w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=cols)
                w.writeheader()
                w.writerows(rows)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        tmp.replace(path)

    def truncate(self, step: int) -> None:
        """Drop rows logged after ``step`` in every stream (a run resumed from that step)."""
        for path in self.log_dir.glob("*.csv"):
            with path.open() as f:
                reader = csv.DictReader(f)
                cols = reader.fieldnames
                rows = [r for r in reader if r.get("step") and float(r["step"]) <= step]
            if cols is not None:
                self._rewrite(path, list(cols), rows)

    def write_row(self, stream: str, row: dict) -> None:
        path = self.log_dir / f"{stream}.csv"
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
            self._rewrite(path, cols, rows)
        self._columns[stream] = cols
        with path.open("a", newline="") as f:
            csv.DictWriter(f, fieldnames=cols).writerow(row)

    def flush(self) -> None:  # every row is written through at once
        return None


class WideCSVLogger(Logger):
    """A TorchRL ``Logger`` writing one wide CSV per stream: ``<log_dir>/<stream>.csv``.

    A metric named ``"train/success"`` goes to column ``success`` of ``train.csv``; names without a
    ``/`` go to ``<exp_name>.csv``. :meth:`log_metrics` writes all metrics of one step and one
    stream as one row (the form this logger is for); :meth:`log_scalar` writes a row of one value.
    ``resume_step``: rows logged after it (by an interrupted process) are dropped first.
    """

    def __init__(self, exp_name: str = "metrics", log_dir: str | os.PathLike = ".", resume_step: int | None = None):
        self._resume_step = resume_step
        super().__init__(exp_name=exp_name, log_dir=str(log_dir))

    def _create_experiment(self) -> _WideCSVFiles:
        files = _WideCSVFiles(Path(self.log_dir))
        if self._resume_step is not None:
            files.truncate(int(self._resume_step))
        return files

    def _split(self, name: str) -> tuple[str, str]:
        stream, _, key = name.rpartition("/")
        return (stream or self.exp_name), key

    def log_scalar(self, name: str, value: float, step: int | None = None) -> None:
        stream, key = self._split(name)
        self.experiment.write_row(stream, {"step": int(step or 0), key: _scalar(value)})

    def log_metrics(self, metrics, step: int | None = None, *, keys_sep: str = "/") -> dict:
        rows: dict[str, dict] = {}
        for name, value in dict(metrics).items():
            stream, key = self._split(name)
            rows.setdefault(stream, {"step": int(step or 0)})[key] = _scalar(value)
        for stream, row in rows.items():
            self.experiment.write_row(stream, row)
        return dict(metrics)

    def log_hparams(self, cfg) -> None:
        """Write the configuration to ``<log_dir>/hparams.yaml``."""
        from omegaconf import OmegaConf

        text = OmegaConf.to_yaml(cfg) if not isinstance(cfg, dict) else OmegaConf.to_yaml(OmegaConf.create(cfg))
        (Path(self.log_dir) / "hparams.yaml").write_text(text)

    def log_video(self, name: str, video: torch.Tensor, step: int | None = None, **kwargs) -> None:
        """Save the frames as ``<log_dir>/videos/<name>_<step>.pt`` (``drs-eval --video`` writes mp4)."""
        out = Path(self.log_dir) / "videos"
        out.mkdir(exist_ok=True)
        torch.save(video.detach().cpu(), out / f"{name.replace('/', '_')}_{int(step or 0)}.pt")

    def log_histogram(self, name: str, data: Sequence, **kwargs):
        raise LoggerConfigError(
            "the wide CSV logger keeps scalars only; histograms go to TensorBoard (logger.tensorboard=true)"
        )

    def __repr__(self) -> str:
        return f"{type(self).__name__}(log_dir={self.log_dir!r})"


class ResumableTensorboardLogger(TensorboardLogger):
    """TorchRL's ``TensorboardLogger`` writing to ``<log_dir>/<exp_name>``; ``resume_step`` purges
    events logged after it, as :class:`WideCSVLogger` drops rows."""

    def __init__(self, exp_name: str = "tb", log_dir: str | os.PathLike = ".", resume_step: int | None = None):
        self._purge_step = None if resume_step is None else int(resume_step) + 1
        super().__init__(exp_name=exp_name, log_dir=str(log_dir))

    def _create_experiment(self):
        from torch.utils.tensorboard import SummaryWriter

        return SummaryWriter(log_dir=str(Path(self.log_dir) / self.exp_name), purge_step=self._purge_step)


def make_wandb_logger(run_dir: Path, project: str, mode: str):
    """TorchRL's ``WandbLogger`` (``mode``: offline, which needs no network, or online)."""
    try:
        from torchrl.record.loggers.wandb import WandbLogger
        import wandb  # noqa: F401
    except ImportError as exc:
        raise LoggerConfigError(
            "logger.wandb=true needs the wandb package: pip install wandb (or set logger.wandb=false)"
        ) from exc
    if mode not in ("offline", "online"):
        raise LoggerConfigError(f"logger.wandb_mode must be offline or online, got {mode!r}")
    return WandbLogger(exp_name=run_dir.name, save_dir=str(run_dir), project=project, offline=mode == "offline")


class RunLogger:
    """A run's loggers: each stream's scalars of one step go to every backend.

    ``backends``: TorchRL ``Logger`` instances (extra ones, e.g. an MLflow logger, may be passed).
    The wide CSV backend gets every value; the others get the finite ones (TensorBoard and wandb
    draw NaN as gaps or errors).
    """

    def __init__(
        self,
        run_dir: str | Path,
        tensorboard: bool = True,
        csv_files: bool = True,
        resume_step: int | None = None,
        wandb: bool = False,
        wandb_project: str = "drs-torchrl",
        wandb_mode: str = "offline",
        backends: Sequence[Logger] = (),
    ):
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.backends: list[Logger] = []
        if csv_files:
            self.backends.append(WideCSVLogger("metrics", self.run_dir, resume_step=resume_step))
        if tensorboard:
            self.backends.append(ResumableTensorboardLogger("tb", self.run_dir, resume_step=resume_step))
        if wandb:
            self.backends.append(make_wandb_logger(self.run_dir, wandb_project, wandb_mode))
        self.backends.extend(backends)

    def log(self, stream: str, step: int, scalars: dict[str, float]) -> None:
        metrics = {f"{stream}/{k}": _scalar(v) for k, v in scalars.items()}
        finite = {k: v for k, v in metrics.items() if math.isfinite(v)}
        for backend in self.backends:
            backend.log_metrics(metrics if isinstance(backend, WideCSVLogger) else finite, step=int(step))

    def flush(self) -> None:
        for backend in self.backends:
            backend.flush()

    def close(self) -> None:
        for backend in self.backends:
            backend.close()
