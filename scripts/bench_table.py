#!/usr/bin/env python3
"""Writes README.md's "What accuracy costs in time" table (the block between
`<!-- bench: costs -->` and `<!-- /bench: costs -->`) from what scripts/bench.sh has just
measured: criterion's medians under target/criterion and the JSON lines the other
benchmarks and the peers appended to the results file. Every row names the command that
measures it; a row whose measurement is missing says so instead of keeping an old number.
Each row stands against its floor, what this machine allows (`--bench floors`): a fit's
(or a budget's refits') passes over its points × the measured cost of one point of the
loss, over every core; a
merge's, decode's or render's bytes at the measured memory bandwidth; a scan's hardware
time. A peer's row names the row whose floor it shares.
It refuses to write the table (exit status 1, the README left as it was) when a
measurement it uses was too unsteady to stand for the code: a criterion median whose 95 %
confidence interval is wider than MAX_CI_WIDTH of it, or a whole-process benchmark whose
runs spread ((largest − smallest) / median) wider than MAX_RUN_SPREAD, or a run during
which a virtual machine's host took more than MAX_STEAL of its CPU time (steal): a busy
machine, whose numbers would read as slower code.

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


# The floor column of a peer's row: its work is its own.
PEER_FLOOR = "the row above's"
# Full-size frames: 3872×2592 RGB; a count is 2 bytes, a merged map 3 × 4 bytes and a mask byte.
FRAME_PIXELS = 3872 * 2592
COUNT_BYTES = 3 * 2
MAP_BYTES = 3 * 4 + 1

# Widest 95 % confidence interval of a criterion median, relative to the median.
MAX_CI_WIDTH = 0.10
# Widest spread of a whole-process benchmark's runs, (largest − smallest) / median.
MAX_RUN_SPREAD = 0.25
# Largest share of the CPU time a virtual machine's host may take over the run (steal).
MAX_STEAL = 0.05


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
        # A whole-process benchmark's spread, or those of its parts (`{"full": {...}}`).
        spreads = [
            (f"{name}/{part}" if part else name, value["spread"])
            for name, record in sorted(self.results.items())
            for part, value in [("", record)]
            + [(k, v) for k, v in sorted(record.items()) if isinstance(v, dict)]
            if "spread" in value
        ]
        lines += [
            f"`{name}`: runs spread {spread:.0%} of their median (limit {MAX_RUN_SPREAD:.0%})"
            for name, spread in spreads
            if spread > MAX_RUN_SPREAD
        ]
        steal = self.results.get("steal")
        if steal and steal["share"] > MAX_STEAL:
            lines.append(
                f"the host took {steal['share']:.0%} of the CPU time over the run (steal; "
                f"limit {MAX_STEAL:.0%})"
            )
        return lines

    def row(self, what, values, target, command, floors=None):
        """A row; `values` None or holding None means not measured in this run.
        `floors`: (measured seconds, floor seconds) per value, for the floor and ratio
        columns; a str says why the row has no floor."""
        if values is None or (isinstance(values, (list, tuple)) and None in values):
            values = "not measured in this run"
        elif isinstance(values, (list, tuple)):
            values = " / ".join(values)
        if isinstance(floors, str):
            floor, times = floors, "—"
        elif not floors or any(m is None or f is None for m, f in floors):
            floor, times = "not measured in this run", "—"
        else:
            floor = " / ".join(duration(f) for _, f in floors)
            times = " / ".join(f"{m / f:.3g}" for m, f in floors)
        self.rows.append([what, values, floor, times, target, command])

    def markdown(self):
        lines = [
            "| what | median | floor | ÷ floor | target | command |",
            "|---|---|---|---|---|---|",
        ]
        lines += ["| " + " | ".join(r) + " |" for r in self.rows]
        return "\n".join(lines)

    # What this machine allows (`cargo bench -p gonio-processing --bench floors`).

    def floors(self):
        return self.results.get("floors")

    def fit_floor(self, full_id):
        """A fit's floor: its loss evaluations × its points (a model choice's: and the
        evaluations × points of the fits that judged the candidates) × one point of its
        model's loss, shared over every core."""
        work = {
            **self.results.get("fit_1000_work", {}).get("fits", {}),
            **self.results.get("fit_samples", {}).get("fits", {}),
        }.get(full_id)
        if not work:
            return None
        point_evaluations = work["evaluations"] * work["points"] + work.get("point_evaluations", 0)
        return self.work_floor(point_evaluations, work["model"])

    def work_floor(self, point_evaluations, model=None):
        """`point_evaluations` points of `model`'s loss (None: at the mean cost of one
        point of the three models'), shared over every core."""
        f = self.floors()
        if not f or point_evaluations is None or (model is not None and model not in f["point_s"]):
            return None
        point = f["point_s"][model] if model else sum(f["point_s"].values()) / len(f["point_s"])
        return point_evaluations * point / f["cores"]

    def fit_floors(self, *full_ids):
        return [(self.median(i), self.fit_floor(i)) for i in full_ids]

    def bytes_floor(self, moved):
        """Moving `moved` bytes (read plus written) at the measured copy bandwidth."""
        f = self.floors()
        return moved / f["copy_bytes_per_s"] if f and moved is not None else None


