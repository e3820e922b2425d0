#!/usr/bin/env python3
"""Writes the tables of docs/results/README.md and the README's Results summary from the
outputs under docs/results/<scene>/ (what scripts/results.sh has just produced), so that
no number in them is written by hand.

Each generated block sits between `<!-- results: NAME -->` and `<!-- /results: NAME -->`;
the prose around the blocks is written by hand and holds no measured number. One function
per section builds its block from the outputs; SECTIONS maps each block to it.

Usage:
  python3 scripts/results_docs.py [--root DIR]          # rewrite the blocks in place
  python3 scripts/results_docs.py [--root DIR] --check  # exit 1, naming the blocks, when
                                                        # a block differs from what the
                                                        # outputs say
DIR is the repository (default: the one holding this script). Needs only the Python
standard library.
"""

import csv
import json
import re
import sys
from pathlib import Path

ROOT = RESULTS = DOCS = None


def set_root(root):
    """Reads the outputs and writes the documents of the repository at `root`."""
    global ROOT, RESULTS, DOCS
    ROOT = Path(root).resolve()
    RESULTS = ROOT / "docs" / "results"
    DOCS = {"results": RESULTS / "README.md", "readme": ROOT / "README.md"}
# Scenes in the order results.sh runs them; any other scene directory follows by name.
ORDER = ["gold", "red", "blue-green", "opal"]
MODEL_NAMES = {
    "cook-torrance": "Cook–Torrance",
    "ward": "Ward",
    "cook-torrance-fresnel": "Cook–Torrance–Fresnel",
}


def scenes():
    """Scene directories that hold a study and a tradeoff, in results.sh's order."""
    found = [
        d.name
        for d in RESULTS.iterdir()
        if (d / "study" / "study.json").is_file() and (d / "tradeoff" / "tradeoff.json").is_file()
    ]
    return sorted(found, key=lambda s: (ORDER.index(s) if s in ORDER else len(ORDER), s))


def read_json(path):
    with open(path, encoding="utf-8") as f:
        return json.load(f)


def read_csv(path):
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def variant_label(model, roughness):
    name = MODEL_NAMES.get(model, model)
    return name if roughness == "shared" else f"{name}, per-channel m"


def shutter(seconds):
    """A shutter time as photographers write it (as gonio's format_shutter)."""
    if seconds >= 0.5 or seconds <= 0:
        return f"{seconds:g} s"
    return f"1/{round(1 / seconds)} s"


def setting(row, roughness):
    """A tradeoff setting in words."""
    theta = ", ".join(f"{t:g}°".replace("-", "−") for t in row["theta_l"])
    shutters = ", ".join(shutter(s) for s in row["shutters_s"])
    n, k = len(row["theta_l"]), len(row["shutters_s"])
    words = (
        f"{n} θL ({theta}), {k} exposure{'s' if k > 1 else ''} ({shutters}), "
        f"stride {row['stride']}, {row['method']}"
    )
    return words + (", per-channel m" if roughness == "per-channel" else "")


def table(header, rows):
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def boxplot(scene):
    """(model, roughness, n_theta_l, metric) → the boxplots.csv row."""
    rows = read_csv(RESULTS / scene / "study" / "boxplots.csv")
    return {(r["model"], r["roughness"], int(r["n_theta_l"]), r["metric"]): r for r in rows}


def study_table():
    """Per scene and variant: ΔErr_p (G) against the reference fitting one θL (median and
    interquartile range) and all θL, the held-out errors, and Nelder–Mead's local minima."""
    rows = []
    for scene in scenes():
        study = read_json(RESULTS / scene / "study" / "study.json")
        boxes = boxplot(scene)
        n_all = len(study["theta_l"])
        held_out = {(h["model"], h["roughness"]): h for h in study["held_out"]}
        for v in study["variants"]:
            key = (v["model"], v["roughness"])
            one = boxes[key + (1, "err_p_g")]
            every = boxes[key + (n_all, "err_p_g")]
            iqr = float(one["q3"]) - float(one["q1"])
            h = held_out.get(key)
            held = (
                " / ".join(f"{e:.4f}" for e in h["median_err_p"]) if h else "–"
            )
            held_uv = f"{h['median_delta_e_uv']:.4f}" if h and h["median_delta_e_uv"] is not None else "–"
            compared = v["nelder_mead_compared"]
            above = f"{v['nelder_mead_above']}/{compared}" if compared else "not compared"
            rows.append(
                [
                    scene,
                    variant_label(*key),
                    f"{float(one['median']):.4f} ({iqr:.4f})",
                    f"{float(every['median']):.4f}",
                    held,
                    held_uv,
                    above,
                ]
            )
    return table(
        [
            "scene",
            "model",
            "ΔErr_p (G), 1 θL: median (IQR)",
            "all θL",
            "held out: median ΔErr_p (R / G / B)",
            "held out: ΔE_u′v′",
            "Nelder–Mead above robust",
        ],
        rows,
    )


