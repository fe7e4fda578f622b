"""Training curve PNG from RUN/curve.csv: training loss (running mean per log
step) and validation MSE (network image units) against iterations, with the
validation PSNR on a second axis.

    python -m dbtor.plot --run RUN --out models/NAME/training-curve.png
"""
import argparse
import csv

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--run", required=True)
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    rows = list(csv.DictReader(open(f"{a.run}/curve.csv")))
    if not rows:
        raise SystemExit(f"{a.run}/curve.csv has no rows")
    it = [int(r["iteration"]) for r in rows]
    loss = [float(r["train_loss"]) for r in rows]
    val = [(int(r["iteration"]), float(r["val_mse"]), float(r["val_psnr_db"])) for r in rows if r["val_mse"]]
    fig, ax = plt.subplots(figsize=(7, 4), dpi=120)
    ax.semilogy(it, loss, lw=0.8, label="training loss (MSE, batch mean)")
    if val:
        ax.semilogy([v[0] for v in val], [v[1] for v in val], "o-", ms=3, label="validation MSE")
        ax2 = ax.twinx()
        ax2.plot([v[0] for v in val], [v[2] for v in val], "s--", ms=3, color="tab:red", label="validation PSNR")
        ax2.set_ylabel("validation PSNR (dB)", color="tab:red")
    ax.set_xlabel("iteration")
    ax.set_ylabel("MSE (network image units)")
    ax.set_title(f"DBToR training: {a.run.rstrip('/').split('/')[-1]}")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(a.out)
    print(f"wrote {a.out} ({len(rows)} log rows, last iteration {it[-1]})")


if __name__ == "__main__":
    main()
