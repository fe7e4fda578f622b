#!/usr/bin/env bash
# The main job: a simulated acquisition through the firmware's processing to
# validated DICOM output.
#  1. dbtor-diag selftest: the shipped geometry and projector at the paper's
#     full geometry (adjointness, analytic slab line integrals, norm bound),
#     and the reconstruction's kernels measured on the shipped model's blocks
#     (each checked against the portable kernel and timed; the chosen one
#     marked).
#  2. host-sim acquire: test-set phantom 0 (never trained on), acquired at
#     N = 8 (Poisson) on the gantry that firmware/config/dbtor.toml names: the
#     cone-beam system frames.system (the whole breast volume through the
#     exact 3-D projector, 2-D detector frames), binned by frames.binning,
#     for the reconstruction geometry frames.geometry (without a system:
#     every coronal slice its own fan beam); written as a recorded
#     acquisition (acquisition.json + counts.f32).
#  3. host-sim stream | dbtor-receive: the gantry's projection stream
#     (GANTRY_INTERFACE.md; its header names the system) over loopback TCP,
#     two processes; the firmware checks the system, acknowledges every
#     frame and spools the acquisition atomically.
#  4. dbtor-process: the cone-beam frames rebinned to slice-wise sinograms
#     (dbt_pipeline::rebin), per-slice DBToR reconstruction with the shipped model
#     (the repository's copy of the model and precision that the shipped
#     firmware/config/dbtor.toml names, trained for that geometry; checksums
#     verified at load; DBTOR_PRECISION=fp32|int8 overrides the precision),
#     tissue classification, glandularity, Monte Carlo MGD (25
#     views, patient-specific and model breast, 1 % uncertainty), dose SR and
#     density SR to the output folder.
#  5. Validation: every report is read back (dbtor-diag report) and, where
#     installed, checked with dciodvfy and dsrdump (apt-get install dicom3tools
#     dcmtk; scripts/install-test-deps.sh installs them).
# Output: out/main-job/ (summary.json, reports/*.dcm). Options for step 3 can
# be given as arguments, e.g. --pacs ORTHANC@127.0.0.1:4242.
# PHYSICS=clinical (issue #27): the gantry's exposure is polychromatic (W/Rh),
# recorded by an energy-integrating detector (the system's converter: CsI, or
# a-Se for Hologic and Siemens) with scatter and no grid
# (host-sim acquire --physics clinical); dbtor-process then removes the
# scatter, linearises the beam hardening and matches the noise to the
# model's training level (--descatter --csi-um 200 --noise-match, or
# --a-se-um for a system with an a-Se detector: the daemon's [recon]
# scatter = "kernel", beam_hardening = "csi" or "a-se",
# noise_match = "training-level"). Default mono
# (the paper's simulated detector, the shipped model's training world).
# ANODE_FILTER=W/Al, W/Ag, Mo/Mo, Mo/Rh or Rh/Rh: the exposure's beam (default W/Rh, the paper's): the
# stream's header carries it, the corrections and the dose use its spectra.
# SYSTEM=<name> (issue #51): the gantry, a built-in cone-beam system
# (hologic-dimensions, ge-essential, siemens-inspiration, siemens-victre,
# paper-cone): acquired on it, received and processed on its rebinning fan of
# frames.geometry. No DBToR model is trained for any but the configured
# system, so another is reported by the physics-based density and the model
# breast's MGD on that gantry's geometry (dbtor-process --physics-only, the
# daemon's reconstructor = "physics"), each report naming the method.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=out/main-job
cargo build --release --locked -q -p dbtor-firmware -p host-sim
rm -rf "$OUT"
mkdir -p "$OUT"
# The shipped configuration is the one place that names the model and the
# gantry geometry it is paired with.
WANT_SYSTEM=${SYSTEM:-}
read -r MODEL PRECISION DIGEST GEOMETRY BINNING SYSTEM < <(python3 -c '
import pathlib, sys, tomllib
c = tomllib.load(open(sys.argv[1], "rb"))
r, f = c["recon"], c["frames"]
print("models/" + pathlib.PurePosixPath(r["model"]).name, r["precision"], r["model_digest"],
      f["geometry"], f.get("binning", 1), f.get("system", "-"))' firmware/config/dbtor.toml)
./target/release/dbtor-diag selftest --binning 1 --model "$MODEL" --precision "${DBTOR_PRECISION:-$PRECISION}"
METHOD_ARGS=(--model "$MODEL" --model-digest "$DIGEST" --precision "${DBTOR_PRECISION:-$PRECISION}")
if [ -n "$WANT_SYSTEM" ] && [ "$WANT_SYSTEM" != "$SYSTEM" ]; then
    echo "SYSTEM=$WANT_SYSTEM: no DBToR model is trained for it (the shipped one is for ${SYSTEM}): physics-only report"
    SYSTEM=$WANT_SYSTEM
    METHOD_ARGS=(--physics-only)
fi
SYSTEM_ARGS=()
[ "$SYSTEM" = "-" ] || SYSTEM_ARGS=(--system "$SYSTEM")
PHYSICS=${PHYSICS:-mono}
case "$PHYSICS" in
    mono|clinical) ;;
    *) echo "PHYSICS=$PHYSICS: expected mono or clinical" >&2; exit 2 ;;