def fit_rows(t):
    ct = t.median("fit_1000/cook-torrance/robust/shared")
    bare = t.median("fit_1000/cook-torrance/robust/shared/no-uncertainty")
    t.row(
        "robust Cook–Torrance fit, 1,000 points, shared m",
        [duration(ct)],
        "≤ 5 ms",
        FIT,
        t.fit_floors("fit_1000/cook-torrance/robust/shared"),
    )
    t.row(
        "same without its uncertainty; the fit with it / without it",
        [f"{duration(bare)}; {ratio(ct, bare, 3)}" if bare and ct else None],
        "≤ 1.1",
        "same",
        t.fit_floors("fit_1000/cook-torrance/robust/shared/no-uncertainty"),
    )
    t.row(
        "robust Ward fit, 1,000 points, shared m",
        [duration(t.median("fit_1000/ward/robust/shared"))],
        "",
        "same",
        t.fit_floors("fit_1000/ward/robust/shared"),
    )
    models = ("cook-torrance", "ward")
    t.row(
        "robust CT / Ward fit, per-channel m",
        [duration(t.median(f"fit_1000/{m}/robust/per-channel")) for m in models],
        "",
        "same",
        t.fit_floors(*(f"fit_1000/{m}/robust/per-channel" for m in models)),
    )
    t.row(
        "Nelder–Mead CT / Ward fit (the paper's method), with its check against the robust fit",
        [duration(t.median(f"fit_1000/{m}/nelder-mead/shared")) for m in models],
        "",
        "same",
        t.fit_floors(*(f"fit_1000/{m}/nelder-mead/shared" for m in models)),
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
        t.fit_floors("fit_samples/auto", "fit_1000/auto"),
    )
    p = t.results.get("fit_auto_command")
    t.row(
        "`gonio fit --model auto` / `--model cook-torrance` as whole processes (samples read, "
        "fit, uncertainty budget, JSON written): full-size `gold` scan; binned 4 × 4; floor: "
        "the auto process's",
        [
            f"{ratio(p[k]['auto_s'], p[k]['cook_torrance_s'])} "
            f"({duration(p[k]['auto_s'])} / {duration(p[k]['cook_torrance_s'])})"
            if p
            else None
            for k in ("full", "binning_4")
        ],
        "≤ 2",
        "`cargo bench -p gonio-daemon --bench fit_auto_command`",
        # The auto process's: its fit's, choice's and budget's passes over the points
        # (reading and writing uncounted), at one point of Cook–Torrance's loss.
        [
            (
                p[k]["auto_s"],
                t.work_floor(p[k]["auto_point_evaluations"], "cook-torrance"),
            )
            for k in ("full", "binning_4")
        ]
        if p and "auto_point_evaluations" in p["full"]
        else None,
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
        t.fit_floors(
            "fit_samples/cook-torrance/robust/shared", "fit_samples/cook-torrance/nelder-mead/shared"
        ),
    )
    peer = t.results.get("peers_fit")
    if peer is None:
        t.row("scipy on the same samples and model", None, "", PEERS_FIT + " (not run: `--no-peers`, or scipy not installable)", PEER_FLOOR)
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
        PEER_FLOOR,
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
        PEER_FLOOR,
    )


