#!/usr/bin/env bash
# CI smoke test of the whole training path (its time: scripts/test-all.sh prints it):
# a small dataset (binned x4 geometry, N8) from host-sim, DBToR with 2+2 blocks
# trained for 4 iterations in two runs (the second resumes from the first's
# checkpoint), the same under torchrun with 2 processes resumed by one (the
# same weights), exported (fp32 + int8 QDQ with equalisation, only the
# convolutions' inputs quantised, fixtures, manifest), re-quantised from its
# folder with GPTQ-rounded weights, the int8 simulation checked against
# onnxruntime, a 2-iteration quantisation-aware fine-tuning exported as the
# int8 blocks, and both exports checked by the firmware's runtime
# (`dbtor-diag model --sign-off`: checksums, fp32 vs PyTorch, int8 vs onnxruntime, then the sign-off the firmware requires, written and verified); then
# the same for a 2-iteration LPD (no mask, trained with --precision bf16 so the
# autocast path is exported and checked too, int8 in onnxruntime's plain graph),
# a 2-iteration fine-tuning (--init) on the taller geometry (int8 with the
# float residual, the third graph form), and a 2-iteration
# U-Net on FBP run once by the evaluation; and a run kept in the repository
# continued by one command (continue_run.py: the datasets regenerated into a
# cache, the compact state saved, restored on "another machine", a segment
# stopped by SIGTERM, the ledger's lines, a changed dataset refused). After
# the first run's export the continued runs and the other models run side
# by side (two independent halves), the first's output printed at the end.
# Needs training/requirements.txt installed and
# the binaries host-sim, dbtor-diag and dbt-eval: from DBTOR_BIN_DIR where
# scripts/test-all.sh built every binary once, else their release build, made here.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
if [ -n "${DBTOR_BIN_DIR:-}" ]; then
    BIN=$(cd "$DBTOR_BIN_DIR" && pwd)
    for b in host-sim dbtor-diag dbt-eval; do
        [ -x "$BIN/$b" ] || { echo "smoke test: DBTOR_BIN_DIR=$DBTOR_BIN_DIR has no $b" >&2; exit 1; }
    done
else
    cargo build --release --locked -q -p host-sim -p dbtor-firmware -p dbt-eval
    BIN=$PWD/target/release
fi
"$BIN"/host-sim dataset --out "$tmp/ds" --slices 1500 --test-phantoms 0 --levels N8 --binning 4 2>/dev/null
cd training
common=(--data "$tmp/ds" --out "$tmp/run" --iters 4 --batch 2 --blocks 2 --val-every 2 --log-every 1)
$PY -m dbtor.train "${common[@]}" --stop-at 2
$PY -m dbtor.train "${common[@]}" | tee "$tmp/second.log"
grep -q "resumed at iteration 2" "$tmp/second.log" || { echo "smoke test: the second run did not resume"; exit 1; }
[ "$(tail -n +2 "$tmp/run/curve.csv" | wc -l)" -ge 4 ] || { echo "smoke test: curve.csv is short"; exit 1; }
# Under torchrun (DistributedDataParallel; gloo on the CPU): two processes to
# iteration 2, resumed by one process to 4, give the one-process run's weights
# (--batch is the global batch); --device cuda without a GPU is refused.
ddp=(--data "$tmp/ds" --out "$tmp/ddp-run" --iters 4 --batch 2 --blocks 2 --val-every 2 --log-every 1 --device cpu)
$PY -m torch.distributed.run --standalone --nproc_per_node 2 -m dbtor.train "${ddp[@]}" --stop-at 2 | tee "$tmp/ddp.log"
grep -q "(2 processes on cpu)" "$tmp/ddp.log" || { echo "smoke test: the torchrun training did not run 2 processes"; exit 1; }
$PY -m dbtor.train "${ddp[@]}" > "$tmp/ddp-resume.log"
grep -q "resumed at iteration 2" "$tmp/ddp-resume.log" || { echo "smoke test: one process did not resume the torchrun run"; exit 1; }
$PY - "$tmp/run/checkpoint.pt" "$tmp/ddp-run/checkpoint.pt" <<'PYEOF'
import sys, torch
a, b = (torch.load(p, weights_only=False)["model"] for p in sys.argv[1:])
d = max(float((a[k] - b[k]).abs().max()) for k in a)
assert d < 1e-5, f"2 processes then 1 moved the weights {d:.2e} from the one-process run's"
print(f"torchrun (2 processes) + resume: weights within {d:.1e} of the one-process run's")
PYEOF
if ! $PY -c "import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)"; then
    if $PY -m dbtor.train --data "$tmp/ds" --out "$tmp/cuda-run" --iters 1 --blocks 2 --device cuda 2> "$tmp/cuda.log"; then
        echo "smoke test: --device cuda ran without a GPU"; exit 1
    fi
    grep -q "sees no CUDA device" "$tmp/cuda.log" || { echo "smoke test: the --device cuda refusal does not say why"; cat "$tmp/cuda.log"; exit 1; }