def study_time_table():
    """Per scene: the study's size and its measured time."""
    rows = []
    for scene in scenes():
        study = read_json(RESULTS / scene / "study" / "study.json")
        compared = sum(v["nelder_mead_compared"] for v in study["variants"])
        rows.append(
            [
                scene,
                study["combinations"],
                len(study["variants"]),
                study["fits"],
                compared,
                study["evaluation_points"],
                f"{study['seconds']:.1f} s",
            ]
        )
    return table(
        [
            "scene",
            "θL combinations",
            "models",
            "robust fits",
            "Nelder–Mead fits compared",
            "samples",
            "time",
        ],
        rows,
    )


def full_scan(scene):
    """The tradeoff row of the full scan: every θL, the whole bracket, every column,
    robust."""
    rows = read_csv(RESULTS / scene / "tradeoff" / "tradeoff.csv")
    n = max(int(r["n_theta_l"]) for r in rows)
    b = max(int(r["bracket"]) for r in rows)
    for r in rows:
        if (int(r["n_theta_l"]), int(r["bracket"]), int(r["stride"]), r["method"]) == (
            n,
            b,
            1,
            "robust",
        ):
            return r
    raise SystemExit(f"{scene}: tradeoff.csv has no full-scan robust row")


def err3(values, digits=4):
    return ", ".join(f"{float(v):.{digits}f}" for v in values)


def tradeoff_table():
    """Per scene: the recommended setting, its time and accuracy, against the full scan."""
    rows = []
    for scene in scenes():
        t = read_json(RESULTS / scene / "tradeoff" / "tradeoff.json")
        r = t["recommended"]
        full = full_scan(scene)
        rows.append(
            [
                scene,
                MODEL_NAMES.get(t["model"], t["model"]),
                setting(r, t["roughness"]),
                f"{r['acquisition_s']:.1f} s + {r['processing_s']:.2f} s",
                err3(r["err_p"]),
                f"{float(full['acquisition_s']):.1f} s + {float(full['processing_s']):.2f} s",
                err3([full["err_p_r"], full["err_p_g"], full["err_p_b"]]),
            ]
        )
    return table(
        [
            "scene",
            "model",
            "recommended setting",
            "acquisition + processing",
            "ΔErr_p (R, G, B)",
            "full scan: acquisition + processing",
            "full scan: ΔErr_p (R, G, B)",
        ],
        rows,
    )


def nelder_mead_counts(study):
    """Nelder–Mead fits compared and ending above the robust loss, over every variant."""
    compared = sum(v["nelder_mead_compared"] for v in study["variants"])
    above = sum(v["nelder_mead_above"] for v in study["variants"])
    return above, compared


def summary_table():
    """The README's summary: per scene the setting to choose, what it costs against the
    full scan, and how often the paper's method ends in a local minimum."""
    rows = []
    for scene in scenes():
        t = read_json(RESULTS / scene / "tradeoff" / "tradeoff.json")
        study = read_json(RESULTS / scene / "study" / "study.json")
        r = t["recommended"]
        full = full_scan(scene)
        above, compared = nelder_mead_counts(study)
        rows.append(
            [
                f"`{scene}`",
                setting(r, t["roughness"]),
                f"{r['total_s']:.1f} s",
                f"{float(full['total_s']):.1f} s",
                f"{max(r['err_p']):.4f}",
                f"{max(float(full[k]) for k in ('err_p_r', 'err_p_g', 'err_p_b')):.4f}",
                f"{above}/{compared}",
            ]
        )
    return table(
        [
            "scene",
            "setting to choose",
            "time",
            "full scan",
            "worst ΔErr_p",
            "full scan",
            "Nelder–Mead fits above the robust loss",
        ],
        rows,
    )


