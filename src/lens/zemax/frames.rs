//! Coordinate breaks and fold mirrors: the frames a .zmx file's surfaces sit in, walked surface by surface.

use super::*;

pub(super) fn rotation_xyz_deg(a: f64, b: f64, g: f64) -> Mat3<f64> {
    crate::lens::system::rotation_xyz_deg([a, b, g])
}

/// The rotation of a coordinate break (PARM 3..5 degrees; PARM 6 = 0: about x, the new y, the
/// new z; otherwise about z, the new y, the new x).
pub(super) fn cb_rotation(s: &RawSurf) -> Mat3<f64> {
    let (a, b, g) = (s.parm(3), s.parm(4), s.parm(5));
    if s.parm(6) == 0.0 {
        rotation_xyz_deg(a, b, g)
    } else {
        Mat3::from_tilt_deg(a, b, g)
    }
}

/// A mirror tilted by this much or more against the axis is a fold mirror (the axis of the
/// surfaces after it turns with the reflection) whatever the coordinate breaks after it say; a
/// mirror tilted less is one when the file's frame after it follows the reflected axis
/// (`Walker::follows_reflection`: an off-axis mirror written as OpticStudio writes a fold), and
/// otherwise a tilted mirror on the axis (a tolerance tilt, say).
pub(super) const FOLD_MIN_DEG: f64 = 20.0;

/// The rotation turning the unit vector `u` onto the unit vector `v` by the shortest arc
/// (`None` when they are opposite).
pub(super) fn turn_onto(u: Vec3<f64>, v: Vec3<f64>) -> Option<Mat3<f64>> {
    let k = u.cross(v);
    let (s, c) = (k.norm(), u.dot(v));
    if s <= 1e-12 {
        return (c > 0.0).then(Mat3::identity);
    }
    let k = k * (1.0 / s);
    // Rodrigues: R = I + sin K + (1 - cos) K², K the cross-product matrix of the unit axis.
    let kk = [[0.0, -k.z, k.y], [k.z, 0.0, -k.x], [-k.y, k.x, 0.0]];
    let mut rows = [[0.0; 3]; 3];
    for (i, row) in rows.iter_mut().enumerate() {
        for (j, e) in row.iter_mut().enumerate() {
            let k2: f64 = (0..3).map(|m| kk[i][m] * kk[m][j]).sum();
            *e = f64::from(u8::from(i == j)) + s * kk[i][j] + (1.0 - c) * k2;
        }
    }
    Some(Mat3 {
        rows: rows.map(|r| Vec3::cst(r[0], r[1], r[2])),
    })
}

/// The rotation of an OpticStudio tilted surface (`TILTSURF`, the plane z = x tan θx + y tan θy
/// of its frame, PARM 1 = tan θx, PARM 2 = tan θy) against its frame: the shortest arc turning +z
/// onto the plane's normal (-tan θx, -tan θy, 1) / norm. The frame itself does not change.
pub(super) fn tilted_surface_rotation(tangents: [f64; 2]) -> Mat3<f64> {
    let n = Vec3::cst(-tangents[0], -tangents[1], 1.0).normalized();
    // The normal has a positive z, so the arc exists.
    turn_onto(Vec3::cst(0.0, 0.0, 1.0), n).unwrap_or_else(Mat3::identity)
}

/// The frame `rot` and axis `axis` of a surface, turned by a `TILTSURF`'s tangents when it has
/// them ([`tilted_surface_rotation`]).
fn tilt_frame(
    rot: Mat3<f64>,
    axis: Vec3<f64>,
    tangents: Option<[f64; 2]>,
) -> (Mat3<f64>, Vec3<f64>) {
    match tangents {
        Some(t) => {
            let r = snap(rot * tilted_surface_rotation(t));
            (r, r.apply(Vec3::cst(0.0, 0.0, 1.0)))
        }
        None => (rot, axis),
    }
}

/// A `TILTSURF` surface's tangents (PARM 1 and 2); other parameters are refused, as is an angle
/// that is not finite.
fn tilt_tangents(s: &RawSurf) -> Result<[f64; 2]> {
    let mut t = [0.0; 2];
    for &(p, v, line) in &s.parm {
        match p {
            1 | 2 if v.is_finite() && v.abs() <= 1e6 => t[p - 1] = v,
            1 | 2 => {
                return Err(invalid(
                    line,
                    format!("PARM {p} = {v}: a tilted surface's tangent must be finite (within ±1e6)"),
                ))
            }
            _ if v != 0.0 => {
                return Err(invalid(
                    line,
                    format!("PARM {p} = {v}: a tilted surface (TILTSURF) has the tangents of its x and y angles (PARM 1 and 2) only"),
                ))
            }
            _ => {}
        }
    }
    Ok(t)
}

