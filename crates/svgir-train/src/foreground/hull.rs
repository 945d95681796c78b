//! The convex hull of a mask's pixels, for "inside the object's outline" where the outline has
//! notches (a blown-out highlight reaching it) that a hole fill would leave open.

/// The convex hull (counter-clockwise, in pixel coordinates) of the pixels of a `width` x
/// `height` soft mask at or over 0.5: Andrew's monotone chain over each row's first and last.
pub(super) fn hull(share: &[f32], width: usize) -> Vec<(f32, f32)> {
    let mut pts: Vec<(f32, f32)> = Vec::new();
    for (y, row) in share.chunks_exact(width).enumerate() {
        let on = |x: &usize| row[*x] >= 0.5;
        if let (Some(a), Some(b)) = ((0..width).find(on), (0..width).rev().find(on)) {
            pts.push((a as f32 + 0.5, y as f32 + 0.5));
            pts.push((b as f32 + 0.5, y as f32 + 0.5));
        }
    }
    pts.sort_by(|p, q| p.0.total_cmp(&q.0).then(p.1.total_cmp(&q.1)));
    pts.dedup();
    if pts.len() < 3 {
        return pts;
    }
    let cross = |o: (f32, f32), a: (f32, f32), b: (f32, f32)| (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0);
    let mut h: Vec<(f32, f32)> = Vec::with_capacity(2 * pts.len());
    for pass in 0..2 {
        let start = h.len();
        let iter: Box<dyn Iterator<Item = &(f32, f32)>> =
            if pass == 0 { Box::new(pts.iter()) } else { Box::new(pts.iter().rev()) };
        for &p in iter {
            while h.len() >= start + 2 && cross(h[h.len() - 2], h[h.len() - 1], p) <= 0.0 {
                h.pop();
            }
            h.push(p);
        }
        h.pop();
    }
    h
}

/// `p` inside (or on) the counter-clockwise convex polygon `h`.
pub(super) fn in_hull(h: &[(f32, f32)], p: (f32, f32)) -> bool {
    h.len() >= 3
        && (0..h.len()).all(|k| {
            let (a, b) = (h[k], h[(k + 1) % h.len()]);
            (b.0 - a.0) * (p.1 - a.1) - (b.1 - a.1) * (p.0 - a.0) >= 0.0
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The hull of a ring of pixels holds its centre, and nothing outside it.
    #[test]
    fn hull_of_a_ring_holds_its_hole() {
        let (w, hgt) = (40usize, 30usize);
        let share: Vec<f32> = (0..w * hgt)
            .map(|k| {
                let (x, y) = ((k % w) as f32 - 20.0, (k / w) as f32 - 15.0);
                let r = (x * x + y * y).sqrt();
                if (8.0..10.0).contains(&r) {
                    1.0
                } else {
                    0.0
                }
            })
            .collect();
        let h = hull(&share, w);
        assert!(in_hull(&h, (20.5, 15.5)), "centre");
        assert!(in_hull(&h, (27.0, 15.5)), "inside the ring");
        assert!(!in_hull(&h, (33.0, 15.5)) && !in_hull(&h, (20.5, 2.0)), "outside");
    }
}
