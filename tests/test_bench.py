"""drs-bench's roofline: the bound it reports follows from the measured GEMM rate and FLOP count."""
import os

import pytest

from drs_torchrl.bench import render_markdown, roofline


def test_roofline_bound_is_the_core_time_formula():
    res = {
        "raw_sim_steps_per_s": 500.0,
        "learn": [{"algo": "sac_cpu", "utd": 0.5}],
        "plain": [{"batch_size": 256, "env_steps_per_s": 100.0, "updates_per_s_overall": 50.0}],
        "components": [{"algo": "sac_cpu", "batch_size": 256, "width": 256, "sac_update_gflop": 1.6, "sac_update_ms": 15.0}],
    }
    (row,) = roofline(res)
    cores = os.cpu_count() or 1
    expect = cores / (0.5 * 1.6 / row["gemm_gflops_1_thread"] + 1 / 500.0)
    assert row["env_steps_per_s_bound"] == pytest.approx(expect)
    assert row["bound_over_plain"] == pytest.approx(expect / 100.0)
    # more FLOPs per update can only lower the bound
    res["components"][0]["sac_update_gflop"] = 16.0
    (row2,) = roofline(res)
    assert row2["env_steps_per_s_bound"] < row["env_steps_per_s_bound"]
    res.update(command="drs-bench", family="pick_cube", collect={}, roofline=[row],
               machine={"cpus": cores, "torch_threads": 1, "platform": "x", "torch": "x", "cuda": False})
    res["learn"] = []
    res["components"] = []
    assert "env steps/s bound" in render_markdown(res)
    # a bracketed plain-loop measurement shows both halves; a bf16 component gets its own roofline row
    res["plain"] = [{"batch_size": 256, "env_steps_per_s": 100.0, "updates_per_s_overall": 50.0, "before": 90.0, "after": 110.0}]
    assert "100.0 (before 90.0, after 110.0)" in render_markdown(res)
    comp = {"algo": "sac_cpu", "batch_size": 256, "width": 256, "sac_update_gflop": 1.6, "sac_update_ms": 15.0,
            "sac_update_ms_by_precision": {"fp32": 15.0, "bf16": 12.0}}
    rows = roofline({**res, "components": [comp], "learn": [{"algo": "sac_cpu", "utd": 0.5}]})
    assert [r["precision"] for r in rows] == ["fp32", "bf16"] and rows[1]["update_ms_measured"] == 12.0
