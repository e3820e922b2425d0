#!/usr/bin/env python3
"""The peers of gonio's benchmarks, measured on the same inputs (run by scripts/bench.sh,
which installs numpy, scipy and OpenCV into .venv-bench/). Prints one JSON object.

  bench_peers.py fit SAMPLES.csv [--model cook-torrance|ward] [--repeats N]
      scipy on the eq. 10 loss of the samples, in-process, median wall time of N runs:
      - minimize(method="Nelder-Mead") with gonio's Nelder–Mead settings (fminsearch's:
        xatol = fatol = 1e-4, at most 200·n iterations and evaluations, bounds Kd, Ks >= 0,
        1e-6 <= m <= 1e6 kept by clipping) from gonio's start (m = 0.3, Kd at the lowest
        β/a, Ks matching the peak);
      - least_squares(method="trf") on the residuals f_p = sqrt(‖y_p − ŷ_p‖), whose sum
        of squares is the eq. 10 loss, with the analytic Jacobian, the same bounds and
        start, ftol = xtol = gtol = 1e-15 (scipy's 1e-8 stops it early, far above the
        minimum, on these square-root residuals) and scipy's cap of 100·n evaluations.
      Each with the loss it reaches and its evaluations.
  bench_peers.py hdr --gonio PATH [--runs N] FRAME...
      `gonio hdr` against OpenCV's CalibrateDebevec + MergeDebevec (its documented
      defaults) on the same 8-bit frames, each as a whole process (read the frames, merge,
      write a floating-point map: gonio an OpenEXR file, OpenCV a Radiance .hdr file, as
      the OpenCV wheels on PyPI write no OpenEXR), interleaved; median wall time and peak
      memory of N runs.
  bench_peers.py opencv-merge OUT.hdr FRAME...
      The OpenCV process that `hdr` times.
"""

import argparse
import csv
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time

M_MIN, M_MAX = 1e-6, 1e6
COS_GRAZING, COS_ALPHA_MIN = 1e-9, 1e-12


def read_samples(path):
    """β (0 where a value was dropped), the mask of measured values, and the 3D cosines
    (or the in-plane ones)."""
    import numpy as np

    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))

    def cols(*names):
        return np.array([[float(r[n]) if r[n] else math.nan for n in names] for r in rows])

    y = cols("r", "g", "b")
    mask = np.isfinite(y)
    y[~mask] = 0.0
    if rows and "n_dot_l" in rows[0]:
        cosines = cols("n_dot_l", "n_dot_v", "n_dot_h", "v_dot_h")
    else:
        ti, tr = np.radians(cols("theta_i", "theta_r")).T
        cosines = np.stack(
            [np.cos(ti), np.cos(tr), np.cos((ti - tr) / 2), np.cos((ti + tr) / 2)], axis=1
        )
    return y, mask.astype(float), cosines


def basis(model, cosines):
    """Diffuse basis a, tan²α and the lobe gain g, as gonio's `Model::basis_at`."""
    import numpy as np

    cos_i, cos_r, n_h, v_h = cosines.T
    c = np.clip(n_h, COS_ALPHA_MIN, 1.0)
    tan2 = np.maximum((1 - c * c) / (c * c), 0.0)
    if model == "cook-torrance":
        v_h = np.maximum(v_h, COS_GRAZING)
        g = np.minimum(1.0, np.minimum(2 * c * cos_r / v_h, 2 * c * cos_i / v_h))
        return np.ones_like(c), tan2, g / (math.pi * c**4 * cos_i * cos_r)
    return np.full_like(c, 1 / math.pi), tan2, 1 / (4 * math.pi * np.sqrt(cos_i * cos_r))


def specular(tan2, gain, m):
    """s(m) and ∂s/∂m."""
    import numpy as np

    m = min(max(m, M_MIN), M_MAX)
    x = tan2 / (m * m)
    s = np.where(x > 708.0, 0.0, gain * np.exp(-np.minimum(x, 708.0)) / (m * m))
    return s, 2 * s * (x - 1) / m


