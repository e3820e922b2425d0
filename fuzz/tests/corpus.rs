//! Every fuzz target over its committed seed corpus (the regression cases included),
//! and over random bytes and mutated seeds (proptest): a reader answers each input
//! with a value or an error, never a panic or an abort.

use gonio_fuzz::{corpus_dir, Scratch, TARGETS};
use proptest::prelude::*;

fn seeds(name: &str) -> Vec<(String, Vec<u8>)> {
    let dir = corpus_dir(name);
    let mut out: Vec<(String, Vec<u8>)> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| {
            let path = e.expect("corpus entry").path();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            (name, std::fs::read(&path).expect("reading a seed"))
        })
        .collect();
    out.sort();
    out
}

/// Seeds named `valid*` are accepted; every other seed is refused with a message,
/// `regression_*` ones (the hostile files that once crashed or aborted) by the size
/// checks that run before anything is allocated, and named by the check that refuses them.
#[test]
fn every_seed_of_every_target_gets_its_expected_answer() {
    gonio_processing::guard::install_quiet_panic_hook();
    let scratch = Scratch::new().unwrap();
    for target in &TARGETS {
        let seeds = seeds(target.name);
        assert!(seeds.len() >= 3, "{}: too few seeds", target.name);
        for (name, bytes) in seeds {
            let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                target.check(&scratch, &bytes)
            }));
            let Ok(outcome) = outcome else {
                panic!("{}/{name} panicked", target.name);
            };
            if name.starts_with("valid") {
                assert_eq!(outcome, Ok(()), "{}/{name}", target.name);
            } else {
                let message = outcome.expect_err(&format!("{}/{name} was accepted", target.name));
                if name.starts_with("regression_huge") {
                    assert!(
                        ["allowed", "need", "claims", "too large"]
                            .iter()
                            .any(|w| message.contains(w)),
                        "{}/{name}: {message}",
                        target.name
                    );
                }
                if name.starts_with("regression_samples_per_pixel") {
                    assert!(
                        message.contains("samples per pixel"),
                        "{}/{name}: {message}",
                        target.name
                    );
                }
            }
        }
    }
}

/// One seed of `target` with a few bytes overwritten, or cut short.
fn mutated(target: &'static str) -> impl Strategy<Value = Vec<u8>> {
    let seeds = seeds(target);
    (
        0..seeds.len(),
        proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
        any::<prop::sample::Index>(),
        any::<bool>(),
    )
        .prop_map(move |(k, edits, cut, truncate)| {
            let mut bytes = seeds[k].1.clone();
            if bytes.is_empty() {
                return bytes;
            }
            for (at, value) in edits {
                let i = at.index(bytes.len());
                bytes[i] = value;
            }
            if truncate {
                bytes.truncate(cut.index(bytes.len()));
            }
            bytes
        })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn random_bytes_are_answered_by_every_reader(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        gonio_processing::guard::install_quiet_panic_hook();
        let scratch = Scratch::new().unwrap();
        for target in &TARGETS {
            let _ = target.check(&scratch, &bytes);
        }
    }

    #[test]
    fn mutated_tiffs_are_answered(bytes in mutated("tiff_sidecar")) {
        gonio_processing::guard::install_quiet_panic_hook();
        let _ = gonio_fuzz::target("tiff_sidecar").unwrap().check(&Scratch::new().unwrap(), &bytes);
    }

    #[test]
    fn mutated_raw_files_are_answered(bytes in mutated("raw")) {
        gonio_processing::guard::install_quiet_panic_hook();
        let _ = gonio_fuzz::target("raw").unwrap().check(&Scratch::new().unwrap(), &bytes);
    }

    #[test]
    fn mutated_exr_maps_are_answered(bytes in mutated("exr")) {
        gonio_processing::guard::install_quiet_panic_hook();
        let _ = gonio_fuzz::target("exr").unwrap().check(&Scratch::new().unwrap(), &bytes);
    }

    #[test]
    fn mutated_text_inputs_are_answered(
        (name, bytes) in prop_oneof![
            Just("samples_csv"), Just("reference_csv"), Just("scene_toml"), Just("setup_json")
        ].prop_flat_map(|name| (Just(name), mutated(name)))
    ) {
        let _ = gonio_fuzz::target(name).unwrap().check(&Scratch::new().unwrap(), &bytes);
    }
}
