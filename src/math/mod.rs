//! Small linear algebra generic over the number type: 3-vectors, rotations and rigid placements;
//! the crate's one normal sampler ([`normal`]), its statistics over units ([`stats`]) and the
//! Zernike polynomials ([`zernike`]).

pub mod normal;
pub mod stats;
pub mod zernike;

use crate::real::Real;
use std::ops::{Add, Mul, Neg, Sub};

/// A 3-vector (x, y, z) in millimetres or a direction, generic over the number type.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Vec3<S> {
    /// x component.
    pub x: S,
    /// y component (the meridional axis).
    pub y: S,
    /// z component (the optical axis).
    pub z: S,
}

impl<S: Real> Vec3<S> {
    /// A vector from its components.
    #[inline(always)]
    pub fn new(x: S, y: S, z: S) -> Self {
        Vec3 { x, y, z }
    }
    /// A constant vector from `f64` components.
    #[inline(always)]
    pub fn cst(x: f64, y: f64, z: f64) -> Self {
        Vec3::new(S::cst(x), S::cst(y), S::cst(z))
    }
    /// Dot product.
    #[inline(always)]
    pub fn dot(self, o: Self) -> S {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    /// Cross product.
    #[inline(always)]
    pub fn cross(self, o: Self) -> Self {
        Vec3::new(
            self.y * o.z - self.z * o.y,
            self.z * o.x - self.x * o.z,
            self.x * o.y - self.y * o.x,
        )
    }
    /// Euclidean length.
    #[inline(always)]
    pub fn norm(self) -> S {
        self.dot(self).sqrt()
    }
    /// Unit vector in the same direction (a zero vector gives non-finite components).
    #[inline(always)]
    pub fn normalized(self) -> Self {
        self * (S::cst(1.0) / self.norm())
    }
    /// Converts the number type through `f64` values (drops derivatives).
    #[inline(always)]
    pub fn map_value<T: Real>(self) -> Vec3<T> {
        Vec3::new(
            T::cst(self.x.value()),
            T::cst(self.y.value()),
            T::cst(self.z.value()),
        )
    }
}

impl<S: Real> Add for Vec3<S> {
    type Output = Self;
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        Vec3::new(self.x + o.x, self.y + o.y, self.z + o.z)
    }
}
impl<S: Real> Sub for Vec3<S> {
    type Output = Self;
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        Vec3::new(self.x - o.x, self.y - o.y, self.z - o.z)
    }
}
impl<S: Real> Mul<S> for Vec3<S> {
    type Output = Self;
    #[inline(always)]
    fn mul(self, s: S) -> Self {
        Vec3::new(self.x * s, self.y * s, self.z * s)
    }
}
impl<S: Real> Neg for Vec3<S> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        Vec3::new(-self.x, -self.y, -self.z)
    }
}

/// A 3x3 matrix stored by rows.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mat3<S> {
    /// Rows of the matrix.
    pub rows: [Vec3<S>; 3],
}

impl<S: Real> Mat3<S> {
    /// The identity.
    pub fn identity() -> Self {
        Mat3 {
            rows: [
                Vec3::cst(1.0, 0.0, 0.0),
                Vec3::cst(0.0, 1.0, 0.0),
                Vec3::cst(0.0, 0.0, 1.0),
            ],
        }
    }
    /// Right-handed rotation by `a` radians about x: maps +z to (0, -sin a, cos a).
    pub fn rot_x(a: S) -> Self {
        let (s, c) = (a.sin(), a.cos());
        let (o, z) = (S::cst(1.0), S::cst(0.0));
        Mat3 {
            rows: [Vec3::new(o, z, z), Vec3::new(z, c, -s), Vec3::new(z, s, c)],
        }
    }
    /// Right-handed rotation by `b` radians about y: maps +z to (sin b, 0, cos b).
    pub fn rot_y(b: S) -> Self {
        let (s, c) = (b.sin(), b.cos());
        let (o, z) = (S::cst(1.0), S::cst(0.0));
        Mat3 {
            rows: [Vec3::new(c, z, s), Vec3::new(z, o, z), Vec3::new(-s, z, c)],
        }
    }
    /// Right-handed rotation by `g` radians about z.
    pub fn rot_z(g: S) -> Self {
        let (s, c) = (g.sin(), g.cos());
        let (o, z) = (S::cst(1.0), S::cst(0.0));
        Mat3 {
            rows: [Vec3::new(c, -s, z), Vec3::new(s, c, z), Vec3::new(z, z, o)],
        }
    }
    /// The tolerance convention `R = Rz(g) Ry(b) Rx(a)` from angles in degrees.
    pub fn from_tilt_deg(a_deg: S, b_deg: S, g_deg: S) -> Self {
        let k = S::cst(std::f64::consts::PI / 180.0);
        Mat3::rot_z(g_deg * k) * Mat3::rot_y(b_deg * k) * Mat3::rot_x(a_deg * k)
    }
    /// Matrix times vector.
    #[inline(always)]
    pub fn apply(&self, v: Vec3<S>) -> Vec3<S> {
        Vec3::new(
            self.rows[0].dot(v),
            self.rows[1].dot(v),
            self.rows[2].dot(v),
        )
    }
    /// Transpose times vector (the inverse for a rotation).
    #[inline(always)]
    pub fn apply_t(&self, v: Vec3<S>) -> Vec3<S> {
        let [r0, r1, r2] = self.rows;
        r0 * v.x + r1 * v.y + r2 * v.z
    }
    /// Transpose.
    pub fn transpose(&self) -> Self {
        let [r0, r1, r2] = self.rows;
        Mat3 {
            rows: [
                Vec3::new(r0.x, r1.x, r2.x),
                Vec3::new(r0.y, r1.y, r2.y),
                Vec3::new(r0.z, r1.z, r2.z),
            ],
        }
    }
}

