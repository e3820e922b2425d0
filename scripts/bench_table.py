#!/usr/bin/env python3
"""Writes README.md's "What accuracy costs in time" table (the block between
`<!-- bench: costs -->` and `<!-- /bench: costs -->`) from what scripts/bench.sh has just
measured: criterion's medians under target/criterion and the JSON lines the other
benchmarks and the peers appended to the results file. Every row names the command that
measures it; a row whose measurement is missing says so instead of keeping an old number.
It refuses to write the table (exit status 1, the README left as it was) when a
measurement it uses was too unsteady to stand for the code: a criterion median whose 95 %
confidence interval is wider than MAX_CI_WIDTH of it, or a whole-process benchmark whose
runs spread ((largest − smallest) / median) wider than MAX_RUN_SPREAD: a busy machine,
whose numbers would read as slower code.

Usage: python3 scripts/bench_table.py RESULTS.jsonl [--criterion DIR] [--readme FILE]
Needs only the Python standard library.
"""

import argparse
import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FIT = "`cargo bench -p gonio-processing --bench fit`"
FIT_SAMPLES = "`GONIO_BENCH_SAMPLES=samples.csv cargo bench -p gonio-processing --bench fit`"
STUDY = "`cargo bench -p gonio-processing --bench study`"
HDR = "`cargo bench -p gonio-processing --bench hdr`"
PEERS_FIT = "`python3 scripts/bench_peers.py fit samples.csv`"
PEERS_HDR = "`python3 scripts/bench_peers.py hdr --gonio target/release/gonio FRAME...`"


# Widest 95 % confidence interval of a criterion median, relative to the median.
MAX_CI_WIDTH = 0.10
# Widest spread of a whole-process benchmark's runs, (largest − smallest) / median.
MAX_RUN_SPREAD = 0.25


def criterion_medians(root):
    """full id → (median seconds, relative width of its 95 % confidence interval), from
    each benchmark's latest run."""
    medians = {}
    for bench in Path(root).glob("**/new/benchmark.json"):
        with open(bench, encoding="utf-8") as f:
            full_id = json.load(f)["full_id"]
        with open(bench.parent / "estimates.json", encoding="utf-8") as f:
            median = json.load(f)["median"]
        point = median["point_estimate"]
        interval = median["confidence_interval"]
        width = (interval["upper_bound"] - interval["lower_bound"]) / point if point > 0 else 0.0
        medians[full_id] = (point * 1e-9, width)
    return medians


def read_results(path):
    """bench name → its last recorded JSON object."""
    results = {}
    if Path(path).is_file():
        for line in Path(path).read_text(encoding="utf-8").splitlines():
            if line.strip():
                record = json.loads(line)
                results[record["bench"]] = record
    return results


def duration(seconds):
    if seconds is None:
        return None
    if seconds < 1e-3:
        return f"{seconds * 1e6:.0f} µs"
    if seconds < 1.0:
        return f"{seconds * 1e3:.3g} ms"
    return f"{seconds:.2f} s"


def ratio(a, b, digits=2):
    return f"{a / b:.{digits}f}" if a is not None and b else None


def megabytes(size):
    return f"{size / 2**20:.0f} MiB"


class Table:
    def __init__(self, medians, results):
        self.medians, self.results, self.rows = medians, results, []
        self.used = set()

    def median(self, full_id):
        self.used.add(full_id)
        found = self.medians.get(full_id)
        return found[0] if found else None

    def unsteady(self):
        """What the table uses that was measured too unsteadily, one line each."""
        lines = [
            f"criterion `{full_id}`: 95 % interval {width:.0%} of its median (limit {MAX_CI_WIDTH:.0%})"
            for full_id, (_, width) in sorted(self.medians.items())
            if full_id in self.used and width > MAX_CI_WIDTH
        ]
        lines += [
            f"`{name}`: runs spread {record['spread']:.0%} of their median (limit {MAX_RUN_SPREAD:.0%})"
            for name, record in sorted(self.results.items())
            if record.get("spread", 0.0) > MAX_RUN_SPREAD
        ]
        return lines

    def row(self, what, values, target, command):
        """A row; `values` None or holding None means not measured in this run."""
        if values is None or (isinstance(values, (list, tuple)) and None in values):
            values = "not measured in this run"
        elif isinstance(values, (list, tuple)):
            values = " / ".join(values)
        self.rows.append([what, values, target, command])

    def markdown(self):
        lines = ["| what | median | target | command |", "|---|---|---|---|"]
        lines += ["| " + " | ".join(r) + " |" for r in self.rows]
        return "\n".join(lines)


