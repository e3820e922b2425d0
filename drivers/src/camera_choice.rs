//! Reading a camera's choice strings: shutter speeds and ISO values as the body lists
//! them (`1/100`, `0.0100s`, `0.5`, `2`, `30"`, `bulb`, `ISO 200`, `Auto`).

/// One shutter-speed choice.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ShutterChoice {
    /// A fixed time, seconds.
    Seconds(f64),
    /// Bulb or time exposure: not a fixed time.
    Bulb,
}

/// Parse a shutter-speed choice; `None` when it is no shutter time at all.
pub fn parse_shutter(choice: &str) -> Option<ShutterChoice> {
    let text = choice.trim().to_ascii_lowercase();
    if text == "bulb" || text == "time" || text == "b" {
        return Some(ShutterChoice::Bulb);
    }
    let number = text
        .strip_suffix("sec")
        .or_else(|| text.strip_suffix('s'))
        .or_else(|| text.strip_suffix('"'))
        .unwrap_or(&text)
        .trim();
    let seconds = match number.split_once('/') {
        Some((num, den)) => num.trim().parse::<f64>().ok()? / den.trim().parse::<f64>().ok()?,
        None => number.parse::<f64>().ok()?,
    };
    (seconds.is_finite() && seconds > 0.0).then_some(ShutterChoice::Seconds(seconds))
}

/// The fixed shutter times among `choices`, seconds, ascending, without duplicates.
pub fn shutter_times<S: AsRef<str>>(choices: &[S]) -> Vec<f64> {
    let mut times: Vec<f64> = choices
        .iter()
        .filter_map(|c| match parse_shutter(c.as_ref()) {
            Some(ShutterChoice::Seconds(t)) => Some(t),
            _ => None,
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times.dedup_by(|a, b| (*a / *b - 1.0).abs() < 1e-9);
    times
}

/// The fixed-time choice nearest to `target_s` on a logarithmic scale (ties go to the
/// shorter time), with its time; `None` when no choice is a fixed time.
pub fn nearest_shutter<S: AsRef<str>>(choices: &[S], target_s: f64) -> Option<(&str, f64)> {
    nearest_by_log(choices, target_s, |c| match parse_shutter(c) {
        Some(ShutterChoice::Seconds(t)) => Some(t),
        _ => None,
    })
}

/// Parse an ISO choice (`100`, `ISO 200`); `None` for `Auto`, `Hi 1` and the like.
pub fn parse_iso(choice: &str) -> Option<u32> {
    let text = choice.trim();
    let number = text
        .strip_prefix("ISO")
        .or_else(|| text.strip_prefix("iso"))
        .unwrap_or(text)
        .trim();
    number.parse::<u32>().ok().filter(|&iso| iso > 0)
}

/// The numeric ISO choice nearest to `target` on a logarithmic scale, with its value.
pub fn nearest_iso<S: AsRef<str>>(choices: &[S], target: u32) -> Option<(&str, u32)> {
    nearest_by_log(choices, f64::from(target), |c| parse_iso(c).map(f64::from))
        .map(|(c, iso)| (c, iso.round() as u32))
}

fn nearest_by_log<S: AsRef<str>>(
    choices: &[S],
    target: f64,
    value: impl Fn(&str) -> Option<f64>,
) -> Option<(&str, f64)> {
    let log_target = target.max(f64::MIN_POSITIVE).ln();
    choices
        .iter()
        .filter_map(|c| value(c.as_ref()).map(|v| (c.as_ref(), v)))
        .min_by(|(_, a), (_, b)| {
            let da = (a.ln() - log_target).abs();
            let db = (b.ln() - log_target).abs();
            da.total_cmp(&db).then(a.total_cmp(b))
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_files::scan_layout::format_shutter;

    fn secs(s: &str) -> f64 {
        match parse_shutter(s) {
            Some(ShutterChoice::Seconds(t)) => t,
            other => panic!("{s:?} -> {other:?}"),
        }
    }

    #[test]
    fn shutter_times_as_written_read_back() {
        // What is written reads back as (nearly) the same time.
        for seconds in [1.0 / 8000.0, 1.0 / 30.0, 0.25, 0.5, 1.3, 2.0, 30.0] {
            let back = secs(&format_shutter(seconds));
            assert!((back / seconds - 1.0).abs() < 0.01, "{seconds} -> {back}");
        }
    }

    #[test]
    fn parses_the_usual_spellings() {
        assert_eq!(secs("1/100"), 0.01);
        assert_eq!(secs("0.0100s"), 0.01);
        assert_eq!(secs(" 0.5 "), 0.5);
        assert_eq!(secs("2"), 2.0);
        assert_eq!(secs("30\""), 30.0);
        assert_eq!(secs("1/8000s"), 1.0 / 8000.0);
        assert_eq!(secs("1.0000s"), 1.0);
        assert_eq!(secs("2 sec"), 2.0);
        assert_eq!(parse_shutter("bulb"), Some(ShutterChoice::Bulb));
        assert_eq!(parse_shutter("Bulb"), Some(ShutterChoice::Bulb));
        for bad in ["", "auto", "1/0", "0", "-1", "x/3", "nan", "inf"] {
            assert_eq!(parse_shutter(bad), None, "{bad:?}");
        }
    }

    #[test]
    fn lists_fixed_times_ascending() {
        let choices = ["1.0000s", "0.1000s", "bulb", "1/10", "0.0001s", "junk"];
        assert_eq!(shutter_times(&choices), vec![0.0001, 0.1, 1.0]);
    }

    #[test]
    fn snaps_to_the_nearest_choice_in_stops() {
        let choices = ["1/1000", "1/250", "1/60", "1/15", "bulb"];
        assert_eq!(nearest_shutter(&choices, 0.004), Some(("1/250", 0.004)));
        // 1/125 is 1 stop from 1/250 and 1.06 stops from 1/60; 1/100 is 0.74 stop from 1/60.
        assert_eq!(
            nearest_shutter(&choices, 1.0 / 125.0).map(|c| c.0),
            Some("1/250")
        );
        assert_eq!(
            nearest_shutter(&choices, 1.0 / 100.0).map(|c| c.0),
            Some("1/60")
        );
        assert_eq!(nearest_shutter(&choices, 100.0).map(|c| c.0), Some("1/15"));
        assert_eq!(nearest_shutter(&choices, 0.0).map(|c| c.0), Some("1/1000"));
        // Exactly between two choices (geometric mean): the shorter wins.
        let tie = (0.004f64 * (1.0 / 60.0)).sqrt();
        assert_eq!(nearest_shutter(&choices, tie).map(|c| c.0), Some("1/250"));
        assert_eq!(nearest_shutter(&["bulb"], 1.0), None);
    }

    #[test]
    fn reads_iso_choices() {
        assert_eq!(parse_iso("100"), Some(100));
        assert_eq!(parse_iso("ISO 200"), Some(200));
        assert_eq!(parse_iso("Auto"), None);
        assert_eq!(parse_iso("Hi 1"), None);
        let choices = ["Auto", "100", "200", "400", "800"];
        assert_eq!(nearest_iso(&choices, 300), Some(("400", 400)));
        assert_eq!(nearest_iso(&choices, 250), Some(("200", 200)));
        assert_eq!(nearest_iso(&["Auto"], 100), None);
    }
}