fi
mkdir -p "$tmp/model"
$PY -m dbtor.plot --run "$tmp/run" --out "$tmp/model/training-curve.png"
$PY -m dbtor.export --run "$tmp/run" --data "$tmp/ds" --out "$tmp/model" --calibration 2 --fixtures 1 | tee "$tmp/export.log"
grep -q "equalised the hidden channels" "$tmp/export.log" || { echo "smoke test: the export did not equalise"; exit 1; }
grep -q '"form": "conv-inputs"' "$tmp/model/manifest.json" || { echo "smoke test: the int8 form is not conv-inputs"; exit 1; }
# The simulation of the int8 graph (qat.py) against onnxruntime, block by block;
# the check refuses a simulation that leaves out the concatenation's quantisation.
$PY -m dbtor.qat --model "$tmp/model" --run "$tmp/run" --data "$tmp/ds" --calibration 2 --slices 1
if $PY -m dbtor.qat --model "$tmp/model" --run "$tmp/run" --data "$tmp/ds" --calibration 2 --slices 1 \
    --omit cat 2> "$tmp/omit.log"; then
    echo "smoke test: the int8 simulation check passed a simulation without the concatenation's quantisation"; exit 1
fi
grep -q "does not reproduce the exported int8 graph" "$tmp/omit.log" || { echo "smoke test: the check failed for another reason"; cat "$tmp/omit.log"; exit 1; }
# GPTQ rounding of the int8 weights (gptq.py): its checks, then the folder
# re-quantised from itself (--from-model): the fp32 blocks byte for byte, the
# int8 ones checked by the firmware's runtime below.
$PY -m dbtor.gptq
$PY -m dbtor.export --from-model "$tmp/model" --data "$tmp/ds" --out "$tmp/gptq-model" --calibration 2 \
    --fixtures 1 --gptq 4 | tee "$tmp/gptq.log"
grep -q "GPTQ moved" "$tmp/gptq.log" || { echo "smoke test: --gptq did not round the weights"; exit 1; }
grep -q '"weight_rounding": "GPTQ on 4 training slices' "$tmp/gptq-model/manifest.json" \
    || { echo "smoke test: the manifest does not record the GPTQ rounding"; exit 1; }