def fit_rows(t):
    ct = t.median("fit_1000/cook-torrance/robust/shared")
    bare = t.median("fit_1000/cook-torrance/robust/shared/no-uncertainty")
    t.row("robust Cook–Torrance fit, 1,000 points, shared m", [duration(ct)], "≤ 5 ms", FIT)
    t.row(
        "same without its uncertainty; the fit with it / without it",
        [f"{duration(bare)}; {ratio(ct, bare, 3)}" if bare and ct else None],
        "≤ 1.1",
        "same",
    )
    t.row(
        "robust Ward fit, 1,000 points, shared m",
        [duration(t.median("fit_1000/ward/robust/shared"))],
        "",
        "same",
    )
    t.row(
        "robust CT / Ward fit, per-channel m",
        [duration(t.median(f"fit_1000/{m}/robust/per-channel")) for m in ("cook-torrance", "ward")],
        "",
        "same",
    )
    t.row(
        "Nelder–Mead CT / Ward fit (the paper's method), with its check against the robust fit",
        [duration(t.median(f"fit_1000/{m}/nelder-mead/shared")) for m in ("cook-torrance", "ward")],
        "",
        "same",
    )


def auto_rows(t):
    """`gonio fit --model auto`'s fit (the model choice, without the budget both share)
    against one robust Cook–Torrance fit with its uncertainty, on the full-size `gold`
    scan and on the 1,000 points of four θL (a binned scan's size)."""
    full = (t.median("fit_samples/auto"), t.median("fit_samples/cook-torrance/robust/shared"))
    small = (t.median("fit_1000/auto"), t.median("fit_1000/cook-torrance/robust/shared"))
    t.row(
        "fit --model auto / one Cook–Torrance fit: full-size `gold` scan; 1,000 points",
        [
            f"{ratio(a, ct)} ({duration(a)} / {duration(ct)})" if a and ct else None
            for a, ct in (full, small)
        ],
        "≤ 2",
        f"{FIT_SAMPLES}; {FIT}",
    )


def peer_fit_rows(t):
    robust = t.median("fit_samples/cook-torrance/robust/shared")
    nm = t.median("fit_samples/cook-torrance/nelder-mead/shared")
    samples = t.results.get("fit_samples")
    points = f"{samples['samples']:,} " if samples else ""
    global_loss = samples["robust_loss"] if samples else None
    t.row(
        f"robust / Nelder–Mead Cook–Torrance fit of the full-size `gold` scan's {points}samples",
        [duration(robust), duration(nm)],
        "",
        FIT_SAMPLES,
    )
    peer = t.results.get("peers_fit")
    if peer is None:
        t.row("scipy on the same samples and model", None, "", PEERS_FIT + " (not run: `--no-peers`, or scipy not installable)")
        return
    ls, sp = peer["least_squares"], peer["nelder_mead"]
    above = lambda loss: f"{100 * (loss / global_loss - 1):.1f} %" if global_loss else "?"
    t.row(
        f"scipy {peer['scipy']} `least_squares` (trf, analytic Jacobian) / gonio robust",
        [
            f"{duration(ls['seconds'])}: {ratio(ls['seconds'], robust, 1)}× the time, loss "
            f"{above(ls['loss'])} above gonio's ({ls['evaluations']} evaluations)"
        ],
        "",
        PEERS_FIT,
    )
    t.row(
        f"scipy {peer['scipy']} Nelder–Mead (gonio's settings and start) / gonio Nelder–Mead",
        [
            f"{duration(sp['seconds'])}: {ratio(sp['seconds'], nm, 1)}× the time, loss "
            f"{above(sp['loss'])} above the robust fit's ({sp['evaluations']} of "
            f"{sp['cap']} evaluations)"
        ],
        "",
        "same",
    )