def start(y, a, tan2, gain, m=0.3):
    import numpy as np

    kd = np.maximum((y / a[:, None]).min(axis=0), 0.0)
    peak = y.argmax(axis=0)
    s, _ = specular(tan2, gain, m)
    ks = [
        max((y[p, c] - kd[c] * a[p]) / s[p], 0.0) if s[p] > 0 else 0.0
        for c, p in enumerate(peak)
    ]
    return np.concatenate([kd, ks, [m]])


def median_time(run, repeats):
    times, result = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        result = run()
        times.append(time.perf_counter() - t)
    return statistics.median(times), result


def fit(args):
    import numpy as np
    import scipy
    from scipy.optimize import least_squares, minimize

    y, mask, cosines = read_samples(args.samples)
    a, tan2, gain = basis(args.model, cosines)
    n = 7

    def predict(x):
        s, ds = specular(tan2, gain, x[6])
        return (x[:3] * a[:, None] + x[3:6] * s[:, None]) * mask, s, ds

    def loss(x):
        return float(np.sqrt(((y - predict(x)[0]) ** 2).sum(axis=1)).sum())

    def residuals(x):
        return np.sqrt(np.sqrt(((y - predict(x)[0]) ** 2).sum(axis=1)))

    def jacobian(x):
        beta, s, ds = predict(x)
        r = y - beta
        norm = np.maximum(np.sqrt((r * r).sum(axis=1)), 1e-300)
        f = np.maximum(np.sqrt(norm), 1e-150)
        u = r / norm[:, None]
        # ∂f/∂θ = −u·∂ŷ/∂θ / (2f); ŷ_c = Kd_c·a + Ks_c·s(m) in the measured channels.
        scale = -1.0 / (2 * f)
        jac = np.empty((len(y), n))
        jac[:, :3] = (u * mask) * (a * scale)[:, None]
        jac[:, 3:6] = (u * mask) * (s * scale)[:, None]
        jac[:, 6] = ((u * mask) * x[3:6]).sum(axis=1) * ds * scale
        return jac

    x0 = start(y, a, tan2, gain)
    lower = [0.0] * 6 + [M_MIN]
    upper = [math.inf] * 6 + [M_MAX]
    nm_seconds, nm = median_time(
        lambda: minimize(
            loss,
            x0,
            method="Nelder-Mead",
            bounds=list(zip(lower, upper)),
            options={"xatol": 1e-4, "fatol": 1e-4, "maxiter": 200 * n, "maxfev": 200 * n},
        ),
        args.repeats,
    )
    ls_seconds, ls = median_time(
        lambda: least_squares(
            residuals,
            x0,
            jac=jacobian,
            bounds=(lower, upper),
            method="trf",
            ftol=1e-15,
            xtol=1e-15,
            gtol=1e-15,
        ),
        args.repeats,
    )
    print(
        json.dumps(
            {
                "samples": len(y),
                "model": args.model,
                "numpy": np.__version__,
                "scipy": scipy.__version__,
                "repeats": args.repeats,
                "nelder_mead": {
                    "seconds": nm_seconds,
                    "loss": float(nm.fun),
                    "evaluations": int(nm.nfev),
                    "cap": 200 * n,
                },
                "least_squares": {
                    "seconds": ls_seconds,
                    "loss": loss(ls.x),
                    "evaluations": int(ls.nfev),
                    "jacobians": int(ls.njev),
                },
            }
        )
    )


def run_process(command):
    """Wall time and peak resident memory (bytes) of one run of `command`."""
    t = time.perf_counter()
    p = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(p.pid, 0)
    seconds = time.perf_counter() - t
    p.returncode = os.waitstatus_to_exitcode(status)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed: {p.stderr.read().decode()}")
    return seconds, usage.ru_maxrss * 1024


