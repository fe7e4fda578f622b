#!/usr/bin/env python3
"""How well the reconstructions explain their projections, from `dbt-eval
accuracy` outputs (`dbt_pipeline::data_fit`, each case's `data_fit`).

Usage: scripts/data-fit-table.py [--limit X] [--rule PREFIX] LABEL=DIR [LABEL=DIR ...]

Each DIR is an `--out` folder of `dbt-eval accuracy` (its accuracy.json).
Prints, per folder, the data residual, its Poisson-noise share and the
excess over the noise (smallest, median, largest), and the error of the
reported glandularity of the breasts within the limit and of those beyond
it (`LIMIT` from `--limit X`, else none). With `--rule PREFIX`, the limit rule of
`dbt_pipeline::density_check::LIMITS.data_fit_max` over the folders whose
label starts with PREFIX (the network's own world's validation breasts):
1.2 x their largest excess, rounded up to the third decimal.
"""
import json
import math
import statistics
import sys


def cases(path):
    d = json.load(open(f"{path}/accuracy.json"))
    for r in d["reconstructors"]:
        yield from r["cases"]


def spread(xs):
    xs = sorted(xs)
    return f"{xs[0]:.4f} / {statistics.median(xs):.4f} / {xs[-1]:.4f}"


def err(cs):
    if not cs:
        return "-"
    e = [100 * (c["g_reported"] - c["g_true"]) for c in cs]
    return f"{len(cs)}: {statistics.mean(e):+.1f} +- {statistics.stdev(e) if len(e) > 1 else 0:.1f}, largest abs {max(map(abs, e)):.1f}"


def main(args):
    rule, limit = None, None
    rest = []
    it = iter(args)
    for a in it:
        if a == "--rule":
            rule = next(it)
        elif a == "--limit":
            limit = float(next(it))
        else:
            rest.append(a)
    if not rest:
        sys.exit(__doc__)
    print("| breasts | n | residual: smallest / median / largest | noise share | excess over the noise | reported - truth within the limit (n: mean +- sd, largest abs, pp) | beyond it |")
    print("|---|---|---|---|---|---|---|")
    by_label = {}
    for a in rest:
        label, path = a.split("=", 1)
        cs = list(cases(path))
        by_label[label] = cs
        fits = [c["data_fit"] for c in cs]
        within = [c for c in cs if limit is None or c["data_fit"]["excess"] <= limit]
        beyond = [c for c in cs if limit is not None and c["data_fit"]["excess"] > limit]
        print(f"| {label} | {len(cs)} | {spread([f['residual'] for f in fits])} | "
              f"{spread([f['noise'] for f in fits])} | {spread([f['excess'] for f in fits])} | "
              f"{err(within)} | {err(beyond)} |")
    if rule:
        labels = [l for l in by_label if l.startswith(rule)]
        if not labels:
            sys.exit(f"--rule {rule}: no folder's label starts with it")
        world = [c["data_fit"]["excess"] for l in labels for c in by_label[l]]
        top = max(world)
        lim = math.ceil(1.2 * top * 1000) / 1000
        print(f"\nrule over {'; '.join(labels)} ({len(world)} breasts): largest excess {top:.4f}, "
              f"limit 1.2 x that, rounded up: {lim:.3f}")


if __name__ == "__main__":
    main(sys.argv[1:])
