"""Efficiency of every estimator relative to `mis`, one column per stage, from an `illum bench`
results.csv: CPU-second efficiency (1 / (relMSE x CPU seconds)) over mis's at one budget, and
what `auto` picked.

    .venv/bin/python bench/estimator_table.py bench/results/estimators/defaults/path_n1.csv --budget 8
"""
from __future__ import annotations

import argparse
import csv


def table(path: str, budget: float) -> str:
    rows = [r for r in csv.DictReader(open(path)) if float(r["budget_s"]) == budget]
    stages = sorted({r["stage"] for r in rows})
    configs = list(dict.fromkeys(r["config"] for r in rows))
    eff = {(r["stage"], r["config"]): float(r["efficiency_cpu"]) for r in rows}
    auto = {r["stage"]: r["auto_choice"] for r in rows if r["config"] == "auto"}
    out = [f"| config | {' | '.join(stages)} |", "|---" * (len(stages) + 1) + "|"]
    for c in configs:
        cells = (f"{eff[(s, c)] / eff[(s, 'mis')]:.2f}" if (s, c) in eff and (s, "mis") in eff else "-"
                 for s in stages)
        out.append(f"| {c} | {' | '.join(cells)} |")
    if auto:
        out += ["", "auto picked: " + "; ".join(f"{s}: {auto[s]}" for s in stages if s in auto)]
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("csv")
    ap.add_argument("--budget", type=float, default=8.0, help="render budget in seconds (default 8)")
    a = ap.parse_args()
    print(table(a.csv, a.budget))


if __name__ == "__main__":
    main()
