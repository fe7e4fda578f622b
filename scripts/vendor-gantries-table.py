#!/usr/bin/env python3
"""The physics-only report on the vendors' gantries (issue #51 point 3):
one row per `dbt-eval accuracy --reconstructors physics...` output folder
and reconstructor: the reported glandularity's error (pp) and the MGD's (%)
against the truth, bias, sd, 95 % limits (bias +- 1.96 sd) and the largest
absolute error, and how many reports the estimate's own checks flagged.

Usage: scripts/vendor-gantries-table.py DIR [DIR ...]
       (each DIR's accuracy.json; the folder's name labels its rows)
"""
import json
import math
import pathlib
import sys


def stats(xs):
    n = len(xs)
    if n == 0:
        return None
    m = sum(xs) / n
    sd = math.sqrt(sum((x - m) ** 2 for x in xs) / (n - 1)) if n > 1 else float("nan")
    return m, sd, m - 1.96 * sd, m + 1.96 * sd, max(abs(x) for x in xs)


def fmt(s):
    if s is None:
        return "| - | - | - | - "
    m, sd, lo, hi, mx = s
    return f"| {m:+.2f} | {sd:.2f} | [{lo:+.1f}, {hi:+.1f}] | {mx:.1f} "


def main():
    if len(sys.argv) < 2:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    print("| run | system | model breast | n | glandularity bias (pp) | sd | 95 % limits | max | "
          "MGD bias (%) | sd | 95 % limits | max | flagged |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for d in sys.argv[1:]:
        p = pathlib.Path(d)
        if not (p / "accuracy.json").is_file():
            print(f"{d}: no accuracy.json, skipped", file=sys.stderr)
            continue
        j = json.loads((p / "accuracy.json").read_text())
        for r in j["reconstructors"]:
            cs = r["cases"]
            g = [100.0 * (c["g_reported"] - c["g_true"]) for c in cs]
            mgd = [100.0 * (c["mgd_est"] / c["mgd_true"] - 1.0) for c in cs]
            flagged = sum(1 for c in cs if not c["density_check"]["confirmed"])
            name = r["reconstructor"]
            breast = "central columns" if "central columns" in name else (
                "homogeneous" if "homogeneous" in name else name)
            print(f"| {p.name} | {j.get('system') or 'fan'} | {breast} | {len(cs)} "
                  f"{fmt(stats(g))}{fmt(stats(mgd))}| {flagged} |")


if __name__ == "__main__":
    main()
