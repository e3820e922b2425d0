//! Pareto front of (cost, error) points: the settings no other setting beats on both.

/// Indices of the non-dominated points, ascending in cost (and so descending in error).
/// A point is dominated when another has cost ≤ and error ≤ with one of them strictly
/// smaller; of identical points the first is kept. Points with a non-finite coordinate
/// are never on the front.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..points.len())
        .filter(|&i| points[i].0.is_finite() && points[i].1.is_finite())
        .collect();
    order.sort_by(|&a, &b| {
        points[a]
            .0
            .total_cmp(&points[b].0)
            .then(points[a].1.total_cmp(&points[b].1))
            .then(a.cmp(&b))
    });
    let mut front = Vec::new();
    let mut best_error = f64::INFINITY;
    for i in order {
        if points[i].1 < best_error {
            best_error = points[i].1;
            front.push(i);
        }
    }
    front
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_only_non_dominated_points_in_cost_order() {
        let points = [
            (3.0, 1.0),      // front
            (1.0, 5.0),      // front
            (2.0, 5.0),      // dominated by (1, 5)
            (2.0, 2.0),      // front
            (4.0, 1.0),      // dominated by (3, 1)
            (f64::NAN, 0.0), // ignored
            (1.0, 5.0),      // duplicate of index 1
        ];
        assert_eq!(pareto_front(&points), vec![1, 3, 0]);
    }
}