REAL = "real-materials"


def form_label(entry):
    """A held-out entry's or candidate's label: the variant's, or `table`."""
    if entry["model"] == "table":
        return "table (θh, θd)"
    return variant_label(entry["model"], entry["roughness"])


def real_materials():
    """Material directories of the real-materials section, by name."""
    root = RESULTS / REAL
    if not root.is_dir():
        return []
    return sorted(d.name for d in root.iterdir() if (d / "held_out.json").is_file())


def real_judged(name):
    """(CT, best parametric, table, auto's choice) held-out entries of a material, and
    whether auto reported a colour shift."""
    held = read_json(RESULTS / REAL / name / "held_out.json")
    entries = held["variants"]
    parametric = [e for e in entries if e["model"] != "table" and e["relative_loss"] is not None]
    ct = next(e for e in entries if e["model"] == "cook-torrance" and e["roughness"] == "shared")
    best = min(parametric, key=lambda e: e["relative_loss"])
    table_entry = next((e for e in entries if e["model"] == "table"), None)
    selection = held["chosen"]["selection"]
    won = selection["candidates"][selection["chosen"]]
    auto = next(
        e
        for e in entries
        if e["model"] == won["model"] and e.get("roughness") == won.get("roughness")
    )
    return ct, best, table_entry, auto, selection["colour_shift"]


def uv(entry, key="median_delta_e_uv"):
    value = entry[key] if entry else None
    return "–" if value is None else f"{value:.4f}"


def real_materials_table():
    """Per real material: Cook–Torrance, the best parametric model, the table and auto's
    choice by median held-out ΔE_u′v′ (all points), and whether the target holds: ≥ 2×
    better than Cook–Torrance where a colour change is reported, never > 2 % worse
    elsewhere. Then per material and candidate the full held-out errors."""
    names = real_materials()
    if not names:
        return (
            "*Skipped*: `GONIO_RGL_DIR` was not set when `scripts/results.sh` last ran. To "
            "produce this section, point it at a directory of RGL-EPFL `*_rgb.bsdf` files: "
            "`GONIO_RGL_DIR=DIR bash scripts/results.sh --real-materials-only`."
        )
    summary, detail = [], []
    for name in names:
        ct, best, table_entry, auto, shift = real_judged(name)
        ratio = auto["median_delta_e_uv"] / ct["median_delta_e_uv"]
        if shift:
            target = "yes" if ratio <= 0.5 else "no"
            goal = "≥ 2× better"
        else:
            target = "yes" if ratio <= 1.02 else "no"
            goal = "≤ 2 % worse"
        summary.append(
            [
                name,
                "yes" if shift else "no",
                uv(ct),
                f"{form_label(best)}: {uv(best)}",
                uv(table_entry),
                form_label(auto),
                f"{ratio:.3f}",
                f"{goal}: {target}",
            ]
        )
        shown = []
        for role, e in [("Cook–Torrance", ct), ("best parametric", best), ("table", table_entry), ("auto's choice", auto)]:
            if e is None:
                continue
            same = next((row for row in shown if row[0] is e), None)
            if same:
                same[1].append(role)
                continue
            shown.append((e, [role]))
        for e, roles in shown:
            loss = "–" if e["relative_loss"] is None else f"{e['relative_loss']:.4f}"
            err = " / ".join(f"{v:.4f}" for v in e["median_err_p"]) if e["median_err_p"] else "–"
            err_lobe = (
                " / ".join(f"{v:.4f}" for v in e["median_err_p_lobe"]) if e["median_err_p_lobe"] else "–"
            )
            detail.append(
                [name, form_label(e), ", ".join(roles), loss, uv(e), uv(e, "median_delta_e_uv_lobe"), err, err_lobe]
            )
    return (
        table(
            [
                "material",
                "colour change reported",
                "Cook–Torrance: ΔE_u′v′",
                "best parametric: ΔE_u′v′",
                "table: ΔE_u′v′",
                "auto's choice",
                "its ΔE_u′v′ / Cook–Torrance's",
                "target",
            ],
            summary,
        )
        + "\n\n"
        + table(
            [
                "material",
                "model",
                "role",
                "held-out loss",
                "ΔE_u′v′ all",
                "ΔE_u′v′ lobe",
                "ΔErr_p R / G / B all",
                "ΔErr_p R / G / B lobe",
            ],
            detail,
        )
    )


