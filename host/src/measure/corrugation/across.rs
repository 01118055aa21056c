//! The lines slid across the rail onto one another: the slope across the
//! running band, so the outer lines' profiles are compared where they lie.

use super::Line;
use nalgebra::{DMatrix, DVector};

/// The rail head's shape across, from the lines: the parabola (two lines:
/// the straight line) through their mean heights at their mean lateral
/// positions, and each line's straight course `v̂_l(u) = a_l + b_l·u`.
#[derive(Debug, Clone, PartialEq)]
pub struct Across {
    vbar: f64,
    /// `h = c0 + c1 (v − v̄) + c2 (v − v̄)²`.
    c: [f64; 3],
    /// Per line `(a_l, b_l)`, `None` for a line under 8 points.
    course: Vec<Option<(f64, f64)>>,
}

impl Across {
    /// From the lines (head frame); `None` with fewer than two lines of at
    /// least 8 points, or lines that give no finite shape.
    pub fn new(lines: &[Line]) -> Option<Across> {
        let mut means = Vec::new();
        let mut course = Vec::new();
        for l in lines {
            if l.points.len() < 8 {
                course.push(None);
                continue;
            }
            let n = l.points.len() as f64;
            let (u, v, h) =
                l.points.iter().fold((0.0, 0.0, 0.0), |m, p| (m.0 + p[0] / n, m.1 + p[1] / n, m.2 + p[2] / n));
            let suu: f64 = l.points.iter().map(|p| (p[0] - u).powi(2)).sum();
            let suv: f64 = l.points.iter().map(|p| (p[0] - u) * (p[1] - v)).sum();
            let b = if suu > 0.0 { suv / suu } else { 0.0 };
            course.push(Some((v - b * u, b)));
            means.push((v, h));
        }
        if means.len() < 2 {
            return None;
        }
        let vbar = means.iter().map(|p| p.0).sum::<f64>() / means.len() as f64;
        let order = if means.len() >= 3 { 3 } else { 2 };
        let a = DMatrix::from_fn(means.len(), order, |i, j| (means[i].0 - vbar).powi(j as i32));
        let b = DVector::from_iterator(means.len(), means.iter().map(|p| p.1));
        let sol = a.svd(true, true).solve(&b, 1e-12).ok()?;
        let c = [sol[0], sol[1], if order == 3 { sol[2] } else { 0.0 }];
        let ok =
            c.iter().all(|c| c.is_finite()) && course.iter().flatten().all(|(a, b)| a.is_finite() && b.is_finite());
        ok.then_some(Across { vbar, c, course })
    }

    /// The lateral slope `dh/dv` at lateral position `v`.
    pub fn slope(&self, v: f64) -> f64 {
        self.c[1] + 2.0 * self.c[2] * (v - self.vbar)
    }

    /// Point `p` of line `line` slid along the lateral slope onto the line's
    /// course: `[u, v̂(u), h − γ(v̂)·(v − v̂(u))]` (unchanged for a line
    /// without a course).
    pub fn slide(&self, line: usize, p: [f64; 3]) -> [f64; 3] {
        match self.course.get(line).copied().flatten() {
            Some((a, b)) => {
                let v = a + b * p[0];
                [p[0], v, p[2] - self.slope(v) * (p[1] - v)]
            }
            None => p,
        }
    }
}

/// Every point of every line slid across onto its line's course
/// ([`Across::slide`]); the lines unchanged if they give no shape across.
///
/// Why (module docs, "Lateral slope"): an inclined laser plane's line moves
/// sideways as the height changes, and on ground that slopes across it meets
/// higher or lower ground, so its height deviations read `1/(1 − γ t)` of
/// the rail's. Sliding the point along the local slope back onto the line's
/// straight course takes that out to first order in the crown's curvature,
/// whatever the plane's lean; the course itself (a pitched head's line
/// wanders across linearly as its height changes along it) is kept.
pub fn slide_across(lines: &mut [Line]) -> Option<Across> {
    let across = Across::new(lines)?;
    for (i, l) in lines.iter_mut().enumerate() {
        for p in &mut l.points {
            *p = across.slide(i, *p);
        }
    }
    Some(across)
}