/// The tilts about x, the new y and the new z (degrees, `Rx(a) Ry(b) Rz(g)`) of a rotation.
pub(super) fn angles_of(r: &Mat3<f64>) -> [f64; 3] {
    // Rx(a) Ry(b) Rz(g) has third column (sin b, -sin a cos b, cos a cos b) and first row
    // (cos b cos g, -cos b sin g, sin b).
    let b = r.rows[0].z.clamp(-1.0, 1.0).asin();
    let a = (-r.rows[1].z).atan2(r.rows[2].z);
    let g = (-r.rows[0].y).atan2(r.rows[0].x);
    // (+ 0.0 turns a negative zero into zero.)
    [
        a.to_degrees() + 0.0,
        b.to_degrees() + 0.0,
        g.to_degrees() + 0.0,
    ]
}

/// Snaps a rotation within 1e-12 of the identity to it, so that a coordinate break and its exact
/// reverse leave no rounding residue.
pub(super) fn snap(r: Mat3<f64>) -> Mat3<f64> {
    let i = Mat3::<f64>::identity();
    let close = r.rows.iter().zip(i.rows.iter()).all(|(a, b)| {
        (a.x - b.x).abs() <= 1e-12 && (a.y - b.y).abs() <= 1e-12 && (a.z - b.z).abs() <= 1e-12
    });
    if close {
        i
    } else {
        r
    }
}

pub(super) fn finite_frame(o: &Vec3<f64>, r: &Mat3<f64>) -> bool {
    [o.x, o.y, o.z].iter().all(|v| v.is_finite())
        && r.rows
            .iter()
            .all(|v| v.x.is_finite() && v.y.is_finite() && v.z.is_finite())
}

pub(super) fn is_identity(r: &Mat3<f64>) -> bool {
    *r == Mat3::identity()
}

impl Walker {
    pub(super) fn axis(&self) -> Vec3<f64> {
        self.rot.apply(Vec3::cst(0.0, 0.0, 1.0))
    }

    /// The travel since the last surface along the leg's axis, with residues of the frames'
    /// rotations (under 1e-12 mm) dropped: a surface written at the previous one's vertex
    /// reads back at a gap of exactly 0 (not ±4e-16, whose sign would send rays either way).
    pub(super) fn gap(&self) -> f64 {
        if self.pending.abs() <= 1e-12 {
            0.0
        } else {
            self.pending
        }
    }

    /// Moves the origin by `d` (global) and counts its axial part (along the leg's axis).
    pub(super) fn shift(&mut self, d: Vec3<f64>) {
        self.origin = self.origin + d;
        self.pending += self.leg_rot.apply_t(d).z;
    }

    /// The current frame in unfolded coordinates: origin, axes and axis. Tiny residues of a
    /// fold's turn (under 1e-12) are dropped, so a surface on the folded axis is untilted.
    pub(super) fn unfolded(&self) -> (Vec3<f64>, Mat3<f64>, Vec3<f64>) {
        if !self.folded {
            return (self.origin, self.rot, self.axis());
        }
        let tiny = |v: f64| if v.abs() <= 1e-12 { 0.0 } else { v };
        let o = self.leg_rot.apply_t(self.origin - self.leg_t);
        let r = snap(self.leg_rot.transpose() * self.rot);
        let a = r.apply(Vec3::cst(0.0, 0.0, 1.0));
        (Vec3::cst(tiny(o.x), tiny(o.y), o.z), r, a)
    }

    /// After the fold mirror just placed (tilted by [`FOLD_MIN_DEG`] or more against the leg's
    /// axis): the axis turns by the mirror's reflection of it, about the mirror's point on the
    /// axis. Returns the fold kept on the mirror.
    pub(super) fn fold(&mut self, n: Vec3<f64>, dir_before: f64) -> Option<crate::lens::Fold> {
        let n = n.normalized();
        let d_in = Vec3::cst(0.0, 0.0, dir_before);
        let v = d_in - n * (2.0 * d_in.dot(n));
        let u = Vec3::cst(0.0, 0.0, -dir_before);
        let r = crate::lens::system::clean_rotation(turn_onto(u, v)?);
        let fold = crate::lens::Fold {
            tilt_deg: angles_of(&r),
            pivot_mm: 0.0,
        };
        let r = fold.rotation();
        let z = self.leg_rot.apply_t(self.origin - self.leg_t).z;
        let p = Vec3::cst(0.0, 0.0, z);
        self.leg_t = self.leg_t + self.leg_rot.apply(p - r.apply(p));
        self.leg_rot = self.leg_rot * r;
        self.folded = true;
        // The travel to the next surface counts from the fold's pivot: a mirror off the axis
        // lies off the pivot along the turned axis too.
        self.pending = self.leg_rot.apply_t(self.origin - self.leg_t).z - z;
        Some(fold)
    }

    /// True when the mirror with unfolded normal `n` is tilted against the leg's axis and the
    /// file's frame `frame_after` (global) after it has its z axis along the reflected light,
    /// against the direction of travel after the mirror, as thicknesses after a mirror are
    /// negative.
    pub(super) fn follows_reflection(&self, n: Vec3<f64>, frame_after: Mat3<f64>) -> bool {
        let n = n.normalized();
        if n.z.abs() >= 1.0 - 1e-15 {
            return false;
        }
        let d_in = Vec3::cst(0.0, 0.0, self.dir);
        let v = d_in - n * (2.0 * d_in.dot(n));
        let after = self
            .leg_rot
            .apply_t(frame_after.apply(Vec3::cst(0.0, 0.0, 1.0)));
        (v + after * self.dir).norm() <= 1e-9
    }

