#!/usr/bin/env python3
"""A simple vectorised numpy Monte Carlo of AAPM TG-195 case 3 (16.8 keV, 0 deg):
the speed peer of `mc-bench`. Same physics as dbt-dose (photoelectric absorbed
locally, Rayleigh with form factors, Compton Klein-Nishina x S), same tables
(crates/dbt-dose/data), analytic geometry, Woodcock tracking with one global
majorant over the dense region, a batch of photons advanced together.

Usage: mc_numpy.py PHOTONS [SEED]   -> prints JSON {photons, seconds, total_ev_per_photon}
"""
import json
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "..", "crates", "dbt-dose", "data")
HC = 12.39841984
MC2 = 510.99895


def load():
    def rows(name):
        out = []
        for line in open(os.path.join(DATA, name)):
            if line.startswith("#") or line.startswith("Z"):
                continue
            out.append([float(v) for v in line.strip().split(",") if v and not v.isalpha()] if name != "elements.csv" else line.strip().split(","))
        return out
    a = {int(r[0]): float(r[2]) for r in rows("elements.csv")}
    xs = np.array(rows("xs.csv"))
    ff = np.array(rows("ff.csv"))
    return a, xs, ff


A, XS, FF = load()
ADIPOSE = {1: .112, 6: .619, 7: .017, 8: .251, 15: .00025, 16: .00025, 19: .00025, 20: .00025}
GLAND = {1: .102, 6: .184, 7: .032, 8: .677, 15: .00125, 16: .00125, 19: .00125, 20: .00125}
SKIN = {1: .098, 6: .178, 7: .05, 8: .667, 15: .00175, 16: .00175, 19: .00175, 20: .00175}
MIX = {z: .2 * GLAND[z] + .8 * ADIPOSE[z] for z in GLAND}
PMMA = {1: .080541, 6: .599846, 8: .319613}
WATER = {1: .111894, 8: .888106}
AIR = {6: .000124, 7: .755268, 8: .231781, 18: .012827}
MATS = [(AIR, 0.001205), (MIX, 0.952), (SKIN, 1.09), (PMMA, 1.19), (WATER, 1.0)]


EGRID = np.round(1.0 + 0.1 * np.arange(591), 1)


def material_tables():
    out = []
    for comp, rho in MATS:
        s = sum(comp.values())
        mu = np.zeros((591, 3))
        x = FF[FF[:, 0] == 1, 1]
        f2 = np.zeros_like(x)
        sf = np.zeros_like(x)
        sinf = 0.0
        for z, w in comp.items():
            w /= s
            r = XS[XS[:, 0] == z]
            mu += w * r[:, 2:5] * rho / 10.0
            rz = FF[FF[:, 0] == z]
            f2 += w / A[z] * rz[:, 2] ** 2
            sf += w / A[z] * rz[:, 3]
            sinf += w / A[z] * z
        u = x * x
        cum = np.concatenate([[0], np.cumsum(0.5 * (f2[1:] + f2[:-1]) * np.diff(u))])
        out.append((mu, u, cum, x, sf / sinf))
    return out


def material_at(p):
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    m = np.zeros(len(p), dtype=np.int64)
    r = np.hypot(x, y)
    inb = (x >= 0) & (r < 100) & (z >= 15) & (z <= 65)
    m[inb] = 2
    m[inb & (r < 98) & (z >= 17) & (z <= 63)] = 1
    plate = (x >= 0) & (x <= 140) & (np.abs(y) <= 130) & (((z >= 13) & (z < 15)) | ((z > 65) & (z <= 67)))
    m[plate] = 3
    body = (x >= -170) & (x < 0) & (np.abs(y) <= 150) & (z >= -110) & (z <= 190)
    m[body] = 4
    return m


def rotate(d, c, phi):
    s = np.sqrt(np.maximum(0, 1 - c * c))
    u, v, w = d[:, 0], d[:, 1], d[:, 2]
    r = np.sqrt(np.maximum(1e-20, 1 - w * w))
    cp, sp = np.cos(phi), np.sin(phi)
    out = np.stack([u * c + s * (u * w * cp - v * sp) / r, v * c + s * (v * w * cp + u * sp) / r, w * c - r * s * cp], 1)
    return out / np.linalg.norm(out, axis=1)[:, None]


