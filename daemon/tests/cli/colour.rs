//! `gonio colour` and `gonio compare` on fit JSONs (docs/ARCHITECTURE.md, "Multi-angle
//! colour"): the table and its files, verdicts, and bad input refused in one line.

use crate::common;

use common::{gonio, gonio_ok, text};
use serde_json::{json, Value};

fn fit(kd: [f64; 3]) -> Value {
    json!({
        "model": "cook-torrance", "roughness": "shared", "kd": kd,
        "ks": [25.0, 20.0, 7.0], "m": [0.07], "loss": 1.0, "err_p": [0.0, 0.0, 0.0],
        "method": "robust", "evaluations": 1, "seconds": 0.0,
        "stderr": {"kd": [0.02, 0.02, 0.02], "ks": [0.1, 0.1, 0.05], "m": [0.0002]}
    })
}

#[test]
fn colour_writes_json_and_csv_and_compare_judges_per_angle() {
    let dir = tempfile::tempdir().unwrap();
    let p = |name: &str| dir.path().join(name).to_str().unwrap().to_owned();
    std::fs::write(p("gold.json"), fit([9.0, 6.5, 2.0]).to_string()).unwrap();
    std::fs::write(p("red.json"), fit([40.0, 3.0, 2.5]).to_string()).unwrap();
    let printed = gonio_ok(&[
        "colour",
        &p("gold.json"),
        "--out",
        &p("colour.json"),
        "--csv",
        &p("colour.csv"),
    ]);
    assert!(
        printed.contains("D65/10") && printed.contains("flop index"),
        "{printed}"
    );
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(p("colour.json")).unwrap()).unwrap();
    let angles = report["angles"].as_array().unwrap();
    assert_eq!(angles.len(), 6);
    for a in angles {
        assert_eq!(a["origin"], "model");
        assert!(a["L"]["expanded"].as_f64().unwrap() > 0.0);
    }
    let csv = std::fs::read_to_string(p("colour.csv")).unwrap();
    assert!(csv.starts_with("aspecular,theta_i,theta_r,origin,L,U_L,"));
    assert_eq!(csv.lines().count(), 7);

    let same = gonio_ok(&["compare", &p("colour.json"), &p("gold.json")]);
    // The same colour twice: ΔE00 0, never a fail (two scans' noise may leave the
    // interval straddling a tight tolerance: undecided).
    assert!(!same.contains("fail") && same.contains("0.00 ±"), "{same}");
    let other = gonio_ok(&[
        "compare",
        &p("gold.json"),
        &p("red.json"),
        "--out",
        &p("cmp.json"),
    ]);
    assert!(other.contains("overall: fail"), "{other}");
    let cmp: Value =
        serde_json::from_str(&std::fs::read_to_string(p("cmp.json")).unwrap()).unwrap();
    assert_eq!(cmp["overall"], "fail");

    let example = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/assets/tolerances.example.toml"
    );
    gonio_ok(&[
        "compare",
        &p("gold.json"),
        &p("gold.json"),
        "--tolerances",
        example,
    ]);
    std::fs::write(p("bad.toml"), "[delta_e00]\n\"15\" = -1\n").unwrap();
    for (args, says) in [
        (
            vec![
                "compare",
                &p("gold.json"),
                &p("gold.json"),
                "--tolerances",
                &p("bad.toml"),
            ],
            "delta_e00.15",
        ),
        (
            vec![
                "colour",
                &p("gold.json"),
                "--geometry",
                "15,200",
                "--out",
                &p("x.json"),
            ],
            "outside",
        ),
        (
            vec![
                "colour",
                &p("gold.json"),
                "--conditions",
                "A/2",
                "--out",
                &p("x.json"),
            ],
            "D65/10",
        ),
        (
            vec!["colour", &p("colour.csv"), "--out", &p("x.json")],
            "is not JSON",
        ),
    ] {
        let out = gonio(&args);
        let err = text(&out.stderr);
        assert!(
            !out.status.success() && err.lines().count() == 1 && err.contains(says),
            "{args:?}: {err}"
        );
    }
}