def tiff_counts(path):
    """(pixels, bytes of its decoded counts) of a TIFF's first image, from its header:
    width × height, × samples per pixel × bytes per sample."""
    import struct

    with open(path, "rb") as f:
        head = f.read(8)
        order = {b"II": "<", b"MM": ">"}[head[:2]]
        f.seek(struct.unpack(order + "I", head[4:8])[0])
        (count,) = struct.unpack(order + "H", f.read(2))
        entries = [struct.unpack(order + "HHI4s", f.read(12)) for _ in range(count)]
        tags = {}
        for tag, kind, n, value in entries:
            code, size = ("H", 2) if kind == 3 else ("I", 4)
            if n * size > 4:
                # The values lie elsewhere; the first is enough (BitsPerSample per sample).
                f.seek(struct.unpack(order + "I", value)[0])
                value = f.read(size)
            tags[tag] = struct.unpack(order + code, value[:size])[0]
    pixels = tags[256] * tags[257]
    return pixels, pixels * tags.get(277, 1) * ((tags.get(258, 1) + 7) // 8)


def hdr(args):
    out = tempfile.mkdtemp()
    gonio = [args.gonio, "hdr", "--out", os.path.join(out, "gonio.exr"), *args.frames]
    opencv = [
        sys.executable,
        os.path.abspath(__file__),
        "opencv-merge",
        os.path.join(out, "opencv.hdr"),
        *args.frames,
    ]
    runs = {"gonio": [], "opencv": []}
    run_process(gonio)
    run_process(opencv)  # warm the page cache and the imports
    for _ in range(args.runs):
        runs["gonio"].append(run_process(gonio))
        runs["opencv"].append(run_process(opencv))
    version = subprocess.run(
        [sys.executable, "-c", "import cv2; print(cv2.__version__)"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    summary = {
        name: {
            "seconds": statistics.median(t for t, _ in r),
            "peak_bytes": statistics.median(m for _, m in r),
        }
        for name, r in runs.items()
    }
    # What gonio's process moves at least: the files read, their counts decoded, the map
    # (three f32 and a mask byte per pixel) written.
    counts = [tiff_counts(path) for path in args.frames]
    moved = {
        "file_bytes": sum(os.path.getsize(path) for path in args.frames),
        "decoded_bytes": sum(b for _, b in counts),
        "map_pixels": max(p for p, _ in counts),
    }
    print(
        json.dumps(
            {
                "frames": len(args.frames),
                "runs": args.runs,
                "opencv_version": version,
                **summary,
                **moved,
            }
        )
    )


def opencv_merge(args):
    import cv2
    import numpy as np

    images, times = [], []
    for path in args.frames:
        with open(os.path.splitext(path)[0] + ".json") as f:
            sidecar = json.load(f)
        raw = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        bits = sidecar.get("significant_bits", 16)
        images.append((raw >> (16 - bits)).astype(np.uint8) if raw.dtype == np.uint16 else raw)
        times.append(sidecar["shutter_s"])
    times = np.array(times, dtype=np.float32)
    response = cv2.createCalibrateDebevec().process(images, times)
    radiance = cv2.createMergeDebevec().process(images, times, response)
    if not cv2.imwrite(args.out, radiance):
        raise SystemExit(f"OpenCV could not write {args.out}")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)
    f = sub.add_parser("fit")
    f.add_argument("samples")
    f.add_argument("--model", default="cook-torrance", choices=["cook-torrance", "ward"])
    f.add_argument("--repeats", type=int, default=5)
    h = sub.add_parser("hdr")
    h.add_argument("--gonio", required=True)
    h.add_argument("--runs", type=int, default=5)
    h.add_argument("frames", nargs="+")
    o = sub.add_parser("opencv-merge")
    o.add_argument("out")
    o.add_argument("frames", nargs="+")
    args = p.parse_args()
    {"fit": fit, "hdr": hdr, "opencv-merge": opencv_merge}[args.command](args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
