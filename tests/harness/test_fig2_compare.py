"""``python -m experiments compare-runs`` and ``pool-replicates``: Figure-2 reports paired run by run (hand-made records)."""

import json

import pytest
import scipy.stats

from experiments.fig2 import compare_runs


def _report(root, rewards):
    for (seed, name), reward in rewards.items():
        folder = root / "fig2_raw" / f"seed{seed}"
        folder.mkdir(parents=True, exist_ok=True)
        (folder / f"{name}.json").write_text(json.dumps({"summary": {"reward": reward}}))
    return root


def test_rows_pair_runs_and_pool_online_phases(tmp_path, capsys):
    a = _report(tmp_path / "a", {(0, "chunk"): 10.0, (1, "chunk"): 20.0, (0, "adaptive"): 5.0, (0, "adaptive_r1"): 7.0,
                                 (1, "adaptive"): 9.0, (0, "fixed"): 4.0, (0, "fixed_r1"): 8.0, (1, "fixed"): 6.0})
    b = _report(tmp_path / "b", {(0, "chunk"): 13.0, (1, "chunk"): 21.0, (2, "chunk"): 99.0, (0, "adaptive"): 6.0,
                                 (0, "adaptive_r1"): 10.0, (1, "adaptive"): 9.0})
    rows = {r["label"]: r for r in compare_runs.compare(a, b)}
    chunk = rows["offline chunk policy"]  # seed 2 is B's alone: left out
    assert (chunk["runs"], chunk["a"], chunk["b"], chunk["difference"]) == (2, 15.0, 17.0, 2.0)
    low, high = scipy.stats.ttest_rel([13.0, 21.0], [10.0, 20.0]).confidence_interval(0.95)
    assert (chunk["ci_low"], chunk["ci_high"]) == pytest.approx((low, high))
    adaptive = rows["fine-tuned, adaptive"]  # (seed, phase) runs: 3 pairs, differences 1, 3, 0
    assert adaptive["runs"] == 3 and adaptive["difference"] == pytest.approx(4.0 / 3) and adaptive["x_better_runs"] == 2
    c = rows["A: (c) adaptive − fixed"]  # A's own (c): adaptive − fixed per run: 1, −1, 3
    assert c["runs"] == 3 and c["difference"] == pytest.approx(1.0) and c["a"] == 6.0
    assert "fine-tuned, fixed" not in rows and "B: (c) adaptive − fixed" not in rows  # B has no fixed arm
    out = tmp_path / "cmp.md"
    assert compare_runs.main([str(a), str(b), "--labels", "ctl", "abl", "--out", str(out)]) == 0
    assert out.read_text().startswith("| reward | ctl (A) | abl (B) |") and "| offline chunk policy | 15.0 | 17.0 | +2.0 [" in out.read_text()
    assert compare_runs.main([str(tmp_path / "missing"), str(b)]) == 2
    assert "no fig2_raw/" in capsys.readouterr().err


def test_pool_replicates_pools_every_online_phase_of_every_report(tmp_path, capsys):
    from experiments.fig2 import pool_replicates

    a = _report(tmp_path / "a", {(0, "adaptive"): 110.0, (0, "fixed"): 100.0, (0, "adaptive_r1"): 90.0,
                                 (0, "fixed_r1"): 100.0, (1, "adaptive"): 120.0, (1, "fixed"): 100.0})
    b = _report(tmp_path / "b", {(0, "adaptive"): 100.0, (0, "fixed"): 100.0, (1, "adaptive"): 130.0,
                                 (1, "fixed"): 100.0})
    assert compare_runs.c_runs(a) == {(0, "adaptive"): (110.0, 100.0), (0, "adaptive_r1"): (90.0, 100.0),
                                      (1, "adaptive"): (120.0, 100.0)}
    pool_replicates.main([str(a), str(b)], prog="pool-replicates")
    rows = capsys.readouterr().out.splitlines()
    # pooled: 5 runs, adaptive 110.0 against fixed 100.0, (c) +10 %; per run +10, -10, +20, 0, +30 %
    assert rows[-2].startswith("| pooled | 5 | 110.0 | 100.0 | +10.00 % | +10.0 ± ")
    with pytest.raises(SystemExit, match="different seeds"):
        pool_replicates.main([str(a), str(_report(tmp_path / "c", {(2, "adaptive"): 1.0, (2, "fixed"): 1.0}))])