def study_rows(t):
    name = "3_samples_x_63_combinations_x_3_models_robust_stride_{}"
    for stride, what in ((1, "study: 3 samples × 63 θL combinations × 3 models, robust, every column (~1,370 per θL)"), (4, "same, every 4th column")):
        t.row(
            what,
            [duration(t.median("study/" + name.format(stride)))],
            "",
            STUDY if stride == 1 else "same",
            [
                (
                    t.median("study/" + name.format(stride)),
                    # Its fits' loss evaluations × points, of its three models.
                    t.work_floor(t.results.get("study_work", {}).get("studies", {}).get(name.format(stride))),
                )
            ],
        )
    s = t.results.get("study_command")
    t.row(
        "`gonio study` of the full-size `gold` scan (3 models, Nelder–Mead compared): "
        "wall / CPU time of the process",
        [f"{duration(s['wall_s'])} / {duration(s['cpu_s'])}" if s else None],
        "≤ 4 s wall",
        "`cargo bench -p gonio-daemon --bench study_command`",
        # Its fits' work, from its study.json (the Nelder–Mead comparison's included).
        [(s["wall_s"], t.work_floor(s.get("point_evaluations")))] if s else None,
    )


def hdr_rows(t):
    linear = t.median("hdr_merge_7x3872x2592/linear")
    # Reading 7 frames' counts and writing the map and its mask.
    merge_floor = t.bytes_floor(FRAME_PIXELS * (7 * COUNT_BYTES + MAP_BYTES))
    memory = t.results.get("hdr_memory")
    t.row(
        "HDR merge, 7 frames of 3872×2592, linear (noise-weighted): time, peak memory",
        [duration(linear) + (f", {megabytes(memory['peak_bytes'])}" if memory else "")]
        if linear
        else None,
        "≤ 0.5 s, ≤ 1.5 GB",
        HDR + "; memory: `/usr/bin/time -v` on its binary, `--bench linear`",
        [(linear, merge_floor)],
    )
    dm = t.median("hdr_merge_7x3872x2592/debevec_malik")
    t.row(
        "HDR merge, same frames, Debevec–Malik",
        [duration(dm)],
        "",
        "same",
        [(dm, merge_floor)],
    )
    peer = t.results.get("peers_hdr")
    if peer is None:
        t.row("OpenCV's Debevec merge on the same frames", None, "OpenCV ≥ 5×", PEERS_HDR + " (not run: `--no-peers`, or OpenCV not installable)", PEER_FLOOR)
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
            "OpenCV ≥ 5×",
            PEERS_HDR,
            # gonio's process: the files read, their counts decoded, the map written.
            [
                (
                    g["seconds"],
                    t.bytes_floor(
                        peer["file_bytes"] + peer["decoded_bytes"] + peer["map_pixels"] * MAP_BYTES
                    ),
                )
            ]
            if "file_bytes" in peer
            else None,
        )
    cmd = t.results.get("hdr_command")
    t.row(
        "`gonio hdr`, 4 Deflate TIFFs of 3872×2592: whole process / merge alone",
        [f"{ratio(cmd['whole_s'], cmd['merge_s'])} ({duration(cmd['whole_s'])} / {duration(cmd['merge_s'])})"]
        if cmd
        else None,
        "≤ 1.5",
        "`cargo bench -p gonio-daemon --bench hdr_command`",
        # The files read, the counts decoded, the map written.
        [
            (
                cmd["whole_s"],
                t.bytes_floor(cmd["file_bytes"] + cmd["decoded_bytes"] + cmd["map_pixels"] * MAP_BYTES),
            )
        ]
        if cmd and "file_bytes" in cmd
        else None,
    )


EXTRACT = (
    "`GONIO_BENCH_SCAN=DIR cargo bench -p gonio-processing --bench extract` (DIR from "
    "`gonio simulate --scene gold`)"
)


def extract_medians(t):
    """The full-size `gold` scan's extraction with and without the samples' uncertainty."""
    return (
        t.median("extract/six_theta_l_scan_to_csv"),
        t.median("extract/six_theta_l_scan_to_csv/no-uncertainty"),
    )


