"""Two `dbt-eval accuracy` runs of the same phantoms, phantom by phantom:
the largest differences in reported, partial-volume and label glandularity
(pp) and patient MGD (%), and the fp32 Winograd bar of eval/README.md
(every reported glandularity within 0.05 pp, every MGD within 0.2 %).

    python3 scripts/compare-accuracy-runs.py A/accuracy.json B/accuracy.json
"""
import json, sys
off = json.load(open(sys.argv[1]))["reconstructors"][0]["cases"]
on = json.load(open(sys.argv[2]))["reconstructors"][0]["cases"]
assert [c["phantom"] for c in off] == [c["phantom"] for c in on]
dg = [abs(a["g_reported"] - b["g_reported"]) * 100 for a, b in zip(off, on)]
dpv = [abs(a["g_partial_volume"] - b["g_partial_volume"]) * 100 for a, b in zip(off, on)]
dl = [abs(a["g_labels"] - b["g_labels"]) * 100 for a, b in zip(off, on)]
dm = [abs(b["mgd_est"] / a["mgd_est"] - 1) * 100 for a, b in zip(off, on)]
print(f"{len(off)} phantoms: reported glandularity max |diff| {max(dg):.4f} pp (mean {sum(dg)/len(dg):.4f}); "
      f"partial volume {max(dpv):.4f} pp; labels {max(dl):.4f} pp; patient MGD max |diff| {max(dm):.4f} %")
ok = max(dg) <= 0.05 and max(dm) <= 0.2
print("bar (every reported glandularity within 0.05 pp, every MGD within 0.2 %):", "PASSED" if ok else "MISSED")