    /// Travels `t` mm along the current z axis.
    pub(super) fn travel(&mut self, t: f64, line: usize) -> Result<()> {
        self.shift(self.axis() * t);
        if !finite_frame(&self.origin, &self.rot) || !self.pending.is_finite() {
            return Err(invalid(
                line,
                "this moves the coordinate system to infinity",
            ));
        }
        Ok(())
    }

    pub(super) fn coordinate_break(
        &mut self,
        s: &RawSurf,
        warnings: &mut Vec<String>,
    ) -> Result<()> {
        if let Some(l) = s.stop {
            return Err(invalid(l, "a coordinate break cannot be the stop"));
        }
        if let Some(g) = &s.glas {
            warnings.push(format!(
                "line {}: GLAS on a coordinate break ignored (the medium continues)",
                g.line
            ));
        }
        let decenter = Vec3::cst(s.parm(1) * self.scale, s.parm(2) * self.scale, 0.0);
        if s.parm(6) == 0.0 {
            // Decenter, then tilt about x, the new y, the new z.
            self.shift(self.rot.apply(decenter));
            self.rot = snap(self.rot * cb_rotation(s));
        } else {
            // Tilt about z, the new y, the new x, then decenter.
            self.rot = snap(self.rot * cb_rotation(s));
            self.shift(self.rot.apply(decenter));
        }
        self.last_cb_line = Some(s.type_line());
        self.travel(s.thickness()? * self.scale, s.type_line())
    }

    /// The Forbes polynomials of a `QED_TYPE` surface (OpticStudio's Q-type asphere) into
    /// `asph`: XDAT 1 the type (0: Qbfs, 1: Qcon; others are refused), XDAT 2 the number of terms,
    /// XDAT 3 the normalization radius, XDAT 4.. the coefficients a_0, a_1, ... (lens units).
    pub(super) fn q_type(
        &self,
        s: &RawSurf,
        asph: &mut [f64; N_ASPH],
        warnings: &mut Vec<String>,
    ) -> Result<Shape> {
        let get = |n: usize| s.xdat.iter().rev().find(|x| x.0 == n);
        let line_of = |n: usize| get(n).map_or(s.type_line(), |x| x.2);
        let value = |n: usize| get(n).map_or(0.0, |x| x.1);
        let ty = value(1);
        if ty != 0.0 && ty != 1.0 {
            return Err(invalid(
                line_of(1),
                format!(
                    "XDAT 1 = {ty}: Q-type asphere type {ty}; tolray reads type 0 (Forbes' Qbfs polynomials) and type 1 (Qcon), each on a conic"
                ),
            ));
        }
        let terms = value(2);
        if !((0.0..=1000.0).contains(&terms) && terms.fract() == 0.0) {
            return Err(invalid(
                line_of(2),
                format!("XDAT 2 = {terms}: the number of Q terms must be a whole number"),
            ));
        }
        let terms = terms as usize;
        let norm = value(3) * self.scale;
        for m in 0..terms {
            let v = value(4 + m);
            if m >= N_ASPH {
                if v != 0.0 {
                    return Err(invalid(
                        line_of(4 + m),
                        format!(
                            "XDAT {} = {v}: Q term a_{m}; tolray traces Q terms a_0 to a_{}",
                            4 + m,
                            N_ASPH - 1
                        ),
                    ));
                }
                continue;
            }
            // A departure: lens units to mm.
            asph[m] = v * self.scale;
        }
        if asph.iter().any(|&a| a != 0.0) && !(norm > 0.0 && norm.is_finite()) {
            return Err(invalid(
                line_of(3),
                format!(
                    "XDAT 3 = {}: the Q terms need a positive normalization radius",
                    value(3)
                ),
            ));
        }
        if let Some(&(n, v, line)) = s.xdat.iter().find(|x| x.0 >= 4 + terms && x.1 != 0.0) {
            warnings.push(format!(
                "line {line}: XDAT {n} = {v} ignored: beyond the {terms} Q terms of XDAT 2"
            ));
        }
        let norm_radius_mm = if norm > 0.0 { norm } else { 1.0 };
        Ok(if ty == 0.0 {
            Shape::Qbfs { norm_radius_mm }
        } else {
            Shape::Qcon { norm_radius_mm }
        })
    }