def study_rows(t):
    name = "study/3_samples_x_63_combinations_x_3_models_robust_stride_{}"
    t.row(
        "study: 3 samples × 63 θL combinations × 3 models, robust, every column (~1,370 per θL)",
        [duration(t.median(name.format(1)))],
        "",
        STUDY,
    )
    t.row("same, every 4th column", [duration(t.median(name.format(4)))], "", "same")
    s = t.results.get("study_command")
    t.row(
        "`gonio study` of the full-size `gold` scan (3 models, Nelder–Mead compared): "
        "wall / CPU time of the process",
        [f"{duration(s['wall_s'])} / {duration(s['cpu_s'])}" if s else None],
        "≤ 4 s wall",
        "`cargo bench -p gonio-daemon --bench study_command`",
    )


def hdr_rows(t):
    linear = t.median("hdr_merge_7x3872x2592/linear")
    memory = t.results.get("hdr_memory")
    t.row(
        "HDR merge, 7 frames of 3872×2592, linear (noise-weighted): time, peak memory",
        [duration(linear) + (f", {megabytes(memory['peak_bytes'])}" if memory else "")]
        if linear
        else None,
        "≤ 0.5 s, ≤ 1.5 GB",
        HDR + "; memory: `/usr/bin/time -v` on its binary, `--bench linear`",
    )
    t.row(
        "HDR merge, same frames, Debevec–Malik",
        [duration(t.median("hdr_merge_7x3872x2592/debevec_malik"))],
        "",
        "same",
    )
    peer = t.results.get("peers_hdr")
    if peer is None:
        t.row("OpenCV's Debevec merge on the same frames", None, "", PEERS_HDR + " (not run: `--no-peers`, or OpenCV not installable)")
    else:
        g, o = peer["gonio"], peer["opencv"]
        t.row(
            f"`gonio hdr` / OpenCV {peer['opencv_version']} CalibrateDebevec + MergeDebevec, "
            f"{peer['frames']} 8-bit frames of the `gold` scene, whole process",
            [
                f"{duration(g['seconds'])}, {megabytes(g['peak_bytes'])} / "
                f"{duration(o['seconds'])}, {megabytes(o['peak_bytes'])}: OpenCV takes "
                f"{ratio(o['seconds'], g['seconds'], 1)}× the time"
            ],
            "",
            PEERS_HDR,
        )
    cmd = t.results.get("hdr_command")
    t.row(
        "`gonio hdr`, 4 Deflate TIFFs of 3872×2592: whole process / merge alone",
        [f"{ratio(cmd['whole_s'], cmd['merge_s'])} ({duration(cmd['whole_s'])} / {duration(cmd['merge_s'])})"]
        if cmd
        else None,
        "≤ 1.5",
        "`cargo bench -p gonio-daemon --bench hdr_command`",
    )


EXTRACT = (
    "`GONIO_BENCH_SCAN=DIR cargo bench -p gonio-processing --bench extract` (DIR from "
    "`gonio simulate --scene gold`)"
)


