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
import json
import os
import subprocess
import sys
import tempfile

import numpy as np
from scipy.optimize import minimize

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_peers import M_MAX, M_MIN, basis, read_samples, specular, start  # noqa: E402


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
    beta = kd * a[:, None] + ks * specular(tan2, gain, m)[0][:, None]
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
    y, mask, cosines = read_samples(samples)
    a, tan2, gain = basis(args.model, cosines)

    def loss(x):
        beta = x[:3] * a[:, None] + x[3:6] * specular(tan2, gain, x[6])[0][:, None]
        return float(np.sqrt(((y - beta * mask) ** 2).sum(axis=1)).sum())

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
