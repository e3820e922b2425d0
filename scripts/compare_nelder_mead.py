#!/usr/bin/env python3
"""gonio's Nelder–Mead (`gonio fit --method nelder-mead`) against scipy's on the same
samples and the same start, with the robust fit as the reference minimum.

scipy runs `minimize(method="Nelder-Mead")` with its defaults (initial simplex 5 % of
each non-zero coordinate, 0.00025 for zeros; xatol = fatol = 1e-4; 200·n iterations and
evaluations) and the bounds Kd, Ks >= 0, 1e-6 <= m <= 1e6, which scipy keeps by clipping.
The start is gonio's: m = 0.3, Kd_c the lowest β_c/a, Ks_c matching the peak of channel c.

Usage:
  python3 scripts/compare_nelder_mead.py SAMPLES.csv [--model cook-torrance|ward]
  python3 scripts/compare_nelder_mead.py --synthetic 10000 [--model ...]
Needs numpy and scipy, and a built `gonio` (target/debug/gonio or --gonio PATH).
"""

import argparse
import csv
import json
import math
import os
import subprocess
import sys
import tempfile

import numpy as np
from scipy.optimize import minimize

M_MIN, M_MAX = 1e-6, 1e6
COS_GRAZING, COS_ALPHA_MIN = 1e-9, 1e-12


def read_samples(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    cols = lambda *names: np.array([[float(r[n]) for n in names] for r in rows])
    y = cols("r", "g", "b")
    if rows and "n_dot_l" in rows[0]:
        cosines = cols("n_dot_l", "n_dot_v", "n_dot_h", "v_dot_h")
    else:
        ti, tr = np.radians(cols("theta_i", "theta_r")).T
        cosines = np.stack(
            [np.cos(ti), np.cos(tr), np.cos((ti - tr) / 2), np.cos((ti + tr) / 2)], axis=1
        )
    return y, cosines


def basis(model, cosines):
    """Diffuse basis a, tan²α and the lobe gain g, as gonio's `Model::basis_at`."""
    cos_i, cos_r, n_h, v_h = cosines.T
    c = np.clip(n_h, COS_ALPHA_MIN, 1.0)
    tan2 = np.maximum((1 - c * c) / (c * c), 0.0)
    if model == "cook-torrance":
        v_h = np.maximum(v_h, COS_GRAZING)
        g = np.minimum(1.0, np.minimum(2 * c * cos_r / v_h, 2 * c * cos_i / v_h))
        return np.ones_like(c), tan2, g / (math.pi * c**4 * cos_i * cos_r)
    return np.full_like(c, 1 / math.pi), tan2, 1 / (4 * math.pi * np.sqrt(cos_i * cos_r))


def specular(tan2, gain, m):
    m = min(max(m, M_MIN), M_MAX)
    x = tan2 / (m * m)
    return np.where(x > 708.0, 0.0, gain * np.exp(-np.minimum(x, 708.0)) / (m * m))


def start(y, a, tan2, gain, m=0.3):
    kd = np.maximum((y / a[:, None]).min(axis=0), 0.0)
    peak = y.argmax(axis=0)
    s = specular(tan2, gain, m)
    ks = [
        max((y[p, c] - kd[c] * a[p]) / s[p], 0.0) if s[p] > 0 else 0.0
        for c, p in enumerate(peak)
    ]
    return np.concatenate([kd, ks, [m]])


def synthetic(n, path):
    """n points of a gold-like Cook–Torrance sample, 2 % multiplicative noise."""
    rng = np.random.default_rng(12)
    kd, ks, m = np.array([9.0, 6.5, 2.0]), np.array([25.0, 20.0, 7.0]), 0.07
    theta_l = rng.choice([-20.0, -25.0, -30.0, -35.0, -40.0, -45.0], 2 * n)
    phi = rng.uniform(-80.0, 80.0, 2 * n)
    ti, tr = theta_l - phi, phi
    keep = np.flatnonzero((np.abs(ti) < 85) & (np.abs(tr) < 85))[:n]
    theta_l, ti, tr = theta_l[keep], ti[keep], tr[keep]
    r_i, r_r = np.radians(ti), np.radians(tr)
    cos = np.stack([np.cos(r_i), np.cos(r_r), np.cos((r_i - r_r) / 2), np.cos((r_i + r_r) / 2)], 1)
    a, tan2, gain = basis("cook-torrance", cos)
    beta = kd * a[:, None] + ks * specular(tan2, gain, m)[:, None]
    beta *= 1 + 0.02 * rng.standard_normal(beta.shape)
    with open(path, "w") as f:
        f.write("theta_l,theta_i,theta_r,r,g,b\n")
        for row in zip(theta_l, ti, tr, *beta.T):
            f.write(",".join(f"{v:.9g}" for v in row) + "\n")


def gonio_fit(gonio, samples, model, method, out):
    subprocess.run(
        [gonio, "fit", samples, "--model", model, "--method", method, "--out", out],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    with open(out) as f:
        return json.load(f)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("samples", nargs="?")
    p.add_argument("--synthetic", type=int, metavar="N")
    p.add_argument("--model", default="cook-torrance", choices=["cook-torrance", "ward"])
    p.add_argument("--gonio", default=os.path.join(os.path.dirname(__file__), "../target/debug/gonio"))
    args = p.parse_args()
    tmp = tempfile.mkdtemp()
    samples = args.samples
    if args.synthetic:
        samples = os.path.join(tmp, "synthetic.csv")
        synthetic(args.synthetic, samples)
    if not samples:
        p.error("give SAMPLES.csv or --synthetic N")
    y, cosines = read_samples(samples)
    a, tan2, gain = basis(args.model, cosines)

    def loss(x):
        beta = x[:3] * a[:, None] + x[3:6] * specular(tan2, gain, x[6])[:, None]
        return float(np.sqrt(((y - beta) ** 2).sum(axis=1)).sum())

    x0 = start(y, a, tan2, gain)
    bounds = [(0, None)] * 6 + [(M_MIN, M_MAX)]
    sp = minimize(loss, x0, method="Nelder-Mead", bounds=bounds)
    robust = gonio_fit(args.gonio, samples, args.model, "robust", os.path.join(tmp, "r.json"))
    nm = gonio_fit(args.gonio, samples, args.model, "nelder-mead", os.path.join(tmp, "n.json"))
    best = robust["loss"]
    print(f"{len(y)} samples, {args.model}, start loss {loss(x0):.6g}")
    print(f"{'method':<22}{'loss':>14}{'/ robust':>12}{'evaluations':>13}  m")
    for name, value, evals, m in [
        ("gonio robust", best, robust["evaluations"], robust["m"][0]),
        ("gonio nelder-mead", nm["loss"], nm["evaluations"], nm["m"][0]),
        ("scipy Nelder-Mead", sp.fun, sp.nfev, sp.x[6]),
    ]:
        print(f"{name:<22}{value:>14.6f}{value / best:>12.6f}{evals:>13}  {m:.6g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