    /// The Zernike terms of an `FZERNSAG` or `SZERNSAG` surface: XDAT 1 the number of terms,
    /// XDAT 2 the normalization radius, XDAT 3.. the coefficients of Z1, Z2, ... (lens units).
    /// Returns the coefficients (mm) and the normalization radius (mm).
    pub(super) fn zernike_terms(
        &self,
        s: &RawSurf,
        ordering: crate::math::zernike::Ordering,
        warnings: &mut Vec<String>,
    ) -> Result<(Vec<f64>, f64)> {
        let get = |n: usize| s.xdat.iter().rev().find(|x| x.0 == n);
        let line_of = |n: usize| get(n).map_or(s.type_line(), |x| x.2);
        let value = |n: usize| get(n).map_or(0.0, |x| x.1);
        let max = ordering.max_terms();
        let terms = value(1);
        if !((0.0..=max as f64).contains(&terms) && terms.fract() == 0.0) {
            return Err(invalid(
                line_of(1),
                format!(
                    "XDAT 1 = {terms}: the number of Zernike terms must be a whole number from 0 to {max}"
                ),
            ));
        }
        let terms = terms as usize;
        let a: Vec<f64> = (0..terms).map(|j| value(3 + j) * self.scale).collect();
        let norm = value(2) * self.scale;
        if !(norm > 0.0 && norm.is_finite()) && a.iter().any(|&v| v != 0.0) {
            {
                return Err(invalid(
                    line_of(2),
                    format!(
                        "XDAT 2 = {}: the Zernike terms need a positive normalization radius",
                        value(2)
                    ),
                ));
            }
        }
        if let Some(&(n, v, line)) = s.xdat.iter().find(|x| x.0 >= 3 + terms && x.1 != 0.0) {
            warnings.push(format!(
                "line {line}: XDAT {n} = {v} ignored: beyond the {terms} Zernike terms of XDAT 1"
            ));
        }
        Ok((
            a,
            if norm > 0.0 && norm.is_finite() {
                norm
            } else {
                1.0
            },
        ))
    }

    /// The phase of a `BINARY_2` surface (OpticStudio's Binary 2): the diffraction order `order`
    /// (PARM 0; missing, 0, with a warning: the phase is off), XDAT 1 the number of terms,
    /// XDAT 2 the normalization radius (lens units), XDAT 3.. the coefficients A_1, A_2, ...
    /// (radians, whatever the lens unit).
    pub(super) fn binary_phase(
        &self,
        s: &RawSurf,
        order: Option<f64>,
        warnings: &mut Vec<String>,
    ) -> Result<crate::lens::phase::RadialPhase> {
        use crate::lens::phase::{RadialPhase, MAX_PHASE_TERMS};
        let get = |n: usize| s.xdat.iter().rev().find(|x| x.0 == n);
        let line_of = |n: usize| get(n).map_or(s.type_line(), |x| x.2);
        let value = |n: usize| get(n).map_or(0.0, |x| x.1);
        let terms = value(1);
        if !((0.0..=MAX_PHASE_TERMS as f64).contains(&terms) && terms.fract() == 0.0) {
            return Err(invalid(
                line_of(1),
                format!(
                    "XDAT 1 = {terms}: the number of phase terms must be a whole number from 0 to {MAX_PHASE_TERMS}"
                ),
            ));
        }
        let terms = terms as usize;
        let coefficients: Vec<f64> = (0..terms).map(|j| value(3 + j)).collect();
        let norm = value(2) * self.scale;
        let any = coefficients.iter().any(|&a| a != 0.0);
        if !(norm > 0.0 && norm.is_finite()) && any {
            return Err(invalid(
                line_of(2),
                format!(
                    "XDAT 2 = {}: the phase terms need a positive normalization radius",
                    value(2)
                ),
            ));
        }
        if let Some(&(n, v, line)) = s.xdat.iter().find(|x| x.0 >= 3 + terms && x.1 != 0.0) {
            warnings.push(format!(
                "line {line}: XDAT {n} = {v} ignored: beyond the {terms} phase terms of XDAT 1"
            ));
        }
        if order.is_none() && any {
            warnings.push(format!(
                "line {}: the BINARY_2 surface has no diffraction order (PARM 0): order 0, its phase off, as in OpticStudio",
                s.type_line()
            ));
        }
        Ok(RadialPhase {
            order: order.unwrap_or(0.0),
            norm_radius_mm: if norm > 0.0 && norm.is_finite() {
                norm
            } else {
                1.0
            },
            coefficients,
        })
    }

