"""drs-bench's distance from the floor (issue 64's goals): the update's ms against its GEMM floor at its own threads
and precision, the loop's env steps/s against min(raw simulator, compute bound) (harmonic for in-process), with numbers
worked out by hand from a fixed GEMM rate."""

import pytest

import drs_torchrl.tools.bench as bench


def test_floor_rows_by_hand(monkeypatch):
    monkeypatch.setattr(bench, "gemm_gflops", lambda batch, width, threads, dtype=None: 100.0 * threads)
    res = {
        "raw_sim_steps_per_s": 500.0,
        "machine": {"torch_threads": 2},
        "components": [
            {"algo": "sac_cpu", "batch_size": 256, "width": 256, "sac_update_gflop": 1.0, "threads": 1,
             "sac_update_ms": 15.0, "sac_update_ms_by_precision": {"fp32": 15.0, "bf16": 12.0}}
        ],
        "learn": [
            {"algo": "sac_cpu", "utd": 0.5, "precision": "fp32", "collector": "background", "learner_threads": 2,
             "env_steps_per_s": 40.0},
            {"algo": "sac_cpu", "utd": 0.5, "precision": "fp32", "collector": "inproc", "learner_threads": 2,
             "env_steps_per_s": 100.0},
            {"algo": "other", "utd": 0.5, "precision": "fp32", "collector": "inproc", "env_steps_per_s": 1.0},
        ],
    }  # fmt: skip
    rows = bench.floor(res)
    upd = [r for r in rows if r["what"] == "update"]
    assert [(r["precision"], r["floor_ms"], r["over_floor"]) for r in upd] == [
        ("fp32", pytest.approx(10.0), pytest.approx(1.5)),  # 1 GFLOP at 100 GFLOP/s (1 thread) = 10 ms
        ("bf16", pytest.approx(10.0), pytest.approx(1.2)),
    ]
    bg, inproc = [r for r in rows if r["what"] == "loop"]  # no components for "other": no row
    # at 2 threads the floor is 5 ms; UTD 0.5 -> 400 env steps/s of compute
    assert bg["compute_bound_steps_per_s"] == pytest.approx(400.0)
    assert bg["limit_steps_per_s"] == pytest.approx(400.0) and bg["of_limit"] == pytest.approx(0.1)
    assert inproc["limit_steps_per_s"] == pytest.approx(1 / (1 / 500 + 1 / 400))  # 222.2: the two take turns
    assert inproc["of_limit"] == pytest.approx(100 / 222.2222, rel=1e-4)
    res.update(command="drs-bench", family="pick_cube", collect={}, plain=[], floor=rows)
    res["machine"].update(cpus=2, platform="x", torch="x", cuda=False)
    res["learn"], res["components"] = [], []  # the floor table alone (the parts' own tables need their timings)
    md = bench.render_markdown(res)
    assert "| SAC update, sac_cpu | bf16 | 1 | 12.00 ms | 10.00 ms (GEMM floor) | 1.20x the floor |" in md
    assert "0.45 of the limit |" in md and "compute bound 400" in md