grep -q '"requantised_from"' "$tmp/gptq-model/manifest.json" || { echo "smoke test: the manifest does not name its source folder"; exit 1; }
for f in "$tmp"/model/fp32/*.onnx; do
    cmp "$f" "$tmp/gptq-model/fp32/$(basename "$f")" || { echo "smoke test: --from-model changed $f"; exit 1; }
done
# the shipped form: the float network's outputs as targets, biases refitted
$PY -m dbtor.export --from-model "$tmp/model" --data "$tmp/ds" --out "$tmp/gptqa-model" --calibration 2 \
    --fixtures 1 --gptq 4 --gptq-asymmetric > "$tmp/gptqa.log"
grep -q "GPTQ moved" "$tmp/gptqa.log" || { echo "smoke test: --gptq-asymmetric did not round"; exit 1; }
grep -q 'asymmetric: the float network' "$tmp/gptqa-model/manifest.json" \
    || { echo "smoke test: the manifest does not record the asymmetric rounding"; exit 1; }
# A model folder read back into PyTorch (train.py --init MODEL, folder.py):
# its fp32 blocks give exactly the run's weights; a folder with a changed
# file is refused, naming the file.
$PY - "$tmp/model" "$tmp/run/checkpoint.pt" <<'PYEOF'
import sys, torch
from dbtor import folder
sd, _ = folder.load_state_dict(sys.argv[1], "dbtor", 2)
ck = torch.load(sys.argv[2], weights_only=False)["model"]
assert sd.keys() == ck.keys(), sorted(set(sd) ^ set(ck))
bad = [k for k in ck if not torch.equal(sd[k], ck[k].reshape(sd[k].shape))]
assert not bad, f"the model folder's weights differ from the run's: {bad}"
print(f"model folder read back: {len(sd)} tensors equal to the run's")
PYEOF
$PY -m dbtor.train --data "$tmp/ds" --out "$tmp/from-model" --init "$tmp/model" --iters 1 --batch 2 --blocks 2 \
    --val-every 1 --log-every 1 | tee "$tmp/from-model.log"
grep -q "initialised from model folder" "$tmp/from-model.log" || { echo "smoke test: --init MODEL did not load the folder"; exit 1; }
grep -q '"model_folder"' "$tmp/from-model/run.json" || { echo "smoke test: run.json does not record the model folder"; exit 1; }
cp -r "$tmp/model" "$tmp/tampered"
printf 'x' >> "$tmp/tampered/fp32/dual00.onnx"
if $PY -m dbtor.train --data "$tmp/ds" --out "$tmp/from-tampered" --init "$tmp/tampered" --iters 1 --batch 2 \
    --blocks 2 2> "$tmp/tampered.log"; then
    echo "smoke test: --init from a tampered model folder was accepted"; exit 1
fi
grep -q "fp32/dual00.onnx does not match its SHA-256" "$tmp/tampered.log" || { echo "smoke test: the tampered-folder refusal does not name the file"; cat "$tmp/tampered.log"; exit 1; }
# The rest is two independent halves, run side by side so that each fills
# the cores the other leaves idle (issue #52 point 7, CI's time): the runs
# continued by one command (their own runs folder, cache and ledger under
# $tmp) in the background, its output kept and printed at the end; the
# other models' trainings and exports (their own folders) in the
# foreground. Both read the first run and its export above and write
# nothing the other reads.
(
set -euo pipefail
# A run kept in the repository and continued by one command (issue #49,
# continue_run.py, state.py, ledger.py), rehearsed in a temporary runs folder,
# cache and ledger: the recipe (two datasets of one geometry sampled
# together; --init from the model folder above), a first
# segment of 2 iterations (datasets generated, compact state saved, ledger
# line), the local run folder deleted (another machine), a second segment
# restored from the compact state and stopped by SIGTERM, a third to the end;
# the state's round trip (weights exact); a changed dataset file refused by name.
cont=($PY -m dbtor.continue_run --runs "$tmp/runs" --cache "$tmp/cache" --ledger "$tmp/ledger.md" --threads 2
      --host-sim "$BIN/host-sim" --quiet)
$PY -m dbtor.continue_run new smoke --runs "$tmp/runs" --current --init "$tmp/model" \
    --dataset "--slices 1500 --test-phantoms 0 --levels N8 --binning 4" \
    --dataset "--slices 1500 --test-phantoms 0 --levels N8 --binning 4 --seed 7" \
    --train "--model dbtor --level N8 --iters 8 --batch 2 --blocks 2 --val-every 4 --log-every 1"
"${cont[@]}" --extra "--stop-at 2" 2>/dev/null | tee "$tmp/cont1.log"
grep -q "initialised from model folder" "$tmp/cont1.log" || { echo "smoke test: the first segment did not start from --init"; exit 1; }
grep -q "saved the state at iteration 2" "$tmp/cont1.log" || { echo "smoke test: no compact state saved"; exit 1; }
rm -rf "$tmp/cache/runs/smoke"
"${cont[@]}" 2>/dev/null > "$tmp/cont2.log" &
pid=$!
# (up to 10 minutes for its third iteration: scripts/test-all.sh runs this
# test beside the test binaries, sharing the cores with them)
for _ in $(seq 6000); do grep -q "^it 3 " "$tmp/cont2.log" && break; sleep 0.1; done
kill -TERM $pid
wait $pid || { echo "smoke test: the SIGTERM-stopped segment failed"; cat "$tmp/cont2.log"; exit 1; }
cat "$tmp/cont2.log"
grep -q "restored the compact state" "$tmp/cont2.log" || { echo "smoke test: the second segment did not restore the compact state"; exit 1; }
stopped=$(sed -n 's/^stopped at iteration \([0-9]*\) of 8.*/\1/p' "$tmp/cont2.log")
[ -n "$stopped" ] && [ "$stopped" -lt 8 ] || { echo "smoke test: SIGTERM did not stop the segment early"; exit 1; }
"${cont[@]}" 2>/dev/null | tee "$tmp/cont3.log"
grep -q "stopped at iteration 8 of 8" "$tmp/cont3.log" || { echo "smoke test: the third segment did not finish"; exit 1; }
[ "$(grep -c '^| smoke |' "$tmp/ledger.md")" = 3 ] || { echo "smoke test: the ledger does not have 3 lines"; cat "$tmp/ledger.md"; exit 1; }
tail -n 1 "$tmp/ledger.md" | grep -q "| $stopped -> 8 |" || { echo "smoke test: the ledger's last segment is wrong"; exit 1; }
$PY -m dbtor.state show "$tmp/runs/smoke/state.dbts" > "$tmp/state.json"
grep -q '"iteration": 8' "$tmp/state.json" || { echo "smoke test: the state is not at 8"; exit 1; }
$PY -m dbtor.state roundtrip "$tmp/cache/runs/smoke/checkpoint.pt"
ds=$(ls -d "$tmp"/cache/datasets/smoke-1-*)
printf 'x' | dd of="$ds/validation/masks.u8" bs=1 seek=0 conv=notrunc 2>/dev/null
if "${cont[@]}" 2> "$tmp/cont4.log" > /dev/null; then
    echo "smoke test: a changed dataset was accepted"; exit 1
