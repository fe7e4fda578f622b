#!/usr/bin/env python3
"""A breastPhantom config of the external VICTRE set (issue #48 point 5).

Usage: scripts/victre/make-cfg.py UPSTREAM_CFG_DIR CLASS K SEED OUTDIR > FILE.cfg

Takes the generator's own VICTRE_<CLASS>.cfg (CLASS: dense, hetero,
scattered, fatty; DIDSR/breastPhantom cfg/), sets the voxel size to 0.5 mm,
the seed and the output folder, and multiplies the shape half-extents
(a1b, a1t, a2l, a2r, a3) by the size scale K; every other setting is
upstream's (README.md, "Proposed 10-breast set").
"""
import re
import sys


def main(argv):
    if len(argv) != 5:
        sys.exit(__doc__)
    upstream, cls, k, seed, out = argv
    k = float(k)
    if cls not in ("dense", "hetero", "scattered", "fatty"):
        sys.exit(f"class {cls!r}: dense, hetero, scattered or fatty")
    if not 0.3 <= k <= 2.0:
        sys.exit(f"size scale {k}: expected 0.3-2.0")
    text = open(f"{upstream}/VICTRE_{cls}.cfg").read()
    seen = set()

    def sub(m):
        key, val = m.group(1), m.group(2)
        seen.add(key)
        if key == "imgRes":
            return f"{key}=0.5"
        if key == "seed":
            return f"{key}={int(seed)}"
        if key == "outputDir":
            return f"{key}={out}"
        if key in ("a1b", "a1t", "a2l", "a2r", "a3"):
            return f"{key}={float(val) * k:.4f}"
        return m.group(0)

    text = re.sub(r"^(\w+)=(.*)$", sub, text, flags=re.M)
    if "seed" not in seen:
        # Upstream leaves the seed out (then /dev/urandom): set it in [base].
        text = re.sub(r"^(imgRes=.*)$", lambda m: f"{m.group(1)}\n# random number seed\nseed={int(seed)}", text, count=1, flags=re.M)
        seen.add("seed")
    missing = {"imgRes", "outputDir", "a1b", "a1t", "a2l", "a2r", "a3"} - seen
    if missing:
        sys.exit(f"VICTRE_{cls}.cfg has no {sorted(missing)}")
    sys.stdout.write(f"# VICTRE_{cls}.cfg, shape x {k}, seed {seed}, 0.5 mm (scripts/victre/make-cfg.py)\n" + text)


if __name__ == "__main__":
    main(sys.argv[1:])