def coverage_table(name="coverage.json"):
    """Per parameter of each model: how often the budget's expanded interval (k = 2) and
    the fit's noise-only 95 % interval held the truth over the coverage scans of `name`."""
    path = RESULTS / "uncertainty" / name
    if not path.is_file():
        return "*Not run*: `bash scripts/results.sh --coverage-only` writes this table."
    report = read_json(path)
    rows = []
    for p in report["parameters"]:
        n = p["scans"]
        rows.append(
            [
                p["parameter"],
                f"{100 * p['expanded_hits'] / n:.1f} % ({p['expanded_hits']}/{n})",
                f"{100 * p['noise_only_hits'] / n:.1f} % ({p['noise_only_hits']}/{n})",
            ]
        )
    hits = sum(p["expanded_hits"] for p in report["parameters"])
    total = sum(p["scans"] for p in report["parameters"])
    stated = ", ".join(f"{k} {v}" for k, v in report["stated"].items())
    if stated:
        stated = f"stated standard uncertainties: {stated}"
    else:
        drawn = ", ".join(f"{k} {v}" for k, v in report["drawn_from"].items())
        stated = f"no uncertainty block (gonio's defaults: {drawn})"
    binning = f", binned {report['binning']}×{report['binning']}" if "binning" in report else ""
    return (
        f"{report['scans']} scans (θL {', '.join(f'{t:g}' for t in report['theta_l_deg'])}°"
        f"{binning}); {stated}.\n\n"
        + table(["parameter", "expanded (k = 2)", "noise-only 95 %"], rows)
        + f"\n\nAll parameters: {100 * hits / total:.1f} %."
    )

def wilson(k, n):
    """The 95 % Wilson interval of a rate k/n, in percent."""
    if n == 0:
        return "–"
    z = 1.96
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * ((p * (1 - p) / n + z * z / (4 * n * n)) ** 0.5) / (1 + z * z / n)
    return f"{100 * p:.0f} % ({k}/{n}; 95 % interval {100 * max(0, centre - half):.0f}–{100 * min(1, centre + half):.0f} %)"


def ratio(f, key):
    a, c = f.get(f"{key}_auto"), f.get(f"{key}_cook_torrance")
    return None if a is None or c is None or c <= 0 else a / c