fi
grep -q "differs: validation/masks.u8" "$tmp/cont4.log" || { echo "smoke test: the dataset refusal does not name the file"; cat "$tmp/cont4.log"; exit 1; }
# The run "smoke" is done: its datasets and local run folder (about 0.5 GB)
# are not kept while the next runs make theirs.
rm -rf "$tmp"/cache/datasets/smoke-[0-9]-* "$tmp/cache/runs/smoke"
# The GPU slot's script (scripts/gpu-slot.sh, issue #49 point 3) on the CPU
# path: everything but the GPU (its self-check's bf16 iteration, the state's
# round trip, the datasets regenerated, training to the budget, the files
# that come back), on a run of its own with a first segment's state.
$PY -m dbtor.continue_run new smoke-slot --runs "$tmp/runs" --init "$tmp/model" \
    --dataset "--slices 1500 --test-phantoms 0 --levels N8 --binning 4" \
    --train "--model dbtor --level N8 --iters 4 --batch 2 --blocks 2 --val-every 2 --log-every 1"
"${cont[@]}" --run smoke-slot --extra "--stop-at 2" > /dev/null 2>&1
# The budget bounds the slot, it does not pace it: the run stops at its 4
# iterations long before; a tight one made the check depend on the machine's
# load (a loaded 2-core machine stopped at 3 with 120 s; test-all runs this
# test beside the test binaries).
(cd .. && OUT="$tmp/slot" DEVICE=cpu BUDGET_S=3600 RUNS="$tmp/runs" RUN=smoke-slot CACHE="$tmp/cache" \
    HOST_SIM="$BIN/host-sim" LEDGER="$tmp/ledger.md" PYTHON="$PY" ./scripts/gpu-slot.sh)
for f in state.dbts curve.csv LEDGER.md slot.log; do
    [ -s "$tmp/slot/$f" ] || { echo "smoke test: the GPU slot did not bring back $f"; exit 1; }
done
grep -q "self-check passed" "$tmp/slot/slot.log" || { echo "smoke test: the GPU slot's self-check"; cat "$tmp/slot/slot.log"; exit 1; }
grep -q '^| smoke-slot |' "$tmp/slot/LEDGER.md" || { echo "smoke test: no ledger row from the GPU slot"; exit 1; }
# Into a file first: `grep -q` leaves at its first match, and the writer's
# broken pipe then failed the pipeline (pipefail) now and then.
$PY -m dbtor.state show "$tmp/slot/state.dbts" > "$tmp/slot-state.json"
grep -q '"iteration": 4' "$tmp/slot-state.json" \
    || { echo "smoke test: the GPU slot's state is not at iteration 4"; exit 1; }
