"""``python -m experiments ogbench``: the quick run end to end, resuming, the report's statistics on
hand-made records, the cost estimate and bad input.

Needs the ``ogbench`` extra (fails under ``CI=true`` without it, skips elsewhere), except for the
report builders, which read records only.
"""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest
from extras import require

from experiments.ogbench.unit import OGBenchBudget

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")


# ------------------------------------------------------------------------------------ quick run
@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    """``ogbench --quick`` once (3 arms x 2 seeds in this process), then a rerun of the stored run."""
    require("ogbench")
    from experiments.ogbench.cli import main

    out = tmp_path_factory.mktemp("ogbench_quick")
    assert main(["--quick", "--out", str(out)]) == 0
    return out, main


def test_quick_run_writes_the_report(quick_run):
    from experiments.ogbench.runner import DEFAULT_TASK, QUICK_BUDGET

    out, _ = quick_run
    for name in ("ogbench.md", "ogbench.json", "ogbench_online_success.png", "ogbench_online_return.png"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    report = json.loads((out / "ogbench.json").read_text(), parse_constant=pytest.fail)
    assert report["task"] == DEFAULT_TASK
    assert report["budget"] == json.loads(json.dumps(QUICK_BUDGET.to_dict()))
    assert list(report["arms"]) == ["adaptive", "fixed", "onestep"]
    for arm in report["arms"].values():
        assert arm["seeds"] == [0, 1]
        for phase in ("offline", "online"):
            stat = arm[phase]
            assert len(stat["per_seed"]) == 2 and all(v in (0.0, 0.5, 1.0) for v in stat["per_seed"])
            assert stat["mean"] == pytest.approx(np.mean(stat["per_seed"]))
            assert 0.0 <= stat["ci_low"] <= stat["iqm"] <= stat["ci_high"] <= 1.0
    assert sorted(report["improvement"]) == ["adaptive > fixed", "adaptive > onestep", "fixed > onestep"]
    assert report["qc_reference"]["offline_updates"] == report["qc_reference"]["online_steps"] == 1_000_000
    assert report["ranking"]["qc"] == "fixed chunks (QC) > one-step (FQL)"
    assert len(report["records"]) == 6 and report["estimate"]["total_cpu"] > 0
    text = (out / "ogbench.md").read_text()
    assert "| offline updates | 4 | 1,000,000 |" in text and "| online steps | 25 | 1,000,000 |" in text
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d UTC", report["date"]) and report["n_units"] == 6
    cpu = sum(report["seconds"].values()) / 60
    assert f"Command: `{report['command']}` ({report['date']})" in text
    assert f"Compute: {cpu:.0f} CPU-min over 6 units (estimate " in text


def test_rerun_skips_stored_units_and_reruns_one_deleted_unit(quick_run, capsys):
    out, main = quick_run
    work = out / "ogbench_work" / "units"
    record = next(work.rglob("fixed-s1/record.json"))
    before = {p: p.stat().st_mtime_ns for p in work.rglob("record.json")}
    capsys.readouterr()
    assert main(["--quick", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("OGBench pointmaze-medium-navigate-singletask-task1-v0: arms")  # the estimate comes first
    assert "6 of 6 unit(s) already stored, 0 to run" in printed
    assert {p: p.stat().st_mtime_ns for p in work.rglob("record.json")} == before
    shutil.rmtree(record.parent)
    assert main(["--quick", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "5 of 6 unit(s) already stored, 1 to run" in printed and "fixed-s1" in printed
    assert record.is_file()
    recorded = json.loads((out / "ogbench.json").read_text())
    recorded["date"] = "2026-01-02 03:04 UTC"  # as if the run had ended then
    (out / "ogbench.json").write_text(json.dumps(recorded))
    assert main(["--quick", "--out", str(out), "--report-only"]) == 0
    rebuilt = json.loads((out / "ogbench.json").read_text())  # the run's command and date, not the rebuild's
    assert rebuilt["date"] == "2026-01-02 03:04 UTC" and rebuilt["command"] == recorded["command"]
    assert "--report-only" not in rebuilt["command"]
    printed = capsys.readouterr().out
    assert "already stored" not in printed and "[1/" not in printed and "report:" in printed  # nothing ran


def test_report_only_from_the_report_alone_keeps_every_table(quick_run, tmp_path):
    out, main = quick_run
    copy = tmp_path / "report"
    copy.mkdir()
    for name in ("ogbench.md", "ogbench.json"):  # a checkout: the report without its units
        shutil.copy(out / name, copy / name)
    assert main(["--quick", "--out", str(copy), "--report-only"]) == 0
    text = (copy / "ogbench.md").read_text()
    assert "Executed lengths L_t of the evaluation plans" in text
    assert text == (out / "ogbench.md").read_text()


def test_report_only_without_stored_units_names_them(quick_run, tmp_path, capsys):
    _, main = quick_run
    assert main(["--quick", "--out", str(tmp_path), "--report-only", "--arms", "fixed"]) == 2
    assert "--report-only: no stored record for ['fixed-s0', 'fixed-s1']" in capsys.readouterr().err


def test_work_directory_of_another_budget_is_refused(quick_run):
    from experiments.ogbench.runner import DEFAULT_TASK, QUICK_BUDGET, build_units, check_stored_budget

    out, _ = quick_run
    other = OGBenchBudget(**{**QUICK_BUDGET.to_dict(), "pretrain_steps": 5})
    _, units = build_units(DEFAULT_TASK, ["fixed"], [0], other, out / "ogbench_work")
    with pytest.raises(ValueError, match="--work: .* another budget"):
        check_stored_budget(units, other)
    check_stored_budget(build_units(DEFAULT_TASK, ["fixed"], [0], QUICK_BUDGET, out / "ogbench_work")[1], QUICK_BUDGET)


@pytest.mark.parametrize(("argv", "message"), [
    (["--task", "cube-single-play-singletask-task9-v0"], "--task: .* names no evaluation task"),
    (["--task", "antmaze-medium-navigate-singletask-task1-v0"], "--task: task 'antmaze"),
    (["--task", "cube-single-v0"], "--task: task must be an OGBench single-task"),
    (["--task", "puzzle-3x3-play-singletask-task1-v0"], "--task: no budget is set for 'puzzle-3x3'"),
    (["--arms", "fixed", "qc"], r"--arms: unknown arm\(s\) \['qc'\]"),
    (["--seeds", "-1"], r"--seeds must be integers in \[0, 1000\), got \[-1\]"),
    (["--seeds", "3", "1000"], r"--seeds must be integers in \[0, 1000\)"),
    (["--episodes", "0"], "--episodes must be an integer >= 1"),
    (["--episodes", "1001"], "--episodes must be <= 1000"),
    (["--workers", "0"], "--workers"),
    (["--serial", "--ray-address", "auto"], "--serial runs the units in this process: .* --ray-address"),
])
def test_bad_input_is_a_clear_error(argv, message, capsys):
    require("ogbench")
    from experiments.ogbench.cli import main

    assert main(["--quick", "--out", "unused", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and re.search(message, err), err


def test_chosen_seeds_and_episodes_reach_the_units(tmp_path):
    require("ogbench")
    from experiments.ogbench.cli import main

    assert main(["--quick", "--seeds", "3", "--episodes", "3", "--arms", "onestep", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "ogbench.json").read_text())
    assert report["arms"]["onestep"]["seeds"] == [3] and report["budget"]["eval_episodes"] == 3
    unit = tmp_path / "ogbench_work" / "units" / report["task"] / "onestep-s3" / "record.json"
    record = json.loads(unit.read_text())
    assert len(record["eval_offline"]["successes"]) == len(record["eval_online"]["successes"]) == 3


def test_serial_runs_the_units_in_this_process_whatever_workers_says(tmp_path, monkeypatch):
    require("ogbench")
    from experiments.common import runner as common_runner
    from experiments.ogbench.cli import main

    def no_processes(workers):
        raise AssertionError(f"--serial started a pool of {workers} processes")

    monkeypatch.setattr(common_runner, "ProcessExecutor", no_processes)
    argv = ["--quick", "--seeds", "3", "--episodes", "2", "--arms", "onestep", "--out", str(tmp_path)]
    assert main([*argv, "--workers", "2", "--serial"]) == 0
    assert json.loads((tmp_path / "ogbench.json").read_text())["arms"]["onestep"]["seeds"] == [3]
    with pytest.raises(AssertionError, match="started a pool of 2 processes"):  # the trap is live without --serial
        main([*argv, "--workers", "2", "--out", str(tmp_path / "pool")])


def test_seeds_are_a_list_kept_distinct_and_sorted():
    from experiments.ogbench.runner import seeds_arg

    assert seeds_arg([12, 10, 12]) == [10, 12]
    assert seeds_arg(range(5)) == [0, 1, 2, 3, 4]  # the default
    with pytest.raises(ValueError, match="--seeds"):
        seeds_arg([])


# ------------------------------------------------------------------------------------ estimate
def test_estimate_scales_the_recorded_unit_seconds_by_the_steps():
    from experiments.ogbench.runner import estimate

    budget = OGBenchBudget(pretrain_steps=1000, finetune_steps=1000)
    report = {"budget": OGBenchBudget(pretrain_steps=3000, finetune_steps=1000).to_dict(),
              "records": [{"arm": "fixed", "seconds": {"total_cpu": 80.0}}, {"arm": "fixed", "seconds": {"total_cpu": 120.0}}]}
    est = estimate(["fixed", "onestep"], 2, budget, workers=2, reports=[report])
    # fixed: 200 CPU s over 8,000 steps = 25 ms per step -> 50 s a unit; onestep, unrecorded, the same rate
    assert est["units_cpu"] == est["total_cpu"] == pytest.approx(4 * 50.0)
    assert est["wall"] == pytest.approx(100.0)  # four units on two workers
    assert estimate(["fixed"], 1, budget, 1)["total_cpu"] > 0  # the committed reports


# ------------------------------------------------------------------------------------ report builders
def _record(arm, seed, offline, online, training=()):
    budget = OGBenchBudget(dataset_episodes=10, pretrain_steps=100, finetune_steps=100, eval_episodes=len(online))
    return {"arm": arm, "task": "cube-single-play-singletask-task2-v0", "seed": seed, "budget": budget.to_dict(),
            "eval_offline": {"successes": offline}, "eval_online": {"successes": online},
            "success_offline": float(np.mean(offline)), "success_online": float(np.mean(online)),
            "curve": [{"step": 0, "success": float(np.mean(offline))}, {"step": 100, "success": float(np.mean(online))}],
            "training_episodes": list(training), "seconds": {"total_cpu": 10.0}}


FIXED_ONLINE = [[1, 1, 1, 1], [1, 1, 1, 0], [0, 0, 0, 0]]  # 7 of 12 succeed


@pytest.fixture
def hand_records():
    return ([_record("fixed", s, [0, 0, 0, 0], FIXED_ONLINE[s]) for s in (2, 0, 1)]
            + [_record("onestep", s, [0, 0, 0, 1], [0, 0, 0, 0]) for s in range(3)])


def test_summary_statistics_on_hand_made_records(hand_records):
    require("rliable")
    from experiments.ogbench.report import summarize

    summary = summarize(hand_records, reps=200)
    fixed = summary["arms"]["fixed"]
    # one score per run: its success rate
    assert fixed["seeds"] == [0, 1, 2] and fixed["online"]["per_seed"] == [1.0, 0.75, 0.0]
    assert fixed["online"]["mean"] == pytest.approx(7 / 12)
    # IQM over 3 runs: 25 % of 3 trims no whole run, so it is their mean
    assert fixed["online"]["iqm"] == pytest.approx(7 / 12)
    assert summary["arms"]["onestep"]["offline"]["mean"] == pytest.approx(0.25)
    assert summary["arms"]["onestep"]["online"] == {"mean": 0.0, "per_seed": [0.0, 0.0, 0.0], "iqm": 0.0,
                                                    "ci_low": 0.0, "ci_high": 0.0}
    # offline: every one-step run (rate 0.25) beats every fixed run (rate 0)
    pair = summary["improvement"]["fixed > onestep"]
    assert pair["offline"]["probability"] == 0.0
    # online, run pairs: 1 > 0 and 0.75 > 0 three times each, 0 = 0 three ties -> (6 + 1.5) / 9
    assert pair["online"]["probability"] == pytest.approx(7.5 / 9)
    # paired per seed: differences 1, 0.75, 0 -> mean 7/12, sd 0.52042, t(0.975, 2) = 4.30265
    paired = pair["online_paired"]
    assert paired["difference"] == pytest.approx(7 / 12) and paired["x_better_runs"] == 2
    assert paired["ci_low"] == pytest.approx(7 / 12 - 4.302653 * 0.520416 / 3 ** 0.5, abs=1e-5)
    assert paired["ci_high"] == pytest.approx(7 / 12 + 4.302653 * 0.520416 / 3 ** 0.5, abs=1e-5)
    assert summary["best_mean_success"] == pytest.approx(7 / 12) and summary["above_bar"]


def test_ranking_against_qc():
    from experiments.ogbench.report import ranking

    assert ranking({"probability": 0.8, "ci_low": 0.6, "ci_high": 0.9}) == "fixed chunks > one-step"
    assert ranking({"probability": 0.2, "ci_low": 0.1, "ci_high": 0.4}) == "one-step > fixed chunks"
    assert ranking({"probability": 0.5, "ci_low": 0.4, "ci_high": 0.6}).startswith("no clear ranking")
    assert ranking(None).startswith("not measured")


def test_markdown_and_curves_on_hand_made_records(hand_records, tmp_path):
    require("rliable")
    from experiments.ogbench.report import format_markdown, return_curve, summarize, write_report

    summary = write_report(hand_records, tmp_path, command="python -m experiments ogbench", reps=200)
    text = (tmp_path / "ogbench.md").read_text()
    assert "| fixed chunks (k = 5, δ = inf) | 3 | 0.0 % | 0.0 % [0.0 %, 0.0 %] | 58.3 % | 58.3 %" in text
    assert "| 100, 75, 0 |" in text and "Command: `python -m experiments ogbench`" in text
    assert summary["ranking"]["agrees_with_qc"] is (summary["ranking"]["ours_online"] == "fixed chunks > one-step")
    assert (tmp_path / "ogbench_online_success.png").stat().st_size > 1000
    on_disk = json.loads((tmp_path / "ogbench.json").read_text(), parse_constant=pytest.fail)
    assert [r["arm"] for r in on_disk["records"]] == ["fixed"] * 3 + ["onestep"] * 3
    training = [{"step": 10, "success": 0.0, "return": -10.0}, {"step": 40, "success": 0.0, "return": -20.0},
                {"step": 80, "success": 1.0, "return": -5.0}]
    centres, means = return_curve([_record("fixed", 0, [0], [1], training)], bins=2)
    assert centres.tolist() == [25.0, 75.0] and means.tolist() == [-15.0, -5.0]
    failing = [_record("fixed", 0, [0, 0], [0, 0]), _record("onestep", 0, [0, 0], [0, 0])]
    assert "**No arm exceeds 10 % success at this budget**" in format_markdown(summarize(failing, reps=50))
    one_arm = format_markdown(summarize(hand_records[3:], reps=50))  # the one-step arm alone
    assert "One arm ran: no pair of arms" in one_arm and "| X > Y |" not in one_arm
    assert "| X > Y |" in text  # two arms: the table of pairs
    cpu = sum(summary["seconds"].values()) / 60
    for estimate, said in ((2 * cpu, "an upper bound"), (cpu / 2, "exceeded: the units cost more")):
        summary["estimate"] = {"total_cpu": estimate * 60}
        assert f"(estimate {estimate:.0f} CPU-min, {said}" in format_markdown(summary)


def test_report_rejects_mixed_tasks_and_reads_run_rates(hand_records):
    require("rliable")
    from experiments.ogbench.report import success_matrix, summarize

    other = {**hand_records[0], "task": "scene-play-singletask-task1-v0"}
    with pytest.raises(ValueError, match="records must come from one task"):
        summarize([*hand_records, other])
    assert success_matrix(hand_records[:3], "online").tolist() == [[1.0], [0.75], [0.0]]  # rates, seed order
    with pytest.raises(ValueError, match="phase must be one of"):
        success_matrix(hand_records, "final")


def test_summary_and_report_show_the_length_histograms_when_recorded(hand_records):
    require("rliable")
    from experiments.ogbench.report import format_markdown, summarize

    for r in hand_records:
        k1 = r["arm"] == "onestep"
        r["eval_offline"]["length_shares"] = [1.0] if k1 else [0.5, 0.0, 0.0, 0.0, 0.5]
        r["eval_online"]["length_shares"] = [1.0] if k1 else [0.0, 0.0, 0.0, 0.0, 1.0]
    r = hand_records[0]
    r["eval_offline"]["length_shares"] = [0.2, 0.0, 0.0, 0.0, 0.8]  # one fixed run differs
    summary = summarize(hand_records, reps=50)
    assert summary["arms"]["fixed"]["offline"]["length_shares"] == pytest.approx([0.4, 0, 0, 0, 0.6])
    assert summary["arms"]["onestep"]["online"]["length_shares"] == [1.0]
    text = format_markdown(summary)
    assert "40 0 0 0 60 | 0 0 0 0 100 |" in text and "| 100 | 100 |" in text
    del hand_records[1]["eval_online"]["length_shares"]  # a record made before 2026-12-04
    assert "length_shares" not in summarize(hand_records, reps=50)["arms"]["fixed"]["online"]
