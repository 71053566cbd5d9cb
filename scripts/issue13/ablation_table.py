"""The issue-13 ablation table from the JSON files of scripts/depth_prior_eval.py.

    python scripts/issue13/ablation_table.py LABEL=RUN/prior_eval.json [...] [--sets tum,hololens,...]

Prints one markdown row per run: for every set, zero-code RMSE / best constant (the ratio) and the median of
predicted / true depth, as "ratio (median)".
"""

from __future__ import annotations

import argparse
import json

SETS = "tum,hololens,cabinet,realsense,redwood,office,gen_v1,gen_v2,gen_v3"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", help="LABEL=path/to/prior_eval.json")
    ap.add_argument("--sets", default=SETS)
    args = ap.parse_args()
    sets = args.sets.split(",")
    print("| run | " + " | ".join(sets) + " |")
    print("|---|" + "---|" * len(sets))
    for spec in args.runs:
        label, path = spec.split("=", 1)
        data = json.load(open(path))
        res = next(iter(data.values()))
        cells = []
        for s in sets:
            r = res.get(s)
            cells.append("-" if not r or "ratio" not in r else f"{r['ratio']:.2f} ({r['median_depth_ratio']:.2f})")
        print(f"| {label} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