esac
./target/release/host-sim acquire --out "$OUT/gantry-acquisition" --index 0 --geometry "$GEOMETRY" --binning "$BINNING" "${SYSTEM_ARGS[@]}" --noise N8 --physics "$PHYSICS" --anode-filter "${ANODE_FILTER:-W/Rh}" 2>/dev/null
CORRECTIONS=()
if [ "$PHYSICS" = clinical ]; then
    # The linearisation is for the gantry's detector: the converter its
    # system states (a-Se for Hologic and Siemens), else 200 um of CsI.
    CONVERTER=$(python3 -c '
import json, sys
s = json.load(open(sys.argv[1])).get("system") or {}
c = s.get("detector", {}).get("converter") or {"material": "CsI", "thickness_um": 200.0}
print("--a-se-um" if c["material"] == "a-Se" else "--csi-um", c["thickness_um"])' "$OUT/gantry-acquisition/acquisition.json")
    read -r CONVERTER_FLAG CONVERTER_UM <<< "$CONVERTER"
    CORRECTIONS=(--descatter "$CONVERTER_FLAG" "$CONVERTER_UM")
    # The noise is matched to a model's training level: none without one.
    [ "${METHOD_ARGS[0]}" = "--physics-only" ] || CORRECTIONS+=(--noise-match)
fi
PORT=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
./target/release/host-sim stream --acq "$OUT/gantry-acquisition" --listen "127.0.0.1:$PORT" 2>/dev/null &
SIM=$!
./target/release/dbtor-receive --connect "127.0.0.1:$PORT" --geometry "$GEOMETRY" --binning "$BINNING" "${SYSTEM_ARGS[@]}" --out "$OUT/spool/acquisition-1"
wait "$SIM"
./target/release/dbtor-process "$OUT/spool/acquisition-1" --out "$OUT/reports" \
    "${METHOD_ARGS[@]}" "${CORRECTIONS[@]}" "$@" > "$OUT/summary.json"
python3 - "$OUT/summary.json" "$OUT/gantry-acquisition/acquisition.json" <<'PY' || cat "$OUT/summary.json"
import json, sys
d = json.load(open(sys.argv[1]))
# The truth stays with the simulator: the gantry never sends it.
h = json.load(open(sys.argv[2]))
r, t = d["result"], h.get("truth") or {}
rss = d.get("peak_rss_mib")
print(f"processed {d['acquisition']} in {d['seconds']:.1f} s ({r['reconstructor']}; {t.get('physics', 'mono')} physics, {h.get('anode_filter', 'W/Rh')}); "
      f"peak resident memory {'%.0f MiB' % rss if rss else 'not reported'}")
print(f"glandularity: reported {r['glandularity']:.3f} ({'calibrated ' if r['calibrated'] else ''}partial volume), "
      f"labels {r['density']['glandularity_labels']:.3f}, partial volume "
      f"{r['density']['glandularity_partial_volume']:.3f}; phantom truth {t.get('glandularity', float('nan')):.3f}")
c = r["density_check"]
pct = lambda g: "none" if g is None else f"{g:.3f}"
if r.get("method") == "physics-only":
    print(f"method: physics-based density alone (no DBToR model trained and calibrated for {r['dose_geometry']['name']} and this beam); its own checks "
          + ("passed" if c["confirmed"] else "NOT PASSED, no composition category reported: " + "; ".join(c["reasons"])))
else:
    print(f"physics density (no learning, same projections): {pct(c['physics'])}; contact region: network "
          f"{pct(c['contact_network'])}, physics {pct(c['contact_physics'])}; "
          + ("density CONFIRMED" if c["confirmed"]
             else "density NOT CONFIRMED, no composition category reported: " + "; ".join(c["reasons"])))
f = c.get("data_fit")
if f:
    print(f"data fit: the reconstruction against its projections, residual {f['residual']:.4f}, "
          f"{f['excess']:.4f} beyond the noise (limit {c['limits']['data_fit_max']:.3f})")
st = r.get("stage_seconds") or {}
if st and r.get("method") == "physics-only":
    print(f"stages: corrections {st['corrections']:.1f} s, physics density and model breast "
          f"{st['classification']:.1f} s, dose {st['dose_model']:.1f} s (model breast); nothing reconstructed")
elif st:
    n = st["slices"]
    print(f"stages: corrections {st['corrections']:.1f} s, reconstruction {st['reconstruction']:.1f} s "
          f"({n} slices, {1e3 * st['reconstruction'] / max(n, 1):.0f} ms each), classification "
          f"{st['classification']:.1f} s, dose {st['dose_patient']:.1f} s (patient) + {st['dose_model']:.1f} s (model breast)")
gantry = r["dose_geometry"]
print(f"dose on the {gantry['name']} gantry ({len(gantry['views'])} views, "
      f"{gantry['views'][0][0]:+.1f} to {gantry['views'][-1][0]:+.1f} deg, support {gantry['support_z_mm']:.0f} mm above the detector)")
print(f"MGD {r['mgd_mgy']:.3f} mGy (+- {100 * r['dose_patient']['mgd_rel_uncertainty']:.2f} %"
      + (", the model breast's: outline and thickness from the projections, interior at the physics density" if r.get("method") == "physics-only" else "")
      + "), "
      f"model breast {r['model_mgd_mgy']:.3f} mGy"
      + (f" ({r['model_mgd_at_physics_mgy']:.3f} mGy at the physics density)" if r.get("model_mgd_at_physics_mgy") else "")
      + f", incident air kerma {r['kerma_mgy']:.2f} mGy")
def interval(name, iv, scale, unit, digits):
    lim = iv["limits"]
    return (f"{name} 95 % interval {scale * lim[0]:.{digits}f}-{scale * lim[1]:.{digits}f} {unit}" if lim
            else f"{name}: no 95 % interval ({iv['basis']})")
iv = r["intervals"]
print(interval("glandularity", iv["glandularity"], 100, "%", 1) + "; " + interval("MGD", iv["mgd"], 1, "mGy", 3))
PY
status=0
for f in "$OUT"/reports/*.dcm; do
    ./target/release/dbtor-diag report "$f" > /dev/null || status=1
    if command -v dciodvfy >/dev/null 2>&1 && command -v dsrdump >/dev/null 2>&1; then
        errors=$(dciodvfy "$f" 2>&1 | grep -c '^Error' || true)
        dsrdump "$f" > /dev/null 2>&1 || errors=$((errors + 1))
        echo "$f: dciodvfy/dsrdump errors: $errors"
        [ "$errors" = "0" ] || status=1
    else
        echo "$f: read back OK; dciodvfy/dsrdump not installed, external validation skipped"
    fi
done
exit $status
