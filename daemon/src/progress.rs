//! Progress of the offline commands on stderr: bars on a terminal, nothing at all when
//! stderr is a pipe or a file (indicatif hides its bars there), so logs and CI output
//! stay clean; and the lines a command tells on stderr ([`say`]).

use indicatif::{ProgressBar, ProgressStyle};

/// Writes `line` and a newline to stderr. A reader that has gone (`2> >(head -1)`)
/// loses the line, never the command's work: `eprintln!` would panic there.
pub fn say(line: std::fmt::Arguments) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "{line}");
}

/// A bar of `total` items named `unit` (`captures`, `fits`, …), with the time elapsed
/// and an estimate of the time left; the message says what is being done.
pub fn bar(total: u64, unit: &str) -> ProgressBar {
    let template =
        format!("{{msg}} [{{bar:30}}] {{pos}}/{{len}} {unit}, {{elapsed}} (ETA {{eta}})");
    ProgressBar::new(total).with_style(
        ProgressStyle::with_template(&template)
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    )
}

/// A spinner for work of unknown length, ticking on its own.
pub fn spinner(message: impl Into<String>) -> ProgressBar {
    let spinner = ProgressBar::new_spinner().with_style(
        ProgressStyle::with_template("{spinner} {msg} {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    spinner.set_message(message.into());
    spinner.enable_steady_tick(std::time::Duration::from_millis(120));
    spinner
}
