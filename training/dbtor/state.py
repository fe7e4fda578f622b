"""A run's whole state in one compact file (`dbtor-state/1`), kept in the
repository so that any machine can continue the run (issue #49 point 2).

    python -m dbtor.state show FILE                   # the header, readable
    python -m dbtor.state unpack FILE --out RUN       # RUN/checkpoint.pt + run.json + curve.csv (export.py reads them)
    python -m dbtor.state roundtrip RUN/checkpoint.pt  # sizes and the moments' quantisation error

The file: the magic line `DBTORSTATE1\\n`, the header's length (8 bytes, little
endian), the header (JSON) and one zlib stream, the payload. The header holds
everything small, readable: the options, iteration, elapsed time, samples seen,
the numpy generator's state (the data position: batches are drawn from it),
torch's CPU generator state (and CUDA's where there is one), the cosine
schedule, Adam's hyper-parameters and step counts, the normalisation, the
dataset recipes with each dataset file's SHA-256, run.json, and the index of
the payload's arrays with the payload's SHA-256. Every array is stored as
byte planes (the most significant byte of every value, then the next, ...:
zlib then finds the repeating sign and exponent bytes). The payload holds:

- the model's parameters and buffers as float32, exactly (the master weights:
  DBToR's 886,500 parameters are 3.5 MB; at that size exactness is kept
  rather than bf16, see training/README.md for the measured cost of bf16
  weights);
- Adam's two moments in bfloat16 (rounded to nearest even; relative error
  at most 2^-9).
- `pack(moments="log8")` (and `roundtrip --moments log8`) writes the
  alternative, which unpack also reads: blockwise (64 values) in the log
  domain, log2 of the block's smallest and largest magnitude as float32 and
  each value one byte (0 for zero, else its log2-magnitude rounded to one
  of 255 levels between the two, or a sign bit and 127 levels for the first
  moment; values too small to move Adam's step by 1e-3 of lr stored as 0;
  tensors of at most 4,096 values, whose few values span the widest
  ranges, in float32).
  Its codes hardly compress, while bfloat16's sign-and-exponent bytes do:
  for DBToR it is no smaller than bfloat16 and four times less precise
  (training/README.md). The first segment of dbtor-x4w wrote its states
  this way.

Written atomically (a temporary file in the same folder, fsync, os.replace):
a run killed while saving leaves the previous state whole.
"""
import argparse
import base64
import hashlib
import io
import json
import math
import os
import struct
import sys
import zlib

import numpy as np
import torch

MAGIC = b"DBTORSTATE1\n"
FORMAT = "dbtor-state/1"
BLOCK = 64
# With the log8 code, moments of tensors this small (biases, PReLU slopes, the
# 5-channel output convolutions) are kept exactly: their few values span the
# widest ranges.
EXACT_MOMENTS = 4096


class StateError(Exception):
    pass


# ---------------------------------------------------------------- the 8-bit log code

