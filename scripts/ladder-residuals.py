"""The data residual (`dbt-eval ladder`, `data_residual`: ||P f - g|| / ||g||
of the reconstruction against its own acquisition) beside the reported
glandularity's error, case by case, for one or more ladder JSONs; and each
file's range. A candidate for a check that needs no truth.

    python3 scripts/ladder-residuals.py A.json [B.json ...]
"""
import json, sys

for path in sys.argv[1:]:
    cases = json.load(open(path))["cases"]
    rows = []
    for c in cases:
        rungs = {r["name"]: r for r in c["rungs"]}
        noisy = next(r for n, r in rungs.items() if n.startswith("recon@"))
        rows.append((c["phantom"], c["thickness_mm"], c["g_true"],
                     100 * (noisy["g_reported"] - c["g_true"]), noisy["data_residual"],
                     rungs["recon"]["data_residual"]))
    print(f"## {path}")
    print("| phantom | T (mm) | G true | reported - truth, noisy (pp) | residual, noisy | residual, noise-free |")
    print("|---|---|---|---|---|---|")
    for p, t, g, e, rn, rc in rows:
        print(f"| {p} | {t:.1f} | {g:.3f} | {e:+.1f} | {rn:.4f} | {rc:.4f} |")
    res = [r[4] for r in rows]
    err = [abs(r[3]) for r in rows]
    print(f"residual, noisy: {min(res):.4f}-{max(res):.4f}; |error| {min(err):.1f}-{max(err):.1f} pp\n")
