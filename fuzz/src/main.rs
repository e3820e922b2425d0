//! The AFL++ driver: `gonio-fuzz TARGET` feeds AFL's inputs to one reader (see
//! [`gonio_fuzz::TARGETS`]); run it through `cargo afl fuzz` as fuzz/README.md shows.

fn main() {
    let name = std::env::args().nth(1).unwrap_or_default();
    let Some(target) = gonio_fuzz::target(&name) else {
        eprintln!(
            "usage: gonio-fuzz TARGET (one of: {})",
            gonio_fuzz::TARGETS
                .iter()
                .map(|t| t.name)
                .collect::<Vec<_>>()
                .join(", ")
        );
        std::process::exit(2);
    };
    let scratch = gonio_fuzz::Scratch::new().expect("a scratch directory");
    gonio_processing::guard::install_quiet_panic_hook();
    // `fuzz_nohook!`: a panic a reader catches itself is its error, not a crash; one
    // that escapes a reader still aborts, and AFL records it.
    afl::fuzz_nohook!(|data: &[u8]| {
        let _ = target.check(&scratch, data);
    });
}