def encode_log8(x, signed, floor=None):
    """(codes uint8 [n], lo float32 [blocks], hi float32 [blocks]) of a float
    array, blockwise (BLOCK values) in the log2 domain. Values whose magnitude
    is below `floor` (a scalar or an array like x) are stored as 0, so that
    values too small to matter do not widen their block's range."""
    flat = np.asarray(x, dtype=np.float32).ravel()
    if floor is not None:
        flat = np.where(np.abs(flat) < np.broadcast_to(np.asarray(floor, np.float32), x.shape).ravel(), 0, flat)
    n = flat.size
    nb = -(-n // BLOCK)
    pad = np.zeros(nb * BLOCK, np.float32)
    pad[:n] = flat
    a = np.abs(pad).reshape(nb, BLOCK).astype(np.float64)
    nz = a > 0
    la = np.log2(np.where(nz, a, 1.0))
    hi = np.where(nz, la, -np.inf).max(axis=1)
    lo = np.where(nz, la, np.inf).min(axis=1)
    empty = ~nz.any(axis=1)
    hi[empty] = 0.0
    lo[empty] = 0.0
    # the block's ends as stored (float32), so that decoding uses the same
    lo32, hi32 = lo.astype(np.float32), hi.astype(np.float32)
    levels = 127 if signed else 255
    step = (hi32.astype(np.float64) - lo32.astype(np.float64)) / (levels - 1)
    safe = np.where(step > 0, step, 1.0)
    code = np.rint((la - lo32.astype(np.float64)[:, None]) / safe[:, None]) + 1
    code = np.clip(code, 1, levels)
    code = np.where(nz, code, 0).astype(np.uint8)
    if signed:
        code |= np.where(pad.reshape(nb, BLOCK) < 0, 128, 0).astype(np.uint8)
    return code.ravel()[:n], lo32, hi32


def decode_log8(code, lo, hi, signed, shape):
    code = np.asarray(code, np.uint8)
    n = code.size
    nb = lo.size
    c = np.zeros(nb * BLOCK, np.uint8)
    c[:n] = code
    c = c.reshape(nb, BLOCK)
    levels = 127 if signed else 255
    mag_code = (c & 127) if signed else c
    step = (hi.astype(np.float64) - lo.astype(np.float64)) / (levels - 1)
    v = np.exp2(lo.astype(np.float64)[:, None] + (mag_code.astype(np.float64) - 1) * step[:, None])
    v = np.where(mag_code == 0, 0.0, v)
    if signed:
        v = np.where(c & 128, -v, v)
    return v.astype(np.float32).ravel()[:n].reshape(shape)


def moment_floor(mom, v, eps):
    """Below these magnitudes a moment is stored as 0: Adam's update
    m / (sqrt(v) + eps) then moves by under 1e-3 of a step of size lr.
    exp_avg_sq: sqrt(v) < 1e-3 eps; exp_avg: |m| < 1e-3 (sqrt(v) + eps)."""
    if mom == "exp_avg_sq":
        return (1e-3 * eps) ** 2
    return 1e-3 * (np.sqrt(v) + eps)


# ---------------------------------------------------------------- pack / unpack

def _b64(t):
    return base64.b64encode(t.cpu().numpy().tobytes()).decode()


def _unb64(s):
    return torch.from_numpy(np.frombuffer(base64.b64decode(s), dtype=np.uint8).copy())


def planes(a):
    """The bytes of an array, most significant byte of every value first,
    then the next, ... (sign and exponent bytes repeat; zlib finds them)."""
    b = np.ascontiguousarray(a).view(np.uint8).reshape(-1, a.dtype.itemsize)
    return np.ascontiguousarray(b[:, ::-1].T)


def unplanes(b, dtype, shape):
    size = np.dtype(dtype).itemsize
    x = np.frombuffer(b, np.uint8).reshape(size, -1)[::-1].T
    return np.ascontiguousarray(x).view(dtype).reshape(shape)


def to_bf16_bits(a):
    """float32 -> bfloat16 bits (uint16), rounded to nearest even (torch's)."""
    return torch.from_numpy(np.ascontiguousarray(a, np.float32)).to(torch.bfloat16).view(torch.int16).numpy().view(np.uint16)


def from_bf16_bits(u):
    return (u.astype(np.uint32) << 16).view(np.float32)


def pack(ck, header_extra, moments="bf16"):
    """The compact file's bytes from a trainer checkpoint dict (train.py's
    save()) and extra header fields (run name, recipes, run.json, ...).
    moments: "bf16" (the format's default) or "log8" (the 8-bit log code)."""
    arrays, index, off = [], [], 0

    def add(name, kind, data, **meta):
        nonlocal off
        b = data.tobytes()
        arrays.append(b)
        index.append({"name": name, "kind": kind, "offset": off, "bytes": len(b), **meta})
        off += len(b)

    for k, t in ck["model"].items():
        a = t.detach().cpu().float().numpy()
        if t.dtype != torch.float32:
            raise StateError(f"model tensor {k} is {t.dtype}, not float32")
        add(f"model/{k}", "f32p", planes(a), shape=list(a.shape))
    adam = ck["adam"]
    steps = {}
    eps = adam["param_groups"][0]["eps"]
    for pid, st in adam["state"].items():
        steps[str(pid)] = float(st["step"])
        v = st["exp_avg_sq"].detach().cpu().float().numpy()
        for mom, signed in (("exp_avg", True), ("exp_avg_sq", False)):
            a = st[mom].detach().cpu().float().numpy()
            if moments == "bf16":
                add(f"adam/{pid}/{mom}", "bf16p", planes(to_bf16_bits(a)), shape=list(a.shape))
                continue
            if a.size <= EXACT_MOMENTS:
                add(f"adam/{pid}/{mom}", "f32p", planes(a), shape=list(a.shape))
                continue
            code, lo, hi = encode_log8(a, signed, floor=moment_floor(mom, v, eps))
            add(f"adam/{pid}/{mom}", "log8s" if signed else "log8", code, shape=list(a.shape), blocks=int(lo.size))
            add(f"adam/{pid}/{mom}/lo", "f32", lo, shape=[int(lo.size)])
            add(f"adam/{pid}/{mom}/hi", "f32", hi, shape=[int(hi.size)])
    payload = zlib.compress(b"".join(arrays), 9)
    groups = [{k: (list(v) if isinstance(v, tuple) else v) for k, v in g.items()} for g in adam["param_groups"]]
    header = {
        "format": FORMAT,
        **header_extra,
        "options": ck["options"],
        "iteration": ck["iteration"],
        "elapsed_s": ck["elapsed_s"],
        "stats": ck["stats"],
        "blocks": ck["blocks"],
        "model_kind": ck["model_kind"],
        "numpy_rng": ck["numpy_rng"],
        "torch_rng": _b64(ck["torch_rng"]),
        "cuda_rng": [_b64(s) for s in ck.get("cuda_rng", [])],
        "schedule": ck["schedule"],
        "adam": {"param_groups": groups, "steps": steps},
        "moment_code": ("bfloat16 (round to nearest even; dbtor/state.py)" if moments == "bf16" else
                        f"log2 8-bit, blocks of {BLOCK}; float32 for tensors of at most {EXACT_MOMENTS} values "
                        "(dbtor/state.py)"),
        "arrays": index,
        "payload_bytes": len(payload),
        "payload_sha256": hashlib.sha256(payload).hexdigest(),
    }
    h = json.dumps(header, indent=1).encode()
    return MAGIC + struct.pack("<Q", len(h)) + h + payload


def read_header(path):
    with open(path, "rb") as f:
        if f.read(len(MAGIC)) != MAGIC:
            raise StateError(f"{path}: not a {FORMAT} file")
        (n,) = struct.unpack("<Q", f.read(8))
        return json.loads(f.read(n))


def unpack(path, device="cpu"):
    """(checkpoint dict as train.py's save() writes it, header)."""
    with open(path, "rb") as f:
        blob = f.read()
    if not blob.startswith(MAGIC):
        raise StateError(f"{path}: not a {FORMAT} file")
    (n,) = struct.unpack("<Q", blob[len(MAGIC):len(MAGIC) + 8])
    start = len(MAGIC) + 8
    header = json.loads(blob[start:start + n])
    if header.get("format") != FORMAT:
        raise StateError(f"{path}: format {header.get('format')!r}, not {FORMAT}")
    payload = blob[start + n:]
    if hashlib.sha256(payload).hexdigest() != header["payload_sha256"]:
        raise StateError(f"{path}: the payload does not match its SHA-256 (a truncated or damaged file)")
    raw = zlib.decompress(payload)
    arr = {}
    for e in header["arrays"]:
        b = raw[e["offset"]:e["offset"] + e["bytes"]]
        kind = e["kind"]
        if kind == "f32p":
            v = unplanes(b, np.float32, e["shape"])
        elif kind == "bf16p":
            v = from_bf16_bits(unplanes(b, np.uint16, e["shape"]))
        elif kind.startswith("log8"):
            v = np.frombuffer(b, dtype=np.uint8)
        elif kind == "f32":
            v = np.frombuffer(b, dtype=np.float32)
        else:
            raise StateError(f"{path}: array {e['name']} of unknown kind {kind!r}")
        arr[e["name"]] = (e, v)
    model = {}
    for name, (e, a) in arr.items():
        if name.startswith("model/"):
            model[name[len("model/"):]] = torch.from_numpy(a.reshape(e["shape"]).copy()).to(device)
    state = {}
    for pid, step in header["adam"]["steps"].items():
        st = {"step": torch.tensor(step)}
        for mom, signed in (("exp_avg", True), ("exp_avg_sq", False)):
            e, code = arr[f"adam/{pid}/{mom}"]
            if e["kind"] in ("f32", "f32p", "bf16p"):
                st[mom] = torch.from_numpy(code.reshape(e["shape"]).copy()).to(device)
                continue
            lo = arr[f"adam/{pid}/{mom}/lo"][1]
            hi = arr[f"adam/{pid}/{mom}/hi"][1]
            st[mom] = torch.from_numpy(decode_log8(code, lo, hi, signed, e["shape"])).to(device)
        state[int(pid)] = st
    groups = [{k: (tuple(v) if k == "betas" else v) for k, v in g.items()} for g in header["adam"]["param_groups"]]
    ck = {"options": header["options"], "model": model, "adam": {"state": state, "param_groups": groups},
          "schedule": header["schedule"], "numpy_rng": header["numpy_rng"],
          "torch_rng": _unb64(header["torch_rng"]), "cuda_rng": [_unb64(s) for s in header.get("cuda_rng", [])],
          "iteration": header["iteration"], "elapsed_s": header["elapsed_s"], "stats": header["stats"],
          "blocks": header["blocks"], "model_kind": header["model_kind"], "save_id": header.get("save_id")}
    return ck, header


def write_atomic(path, data):
    """Write bytes to `path` through a temporary file in its folder (fsync,
    os.replace): readers see the old file or the new one, never a part."""
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    tmp = os.path.join(d, f".{os.path.basename(path)}.tmp{os.getpid()}")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def save(path, ck, header_extra, moments="bf16"):
    data = pack(ck, header_extra, moments=moments)
    write_atomic(path, data)
    return len(data)


# ---------------------------------------------------------------- dataset fingerprints

def dataset_files(root):
    out = []
    for d, dirs, files in os.walk(root):
        dirs.sort()
        for f in sorted(files):
            p = os.path.join(d, f)
            out.append(os.path.relpath(p, root))
    return sorted(out)


def fingerprint(root, chunk=1 << 22):
    """{relative path: sha256} of every file of a dataset folder."""
    fp = {}
    for rel in dataset_files(root):
        h = hashlib.sha256()
        with open(os.path.join(root, rel), "rb") as f:
            while True:
                b = f.read(chunk)
                if not b:
                    break
                h.update(b)
        fp[rel] = h.hexdigest()
    return fp


def fingerprint_digest(fp):
    """One SHA-256 over a fingerprint (its sorted `sha256  path` lines)."""
    return hashlib.sha256("".join(f"{v}  {k}\n" for k, v in sorted(fp.items())).encode()).hexdigest()


def compare_fingerprints(want, have, where):
    """Refuse (StateError naming the files) a dataset that is not the one the
    state was trained on."""
    missing = sorted(set(want) - set(have))
    extra = sorted(set(have) - set(want))
    changed = sorted(k for k in set(want) & set(have) if want[k] != have[k])
    if missing or extra or changed:
        parts = []
        if changed:
            parts.append("differs: " + ", ".join(changed))
        if missing:
            parts.append("missing: " + ", ".join(missing))
        if extra:
            parts.append("not in the recipe: " + ", ".join(extra))
        raise StateError(f"{where}: not the dataset of the run's recipe ({'; '.join(parts)})")


# ---------------------------------------------------------------- command line

def _roundtrip(path, moments):
    ck = torch.load(path, weights_only=False, map_location="cpu")
    blob = pack(ck, {"run": "roundtrip"}, moments=moments)
    tmp = io.BytesIO(blob)
    tmp_path = path + ".roundtrip.tmp"
    write_atomic(tmp_path, tmp.getvalue())
    back, _ = unpack(tmp_path)
    os.remove(tmp_path)
    n_params = sum(t.numel() for t in ck["model"].values())
    print(f"{len(ck['model'])} model tensors, {n_params:,} values; moments {moments}: state file "
          f"{len(blob):,} bytes ({len(blob) / 2**20:.2f} MiB; the torch checkpoint {os.path.getsize(path):,})")
    for k in ck["model"]:
        assert torch.equal(back["model"][k], ck["model"][k].cpu()), k
    for mom in ("exp_avg", "exp_avg_sq"):
        worst, rel_sum, cnt, zeroed = 0.0, 0.0, 0, 0
        for pid, st in ck["adam"]["state"].items():
            a = st[mom].cpu().double()
            b = back["adam"]["state"][pid][mom].double()
            kept = b != 0
            zeroed += int(((a != 0) & ~kept).sum())
            r = ((b[kept] - a[kept]) / a[kept]).abs()
            if r.numel():
                worst = max(worst, float(r.max()))
                rel_sum += float(r.sum())
                cnt += r.numel()
        print(f"{mom}: relative error mean {rel_sum / max(cnt, 1):.2e}, max {worst:.2e} "
              f"({zeroed:,} values under the floor stored as 0)")
    # what matters: Adam's step direction m / (sqrt(v) + eps) (bias corrections alike on both sides)
    eps = ck["adam"]["param_groups"][0]["eps"]
    num = den = worst = 0.0
    for pid, st in ck["adam"]["state"].items():
        u = st["exp_avg"].cpu().double() / (st["exp_avg_sq"].cpu().double().sqrt() + eps)
        b = back["adam"]["state"][pid]
        ub = b["exp_avg"].double() / (b["exp_avg_sq"].double().sqrt() + eps)
        num += float(((ub - u) ** 2).sum())
        den += float((u ** 2).sum())
        worst = max(worst, float((ub - u).abs().max()))
    print(f"Adam's step m/(sqrt(v)+eps): relative RMS error {math.sqrt(num / max(den, 1e-300)):.2e}, "
          f"largest change {worst:.2e} (in units of lr)")
    print("weights, RNG states, schedule, step counts: exact")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("show")
    s.add_argument("file")
    s.add_argument("--arrays", action="store_true", help="also the payload's index")
    u = sub.add_parser("unpack")
    u.add_argument("file")
    u.add_argument("--out", required=True)
    r = sub.add_parser("roundtrip")
    r.add_argument("checkpoint")
    r.add_argument("--moments", choices=["bf16", "log8"], default="bf16")
    a = ap.parse_args(argv)
    try:
        if a.cmd == "show":
            h = read_header(a.file)
            if not a.arrays:
                h["arrays"] = f"{len(h['arrays'])} arrays (--arrays lists them)"
            for k in ("torch_rng", "cuda_rng"):
                if k in h:
                    h[k] = f"({len(h[k])} characters)"
            print(json.dumps(h, indent=1))
        elif a.cmd == "unpack":
            ck, h = unpack(a.file)
            os.makedirs(a.out, exist_ok=True)
            torch.save(ck, os.path.join(a.out, "checkpoint.pt"))
            with open(os.path.join(a.out, "run.json"), "w") as f:
                json.dump(h["run_json"], f, indent=2)
            curve = os.path.join(os.path.dirname(os.path.abspath(a.file)), "curve.csv")
            if os.path.exists(curve):
                with open(curve) as f, open(os.path.join(a.out, "curve.csv"), "w") as g:
                    g.write(f.read())
            print(f"{a.out}: checkpoint.pt (iteration {ck['iteration']}), run.json, curve.csv")
        else:
            _roundtrip(a.checkpoint, a.moments)
    except StateError as e:
        sys.exit(str(e))


if __name__ == "__main__":
    main()