impl<S: Real> Mul for Mat3<S> {
    type Output = Self;
    fn mul(self, o: Self) -> Self {
        let ot = o.transpose();
        let row = |r: Vec3<S>| Vec3::new(r.dot(ot.rows[0]), r.dot(ot.rows[1]), r.dot(ot.rows[2]));
        Mat3 {
            rows: [row(self.rows[0]), row(self.rows[1]), row(self.rows[2])],
        }
    }
}

/// A rigid placement `x_global = translation + rotation * x_local`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rigid<S> {
    /// Rotation from local to global axes.
    pub rotation: Mat3<S>,
    /// Position of the local origin in the global frame (mm).
    pub translation: Vec3<S>,
}

impl<S: Real> Rigid<S> {
    /// The identity placement.
    pub fn identity() -> Self {
        Rigid {
            rotation: Mat3::identity(),
            translation: Vec3::cst(0.0, 0.0, 0.0),
        }
    }
    /// Composition: `self ∘ inner` (apply `inner` first).
    pub fn compose(&self, inner: &Rigid<S>) -> Rigid<S> {
        Rigid {
            rotation: self.rotation * inner.rotation,
            translation: self.translation + self.rotation.apply(inner.translation),
        }
    }
    /// A rotation `r` about the pivot point `pivot` followed by a translation `t`:
    /// `x -> pivot + r (x - pivot) + t`.
    pub fn about_pivot(r: Mat3<S>, pivot: Vec3<S>, t: Vec3<S>) -> Self {
        Rigid {
            rotation: r,
            translation: pivot - r.apply(pivot) + t,
        }
    }
    /// Maps a local point to the global frame.
    #[inline(always)]
    pub fn point_to_global(&self, p: Vec3<S>) -> Vec3<S> {
        self.translation + self.rotation.apply(p)
    }
    /// Maps a global point to the local frame.
    #[inline(always)]
    pub fn point_to_local(&self, p: Vec3<S>) -> Vec3<S> {
        self.rotation.apply_t(p - self.translation)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_about_x_is_right_handed() {
        let r = Mat3::<f64>::rot_x(0.3);
        let z = r.apply(Vec3::cst(0.0, 0.0, 1.0));
        assert!((z.y + 0.3f64.sin()).abs() < 1e-15 && (z.z - 0.3f64.cos()).abs() < 1e-15);
        let r = Mat3::<f64>::rot_y(0.3);
        let z = r.apply(Vec3::cst(0.0, 0.0, 1.0));
        assert!((z.x - 0.3f64.sin()).abs() < 1e-15);
    }

    #[test]
    fn rigid_round_trip_and_pivot() {
        let r = Mat3::<f64>::from_tilt_deg(1.0, -2.0, 3.0);
        let pivot = Vec3::cst(0.0, 0.0, 5.0);
        let g = Rigid::about_pivot(r, pivot, Vec3::cst(0.1, 0.0, 0.0));
        // The pivot only moves by the translation.
        let p = g.point_to_global(pivot);
        assert!((p.x - 0.1).abs() < 1e-15 && p.y.abs() < 1e-15 && (p.z - 5.0).abs() < 1e-14);
        let q = Vec3::cst(1.0, -2.0, 7.0);
        let back = g.point_to_local(g.point_to_global(q));
        assert!((back - q).norm() < 1e-13);
        // R^T R = I
        let i = r.transpose() * r;
        for (k, row) in i.rows.iter().enumerate() {
            let e = [row.x, row.y, row.z];
            for (j, v) in e.iter().enumerate() {
                assert!((v - if j == k { 1.0 } else { 0.0 }).abs() < 1e-15);
            }
        }
    }
}