    /// A STANDARD or EVENASPH surface: a lens surface, or a dummy that only moves the frame.
    ///
    /// `frame_after`: the file's frame after the coordinate breaks that follow the surface
    /// (global), which tells whether a tilted mirror is a fold mirror.
    pub(super) fn surface(
        &mut self,
        k: usize,
        s: &RawSurf,
        frame_after: Mat3<f64>,
        catalogs: &GlassCatalogs,
        warnings: &mut Vec<String>,
    ) -> Result<()> {
        let ty = s.type_name();
        let scale = self.scale;
        // A tilted surface is a plane: its tangents turn it against its frame, below.
        let tilted = ty == "TILTSURF";
        let tangents = if tilted {
            Some(tilt_tangents(s)?)
        } else {
            None
        };
        let c = if tilted {
            0.0
        } else {
            s.curv.as_ref().map_or(0.0, |c| c.v) / scale
        };
        let mut asph = [0.0; N_ASPH];
        let mut shape = Shape::Even;
        let mut grating = Grating {
            lines_per_um: 0.0,
            order: 0.0,
        };
        let zernike_sag = ty == "FZERNSAG" || ty == "SZERNSAG";
        let mut zernike = Vec::new();
        // BINARY_2: PARM 0, the diffraction order.
        let mut order = None;
        let mut phase = None;
        // PARM 0: extrapolate beyond the normalization radius (OpticStudio's default, 1);
        // PARM 9 and 10: the Zernike decenter.
        let (mut extrapolate, mut decenter_mm) = (true, [0.0; 2]);
        // GRINSUR1 to 3: PARM 1 to 8 (Δt, n0, then the coefficients), in mm.
        let grin = matches!(ty.as_str(), "GRINSUR1" | "GRINSUR2" | "GRINSUR3");
        let mut grin_parm = [0.0; 9];
        for &(p, v, line) in &s.parm {
            match ty.as_str() {
                "TILTSURF" => {}
                "GRINSUR1" if p == 4 && v != 0.0 => {
                    return Err(invalid(
                        line,
                        format!(
                        "PARM 4 = {v}: tolray reads Gradient 1's n0 + nr2 r², not the r term nr1"
                    ),
                    ))
                }
                "GRINSUR1" if (1..=3).contains(&p) => {
                    grin_parm[p] = grin_in_mm(ty.as_str(), p, v, scale);
                }
                "GRINSUR2" | "GRINSUR3" if (1..=8).contains(&p) => {
                    grin_parm[p] = grin_in_mm(ty.as_str(), p, v, scale);
                }
                "FZERNSAG" | "SZERNSAG" if p == 0 => {
                    if v != 0.0 && v != 1.0 {
                        return Err(invalid(
                            line,
                            format!("PARM 0 = {v}: Extrapolate is 0 or 1"),
                        ));
                    }
                    extrapolate = v != 0.0;
                }
                "FZERNSAG" | "SZERNSAG" if (1..=N_ASPH).contains(&p) => {
                    // α_p ρ^{2p} on the raw radius, as EVENASPH.
                    asph[p - 1] = v * scale.powi(1 - 2 * p as i32);
                }
                "FZERNSAG" | "SZERNSAG" if p == 9 || p == 10 => decenter_mm[p - 9] = v * scale,
                "BINARY_2" if p == 0 => order = Some(v),
                "BINARY_2" if (1..=N_ASPH).contains(&p) => {
                    // α_p ρ^{2p}, as EVENASPH.
                    asph[p - 1] = v * scale.powi(1 - 2 * p as i32);
                }
                "EVENASPH" if (1..=N_ASPH).contains(&p) => {
                    // a_{2p} ρ^{2p}: lens units^{1-2p} to mm^{1-2p}.
                    asph[p - 1] = v * scale.powi(1 - 2 * p as i32);
                }
                "ODDASPHE" if (1..=N_ASPH).contains(&p) => {
                    // β_p ρ^p: lens units^{1-p} to mm^{1-p}.
                    shape = Shape::Odd;
                    asph[p - 1] = v * scale.powi(1 - p as i32);
                }
                "TOROIDAL" if p == 1 => {
                    // The radius of rotation; 0 means none (a cylinder).
                    let r = v * scale;
                    let c_rot = if r == 0.0 { 0.0 } else { 1.0 / r };
                    if !c_rot.is_finite() {
                        return Err(invalid(line, format!("PARM 1 = {v}: radius of rotation")));
                    }
                    shape = Shape::Toroidal { c_rot };
                }
                "PARAXIAL" if p == 1 => {
                    if v == 0.0 {
                        return Err(invalid(
                            line,
                            "PARM 1 = 0: a PARAXIAL surface needs a focal length",
                        ));
                    }
                    shape = Shape::Paraxial {
                        focal_mm: v * scale,
                    };
                }
                // The OPD mode changes how OpticStudio computes optical path, not rays.
                "PARAXIAL" if p == 2 => {}
                // Lines per µm (whatever the lens unit) and the diffraction order.
                "DGRATING" if p == 1 => grating.lines_per_um = v,
                "DGRATING" if p == 2 => grating.order = v,
                "TOROIDAL" if (2..=N_ASPH).contains(&p) => {
                    // α_{p-1} y^{2(p-1)}.
                    let j = p - 1;
                    asph[j - 1] = v * scale.powi(1 - 2 * j as i32);
                }
                _ if v != 0.0 => {
                    let what = match ty.as_str() {
                        "EVENASPH" => "tolray reads even-asphere terms r^2 to r^16 (PARM 1 to 8)",
                        "ODDASPHE" => "tolray reads odd-asphere terms r^1 to r^8 (PARM 1 to 8)",
                        "TOROIDAL" => {
                            "tolray reads the radius of rotation (PARM 1) and y^2 to y^14 (PARM 2 to 8)"
                        }
                        "PARAXIAL" => "a PARAXIAL surface has a focal length (PARM 1) and an OPD mode (PARM 2)",
                        "DGRATING" => "a DGRATING surface has lines per µm (PARM 1) and an order (PARM 2)",
                        "QED_TYPE" => "a Q-type surface keeps its data in XDAT",
                        "FZERNSAG" | "SZERNSAG" => "tolray reads Extrapolate (PARM 0), r^2 to r^16 (PARM 1 to 8) and the Zernike decenter (PARM 9, 10)",
                        "BINARY_2" => "tolray reads the diffraction order (PARM 0) and r^2 to r^16 (PARM 1 to 8)",
                        "GRINSUR1" => "a Gradient 1 surface has Δt, n0 and nr2 (PARM 1 to 3)",
                        "GRINSUR2" | "GRINSUR3" => "a Gradient 2 or 3 surface has Δt, n0 and six coefficients (PARM 1 to 8)",
                        _ => "a STANDARD surface has no parameters",
                    };
                    warnings.push(format!("line {line}: PARM {p} = {v} ignored: {what}"));
                }
                _ => {}
            }
        }
        if ty == "ODDASPHE" {
            shape = Shape::Odd;
        }
        if ty == "PARAXIAL" {
            if !matches!(shape, Shape::Paraxial { .. }) {
                return Err(invalid(
                    s.type_line(),
                    "a PARAXIAL surface needs its focal length (PARM 1)",
                ));
            }
            if c != 0.0 || s.coni.as_ref().is_some_and(|k| k.v != 0.0) {
                let l = s.curv.as_ref().map_or(s.line, |c| c.line);
                return Err(invalid(
                    l,
                    "a PARAXIAL surface is flat (CURV and CONI must be 0)",
                ));
            }
        }
        if ty == "TOROIDAL" {
            if !matches!(shape, Shape::Toroidal { .. }) {
                shape = Shape::Toroidal { c_rot: 0.0 };
            }
            // XDAT 1: the number of Zernike terms, XDAT 2: their normalization radius, XDAT 3..:
            // the coefficients.
            let terms = s.xdat.iter().rev().find(|x| x.0 == 1).map_or(0.0, |x| x.1);
            if let Some(&(n, v, line)) = s.xdat.iter().find(|x| x.0 >= 3 && x.1 != 0.0) {
                if terms > 0.0 {
                    return Err(invalid(
                        line,
                        format!(
                            "XDAT {n} = {v}: a Zernike term on a TOROIDAL surface; tolray traces toroids without Zernike terms"
                        ),
                    ));
                }
            }
        } else if ty == "QED_TYPE" {
            shape = self.q_type(s, &mut asph, warnings)?;
        } else if ty == "BINARY_2" {
            phase = Some(self.binary_phase(s, order, warnings)?);
        } else if zernike_sag {
            let ordering = if ty == "FZERNSAG" {
                crate::math::zernike::Ordering::Fringe
            } else {
                crate::math::zernike::Ordering::Standard
            };
            let (terms, norm_radius_mm) = self.zernike_terms(s, ordering, warnings)?;
            zernike = terms;
            shape = Shape::Zernike {
                ordering,
                norm_radius_mm,
                decenter_mm,
                extrapolate,
            };
        } else if let Some(&(n, v, line)) = s.xdat.iter().find(|x| x.1 != 0.0) {
            warnings.push(format!(
                "line {line}: XDAT {n} = {v} (extra surface data) ignored: a {ty} surface has none tolray reads"
            ));
        }
        let mirror = s.glas.as_ref().is_some_and(|g| {
            g.v.first()
                .is_some_and(|n| n.eq_ignore_ascii_case("MIRROR"))
        });
        // A mirror sends the light back through the medium it came in.
        let material = match &s.glas {
            _ if mirror && grin => {
                return Err(invalid(
                    s.type_line(),
                    format!("SURF {k}: a mirror cannot start a gradient-index medium ({ty})"),
                ))
            }
            _ if mirror => self.medium.clone(),
            // The medium is the type's (Gradient 1 to 3 have no dispersion: any glass is unused).
            _ if grin => {
                let g = super::super::Gradient::from_zemax(&ty, &grin_parm)
                    .expect("a GRINSUR type tolray reads");
                if let Some(gl) = s.glas.as_ref().filter(|g| !g.v.is_empty()) {
                    warnings.push(format!(
                        "line {}: GLAS {} ignored: a {ty} surface's index is its own (n0 = {})",
                        gl.line, gl.v[0], g.n0
                    ));
                }
                g.validate().map_err(|e| {
                    invalid(
                        s.type_line(),
                        format!("SURF {k} ({ty}): {}", e.full_message()),
                    )
                })?;
                Material::Gradient(Box::new(g))
            }
            Some(g) => glass(&g.v, g.line, catalogs, warnings)?,
            None => Material::Air,
        };
        let diam = s.diam.as_ref().map(|d| (d.v.0 * scale, d.v.1));
        let aperture = s.hard_aperture(scale)?;
        let dummy = ty == "STANDARD"
            && !mirror
            && c == 0.0
            && s.stop.is_none()
            && material == self.medium
            && aperture.is_none()
            && !diam.is_some_and(|d| d.1);
        if tilted {
            for (what, v, l) in [
                ("CURV", s.curv.as_ref().map(|c| (c.v, c.line))),
                ("CONI", s.coni.as_ref().map(|k| (k.v, k.line))),
            ]
            .into_iter()
            .filter_map(|(w, x)| x.map(|(v, l)| (w, v, l)))
            {
                if v != 0.0 {
                    warnings.push(format!(
                        "line {l}: {what} {v} ignored: a tilted surface (TILTSURF) is a plane, as in OpticStudio"
                    ));
                }
            }
            if let Some(t) = tangents.filter(|_| aperture.is_some()) {
                let slope = t[0].hypot(t[1]);
                warnings.push(format!(
                    "line {}: the hard aperture of a tilted surface (TILTSURF) is applied in the tilted plane, OpticStudio's in its x-y frame: along the tilt, tolray's clips {:.3} % closer to the axis",
                    s.aperture.as_ref().map_or(s.line, |x| x.line),
                    100.0 * (1.0 - 1.0 / (1.0 + slope * slope).sqrt())
                ));
            }
        }
        if !dummy {
            let (origin, rot, axis) = self.unfolded();
            // A tilted surface turns against its frame, which the surfaces after it keep.
            let (rot, axis) = tilt_frame(rot, axis, tangents);
            if let Some(t) = tangents.filter(|_| mirror) {
                let deg = t[0].hypot(t[1]).atan().to_degrees();
                if deg >= FOLD_MIN_DEG {
                    return Err(invalid(
                        s.type_line(),
                        format!("SURF {k} is a mirror tilted {deg:.1} degrees by TILTSURF, which keeps the frame; tolray turns the axis at a mirror tilted {FOLD_MIN_DEG} degrees or more: write it as coordinate break, mirror, coordinate break, as OpticStudio advises for fold mirrors"),
                    ));
                }
            }
            if axis.z <= 1e-9 {
                return Err(invalid(
                    s.line,
                    format!(
                        "SURF {k} is turned by 90 degrees or more against the axis by coordinate breaks; tolray turns the axis only at a fold mirror (a mirror tilted {FOLD_MIN_DEG} degrees or more)"
                    ),
                ));
            }
            // (Before the first surface, a negative travel is a virtual object's distance.)
            if self.gap() * self.dir < 0.0 && !self.built.is_empty() {
                return Err(invalid(
                    s.line,
                    format!(
                        "SURF {k} lies {} mm before the previous surface along the light's path; tolray needs the surfaces in order along the axis (thicknesses are negative after a mirror)",
                        self.pending.abs()
                    ),
                ));
            }
            let gap = self.gap();
            match self.built.last_mut() {
                Some(prev) => prev.surface.d_next_mm = gap,
                None => {
                    self.object_gap = Some(gap);
                    self.first_vertex = self.origin;
                    self.leg_t = Vec3::cst(0.0, 0.0, self.origin.z);
                }
            }
            self.pending = 0.0;
            if let Some(l) = s.stop {
                if let Some(first) = self.stop_line {
                    return Err(invalid(
                        l,
                        format!("a second STOP (the first is at line {first})"),
                    ));
                }
                self.stop_line = Some(l);
            }
            // The semi-diameter: DIAM, else MEMA, else a floating aperture's own value (FLAP's
            // second number); surfaces without one get the paraxial beam's size later.
            let flap = s
                .aperture
                .as_ref()
                .filter(|a| a.v.0 == "FLAP")
                .and_then(|a| a.v.1.get(1))
                .map(|r| r * scale);
            let semi = diam
                .map(|d| d.0)
                .filter(|&d| d > 0.0)
                .or_else(|| s.mema.as_ref().map(|m| m.v * scale).filter(|&m| m > 0.0))
                .or(flap.filter(|&r| r > 0.0));
            let is_stop = s.stop.is_some();
            // A flat stop in air is a bare aperture (DeepLens' "Aperture").
            let role = if mirror {
                SurfaceRole::Mirror
            } else if is_stop
                && ty == "STANDARD"
                && c == 0.0
                && self.medium.is_air()
                && material.is_air()
            {
                SurfaceRole::Aperture
            } else {
                SurfaceRole::Refractive
            };
            let vec_local = if is_identity(&rot) {
                [0.0, 0.0, 1.0]
            } else {
                [axis.x, axis.y, axis.z]
            };
            let mut surface = Surface {
                role,
                c,
                k: if tilted {
                    0.0
                } else {
                    s.coni.as_ref().map_or(0.0, |c| c.v)
                },
                asph,
                shape,
                semi_aperture_mm: semi.unwrap_or(0.0),
                aperture,
                d_next_mm: 0.0,
                material: material.clone(),
                is_stop,
                pos_xy_mm: [origin.x, origin.y],
                vec_local,
                roll_deg: 0.0,
                grating: (ty == "DGRATING").then_some(grating),
                fold: None,
                zernike: zernike.clone(),
                phase: phase.clone(),
            };
            // A coordinate break that rolls the frame about the surface's axis matters where
            // the surface is not symmetric about it (toroid, grating, a non-circular or
            // decentred aperture); elsewhere it changes nothing and is dropped.
            let roll = crate::lens::system::roll_of(&rot, surface.vec_local);
            if roll != 0.0 && !surface.is_axially_symmetric() {
                surface.roll_deg = roll;
            }
            // A mirror tilted far enough against the axis is a fold mirror, and so is any
            // tilted mirror after which the file's frame follows the reflected axis (OpticStudio's
            // coordinate break, mirror, coordinate break): the surfaces after it are placed on
            // the reflected axis, so the unfolded model's gaps are the file's thicknesses and
            // its paraxial model that of OpticStudio, which ignores the coordinate breaks.
            if mirror
                && (axis.z < FOLD_MIN_DEG.to_radians().cos()
                    || self.follows_reflection(axis, frame_after))
            {
                surface.fold = self.fold(axis, self.dir);
                if surface.fold.is_none() {
                    return Err(invalid(
                        s.line,
                        format!("SURF {k} is a mirror at grazing incidence to the axis"),
                    ));
                }
            }
            self.built.push(Built {
                surface,
                raw: s.clone(),
                index: k,
                has_diam: semi.is_some(),
            });
            if mirror {
                self.dir = -self.dir;
            }
        }
        self.medium = material;
        let line = s.disz.as_ref().map_or(s.line, |d| d.line);
        self.travel(s.thickness()? * scale, line)
    }