def verdicts_table():
    """The colour-shift verdict's false-alarm and detection rates and auto's held-out
    brightness (mean ΔErr_p over R, G, B, all points of the unseen θL) and colour against
    Cook–Torrance's, over the randomized family and per RGL material."""
    path = RESULTS / "verdicts" / "verdicts.json"
    if not path.is_file():
        return "*Not run*: `bash scripts/results.sh --verdicts-only` writes this table."
    report = read_json(path)
    command = (RESULTS / "verdicts" / "command.txt").read_text(encoding="utf-8").strip()
    family = report["family"]
    text = f"Command: `{command}`.\n\n"
    if family:
        n = len(family)
        shifts = sum(1 for f in family if f["colour_shift"])
        noisy = [f for f in family if f["drawn"]["noise"] > 0 and f["lobe_colour_change"]]
        significant = sum(1 for f in noisy if f["lobe_colour_change"]["p_value"] < 0.01)
        saturated = [re.search(r"R/G/B: (\d+)/(\d+)/(\d+) saturated", f["dropped"]) for f in family]
        clipped = sum(1 for m in saturated if m and any(int(x) > 0 for x in m.groups()))
        ratios = sorted(r for r in (ratio(f, "err_p") for f in family) if r is not None)
        over = sum(1 for r in ratios if r > 1.05)
        noise_free = sum(1 for f in family if f["drawn"]["noise"] == 0)
        rows = [
            ["scans (noise-free; with a clipped channel)", f"{n} ({noise_free}; {clipped})"],
            ["colour shift reported (target ≤ 5 %)", wilson(shifts, n)],
            [
                "lobe chromaticity test significant, scans with noise (p < 0.01; stated false-alarm rate 1 %)",
                wilson(significant, len(noisy)),
            ],
            ["auto's / Cook–Torrance's brightness error: median, largest", f"{ratios[len(ratios) // 2]:.3f}, {ratios[-1]:.3f}"],
            ["scans where it exceeds 1.05 (target: none)", f"{over} of {len(ratios)}"],
        ]
        chosen = {}
        for f in family:
            chosen[f["chosen"]] = chosen.get(f["chosen"], 0) + 1
        rows.append(["auto's choice", ", ".join(f"{k} {v}" for k, v in sorted(chosen.items()))])
        text += "**Family** (one specular colour; extraction's dropped channels in the outputs):\n\n"
        text += table(["", "value"], rows) + "\n\n"
    rgl = report["rgl"]
    if not rgl:
        return text + "*RGL part skipped*: `GONIO_RGL_DIR` was not set."
    rows = []
    one_colour = [r for r in rgl if not r["material"].startswith("cc_")]
    films = [r for r in rgl if r["material"].startswith("cc_")]
    summary = [
        [
            "fits of the other materials reporting a shift (target ≤ 5 %)",
            wilson(sum(1 for r in one_colour if r["colour_shift"]), len(one_colour)),
        ],
        [
            "fits of the colour-changing films (`cc_*`) reporting a shift (target ≥ 95 %)",
            wilson(sum(1 for r in films if r["colour_shift"]), len(films)),
        ],
    ]
    for name in sorted({r["material"] for r in rgl}):
        clean = [r for r in rgl if r["material"] == name and r.get("seed", 0) is None]
        runs = [r for r in rgl if r["material"] == name and r.get("seed", 0) is not None]
        k = sum(1 for r in runs if r["colour_shift"])
        if not clean:
            without_noise = "–"
        else:
            size = (clean[0].get("lobe_colour_change") or {}).get("size_uv")
            without_noise = ("shift" if clean[0]["colour_shift"] else "none") + (
                "" if size is None else f" ({size:.4f})"
            )
        sizes = [r["lobe_colour_change"]["size_uv"] for r in runs if r["lobe_colour_change"]]
        bright = [x for x in (ratio(r, "err_p") for r in runs) if x is not None]
        colour = [x for x in (ratio(r, "delta_e_uv") for r in runs) if x is not None]
        worst = max(bright) if bright else None
        if name.startswith("cc_"):
            ok = k == len(runs) and all(r["colour_shift"] for r in clean) and colour and max(colour) <= 0.5 and worst is not None and worst <= 1.05
            target = "shift, colour ≤ 0.5×, brightness ≤ 1.05×: " + ("yes" if ok else "no")
        else:
            target = "brightness ≤ 1.05×: " + ("yes" if worst is not None and worst <= 1.05 else "no")
        rows.append(
            [
                name,
                without_noise,
                f"{k}/{len(runs)}",
                ", ".join(f"{x:.4f}" for x in sizes) or "–",
                "–" if worst is None else f"{worst:.3f}",
                "–" if not colour else f"{max(colour):.3f}",
                ", ".join(sorted({r["chosen"] for r in runs})),
                target,
            ]
        )
    text += "**RGL-EPFL files**, each without noise and with several noise seeds:\n\n"
    text += table(["", "value"], summary) + "\n\n"
    return text + table(
        [
            "material",
            "without noise: verdict (lobe Δu′v′)",
            "colour shift reported with noise",
            "lobe's largest Δu′v′ across θL",
            "auto / Cook–Torrance brightness error (largest)",
            "auto / Cook–Torrance ΔE_u′v′ (largest)",
            "auto's choice",
            "target",
        ],
        rows,
    )


# Block name → (document, function).
def colour_block(report, title):
    """One scan's multi-angle colour: L*, a*, b*, C*, h per aspecular angle, each ± its
    expanded uncertainty, where each comes from (data or model), and the flop index."""
    def pm(q, digits=1):
        return f"{q['value']:.{digits}f} ± {q['expanded']:.{digits}f}"

    rows = [
        [
            f"{a['aspecular']:g}",
            a["origin"] + (" (beyond the data: not a reading)" if a.get("beyond_data") else ""),
            *(pm(a[k]) for k in ("L", "a", "b", "C", "h")),
        ]
        for a in report["angles"]
    ]
    flop = report.get("flop_index")
    flop = f"; flop index {pm(flop, 2)}" if flop else ""
    notes = "".join(f" {n}" for n in report.get("notes", []))
    return (
        f"**{title}** ({MODEL_NAMES.get(report['model'], report['model'])}, "
        f"{report['conditions']}{flop}).{notes}\n\n"
        + table(["aspecular °", "from", "L*", "a*", "b*", "C*", "h °"], rows)
    )


