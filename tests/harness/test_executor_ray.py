"""The Ray path of the executor on a real Ray head (issue 21): same results as a local run.

The test starts ``ray start --head`` inside fresh network and PID namespaces (``unshare``, root
only) where only loopback is up: Ray binds 127.0.0.1 there and nothing leaves the machine; when the
namespace's first process exits, every Ray process goes with it. Without ``unshare`` rights or Ray
the test fails under ``CI=true`` (``.ci/run`` runs as root and installs the ``peers`` extra) and
skips elsewhere.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import executor_helpers as helpers
import pytest
from extras import require, unavailable

from envs.collection import collect_dataset
from experiments.common.runner import SerialExecutor, run_units

# Starts a Ray head in a network namespace: about 40 s on idle cores, over 300 s next to two busy
# training processes, so the subprocess's own 600-s limit decides, not setup.cfg's 300 s per test.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]

REPO = Path(__file__).resolve().parents[2]
PORT = 6390


def _missing() -> str | None:
    """Why a Ray head cannot be started in a private network namespace here (``None``: it can)."""
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return "needs unshare and ip (util-linux, iproute2)"
    if os.geteuid() != 0:
        return "needs root to create a network namespace (unshare -n)"
    if not (Path(sys.executable).parent / "ray").is_file():
        return 'needs ray: pip install "sb3-ua2c[peers]"'
    return None


def _ray_or_skip() -> None:
    reason = _missing()
    if reason is None:
        return
    unavailable(f"the Ray executor test: {reason}")


def _run_on_ray_head(tmp_path: Path, driver: list[str]) -> subprocess.CompletedProcess:
    """Start a Ray head on loopback in fresh network and PID namespaces, run ``driver`` (a command) there,
    and tear everything down with the namespace; fails with the head's log if the driver fails."""
    _ray_or_skip()
    short = Path(tempfile.mkdtemp(prefix="ray"))  # Ray's unix sockets need a short path
    ray = Path(sys.executable).parent / "ray"
    script = " && ".join([
        "ip link set lo up",
        f"{shlex.quote(str(ray))} start --head --port {PORT} --num-cpus 2 --include-dashboard=false "
        f"--disable-usage-stats --temp-dir {shlex.quote(str(short))} > {shlex.quote(str(tmp_path / 'ray.log'))} 2>&1",
        " ".join(shlex.quote(a) for a in driver),
    ])
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0",
           "PYTHONPATH": os.pathsep.join([str(REPO), str(REPO / "tests"), os.environ.get("PYTHONPATH", "")])}
    try:  # about 40 s on idle cores, over 240 s next to two busy training processes
        proc = subprocess.run(["unshare", "--net", "--pid", "--fork", "--mount-proc", "sh", "-c", script],
                              env=env, capture_output=True, text=True, timeout=600, cwd=REPO)
    finally:
        shutil.rmtree(short, ignore_errors=True)
    log = (tmp_path / "ray.log").read_text() if (tmp_path / "ray.log").exists() else ""
    assert proc.returncode == 0, f"{proc.stdout}\n{proc.stderr}\n{log}"
    return proc


def test_ray_head_gives_the_local_results(tmp_path):
    _ray_or_skip()
    out = tmp_path / "ray.json"
    dataset = collect_dataset(tmp_path / "dataset", 2, env_kwargs={"time_limit": 2.0}, seed=5).path
    args = ", ".join(repr(str(a)) for a in (f"127.0.0.1:{PORT}", dataset, tmp_path / "on_ray", out))
    _run_on_ray_head(tmp_path, [sys.executable, "-c", f"import executor_helpers as h; h.run_demo_on_ray({args})"])
    on_ray = json.loads(out.read_text())
    local = {r.name: r.value for r in run_units(helpers.demo_units(dataset, tmp_path / "local"), SerialExecutor(),
                                                printer=None)}
    assert {local[name].pop("pid") for name in ("sq3", "sumo0", "sumo1")} == {os.getpid()}
    assert len({on_ray[name].pop("pid") for name in ("sq3", "sumo0", "sumo1")}) == 3  # max_calls=1: fresh workers
    for record in (local["sac"], on_ray["sac"]):  # timings differ from run to run
        del record["wall_seconds"], record["cpu_seconds"]
    assert on_ray == local
    assert local["sq3"] == {"x": 3, "square": 9} and local["sumo0"]["steps"] == 10
    assert [e["end_step"] for e in local["sac"]["online_episodes"]] == [10, 20]


def _arm_numbers(report: Path) -> dict:
    """What a peers report measured, without the times (they differ from run to run)."""
    arms = json.loads((report / "peers.json").read_text())["arms"]
    return {arm: {k: v for k, v in stats.items() if k not in ("wall_seconds", "cpu_seconds")}
            for arm, stats in arms.items()}


def test_peers_quick_on_a_ray_head_gives_the_local_numbers(tmp_path):
    _ray_or_skip()
    require("d3rlpy")
    from experiments.peers import cli

    quick = ["--quick", "--seeds", "0", "--arms", "ua2c_adaptive", "sac", "iql"]  # UA2C, SB3 and d3rlpy units
    assert cli.main([*quick, "--workers", "1", "--out", str(tmp_path / "local")]) == 0
    proc = _run_on_ray_head(tmp_path, [sys.executable, "-m", "experiments", "peers", *quick, "--ray-address",
                                       f"127.0.0.1:{PORT}", "--out", str(tmp_path / "ray")])
    assert "[3/3] unit seed0/" in proc.stdout  # every arm ran as a Ray task
    local, on_ray = _arm_numbers(tmp_path / "local"), _arm_numbers(tmp_path / "ray")
    assert sorted(on_ray) == sorted(local) == ["iql", "iql_best_of_n", "sac", "ua2c_adaptive"]
    assert on_ray == local


def test_missing_unshare_fails_under_ci(monkeypatch):
    monkeypatch.setattr(shutil, "which", lambda name: None)
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="CI must run this test: the Ray executor test: needs unshare"):
        _ray_or_skip()


def test_missing_unshare_skips_on_a_developer_machine(monkeypatch):
    monkeypatch.setattr(shutil, "which", lambda name: None)
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match="needs unshare"):
        _ray_or_skip()
