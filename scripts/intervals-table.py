#!/usr/bin/env python3
"""The reports' 95 % intervals against the truth, from `dbt-eval accuracy` outputs.

Usage: scripts/intervals-table.py LABEL=DIR [LABEL=DIR ...]

Each DIR is an `--out` folder of `dbt-eval accuracy` (its accuracy.json) of a
run with the model's report intervals loaded (issue #48 point 4). Prints, per
folder, how many intervals were given, how many hold the truth, and their
median width (glandularity in pp, MGD in % of the reported figure).
"""
import json
import statistics
import sys


def main(args):
    if not args:
        sys.exit(__doc__)
    print("| breasts | n | glandularity: given | holds the truth | median width (pp) | MGD: given | holds the truth | median width (% of the estimate) |")
    print("|---|---|---|---|---|---|---|---|")
    for arg in args:
        label, _, path = arg.partition("=")
        d = json.load(open(f"{path}/accuracy.json"))
        for r in d["reconstructors"]:
            cs = r["cases"]
            g = [(c["intervals"]["glandularity"]["limits"], c["g_true"], c["g_reported"]) for c in cs]
            m = [(c["intervals"]["mgd"]["limits"], c["mgd_true"], c["mgd_est"]) for c in cs]
            def row(xs, scale):
                given = [(lim, t, v) for lim, t, v in xs if lim]
                held = sum(1 for lim, t, _ in given if lim[0] <= t <= lim[1])
                widths = [scale(lim, v) for lim, _, v in given]
                w = f"{statistics.median(widths):.1f}" if widths else "-"
                return f"{len(given)} | {held} | {w}"
            print(
                f"| {label} | {len(cs)} | "
                + row(g, lambda lim, v: 100 * (lim[1] - lim[0]))
                + " | "
                + row(m, lambda lim, v: 100 * (lim[1] - lim[0]) / v)
                + " |"
            )


if __name__ == "__main__":
    main(sys.argv[1:])