# A U-Net run (issue #49 point 5) continued by the same command: the FBP of
# its level, its input, added to the regenerated dataset before the first
# segment hashes it.
$PY -m dbtor.continue_run new smoke-unet --runs "$tmp/runs" \
    --dataset "--slices 1500 --test-phantoms 0 --levels N8 --binning 4" \
    --train "--model unet --level N8 --iters 2 --batch 2 --val-every 2 --log-every 1"
"${cont[@]}" --run smoke-unet --no-compile > "$tmp/unet.log" 2>&1 \
    || { echo "smoke test: the U-Net run"; cat "$tmp/unet.log"; exit 1; }
grep -q "^adding the FBP" "$tmp/unet.log" && grep -q "stopped at iteration 2 of 2" "$tmp/unet.log" \
    || { echo "smoke test: the U-Net run did not add its FBP or did not finish"; cat "$tmp/unet.log"; exit 1; }
ds=$(ls -d "$tmp"/cache/datasets/smoke-unet-0-*)
[ -s "$ds/train/fbp-N8.f32" ] && [ -s "$ds/validation/fbp-N8.f32" ] \
    || { echo "smoke test: the U-Net run's dataset has no FBP"; exit 1; }

) > "$tmp/continued.log" 2>&1 &
continued=$!
# A failure in the foreground half stops the background one before $tmp goes.
trap 'pkill -TERM -P "$continued" 2>/dev/null || true; kill "$continued" 2>/dev/null || true; rm -rf "$tmp"' EXIT
# Quantisation-aware fine-tuning (2 iterations) and an export of its int8
# blocks beside the first run's fp32 ones.
$PY -m dbtor.train --data "$tmp/ds" --out "$tmp/qat-run" --init "$tmp/run" --qat --qat-calibration 2 \
    --iters 2 --batch 2 --blocks 2 --val-every 2 --log-every 1
if $PY -m dbtor.export --run "$tmp/run" --int8-run "$tmp/qat-run" --data "$tmp/ds" --out "$tmp/bad-qat" \
    --calibration 2 --fixtures 1 2> "$tmp/bad-qat.log"; then
    echo "smoke test: a QAT run was exported equalised, unlike what it simulated"; exit 1
fi
grep -q "pass --equalise 0" "$tmp/bad-qat.log" || { echo "smoke test: the QAT export refusal does not say why"; cat "$tmp/bad-qat.log"; exit 1; }
$PY -m dbtor.export --run "$tmp/run" --int8-run "$tmp/qat-run" --data "$tmp/ds" --out "$tmp/qat-model" \
    --calibration 2 --fixtures 1 --equalise 0
grep -q '"int8_run"' "$tmp/qat-model/manifest.json" || { echo "smoke test: the manifest does not record --int8-run"; exit 1; }
cmp "$tmp/model/fp32/dual00.onnx" "$tmp/qat-model/fp32/dual00.onnx" || { echo "smoke test: --int8-run changed the fp32 blocks"; exit 1; }
$PY -m dbtor.qat --model "$tmp/qat-model" --run "$tmp/qat-run" --data "$tmp/ds" --calibration 2 --slices 1
cd ..
"$BIN"/dbtor-diag model "$tmp/model" --sign-off
"$BIN"/dbtor-diag model "$tmp/qat-model" --sign-off
"$BIN"/dbtor-diag model "$tmp/gptq-model" --sign-off
"$BIN"/dbtor-diag model "$tmp/gptqa-model" --sign-off
# The LPD baseline (no mask): trained, exported and checked the same way.
cd training
# (with the loss weighted near the breast's surface, recorded in the
# manifest's options; a resume that asks for another weight is refused)
$PY -m dbtor.train --data "$tmp/ds" --out "$tmp/lpd-run" --model lpd --iters 2 --batch 2 --blocks 2 \
    --val-every 2 --log-every 1 --precision bf16 --edge-weight 4 --edge-px 2
if $PY -m dbtor.train --data "$tmp/ds" --out "$tmp/lpd-run" --model lpd --iters 2 --batch 2 --blocks 2 \
    --precision bf16 --edge-weight 2 --edge-px 2 2> "$tmp/edge.log"; then
    echo "smoke test: a resume with another --edge-weight was accepted"; exit 1
