#!/usr/bin/env python3
"""Derive the Winograd F(3x3, 3x3) transforms of crates/dbt-conv/src/int8/winograd.rs.

Toom-Cook on the points 0, 1, -1, 2 and infinity (Lavin & Gray 2016,
arXiv:1509.09308, section 4): A^T is the Vandermonde matrix of the points
(infinity: the last row's 1), G the interpolation weights a^k / prod(a - b),
and B^T solves A^T[(G g) . (B^T d)] = correlation(d, g) for every d and g,
found here by exact linear algebra on fractions. Prints the matrices, the
scale that makes G integer (6), the largest absolute row sums behind the
kernel's i16 ranges, and checks the 2-D identity on random integers.

    python3 scripts/winograd-f33.py
"""
from fractions import Fraction as F
import random

M, R = 3, 3
N = M + R - 1
POINTS = [F(0), F(1), F(-1), F(2), None]  # None: infinity


def derive():
    fin = [a for a in POINTS if a is not None]
    at = [[(a ** i if a is not None else F(1 if i == M - 1 else 0)) for a in POINTS] for i in range(M)]
    g = []
    for a in POINTS:
        if a is None:
            g.append([F(0)] * (R - 1) + [F(1)])
            continue
        f = F(1)
        for b in fin:
            if b != a:
                f *= a - b
        g.append([a ** k / f for k in range(R)])
    # sum_j AT[i][j] G[j][k] BT[j][p] = [p == i + k]: linear in BT
    rows = []
    for i in range(M):
        for k in range(R):
            for p in range(N):
                row = [F(0)] * (N * N + 1)
                for j in range(N):
                    row[j * N + p] += at[i][j] * g[j][k]
                row[-1] = F(int(p == i + k))
                rows.append(row)
    piv, r = [], 0
    for c in range(N * N):
        pr = next((e for e in range(r, len(rows)) if rows[e][c] != 0), None)
        if pr is None:
            continue
        rows[r], rows[pr] = rows[pr], rows[r]
        pv = rows[r][c]
        rows[r] = [v / pv for v in rows[r]]
        for e in range(len(rows)):
            if e != r and rows[e][c] != 0:
                f = rows[e][c]
                rows[e] = [x - f * y for x, y in zip(rows[e], rows[r])]
        piv.append(c)
        r += 1
    assert all(v == 0 for e in range(r, len(rows)) for v in rows[e]), "no solution"
    x = [F(0)] * (N * N)
    for e, c in enumerate(piv):
        x[c] = rows[e][-1]
    bt = [[x[j * N + p] for p in range(N)] for j in range(N)]
    return at, g, bt


def main():
    at, g, bt = derive()
    scale = 6
    gp = [[v * scale for v in row] for row in g]
    assert all(v.denominator == 1 for row in gp + bt + at for v in row), "not integer"
    show = lambda name, m: print(name, [[int(v) for v in row] for row in m])
    show("BT =", bt)
    show("G' = 6 G =", gp)
    show("AT =", at)
    sb = max(sum(abs(v) for v in row) for row in bt)
    sg = max(sum(abs(v) for v in row) for row in gp)
    print(f"largest |row sum|: B^T {sb}, G' {sg}; |V| <= {sb * sb * 255}, |U| <= {sg * sg * 128} (i16: 32767)")
    mul = lambda a, b: [[sum(a[i][k] * b[k][j] for k in range(len(b))) for j in range(len(b[0]))] for i in range(len(a))]
    tr = lambda a: [list(r) for r in zip(*a)]
    rng = random.Random(1)
    for _ in range(100):
        d = [[F(rng.randint(0, 255)) for _ in range(N)] for _ in range(N)]
        k = [[F(rng.randint(-128, 127)) for _ in range(R)] for _ in range(R)]
        u, v = mul(mul(gp, k), tr(gp)), mul(mul(bt, d), tr(bt))
        y = mul(mul(at, [[u[i][j] * v[i][j] for j in range(N)] for i in range(N)]), tr(at))
        for a in range(M):
            for b in range(M):
                want = sum(d[a + i][b + j] * k[i][j] for i in range(R) for j in range(R))
                assert y[a][b] == scale * scale * want
    print(f"identity: A^T[(G' g G'^T) . (B^T d B)]A = {scale * scale} x correlation on 100 random cases")


if __name__ == "__main__":
    main()