def colour_table():
    """The multi-angle colour of every example scene and RGL file (`gonio colour` of its
    `--model auto` fit), values ± U (k = 2)."""
    found = [(s, RESULTS / s / "colour.json") for s in ORDER]
    real = RESULTS / "real-materials"
    if real.is_dir():
        found += [(d.name, d / "colour.json") for d in sorted(real.iterdir())]
    found = [(name, path) for name, path in found if path.is_file()]
    if not found:
        return "*Not run*: `bash scripts/results.sh --colour-only` writes these tables."
    transform = read_json(found[0][1])["transform"]
    head = (
        f"Camera RGB → XYZ: over its test spectra ({transform['spectra']}), the transform's "
        f"ΔE00 median {transform['delta_e00_median']:.2f}, 95th percentile "
        f"{transform['delta_e00_p95']:.2f}, largest {transform['delta_e00_max']:.2f}; it "
        "enters each value's uncertainty."
    )
    blocks = [colour_block(read_json(path), name) for name, path in found]
    return head + "\n\n" + "\n\n".join(blocks)


def breakdown_rows(breakdown):
    """Per kind of material: the coverage by coordinate, by origin and by the class of
    lines dominating U; what it would be with each class left out; the median of
    |error|/U (about 0.34 for a normal error and U = 2u)."""
    def rate(c):
        return wilson(c["within"], c["of"])

    def group(label, g):
        without = "; ".join(
            f"without {w['term']} {w['count']['within']}/{w['count']['of']}" for w in g["without"]
        )
        return [
            label,
            "",
            f"{rate(g['count'])}; median |error|/U {g['median_error_over_u']:.2f}; {without}",
            "",
        ]

    rows = []
    for kind in breakdown:
        rows.append(group(f"breakdown: {kind['kind']}", kind["all"]))
        rows += [group(f"… {kind['kind']}: {c['coordinate']}*", c["group"]) for c in kind["by_coordinate"]]
        rows += [group(f"… {kind['kind']}: from the {o['origin']}", o["group"]) for o in kind["by_origin"]]
        rows += [
            group(f"… {kind['kind']}: U mostly {t['term']}", t["group"])
            for t in kind["by_dominant_term"]
            if t["group"]["count"]["of"]
        ]
    return rows


def beyond_data_rows(beyond):
    """Model values flagged beyond the data, and of those the ones whose truth is darker."""
    if not beyond:
        return []
    flagged, darker = beyond["of_model_values"], beyond["truth_darker"]
    return [
        ["model values flagged beyond the data", "reported", f"{flagged['within']}/{flagged['of']}", ""],
        ["… whose truth is darker than the value", "reported", f"{darker['within']}/{darker['of']}", ""],
    ]


def by_material_rows(by_material):
    """The coverage's 95 % intervals resampling whole materials, all and per kind."""
    if not by_material:
        return []

    def interval(i):
        lo, hi = i["interval_95"]
        return f"{100 * lo:.1f}–{100 * hi:.1f} % ({i['materials']} materials)"

    return [
        ["… 95 % interval resampling whole materials", "", interval(by_material["all"]), ""],
        *[
            [f"… … {k['kind']}", "", interval(k["interval"]), ""]
            for k in by_material["by_kind"]
        ],
    ]


