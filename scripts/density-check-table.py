#!/usr/bin/env python3
"""The density cross-check's figures from `dbt-eval accuracy` outputs.

Usage: scripts/density-check-table.py [--rule] LABEL=DIR [LABEL=DIR ...]

Each DIR is an `--out` folder of `dbt-eval accuracy` (its accuracy.json).
Prints, per folder and reconstructor, the disagreements between the reported
glandularity and the physics density (whole breast, and over the physics'
contact region), how many reports the limits leave unconfirmed, and the
error of the reported figure of those confirmed and of those not; then, over
all folders, the limit rule of `dbt_pipeline::density_check::LIMITS`: in each
band of the reported glandularity (below 20 %, 20-40 %, from 40 %), 1.2 x the
largest |disagreement| of the cases in the band, rounded up to a whole pp,
and the smallest fill rule (0.95 x the smallest fill, rounded down to two
places).
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


BANDS = [(0.0, 0.2), (0.2, 0.4), (0.4, math.inf)]


def band_name(lo, hi):
    return f"{100 * lo:.0f}-{100 * hi:.0f} %" if hi != math.inf else f"from {100 * lo:.0f} %"


def main(args):
    rule_wanted = "--rule" in args
    args = [a for a in args if a != "--rule"]
    if not args:
        sys.exit(__doc__)
    print("| breasts | n | reported - physics, whole (pp): mean +- sd, largest abs | contact region (pp) | not confirmed | reported - truth, confirmed (pp): mean +- sd, largest abs | reported - truth, not confirmed (pp) |")
    print("|---|---|---|---|---|---|---|")
    whole_all, contact_all = [], []
    banded = []  # (reported, whole, contact, fill)
    for a in args:
        label, path = a.split("=", 1)
        for rec, cs in cases(path):
            w = [c["density_check"]["difference_pp"] for c in cs if c["density_check"]["difference_pp"] is not None]
            k = [c["density_check"]["contact_difference_pp"] for c in cs if c["density_check"]["contact_difference_pp"] is not None]
            whole_all += w
            contact_all += k
            banded += [(c["g_reported"], c["density_check"]["difference_pp"],
                        c["density_check"]["contact_difference_pp"],
                        c["plausibility"]["volume"]["fill"]) for c in cs]
            ok = [100 * (c["g_reported"] - c["g_true"]) for c in cs if c["density_check"]["confirmed"]]
            bad = [100 * (c["g_reported"] - c["g_true"]) for c in cs if not c["density_check"]["confirmed"]]
            largest = lambda xs: f", {max(map(abs, xs)):.1f}" if xs else ""
            print(f"| {label} | {len(cs)} | {fmt(w)}{largest(w)} | {fmt(k)}{largest(k)} | {len(bad)} | {fmt(ok)}{largest(ok)} | {', '.join(f'{b:+.1f}' for b in bad) or '-'} |")
    if rule_wanted and banded:
        print("\n| reported glandularity | n | largest abs, whole (pp) | limit | largest abs, contact (pp) | limit |")
        print("|---|---|---|---|---|---|")
        for lo, hi in BANDS:
            sel = [b for b in banded if lo <= b[0] < hi]
            w = [abs(b[1]) for b in sel if b[1] is not None]
            k = [abs(b[2]) for b in sel if b[2] is not None]
            if not w or not k:
                print(f"| {band_name(lo, hi)} | {len(sel)} | - | - | - | - |")
                continue
            rule = lambda xs: math.ceil(1.2 * max(xs) - 1e-9)
            print(f"| {band_name(lo, hi)} | {len(sel)} | {max(w):.1f} | {rule(w)} | {max(k):.1f} | {rule(k)} |")
        fills = [b[3] for b in banded if b[3] is not None]
        print(f"\nsmallest fill {min(fills):.3f}: limit {math.floor(0.95 * min(fills) * 100) / 100:.2f}")


if __name__ == "__main__":
    main(sys.argv[1:])