def budget_rows(t):
    """The uncertainty budget of a full-size scan: the samples' sensitivities (extraction
    with and without them) plus the propagation to a fit, and the Monte Carlo."""
    with_u, without = extract_medians(t)
    extra = with_u - without if with_u and without else None
    # The Cook–Torrance fit without its budget, which both models' propagation is set against.
    fit_alone = t.median("fit_samples/cook-torrance/robust/shared")
    for model, label in (("cook-torrance", "Cook–Torrance"), ("cook-torrance-fresnel", "Cook–Torrance–Fresnel")):
        propagation = t.median(f"fit_samples/{model}/robust/shared/budget")
        total = extra + propagation if extra is not None and propagation else None
        t.row(
            f"uncertainty budget of the full-size `gold` scan, {label}: samples' sensitivities "
            "(extraction with / without them) + propagation to the fit = total; the "
            "Cook–Torrance fit with its propagation ÷ without; floor: the propagation's",
            [
                f"{duration(extra)} ({duration(with_u)} / {duration(without)}) + "
                f"{duration(propagation)} = **{duration(total)}**; "
                f"{ratio(fit_alone + propagation, fit_alone)}"
                if total is not None and fit_alone
                else None
            ],
            "≤ 2 s; ≤ 2",
            EXTRACT + "; " + FIT_SAMPLES,
            [(propagation, t.fit_floor(f"fit_samples/{model}/robust/shared/budget"))],
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
        [
            (r["seconds"], t.work_floor(r["evaluations"] * r["points"] if "points" in r else None, "cook-torrance"))
            for r in mc["runs"]
        ]
        if mc
        else None,
    )


def scan_rows(t):
    f, files = t.floors(), t.results.get("extract_input")
    with_u, without = extract_medians(t)
    read_floor = files["file_bytes"] / f["read_bytes_per_s"] if f and files else None
    t.row(
        "6-θL full-size `gold` scan (24 TIFFs) → samples.csv, with / without the samples' "
        "uncertainty; their ratio",
        [
            duration(with_u),
            duration(without),
            ratio(with_u, without),
        ],
        "ratio ≤ 1.5",
        EXTRACT,
        # Reading the capture files at the read bandwidth.
        [(with_u, read_floor), (without, read_floor)],
    )
    labels = ["none", "default effects (noise, vignetting)", "spectral (thin film)", "all (thin film + every effect)"]
    t.row(
        "render 3872×2592: no effects / default (noise, vignetting) / thin film / everything",
        [duration(t.median(f"render 3872x2592/{label}")) for label in labels],
        "≤ 0.3 s",
        "`cargo bench -p gonio-mock-hw --bench render`",
        # Writing the frame's counts.
        [(t.median(f"render 3872x2592/{label}"), t.bytes_floor(FRAME_PIXELS * COUNT_BYTES)) for label in labels],
    )
    for key, what, command in (
        (
            "scan",
            "6-θL `gold` scan through `gonio serve` on the emulators, auto bracket",
            "`cargo bench -p gonio-daemon --bench scan -- --runs 5`",
        ),
        (
            "scan_time_scale_1",
            "same scan at the hardware's own speeds (the emulators' time scale 1, not 0.1), one run",
            "`cargo bench -p gonio-daemon --bench scan -- --runs 1 --time-scale 1`",
        ),
    ):
        scan = t.results.get(key)
        t.row(
            what + ": wall time / time in hardware steps",
            [f"{scan['ratio']:.3f} ({scan['wall_s']:.2f} s / {scan['hardware_s']:.2f} s)"] if scan else None,
            "≤ 1.02",
            command,
            # The hardware's own time.
            [(scan["wall_s"], scan["hardware_s"])] if scan else None,
        )

def conditions(results):
    c = results.get("conditions")
    if not c:
        return "Measured conditions unknown."
    took = results.get("duration")
    took = f"; the run took {took['seconds'] / 60:.0f} min" if took else ""
    steal = results.get("steal")
    steal = f", the host took {steal['share']:.1%} of the CPU time (steal)" if steal else ""
    return (
        f"Measured by `bash scripts/bench.sh` on {c['date']}: {c['cpu']}, {c['cores']} cores, "
        f"load average {c['load']} when it started{took}{steal}; criterion medians, and medians of "
        "the other benchmarks' own runs. "
        + floors_note(results)
    )


def floors_note(results):
    f = results.get("floors")
    if not f:
        return "Floors: not measured in this run."
    points = ", ".join(f"{m} {s * 1e9:.1f} ns" for m, s in f["point_s"].items())
    return (
        "Floor: what this machine allows (`cargo bench -p gonio-processing --bench floors`): "
        f"a fit's loss evaluations (a budget's: its refits' loss evaluations and "
        f"Gauss–Newton passes) × its points × one point of the loss ({points} on one "
        f"core) over {f['cores']} cores; a merge's, decode's or render's bytes at "
        f"{f['copy_bytes_per_s'] / 1e9:.1f} GB/s (copy: read plus written; reading alone "
        f"{f['read_bytes_per_s'] / 1e9:.1f} GB/s); a scan's hardware time. ÷ floor: the "
        "median over its floor."
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
