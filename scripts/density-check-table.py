#!/usr/bin/env python3
"""The density cross-check's figures from `dbt-eval accuracy` outputs.

Usage: scripts/density-check-table.py [--rule] LABEL=DIR [LABEL=DIR ...]

Each DIR is an `--out` folder of `dbt-eval accuracy` (its accuracy.json).
Prints, per folder and reconstructor, the disagreements between the reported
glandularity and the physics density (whole breast, and over the physics'
contact region), how many reports the limits leave unconfirmed, and the
error of the reported figure of those confirmed and of those not; then, over
all folders, the limit rule of `dbt_pipeline::density_check::LIMITS`
(1.2 x the largest |disagreement|, rounded up to a whole pp).
"""
import json
import math
import statistics
import sys


def cases(path):
    d = json.load(open(f"{path}/accuracy.json"))
    for r in d["reconstructors"]:
        yield r["reconstructor"], r["cases"]


def fmt(xs):
    if not xs:
        return "-"
    m = statistics.mean(xs)
    sd = statistics.stdev(xs) if len(xs) > 1 else 0.0
    return f"{m:+.1f} +- {sd:.1f}"


def main(args):
    rule_wanted = "--rule" in args
    args = [a for a in args if a != "--rule"]
    if not args:
        sys.exit(__doc__)
    print("| breasts | n | reported - physics, whole (pp): mean +- sd, largest abs | contact region (pp) | not confirmed | reported - truth, confirmed (pp): mean +- sd, largest abs | reported - truth, not confirmed (pp) |")
    print("|---|---|---|---|---|---|---|")
    whole_all, contact_all = [], []
    for a in args:
        label, path = a.split("=", 1)
        for rec, cs in cases(path):
            w = [c["density_check"]["difference_pp"] for c in cs if c["density_check"]["difference_pp"] is not None]
            k = [c["density_check"]["contact_difference_pp"] for c in cs if c["density_check"]["contact_difference_pp"] is not None]
            whole_all += w
            contact_all += k
            ok = [100 * (c["g_reported"] - c["g_true"]) for c in cs if c["density_check"]["confirmed"]]
            bad = [100 * (c["g_reported"] - c["g_true"]) for c in cs if not c["density_check"]["confirmed"]]
            largest = lambda xs: f", {max(map(abs, xs)):.1f}" if xs else ""
            print(f"| {label} | {len(cs)} | {fmt(w)}{largest(w)} | {fmt(k)}{largest(k)} | {len(bad)} | {fmt(ok)}{largest(ok)} | {', '.join(f'{b:+.1f}' for b in bad) or '-'} |")
    if rule_wanted and whole_all and contact_all:
        rule = lambda xs: math.ceil(1.2 * max(map(abs, xs)))
        print(f"\nlimit rule (1.2 x largest |disagreement|, rounded up): whole {rule(whole_all)} pp, contact region {rule(contact_all)} pp")


if __name__ == "__main__":
    main(sys.argv[1:])
