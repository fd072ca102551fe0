"""The run's loggers are TorchRL ``Logger``s: wide CSV rows per stream, TensorBoard events, resume truncation."""

from __future__ import annotations

import csv
import importlib.util
import math

import pytest
from torchrl.record.loggers import Logger

from drs_torchrl.runtime.run_logger import LoggerConfigError, ResumableTensorboardLogger, RunLogger, WideCSVLogger


def rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def test_wide_csv_logger_is_a_torchrl_logger_writing_one_row_per_stream_and_step(tmp_path):
    log = WideCSVLogger("metrics", tmp_path)
    assert isinstance(log, Logger)
    log.log_metrics({"train/success": 0.5, "train/reward_mean": -1.5, "eval/success_once": 0.2}, step=100)
    log.log_metrics({"train/success": 0.75, "train/disc_accuracy": 0.9}, step=200)  # a column that appears later
    log.log_scalar("eval/success_once", 0.4, step=200)
    train = rows(tmp_path / "train.csv")
    assert [r["step"] for r in train] == ["100", "200"]
    assert float(train[0]["reward_mean"]) == -1.5 and train[0]["disc_accuracy"] == ""
    assert float(train[1]["disc_accuracy"]) == 0.9 and float(train[1]["success"]) == 0.75
    assert [float(r["success_once"]) for r in rows(tmp_path / "eval.csv")] == [0.2, 0.4]
    with pytest.raises(LoggerConfigError, match="TensorBoard"):
        log.log_histogram("train/x", [1.0, 2.0])


def test_resume_drops_rows_logged_after_the_checkpoint(tmp_path):
    log = WideCSVLogger("metrics", tmp_path)
    for step in (100, 200, 300):
        log.log_metrics({"train/success": step / 1000}, step=step)
    WideCSVLogger("metrics", tmp_path, resume_step=200)  # the run resumes from its step-200 checkpoint
    assert [r["step"] for r in rows(tmp_path / "train.csv")] == ["100", "200"]


def test_a_failed_header_rewrite_keeps_the_logged_rows(tmp_path, monkeypatch):
    """A new column rewrites the file: a full disk (or a kill) midway must not cost the run's history."""
    log = WideCSVLogger("metrics", tmp_path)
    log.log_metrics({"train/success": 0.1}, step=100)
    real = csv.DictWriter.writerows

    def disk_full(self, rows):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(csv.DictWriter, "writerows", disk_full)
    with pytest.raises(OSError, match="No space"):
        log.log_metrics({"train/success": 0.2, "train/disc_loss": 0.7}, step=200)
    monkeypatch.setattr(csv.DictWriter, "writerows", real)
    assert [r["success"] for r in rows(tmp_path / "train.csv")] == ["0.1"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["train.csv"]


def test_run_logger_fans_out_to_tensorboard_and_keeps_nan_in_csv_only(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    log = RunLogger(tmp_path, tensorboard=True, csv_files=True)
    assert [type(b) for b in log.backends] == [WideCSVLogger, ResumableTensorboardLogger]
    log.log("train", 10, {"success": 1.0, "disc_accuracy": float("nan")})
    log.log("train", 20, {"success": 0.5, "disc_accuracy": 0.8})
    log.close()
    assert math.isnan(float(rows(tmp_path / "train.csv")[0]["disc_accuracy"]))
    acc = EventAccumulator(str(tmp_path / "tb"))
    acc.Reload()
    assert [e.step for e in acc.Scalars("train/success")] == [10, 20]
    assert [e.step for e in acc.Scalars("train/disc_accuracy")] == [20]


def test_wandb_without_the_package_is_a_config_error(monkeypatch):
    from drs_torchrl.runtime.errors import ConfigError
    from drs_torchrl.apps.validation import validate_config

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "wandb" else real(name, *a))
    from hydra import compose, initialize_config_dir

    from drs_torchrl.apps.cli import conf_dir

    with initialize_config_dir(config_dir=conf_dir(), version_base=None):
        cfg = compose("learn", overrides=["logger.wandb=true"])
    with pytest.raises(ConfigError, match="pip install wandb"):
        validate_config(cfg, "learn")