fi
grep -q "edge_weight" "$tmp/edge.log" || { echo "smoke test: the refused resume does not name edge_weight"; cat "$tmp/edge.log"; exit 1; }
# (exported with onnxruntime's plain int8 graph, the other form the runtime reads)
$PY -m dbtor.export --run "$tmp/lpd-run" --data "$tmp/ds" --out "$tmp/lpd" --calibration 2 --fixtures 1 \
    --equalise 0 --int8-form plain
cd ..
grep -q '"kind": "lpd"' "$tmp/lpd/manifest.json" || { echo "smoke test: the LPD export is not kind lpd"; exit 1; }
grep -q '"precision": "bf16"' "$tmp/lpd/manifest.json" || { echo "smoke test: the LPD manifest does not record bf16 training"; exit 1; }
grep -q '"edge_weight": 4.0' "$tmp/lpd/manifest.json" || { echo "smoke test: the LPD manifest does not record the edge weight"; exit 1; }
grep -q '"form": "plain"' "$tmp/lpd/manifest.json" || { echo "smoke test: the LPD int8 form is not plain"; exit 1; }
"$BIN"/dbtor-diag model "$tmp/lpd" --sign-off
# Fine-tuning on the taller geometry (paper-tall.toml, 100 rows at x4): --init
# from the DBToR run, 2 iterations, exported with the tall geometry and checked;
# --init from a run of another kind is refused.
"$BIN"/host-sim dataset --out "$tmp/ds-tall" --slices 1500 --test-phantoms 0 --levels N8 \
    --binning 4 --geometry crates/dbt-geometry/geometry/paper-tall.toml 2>/dev/null
cd training
$PY -m dbtor.train --data "$tmp/ds-tall" --out "$tmp/tall-run" --init "$tmp/run" --iters 2 --batch 2 \
    --blocks 2 --val-every 2 --log-every 1 | tee "$tmp/tall.log"
grep -q "initialised from" "$tmp/tall.log" || { echo "smoke test: --init did not load the weights"; exit 1; }
if $PY -m dbtor.train --data "$tmp/ds-tall" --out "$tmp/bad-run" --init "$tmp/lpd-run" --iters 2 --batch 2 \
    --blocks 2 2> "$tmp/bad.log"; then
    echo "smoke test: --init from an LPD run into a DBToR run was accepted"; exit 1
fi
grep -q "not a dbtor" "$tmp/bad.log" || { echo "smoke test: the --init refusal does not say why"; cat "$tmp/bad.log"; exit 1; }
$PY -m dbtor.export --run "$tmp/tall-run" --data "$tmp/ds-tall" --out "$tmp/tall" --calibration 2 --fixtures 1 \
    --int8-form float-residual
$PY -m dbtor.qat --model "$tmp/tall" --run "$tmp/tall-run" --data "$tmp/ds-tall" --calibration 2 --slices 1
cd ..
grep -q '"form": "float-residual"' "$tmp/tall/manifest.json" || { echo "smoke test: the tall int8 form is not float-residual"; exit 1; }
grep -q '"rows": 100' "$tmp/tall/manifest.json" || { echo "smoke test: the tall export lost its geometry"; exit 1; }
grep -q '"init"' "$tmp/tall/manifest.json" || { echo "smoke test: the manifest does not record --init"; exit 1; }
"$BIN"/dbtor-diag model "$tmp/tall" --sign-off
# The U-Net baseline on FBP: the FBP array, 2 iterations, export (the exporter
# checks onnxruntime against PyTorch), and one evaluation slice through the
# Rust runtime (tract).
"$BIN"/host-sim fbp --data "$tmp/ds" --level N8
cd training
$PY -m dbtor.train --data "$tmp/ds" --out "$tmp/unet-run" --model unet --iters 2 --batch 2 --val-every 2 --log-every 1
$PY -m dbtor.export_unet --run "$tmp/unet-run" --data "$tmp/ds" --out "$tmp/unet" --fixtures 1
cd ..
"$BIN"/dbt-eval baselines --unet "$tmp/unet" --phantoms 1 --slices 1 --levels N8 --iterations 2 \
    --json "$tmp/unet-eval.json" > "$tmp/unet-eval.txt"
grep -q "| U-Net | N8 |" "$tmp/unet-eval.txt" || { echo "smoke test: no U-Net row"; exit 1; }
if ! wait "$continued"; then
    cat "$tmp/continued.log"
    echo "smoke test: the continued runs (above) failed"; exit 1
fi
cat "$tmp/continued.log"
echo "training smoke test passed"
