//! The one naming of a scan directory that every writer and checker of one shares: the
//! captures of each light angle θL in a directory `theta_l_<θL>` named to 0.1°.

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

#[cfg(test)]
mod tests {
    use super::*;

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