def main():
    n = int(sys.argv[1])
    rng = np.random.default_rng(int(sys.argv[2]) if len(sys.argv) > 2 else 1)
    e0 = 16.8
    tabs = material_tables()

    def mu_of(k, energies):
        m = tabs[k][0]
        return np.stack([np.interp(energies, EGRID, m[:, c]) for c in range(3)], 1)
    t0 = time.time()
    # Emit: isotropic into the field (rejection on h / r^3).
    src = np.array([0.0, 0.0, 660.0])
    pts = []
    while sum(len(q) for q in pts) < n:
        q = np.stack([rng.uniform(0, 140, n), rng.uniform(-130, 130, n), np.zeros(n)], 1)
        r = np.linalg.norm(q - src, axis=1)
        pts.append(q[rng.random(n) <= (660.0 / r) ** 3])
    q = np.concatenate(pts)[:n]
    d = (q - src) / np.linalg.norm(q - src, axis=1)[:, None]
    # Start at z = 190 (top of the dense region; air above it is neglected:
    # about 0.05 % attenuation over 470 mm at 16.8 keV is applied as weight).
    t = (190.0 - 660.0) / d[:, 2]
    p = src + t[:, None] * d
    e = np.full(n, e0)
    wgt = np.exp(-mu_of(0, e).sum(1) * t)
    dep = 0.0
    # Global majorant over the energies a photon can have (Compton lowers E).
    e_low = e0 / (1 + 2 * e0 / MC2)
    mu_max = max(mu_of(k, np.array([e_low - 0.2])).sum() for k in range(len(tabs)))
    lo, hi = np.array([-170.0, -150.0, -110.0]), np.array([140.0, 150.0, 190.0])
    alive = np.ones(n, bool)
    while alive.any():
        idx = np.nonzero(alive)[0]
        s = -np.log(1 - rng.random(len(idx))) / mu_max
        p[idx] += s[:, None] * d[idx]
        out = np.any((p[idx] < lo) | (p[idx] > hi), axis=1)
        alive[idx[out]] = False
        idx = idx[~out]
        m = material_at(p[idx])
        mus = np.empty((len(idx), 3))
        for k in range(len(tabs)):
            sel = m == k
            if sel.any():
                mus[sel] = mu_of(k, e[idx[sel]])
        real = rng.random(len(idx)) * mu_max < mus.sum(1)
        idx, m, mus = idx[real], m[real], mus[real]
        r = rng.random(len(idx)) * mus.sum(1)
        photo = r < mus[:, 0]
        ray = ~photo & (r < mus[:, 0] + mus[:, 1])
        comp = ~photo & ~ray
        dep += np.sum((e[idx] * wgt[idx])[photo & (m == 1)])
        alive[idx[photo]] = False
        for kind in (ray, comp):
            ii, mm = idx[kind], m[kind]
            cos = np.empty(len(ii))
            todo = np.ones(len(ii), bool)
            while todo.any():
                j = np.nonzero(todo)[0]
                if kind is ray:
                    xmax = e[ii[j]] / HC
                    umax = xmax ** 2
                    c = np.empty(len(j))
                    for k in range(len(tabs)):
                        sel = mm[j] == k
                        if sel.any():
                            _, u, cum, _, _ = tabs[k]
                            g = rng.random(sel.sum()) * np.interp(umax[sel], u, cum)
                            c[sel] = 1 - 2 * np.minimum(np.interp(g, cum, u), umax[sel]) / umax[sel]
                    ok = rng.random(len(j)) * 2 <= 1 + c * c
                else:
                    kk = e[ii[j]] / MC2
                    c = rng.uniform(-1, 1, len(j))
                    eps = 1 / (1 + kk * (1 - c))
                    kn = eps * eps * (eps + 1 / eps - (1 - c * c)) / 2
                    x = e[ii[j]] / HC * np.sqrt((1 - c) / 2)
                    sr = np.empty(len(j))
                    for k in range(len(tabs)):
                        sel = mm[j] == k
                        if sel.any():
                            sr[sel] = np.interp(x[sel], tabs[k][3], tabs[k][4])
                    ok = rng.random(len(j)) <= kn * sr
                cos[j[ok]] = c[ok]
                todo[j[ok]] = False
            if kind is comp:
                enew = e[ii] / (1 + e[ii] / MC2 * (1 - cos))
                dep += np.sum(((e[ii] - enew) * wgt[ii])[mm == 1])
                e[ii] = enew
            d[ii] = rotate(d[ii], cos, rng.uniform(0, 2 * np.pi, len(ii)))
    secs = time.time() - t0
    print(json.dumps({"photons": n, "seconds": secs, "total_ev_per_photon": dep * 1e3 / n}))


if __name__ == "__main__":
    main()