def budget_rows(t):
    """The uncertainty budget of a full-size scan: the samples' sensitivities (extraction
    with and without them) plus the propagation to a fit, and the Monte Carlo."""
    with_u = t.median("extract/six_theta_l_scan_to_csv")
    without = t.median("extract/six_theta_l_scan_to_csv/no-uncertainty")
    extra = with_u - without if with_u and without else None
    for model, label in (("cook-torrance", "Cook–Torrance"), ("cook-torrance-fresnel", "Cook–Torrance–Fresnel")):
        propagation = t.median(f"fit_samples/{model}/robust/shared/budget")
        total = extra + propagation if extra is not None and propagation else None
        t.row(
            f"uncertainty budget of the full-size `gold` scan, {label}: samples' sensitivities "
            "(extraction with / without them) + propagation to the fit = total",
            [
                f"{duration(extra)} ({duration(with_u)} / {duration(without)}) + "
                f"{duration(propagation)} = **{duration(total)}**"
                if total is not None
                else None
            ],
            "≤ 2 s",
            EXTRACT + "; " + FIT_SAMPLES,
        )
    mc = t.results.get("budget_monte_carlo")
    t.row(
        "Monte Carlo of the Cook–Torrance budget (JCGM 101), 250 / 500 / 1,000 draws: time; "
        "its standard deviation of Ks_G and m over the law of propagation's u_c; m's 95 % "
        "interval (its convergence with the draws)",
        [
            "; ".join(
                f"{r['draws']}: {duration(r['seconds'])}, "
                f"{r['ks_g_std'] / mc['ks_g_combined']:.3f} / {r['m_std'] / mc['m_combined']:.3f}"
                + (
                    f", m [{r['m_interval'][0]:.4g}, {r['m_interval'][1]:.4g}]"
                    if "m_interval" in r
                    else ""
                )
                for r in mc["runs"]
            )
        ]
        if mc
        else None,
        "1,000 draws ≤ 5 s",
        FIT_SAMPLES,
    )


def scan_rows(t):
    t.row(
        "6-θL full-size `gold` scan (24 TIFFs) → samples.csv, with / without the samples' "
        "uncertainty",
        [
            duration(t.median("extract/six_theta_l_scan_to_csv")),
            duration(t.median("extract/six_theta_l_scan_to_csv/no-uncertainty")),
        ],
        "",
        EXTRACT,
    )
    labels = ["none", "default effects (noise, vignetting)", "spectral (thin film)", "all (thin film + every effect)"]
    t.row(
        "render 3872×2592: no effects / default (noise, vignetting) / thin film / everything",
        [duration(t.median(f"render 3872x2592/{label}")) for label in labels],
        "≤ 0.3 s",
        "`cargo bench -p gonio-mock-hw --bench render`",
    )
    scan = t.results.get("scan")
    t.row(
        "6-θL `gold` scan through `gonio serve` on the emulators, auto bracket: wall time / "
        "time in hardware steps",
        [f"{scan['ratio']:.3f} ({scan['wall_s']:.2f} s / {scan['hardware_s']:.2f} s)"] if scan else None,
        "≤ 1.05",
        "`cargo bench -p gonio-daemon --bench scan -- --runs 5`",
    )


def conditions(results):
    c = results.get("conditions")
    if not c:
        return "Measured conditions unknown."
    took = results.get("duration")
    took = f"; the run took {took['seconds'] / 60:.0f} min" if took else ""
    return (
        f"Measured by `bash scripts/bench.sh` on {c['date']}: {c['cpu']}, {c['cores']} cores, "
        f"load average {c['load']} when it started{took}; criterion medians, and medians of "
        "the other benchmarks' own runs."
    )


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("results")
    p.add_argument("--criterion", default=str(ROOT / "target" / "criterion"))
    p.add_argument("--readme", default=str(ROOT / "README.md"))
    args = p.parse_args()
    results = read_results(args.results)
    t = Table(criterion_medians(args.criterion), results)
    for rows in (fit_rows, auto_rows, peer_fit_rows, budget_rows, study_rows, hdr_rows, scan_rows):
        rows(t)
    unsteady = t.unsteady()
    if unsteady:
        print(t.markdown())
        raise SystemExit(
            "the table is not written: measurements too unsteady to stand for the code "
            "(run again on an idle machine):\n  " + "\n  ".join(unsteady)
        )
    block = t.markdown() + "\n\n" + conditions(results) + "\n"
    readme = Path(args.readme)
    text = readme.read_text(encoding="utf-8")
    pattern = re.compile(r"(<!-- bench: costs -->\n)(.*?)(<!-- /bench: costs -->)", re.S)
    if not pattern.search(text):
        raise SystemExit(f"{readme}: no block `<!-- bench: costs -->`")
    readme.write_text(pattern.sub(lambda m: m.group(1) + block + m.group(3), text), encoding="utf-8")
    print(block)


if __name__ == "__main__":
    main()
