//! 3-vectors as plain `[f64; 3]`: the few operations the simulator and the
//! joint corrugation fit need, in one place.
//!
//! Plain arrays rather than nalgebra's `Vector3`: the callers store and
//! serialise `[f64; 3]` (scene geometry, calibration planes), and a handful
//! of operations per image row do not need a matrix library's types at every
//! boundary. Calibration, which solves real linear systems, uses nalgebra.

/// A 3-vector; its unit is the caller's (millimetres unless stated).
pub type Vec3 = [f64; 3];

/// `a · b`.
pub fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `a × b`.
pub fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// `a − b`.
pub fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `a + b`.
pub fn add(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `k·a`.
pub fn scale(a: Vec3, k: f64) -> Vec3 {
    [a[0] * k, a[1] * k, a[2] * k]
}

/// `k·a + b`.
pub fn axpy(k: f64, a: Vec3, b: Vec3) -> Vec3 {
    [b[0] + k * a[0], b[1] + k * a[1], b[2] + k * a[2]]
}

/// `|a|`.
pub fn norm(a: Vec3) -> f64 {
    dot(a, a).sqrt()
}

/// `a / |a|`, or `None` for a zero or non-finite vector.
pub fn unit(a: Vec3) -> Option<Vec3> {
    let n = norm(a);
    (n > 0.0 && n.is_finite()).then(|| scale(a, 1.0 / n))
}

/// `a / |a|` for a vector non-zero by construction (NaN for a zero vector).
pub fn normalized(a: Vec3) -> Vec3 {
    scale(a, 1.0 / norm(a))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn products_of_the_axes() {
        let (x, y, z) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]);
        assert_eq!(cross(x, y), z);
        assert_eq!(cross(y, z), x);
        assert_eq!(dot(x, y), 0.0);
        assert_eq!(norm([3.0, 4.0, 12.0]), 13.0);
        assert_eq!(unit([0.0, 0.0, 2.0]), Some(z));
        assert_eq!(unit([0.0; 3]), None);
        assert_eq!(unit([f64::NAN, 0.0, 0.0]), None);
        assert_eq!(axpy(2.0, x, y), [2.0, 1.0, 0.0]);
        assert_eq!(add(sub(z, x), x), z);
    }
}
