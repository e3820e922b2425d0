//! The one naming of a scan directory that every writer and checker of one shares: the
//! captures of each light angle θL in a directory `theta_l_<θL>` named to 0.1°, and
//! their exposures' shutter times as photographers write them.

/// The directory of the captures of light angle `theta_l` (degrees) in a scan directory.
pub fn theta_dir_name(theta_l: f64) -> String {
    format!("theta_l_{theta_l:.1}")
}

/// Whether light angles `a` and `b` (degrees) share a directory, so that a scan cannot
/// hold both: equal to 0.1° as numbers (0 and −0.0, or 0.04 and −0.04, are one angle)
/// or as their directories are named (`{:.1}` rounds a half to even: −1.25 and −1.2
/// are both `theta_l_-1.2`).
pub fn same_theta_dir(a: f64, b: f64) -> bool {
    let tenths = |t: f64| (t * 10.0).round() + 0.0;
    tenths(a) == tenths(b) || theta_dir_name(a) == theta_dir_name(b)
}

/// Shorter times than this are written as fractions (`1/4 s`), longer ones as decimals
/// (`0.3 s`), as camera bodies and photographers do.
const FRACTION_BELOW_S: f64 = 0.3;

/// A shutter time as photographers write it: `1/30 s`, `1/8000 s`, `0.5 s`, `1.3 s`,
/// `2 s`, `30 s` (fractions below 0.3 s, one decimal below 10 s, whole seconds above).
pub fn format_shutter(seconds: f64) -> String {
    if !(seconds.is_finite() && seconds > 0.0) {
        return format!("{seconds} s");
    }
    if seconds < FRACTION_BELOW_S {
        return format!("1/{} s", (1.0 / seconds).round());
    }
    let text = if seconds < 10.0 {
        format!("{seconds:.1}")
    } else {
        format!("{seconds:.0}")
    };
    format!("{} s", text.strip_suffix(".0").unwrap_or(&text))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shutter_times_are_written_as_photographers_do() {
        let cases = [
            (1.0 / 8000.0, "1/8000 s"),
            (1.0 / 60.0, "1/60 s"),
            (1.0 / 30.0, "1/30 s"),
            (0.25, "1/4 s"),
            (1.0 / 3.0, "0.3 s"),
            (0.5, "0.5 s"),
            (1.3, "1.3 s"),
            (2.0, "2 s"),
            (30.0, "30 s"),
            (0.0, "0 s"),
        ];
        for (seconds, text) in cases {
            assert_eq!(format_shutter(seconds), text, "{seconds}");
        }
    }

    #[test]
    fn angles_one_directory_holds_are_the_same() {
        assert_eq!(theta_dir_name(-20.0), "theta_l_-20.0");
        for (a, b) in [
            (-20.0, -20.0),
            (0.0, -0.0),
            (-0.04, 0.04),
            (-1.25, -1.2),
            (-1.25, -1.3),
        ] {
            assert!(same_theta_dir(a, b), "{a} {b}");
        }
        for (a, b) in [(-20.0, -20.2), (-1.2, -1.3)] {
            assert!(!same_theta_dir(a, b), "{a} {b}");
        }
    }
}
