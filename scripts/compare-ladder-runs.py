"""Two `dbt-eval ladder` runs of twin phantoms (the same population indices,
e.g. `anatomical` and `anatomical-spread`), rung by rung: the second run's
reported glandularity error minus the first's, phantom by phantom (pp), its
mean and sd, and in how many pairs the second reads lower.

    python3 scripts/compare-ladder-runs.py A.json B.json
"""
import json, statistics, sys

a = json.load(open(sys.argv[1]))["cases"]
b = json.load(open(sys.argv[2]))["cases"]
n = min(len(a), len(b))
index = lambda name: name.rsplit("(population index ", 1)[-1]
assert [index(c["phantom"]) for c in a[:n]] == [index(c["phantom"]) for c in b[:n]], "not twins"
err = lambda case, rung: 100 * (next(r for r in case["rungs"] if r["name"] == rung)["g_reported"] - case["g_true"])
print(f"{n} pairs; second - first, reported glandularity error (pp)")
for rung in [r["name"] for r in a[0]["rungs"]]:
    if not all(any(r["name"] == rung for r in c["rungs"]) for c in b[:n]):
        continue
    d = [err(y, rung) - err(x, rung) for x, y in zip(a[:n], b[:n])]
    sd = statistics.stdev(d) if n > 1 else float("nan")
    print(f"| {rung} | {statistics.mean(d):+.2f} | {sd:.2f} | {sum(v < 0 for v in d)} of {n} lower |")
