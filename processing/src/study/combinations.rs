//! Enumeration of the θL subsets a study fits (paper §2.3: 63 for six directions).

/// Largest number of θL a study enumerates (2¹⁶ − 1 subsets).
pub const MAX_THETA_L: usize = 16;

/// Every non-empty subset of `theta_l`, ordered by size, then lexicographically by the
/// positions of its members in `theta_l` (so `[a, b, c]` gives `[a] [b] [c] [a,b] [a,c]
/// [b,c] [a,b,c]`). Returns `None` when `theta_l` has more than [`MAX_THETA_L`] values.
pub fn combinations(theta_l: &[f64]) -> Option<Vec<Vec<f64>>> {
    let n = theta_l.len();
    if n > MAX_THETA_L {
        return None;
    }
    let mut masks: Vec<u32> = (1u32..(1u32 << n)).collect();
    let members = |mask: u32| (0..n).filter(move |&i| mask & (1 << i) != 0);
    masks.sort_by(|&a, &b| {
        a.count_ones()
            .cmp(&b.count_ones())
            .then_with(|| members(a).cmp(members(b)))
    });
    Some(
        masks
            .into_iter()
            .map(|mask| members(mask).map(|i| theta_l[i]).collect())
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn three_values_in_size_then_lexicographic_order() {
        let c = combinations(&[1.0, 2.0, 3.0]).unwrap();
        let expected: Vec<Vec<f64>> = vec![
            vec![1.0],
            vec![2.0],
            vec![3.0],
            vec![1.0, 2.0],
            vec![1.0, 3.0],
            vec![2.0, 3.0],
            vec![1.0, 2.0, 3.0],
        ];
        assert_eq!(c, expected);
    }

    #[test]
    fn empty_input_has_no_subsets_and_too_many_is_refused() {
        assert!(combinations(&[]).unwrap().is_empty());
        assert!(combinations(&[0.0; MAX_THETA_L + 1]).is_none());
    }
}
