#!/usr/bin/env python3
"""Whether another beam keeps the W/Rh glandularity calibration (eval/README.md,
"The W/Ag beam"): reads two `dbt-eval accuracy --no-calibration` runs of the
same validation phantoms, one per beam, applies the model's W/Rh calibration
under KEY to each case's partial-volume estimate exactly as the pipeline does
(`GlandularityCalibration::apply`: offset + slope x PV + per_mm x (T - 50 mm),
clamped to 0..1), and prints both beams' reported-glandularity errors and the
bar: the other beam's bias within 0.5 pp and sd within 0.1 pp of W/Rh's, and
no error beyond 3 pp.

Usage: scripts/beam-calibration-bar.py MODEL_DIR KEY W_RH_RUN OTHER_RUN
  e.g. models/dbtor-x4t3qa "int8 | scatter removed + linearised" \
       /work/runs/wag/val-WRh /work/runs/wag/val-WAg
"""
import json
import statistics
import sys


def errors(run, cal):
    cases = json.load(open(f"{run}/accuracy.json"))["reconstructors"][0]["cases"]
    out = []
    for c in cases:
        g = cal["offset"] + cal["slope"] * c["g_partial_volume"] + cal.get("per_mm", 0.0) * (
            c["thickness_mm"] - 50.0
        )
        g = min(1.0, max(0.0, g))
        out.append(100.0 * (g - c["g_true"]))
    return out


def main():
    if len(sys.argv) != 5:
        sys.exit(__doc__)
    model, key, w_rh, other = sys.argv[1:]
    cals = json.load(open(f"{model}/glandularity-calibration.json"))["calibrations"]
    if key not in cals:
        sys.exit(f"{model}: no calibration under {key!r} (has {sorted(cals)})")
    cal = cals[key]
    a, b = errors(w_rh, cal), errors(other, cal)
    if len(a) != len(b):
        sys.exit(f"the runs hold {len(a)} and {len(b)} cases: not the same phantoms")
    print(f"calibration {key!r}: G = {cal['offset']:+.5f} + {cal['slope']:.5f} x PV")
    print("| beam | n | bias (pp) | sd (pp) | max abs (pp) |")
    print("|---|---|---|---|---|")
    for name, e in (("W/Rh", a), ("other", b)):
        print(f"| {name} ({sys.argv[3 if name == 'W/Rh' else 4]}) | {len(e)} | "
              f"{statistics.mean(e):+.2f} | {statistics.stdev(e):.2f} | {max(map(abs, e)):.2f} |")
    db = abs(statistics.mean(b) - statistics.mean(a))
    ds = statistics.stdev(b) - statistics.stdev(a)
    worst = max(map(abs, b))
    ok = db <= 0.5 and ds <= 0.1 and worst <= 3.0
    print(f"bar: |bias difference| {db:.2f} pp (<= 0.5), sd difference {ds:+.2f} pp (<= 0.1), "
          f"largest error {worst:.2f} pp (<= 3): {'kept' if ok else 'missed: its own calibrations'}")


if __name__ == "__main__":
    main()
