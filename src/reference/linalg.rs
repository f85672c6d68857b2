//! The few 3×3 / 2×3 matrix helpers the reference needs, row-major, no dependencies, so the
//! math in `project.rs` and `backward.rs` reads like the formulas it implements.

pub type Vec3 = [f64; 3];
pub type Mat3 = [[f64; 3]; 3];
/// Two rows of three: the EWA Jacobian and its products.
pub type Mat23 = [[f64; 3]; 2];

pub fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub fn scale(a: Vec3, s: f64) -> Vec3 {
    [a[0] * s, a[1] * s, a[2] * s]
}

pub fn add_assign(a: &mut Vec3, b: Vec3) {
    for k in 0..3 {
        a[k] += b[k];
    }
}

pub fn transpose(m: &Mat3) -> Mat3 {
    let mut t = [[0.0; 3]; 3];
    for (i, row) in m.iter().enumerate() {
        for (j, v) in row.iter().enumerate() {
            t[j][i] = *v;
        }
    }
    t
}

pub fn mat_vec(m: &Mat3, v: Vec3) -> Vec3 {
    [dot(m[0], v), dot(m[1], v), dot(m[2], v)]
}

/// `a · b` for 3×3 matrices.
pub fn mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

/// `a · b` for a 2×3 times a 3×3.
pub fn mul23(a: &Mat23, b: &Mat3) -> Mat23 {
    let mut c = [[0.0; 3]; 2];
    for i in 0..2 {
        for j in 0..3 {
            c[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

/// `t · s · tᵀ` for a 2×3 `t` and a symmetric 3×3 `s`, returned as the 2×2 symmetric
/// `[a, b, c]` = `[[a, b], [b, c]]`.
pub fn project_sym(t: &Mat23, s: &Mat3) -> [f64; 3] {
    let ts = mul23(t, s);
    [dot(ts[0], t[0]), dot(ts[0], t[1]), dot(ts[1], t[1])]
}
