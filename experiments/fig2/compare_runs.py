"""An ablation against its control: two Figure-2 reports on the same seeds and datasets, paired run by run
(``python -m experiments compare-runs A B``): per method the paired difference ``B − A``, and each (c)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from experiments.common.names import replicate_name
from experiments.common.stats import interval, paired_difference

#: rows of the comparison: (label, methods pooled into it; their runs are (seed, method) pairs)
ROWS = (("offline chunk policy", ("chunk",)), ("offline chunk policy, sampled", ("chunk_sampled",)),
        ("fine-tuned, adaptive", ("adaptive",)), ("fine-tuned, fixed", ("fixed",)),
        ("fine-tuned, adaptive, sampled", ("adaptive_sampled",)), ("fine-tuned, fixed, sampled", ("fixed_sampled",)))
MAX_PHASES = 10


def run_rewards(report: Path, method: str) -> dict[tuple[int, str], float]:
    """``{(seed, unit): mean reward}`` of ``method`` in every seed and online phase of a report directory."""
    out = {}
    base, sampled, _ = method.partition("_sampled")
    for seed_dir in sorted((report / "fig2_raw").glob("seed*")):
        seed = int(seed_dir.name.removeprefix("seed"))
        for name in (replicate_name(base, r) + sampled for r in range(MAX_PHASES)):
            if (seed_dir / f"{name}.json").is_file():
                out[(seed, name)] = float(json.loads((seed_dir / f"{name}.json").read_text())["summary"]["reward"])
    return out


def c_runs(report: Path, suffix: str = "") -> dict[tuple[int, str], tuple[float, float]]:
    """``{(seed, unit): (adaptive reward, fixed reward)}``: Figure 2 (c)'s paired runs in a report directory."""
    ad, fx = run_rewards(report, "adaptive" + suffix), run_rewards(report, "fixed" + suffix)
    return {(s, u): (ad[(s, u)], fx[(s, u.replace("adaptive", "fixed"))]) for s, u in sorted(ad)
            if (s, u.replace("adaptive", "fixed")) in fx}


def compare(a: Path, b: Path) -> list[dict]:
    """One row per :data:`ROWS` entry both reports hold, plus (c) of each report."""
    pairs = []  # (label, runs of B (or adaptive), the same runs of A (or fixed))
    for label, methods in ROWS:
        ra = {k: v for m in methods for k, v in run_rewards(a, m).items()}
        rb = {k: v for m in methods for k, v in run_rewards(b, m).items()}
        shared = sorted(set(ra) & set(rb))
        pairs.append((label, [rb[k] for k in shared], [ra[k] for k in shared]))
    for name, report in (("A", a), ("B", b)):
        for suffix in ("", "_sampled"):
            runs = c_runs(report, suffix).values()
            pairs.append((f"{name}: (c) adaptive − fixed{', sampled' if suffix else ''}", [ad for ad, _ in runs],
                          [fx for _, fx in runs]))
    return [{"label": label, "a": sum(y) / len(y), "b": sum(x) / len(x), **paired_difference(x, y)}
            for label, x, y in pairs if len(x) >= 2]


def format_table(rows: Sequence[dict], labels: Sequence[str]) -> str:
    lines = [f"| reward | {labels[0]} (A) | {labels[1]} (B) | B − A, paired [95 % CI] | runs (B ahead) |",
             "|---|---|---|---|---|"]
    for r in rows:
        c = ": (c)" in r["label"]  # a report's own (c): A is its fixed arm, B its adaptive arm
        lines.append(f"| {r['label']} | {'fixed ' * c}{r['a']:.1f} | {'adaptive ' * c}{r['b']:.1f} | "
                     f"{interval(r, digits=1)} | {r['runs']} ({r['x_better_runs']}) |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None, prog: str = "python -m experiments compare-runs") -> int:
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n")[0])
    parser.add_argument("a", type=Path, help="the control's report directory (A)")
    parser.add_argument("b", type=Path, help="the ablation's report directory (B)")
    parser.add_argument("--labels", nargs=2, default=["A", "B"], help="names of A and B in the table")
    parser.add_argument("--out", type=Path, default=None, help="also write the table to this markdown file")
    args = parser.parse_args(argv)
    for report in (args.a, args.b):
        if not (report / "fig2_raw").is_dir():
            print(f"error: no fig2_raw/ under {report}", file=sys.stderr)
            return 2
    table = format_table(compare(args.a, args.b), args.labels)
    print(table)
    if args.out is not None:
        args.out.write_text(table + "\n", encoding="utf-8")
    return 0