    /// The image surface closes the last gap and gives the sensor's half-diagonal (`None`
    /// without a `DIAM`: the caller sizes it by the fields).
    pub(super) fn image(&mut self, img: &RawSurf) -> Result<Option<f64>> {
        let ty = img.type_name();
        if !matches!(ty.as_str(), "STANDARD" | "EVENASPH" | "TILTSURF") {
            return Err(invalid(
                img.type_line(),
                format!("image surface type {ty} is not supported: the image is a plane or a conic (STANDARD, EVENASPH without terms) or a tilted plane (TILTSURF)"),
            ));
        }
        let tangents = if ty == "TILTSURF" {
            Some(tilt_tangents(img)?)
        } else {
            None
        };
        if let Some(&(_, _, l)) = img.parm.iter().find(|p| ty == "EVENASPH" && p.1 != 0.0) {
            return Err(invalid(
                l,
                "the image surface has asphere terms; tolray's image surface is a plane or a conic",
            ));
        }
        // A curved image surface: a conic about the image frame's axis.
        let (curvature_per_mm, conic) = if tangents.is_some() {
            (0.0, 0.0)
        } else {
            (
                img.curv.as_ref().map_or(0.0, |c| c.v) / self.scale,
                img.coni.as_ref().map_or(0.0, |k| k.v),
            )
        };
        if !(curvature_per_mm.abs() <= 1000.0 && conic.abs() <= 1e6) {
            let l = img.curv.as_ref().map_or(img.line, |c| c.line);
            return Err(invalid(
                l,
                format!("the image surface's curvature {curvature_per_mm} 1/mm (within ±1000) or conic {conic} (within ±1e6) is out of range"),
            ));
        }
        if let Some(l) = img.stop {
            return Err(invalid(l, "the image surface cannot be the stop"));
        }
        // A tilted, rolled or decentred image plane keeps its pose (in the current leg of the
        // axis); one turned by 90 degrees or more against that leg is not a plane the light
        // reaches along it.
        let (origin, rot, axis) = self.unfolded();
        let (rot, axis) = tilt_frame(rot, axis, tangents);
        if axis.z <= 1e-9 {
            return Err(invalid(
                self.last_cb_line.unwrap_or(img.line),
                format!("the image plane is turned by 90 degrees or more against the axis by coordinate breaks (the last one is here); tolray turns the axis only at a fold mirror (a mirror tilted {FOLD_MIN_DEG} degrees or more)"),
            ));
        }
        let normal = if is_identity(&rot) {
            [0.0, 0.0, 1.0]
        } else {
            [axis.x, axis.y, axis.z]
        };
        self.image_plane = ImagePlane {
            decenter_mm: [origin.x, origin.y],
            normal,
            roll_deg: crate::lens::system::roll_of(&rot, normal),
            curvature_per_mm,
            conic,
        };
        // An image surface before the last lens surface along the light's path is a virtual
        // image (OpticStudio's negative image thickness): the rays are extended backwards to it.
        let gap = self.gap();
        let Some(last) = self.built.last_mut() else {
            return Err(Error::invalid(
                "the file has no lens surface between the object and the image",
            ));
        };
        last.surface.d_next_mm = gap;
        let r_sensor = img.diam.as_ref().map_or(0.0, |d| d.v.0 * self.scale);
        if r_sensor < 0.0 || !r_sensor.is_finite() {
            return Err(invalid(
                img.diam.as_ref().map_or(img.line, |d| d.line),
                format!("the image semi-diameter (DIAM) {r_sensor} mm must be positive"),
            ));
        }
        Ok((r_sensor > 0.0).then_some(r_sensor))
    }
}

/// A Gradient 1-3 surface's PARM `p` = `v` in mm-based units, for a lens unit of `scale` mm:
/// Δt (PARM 1) is a length, n0 (PARM 2) a number, and a coefficient on r^(2k) or z^j carries
/// the inverse power of the length.
fn grin_in_mm(ty: &str, p: usize, v: f64, scale: f64) -> f64 {
    let power = match (ty, p) {
        (_, 1) => return v * scale,
        (_, 2) => return v,
        // Gradient 3: nr2, nr4, nr6, then nz1, nz2, nz3.
        ("GRINSUR3", 6..=8) => (p - 5) as i32,
        _ => 2 * (p as i32 - 2),
    };
    v * scale.powi(-power)
}
