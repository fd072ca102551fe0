"""The apps' count options refuse what would do nothing or the wrong thing, naming the option (no simulator)."""

import importlib

import pytest


@pytest.mark.parametrize(
    "module, argv, message",
    [
        # --jobs 0 started nothing and blamed runs "that are not in this invocation"; --threads 0 failed every run
        ("study", ["s.yaml", "--jobs", "0"], "argument --jobs/-j: must be >= 1, got 0"),
        ("study", ["s.yaml", "--threads", "0"], "argument --threads: must be >= 1, got 0"),
        ("study", ["s.yaml", "--jobs", "two"], "argument --jobs/-j: must be a whole number, got 'two'"),
        ("evaluate", ["run", "--episodes", "-1"], "argument --episodes: must be >= 1, got -1"),
        ("probe", ["--reward", "r", "--policy", "p", "--out", "o", "--episodes", "0"], "argument --episodes"),
        ("reporting", ["run", "--reward-episode", "--tries", "0"], "argument --tries: must be >= 1, got 0"),
        ("demos", ["--num", "0"], "argument --num: must be >= 1, got 0"),
        ("demos", ["--from-policy", "run", "--max-episodes", "0"], "argument --max-episodes: must be >= 1, got 0"),
        ("bench", ["--learn-frames", "0"], "argument --learn-frames: must be >= 1, got 0"),
        ("bench", ["--checkpoint", "-5"], "argument --checkpoint: must be >= 0, got -5"),
    ],
)
def test_a_count_of_zero_is_refused_naming_the_option(module, argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    package = "apps" if module == "evaluate" else "tools"  # the training path's apps, the tools built on them
    main = importlib.import_module(f"drs_torchrl.{package}.{module}").main
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []  # refused before anything was written


def test_drs_plot_reward_episode_refuses_more_than_one_run(capsys):
    """It draws the first run's episode only; the others had been ignored without a word."""
    from drs_torchrl.tools.reporting import main

    with pytest.raises(SystemExit) as e:
        main(["a", "b", "--reward-episode"])
    assert e.value.code == 2
    assert "--reward-episode draws one run's episode; give one run directory, not 2" in capsys.readouterr().err
