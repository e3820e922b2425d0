#!/usr/bin/env python3
"""Two `gonio` binaries side by side on the same samples: their fits' answers and their
whole-process times.

    scripts/fit_compare.py answers OLD_GONIO NEW_GONIO S.csv... [-- FIT ARGS]
    scripts/fit_compare.py times RUNS NAME=COMMAND...

`answers` runs `gonio fit S.csv FIT ARGS --out …` with each binary (default FIT ARGS:
`--model auto`) and prints, per samples file, the chosen model, whether the colour-shift
verdict is the same, and the largest difference of each group of numbers between the two
fit JSONs: the parameters, the held-out scores of every candidate, the budget's combined
uncertainties and interval ends, and the Monte Carlo's interval ends (relative to the
interval's width) — the differences a change of speed must keep within its tolerance.

`times` runs the named shell commands in turn, RUNS rounds (interleaved: one of each per
round), and prints each one's median wall and CPU (user + system) seconds with their
spread (max − min over median), the ratios of the medians to the first command's, and the
1-minute load average before and after.
"""

import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time


def fit(binary, samples, args, out):
    subprocess.run([binary, "fit", samples, *args, "--out", out], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    with open(out) as f:
        return json.load(f)


def relative(a, b):
    scale = max(abs(a), abs(b))
    return 0.0 if scale == 0 else abs(a - b) / scale


def parameters(result):
    out = {}
    for name in ("kd", "ks", "ks_90"):
        for c, v in enumerate(result.get(name) or []):
            out[f"{name}_{c}"] = v
    m = result["m"]
    for c, v in enumerate(m if isinstance(m, list) else [m]):
        out[f"m_{c}"] = v
    return out


def scores(result):
    selection = result.get("selection") or {}
    out = {}
    for k, cand in enumerate(selection.get("candidates", [])):
        for key in ("score", "held_out_delta_e_uv", "held_out_delta_e_uv_lobe"):
            if cand.get(key) is not None:
                out[f"{k}.{key}"] = cand[key]
    return out


def budget_numbers(result):
    """Combined uncertainties (relative) and interval ends (relative to the width)."""
    budget = result.get("budget") or {}
    params = budget.get("parameters") or {}
    combined, ends, mc = {}, {}, {}
    for name, values in params.items():
        for c, b in enumerate(values or []):
            combined[f"{name}_{c}"] = b["combined"]
            ends[f"{name}_{c}"] = b["interval"]
    carlo = (budget.get("monte_carlo") or {}).get("parameters") or {}
    for name, values in carlo.items():
        for c, d in enumerate(values or []):
            mc[f"{name}_{c}"] = d["interval"]
    return combined, ends, mc


def largest(a, b, measure):
    worst = (0.0, None)
    for key in a.keys() & b.keys():
        d = measure(a[key], b[key])
        if d > worst[0]:
            worst = (d, key)
    return worst


def width_relative(x, y):
    width = max(abs(x[1] - x[0]), abs(y[1] - y[0]), 1e-300)
    return max(abs(x[0] - y[0]), abs(x[1] - y[1])) / width


def answers(old, new, files, args):
    print("samples | chosen old→new | colour shift | params (rel) | held-out scores (rel) |"
          " budget u_c (rel) | budget ends (÷ width) | MC ends (÷ width)")
    with tempfile.TemporaryDirectory() as tmp:
        for samples in files:
            a = fit(old, samples, args, os.path.join(tmp, "old.json"))
            b = fit(new, samples, args, os.path.join(tmp, "new.json"))
            chosen = lambda r: (r.get("selection") or {}).get("chosen", "-")
            shift = lambda r: (r.get("selection") or {}).get("colour_shift", "-")
            ca, ea, ma = budget_numbers(a)
            cb, eb, mb = budget_numbers(b)
            cells = [
                largest(parameters(a), parameters(b), relative),
                largest(scores(a), scores(b), relative),
                largest(ca, cb, relative),
                largest(ea, eb, width_relative),
                largest(ma, mb, width_relative),
            ]
            text = " | ".join(f"{d:.2e} ({k})" if k else "0" for d, k in cells)
            print(f"{os.path.basename(samples)} | {chosen(a)}→{chosen(b)} | "
                  f"{'same' if shift(a) == shift(b) else 'DIFFERENT'} | {text}")


def times(runs, commands):
    named = [c.split("=", 1) for c in commands]
    wall = {n: [] for n, _ in named}
    cpu = {n: [] for n, _ in named}
    load_before = os.getloadavg()[0]
    for _ in range(runs):
        for name, command in named:
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            start = time.monotonic()
            subprocess.run(command, shell=True, check=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            wall[name].append(time.monotonic() - start)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu[name].append(after.ru_utime - before.ru_utime
                             + after.ru_stime - before.ru_stime)
    load_after = os.getloadavg()[0]
    first = named[0][0]
    base_wall = statistics.median(wall[first])
    base_cpu = statistics.median(cpu[first])
    print(f"{runs} interleaved rounds, load average {load_before:.2f} → {load_after:.2f}")
    for name, _ in named:
        w, c = statistics.median(wall[name]), statistics.median(cpu[name])
        spread = (max(wall[name]) - min(wall[name])) / w
        print(f"{name}: wall {w:.3f} s (spread {spread:.0%}), CPU {c:.3f} s;"
              f" ÷ {first}: wall {w / base_wall:.2f}, CPU {c / base_cpu:.2f}")


def main():
    if len(sys.argv) < 2 or sys.argv[1] not in ("answers", "times"):
        sys.exit(__doc__)
    if sys.argv[1] == "answers":
        rest = sys.argv[2:]
        args = ["--model", "auto"]
        if "--" in rest:
            k = rest.index("--")
            rest, args = rest[:k], rest[k + 1:]
        if len(rest) < 3:
            sys.exit(__doc__)
        answers(rest[0], rest[1], rest[2:], args)
    else:
        if len(sys.argv) < 4:
            sys.exit(__doc__)
        times(int(sys.argv[2]), sys.argv[3:])


if __name__ == "__main__":
    main()