def colour_validation_table():
    """The multi-angle colour against the emulator's spectral truth
    (tests/tests/end_to_end/colour_validation.rs): coverage of the expanded intervals, the ΔE00 to
    the truth, repeatability within compare's U, discrimination; each target beside it."""
    out = RESULTS / "colour-validation"
    path = out / "figures.json"
    if not path.is_file():
        return "*Not run*: `bash scripts/results.sh --colour-validation` writes this table."
    f = read_json(path)
    command = (out / "command.txt").read_text(encoding="utf-8").strip()

    def rate(c):
        return wilson(c["within"], c["of"])

    def met(c, lo, hi):
        return "yes" if lo <= c["share"] <= hi else "no"

    def spread(d):
        return (
            f"median {d['median']:.2f}, 75th percentile {d['p75']:.2f}, 95th {d['p95']:.2f}, "
            f"largest {d['max']:.2f} ({d['geometries']} geometries)"
        )

    cov, by, origin = f["coverage"], f["coverage_by_coordinate"], f["coverage_by_origin"]
    rep, kd = f["repeatability"], f["kd_plus_1_percent"]
    rows = [
        ["L*, a*, b* inside U (k = 2), all", "92–98 %", rate(cov), met(cov, 0.92, 0.98)],
        *[[f"… {k}* only", "", rate(by[k]), ""] for k in ("L", "a", "b")],
        ["… from the data", "", rate(origin["data"]), ""],
        ["… from the model", "", rate(origin["model"]), ""],
        *[[f"… {k['kind']}", "", rate(k["count"]), ""] for k in f["coverage_by_kind"]],
        *by_material_rows(f.get("coverage_by_material")),
        *breakdown_rows(f.get("coverage_breakdown", [])),
        *beyond_data_rows(f.get("beyond_data")),
        ["ΔE00 to the spectral truth", "reported", spread(f["delta_e00"]), ""],
        ["… from the model", "reported", spread(f["delta_e00_model"]), ""],
        [
            f"repeats within compare's U ({rep['materials']} materials)",
            "≥ 95 %",
            rate(rep["all"]),
            met(rep["all"], 0.95, 1.0),
        ],
        *[
            [f"… at {a['aspecular']:g}°", "≥ 95 %", rate(a["count"]), met(a["count"], 0.95, 1.0)]
            for a in rep["by_angle"]
        ],
        ["gold against red", "fail", f["gold_against_red"], "yes" if f["gold_against_red"] == "fail" else "no"],
        ["Kd + 1 %: ΔE00 within U of the truth's", "≥ 95 %", rate(kd), met(kd, 0.95, 1.0)],
    ]
    return (
        f"{f['scans']} emulated scans of {f['materials']} materials (the four example scenes "
        f"and {f['random_materials']} random ones), ASTM E2539's six angles each. Command: "
        f"`{command}`.\n\n"
        + table(["figure", "target", "measured", "met"], rows)
    )


SECTIONS = {
    "study": ("results", study_table),
    "study-time": ("results", study_time_table),
    "tradeoff": ("results", tradeoff_table),
    "real-materials": ("results", real_materials_table),
    "coverage": ("results", coverage_table),
    "coverage-defaults": ("results", lambda: coverage_table("coverage-defaults.json")),
    "coverage-lab": ("results", lambda: coverage_table("coverage-lab.json")),
    "verdicts": ("results", verdicts_table),
    "colour": ("results", colour_table),
    "colour-validation": ("results", colour_validation_table),
    "summary": ("readme", summary_table),
}


def block_pattern(name):
    return re.compile(
        rf"(<!-- results: {re.escape(name)} -->\n)(.*?)(<!-- /results: {re.escape(name)} -->)",
        re.S,
    )


def main(argv):
    args = argv[1:]
    root = Path(__file__).resolve().parent.parent
    if args[:1] == ["--root"] and len(args) >= 2:
        root, args = Path(args[1]), args[2:]
    check = args == ["--check"]
    if args and not check:
        raise SystemExit(__doc__)
    set_root(root)
    texts = {k: p.read_text(encoding="utf-8") for k, p in DOCS.items()}
    stale = []
    for name, (doc, build) in SECTIONS.items():
        pattern = block_pattern(name)
        found = pattern.search(texts[doc])
        if not found:
            raise SystemExit(f"{DOCS[doc]}: no block `<!-- results: {name} -->`")
        block = build() + "\n"
        if found.group(2) != block:
            stale.append(f"{DOCS[doc].relative_to(ROOT)}: {name}")
            texts[doc] = pattern.sub(lambda m: m.group(1) + block + m.group(3), texts[doc])
    if check:
        if stale:
            print(
                "these blocks differ from the outputs under docs/results "
                "(run `python3 scripts/results_docs.py`):\n  " + "\n  ".join(stale)
            )
            return 1
        return 0
    for doc, path in DOCS.items():
        path.write_text(texts[doc], encoding="utf-8")
    for s in stale:
        print(f"rewrote {s}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
