//! Pure view geometry: poses, fields of view, per-pixel rays and the gaze
//! in normalised view coordinates. No OpenXR calls; unit-tested.
//!
//! Conventions are OpenXR's: right-handed, +X right, +Y up, the view looks
//! down −Z; quaternions are `[x, y, z, w]`; field-of-view angles are
//! signed radians from the view's forward axis (left and down negative in a
//! usual symmetric view).

/// A rigid pose: position in metres and orientation as a unit quaternion
/// `[x, y, z, w]`, both in some base space (the session's reference space,
/// or a view's space — the owner says which).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Position in metres.
    pub position_m: [f32; 3],
    /// Orientation, unit quaternion `[x, y, z, w]`.
    pub orientation: [f32; 4],
}

impl Pose {
    /// At the origin, not rotated.
    pub const IDENTITY: Pose = Pose {
        position_m: [0.0; 3],
        orientation: [0.0, 0.0, 0.0, 1.0],
    };

    /// This pose expressed in the space of `base` (both given in the same
    /// space): `base⁻¹ · self`. E.g. the gaze pose in a view's space, from
    /// both located in the reference space.
    pub fn relative_to(&self, base: &Pose) -> Pose {
        let inv = quat_conjugate(base.orientation);
        let d = [
            self.position_m[0] - base.position_m[0],
            self.position_m[1] - base.position_m[1],
            self.position_m[2] - base.position_m[2],
        ];
        Pose {
            position_m: quat_rotate(inv, d),
            orientation: quat_normalize(quat_mul(inv, self.orientation)),
        }
    }

    /// The pose's forward direction (its −Z axis) in the base space.
    pub fn forward(&self) -> [f32; 3] {
        quat_rotate(self.orientation, [0.0, 0.0, -1.0])
    }
}

/// A view's field of view as OpenXR gives it: signed angles in radians of
/// the four frustum edges from the forward axis (`angle_left_rad` and
/// `angle_down_rad` are negative for a view that contains the forward axis).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fov {
    /// Left edge, radians (negative to the left).
    pub angle_left_rad: f32,
    /// Right edge, radians.
    pub angle_right_rad: f32,
    /// Top edge, radians.
    pub angle_up_rad: f32,
    /// Bottom edge, radians (negative below).
    pub angle_down_rad: f32,
}

impl Fov {
    /// A symmetric view of `horizontal_deg` × `vertical_deg` total.
    pub fn symmetric_deg(horizontal_deg: f32, vertical_deg: f32) -> Fov {
        let h = (horizontal_deg * 0.5).to_radians();
        let v = (vertical_deg * 0.5).to_radians();
        Fov {
            angle_left_rad: -h,
            angle_right_rad: h,
            angle_up_rad: v,
            angle_down_rad: -v,
        }
    }

    /// Total horizontal field of view in degrees.
    pub fn horizontal_deg(&self) -> f32 {
        (self.angle_right_rad - self.angle_left_rad).to_degrees()
    }

    /// Total vertical field of view in degrees.
    pub fn vertical_deg(&self) -> f32 {
        (self.angle_up_rad - self.angle_down_rad).to_degrees()
    }

    /// The tangent-space projection of this field of view.
    pub fn projection(&self) -> TangentProjection {
        TangentProjection {
            tan_left: self.angle_left_rad.tan(),
            tan_right: self.angle_right_rad.tan(),
            tan_up: self.angle_up_rad.tan(),
            tan_down: self.angle_down_rad.tan(),
        }
    }
}

/// A view's projection in tangent space: the image plane at distance 1 in
/// front of the eye spans `x ∈ [tan_left, tan_right]`, `y ∈ [tan_down,
/// tan_up]`. Pixel `(x, y)` of a `W×H` image (row 0 at the top) looks along
/// `(tx, ty, −1)` with `tx = tan_left + (x + ½)/W · (tan_right − tan_left)`
/// and `ty = tan_up − (y + ½)/H · (tan_up − tan_down)`.
///
/// For a shader, [`TangentProjection::scale_offset`] packs the same map as
/// `t = offset + uv · scale` with `uv ∈ [0,1]²`, top-left origin.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TangentProjection {
    /// tan of the left edge angle (negative to the left).
    pub tan_left: f32,
    /// tan of the right edge angle.
    pub tan_right: f32,
    /// tan of the top edge angle.
    pub tan_up: f32,
    /// tan of the bottom edge angle (negative below).
    pub tan_down: f32,
}

impl TangentProjection {
    /// Tangent-plane point `(tx, ty)` of normalised view coordinates
    /// (`u, v ∈ [0,1]`, top-left origin).
    pub fn tangent_at_uv(&self, u: f32, v: f32) -> [f32; 2] {
        [
            self.tan_left + u * (self.tan_right - self.tan_left),
            self.tan_up - v * (self.tan_up - self.tan_down),
        ]
    }

    /// Unit direction in view space (−Z forward, +Y up) through the centre
    /// of pixel `(x, y)` of a `width_px × height_px` image (row 0 at the
    /// top).
    pub fn pixel_ray(&self, x: u32, y: u32, width_px: u32, height_px: u32) -> [f32; 3] {
        let u = (x as f32 + 0.5) / width_px.max(1) as f32;
        let v = (y as f32 + 0.5) / height_px.max(1) as f32;
        let [tx, ty] = self.tangent_at_uv(u, v);
        normalize([tx, ty, -1.0])
    }

    /// `[offset_x, offset_y, scale_x, scale_y]` with
    /// `(tx, ty) = offset + (u, v) · scale` — the per-pixel ray of
    /// [`TangentProjection::pixel_ray`] in four numbers for a uniform buffer.
    pub fn scale_offset(&self) -> [f32; 4] {
        [
            self.tan_left,
            self.tan_up,
            self.tan_right - self.tan_left,
            self.tan_down - self.tan_up,
        ]
    }

    /// Normalised view coordinates (`u, v`, top-left origin) where a view
    /// space direction meets the image plane; `None` for a direction that
    /// does not point in front of the eye (`z ≥ 0`). Values outside `[0,1]`
    /// mean outside the field of view.
    pub fn uv_of_direction(&self, dir: [f32; 3]) -> Option<[f32; 2]> {
        if dir[2] >= -1e-6 {
            return None;
        }
        let tx = dir[0] / -dir[2];
        let ty = dir[1] / -dir[2];
        Some([
            (tx - self.tan_left) / (self.tan_right - self.tan_left),
            (self.tan_up - ty) / (self.tan_up - self.tan_down),
        ])
    }
}

/// Normalised view coordinates (`[u, v]`, top-left origin, `[0,1]` inside
/// the field of view) of a gaze whose orientation is given in the view's
/// space (see [`Pose::relative_to`]): where the gaze's forward axis (−Z)
/// meets the view's image plane. `None` when the gaze does not point in
/// front of the view. Values outside `[0,1]` mean the gaze is outside the
/// view's field of view; the caller decides whether to clamp.
///
/// The gaze ray is taken as leaving the eye itself: the few centimetres
/// between the gaze origin (between the eyes) and each eye are ignored,
/// which is exact for a gaze converged at infinity.
pub fn gaze_to_view_uv(gaze_orientation_in_view: [f32; 4], fov: &Fov) -> Option<[f32; 2]> {
    let dir = quat_rotate(gaze_orientation_in_view, [0.0, 0.0, -1.0]);
    fov.projection().uv_of_direction(dir)
}

/// Quaternion of a rotation of `angle_rad` about `axis` (need not be unit).
pub fn quat_from_axis_angle(axis: [f32; 3], angle_rad: f32) -> [f32; 4] {
    let [x, y, z] = normalize(axis);
    let (s, c) = (angle_rad * 0.5).sin_cos();
    [x * s, y * s, z * s, c]
}

/// Hamilton product `a · b` (apply `b`, then `a`).
pub fn quat_mul(a: [f32; 4], b: [f32; 4]) -> [f32; 4] {
    let [ax, ay, az, aw] = a;
    let [bx, by, bz, bw] = b;
    [
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ]
}

/// Conjugate (the inverse of a unit quaternion).
pub fn quat_conjugate(q: [f32; 4]) -> [f32; 4] {
    [-q[0], -q[1], -q[2], q[3]]
}

/// `v` rotated by the unit quaternion `q`.
pub fn quat_rotate(q: [f32; 4], v: [f32; 3]) -> [f32; 3] {
    // v' = v + 2w (u × v) + 2 u × (u × v), u = (x, y, z)
    let u = [q[0], q[1], q[2]];
    let w = q[3];
    let t = cross(u, v);
    let t = [2.0 * t[0], 2.0 * t[1], 2.0 * t[2]];
    let ut = cross(u, t);
    [
        v[0] + w * t[0] + ut[0],
        v[1] + w * t[1] + ut[1],
        v[2] + w * t[2] + ut[2],
    ]
}

fn quat_normalize(q: [f32; 4]) -> [f32; 4] {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if n > 0.0 {
        [q[0] / n, q[1] / n, q[2] / n, q[3] / n]
    } else {
        [0.0, 0.0, 0.0, 1.0]
    }
}

fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalize(v: [f32; 3]) -> [f32; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if n > 0.0 {
        [v[0] / n, v[1] / n, v[2] / n]
    } else {
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const EPS: f32 = 1e-5;

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() < EPS
    }

    fn close3(a: [f32; 3], b: [f32; 3]) -> bool {
        a.iter().zip(b).all(|(x, y)| close(*x, y))
    }

    #[test]
    fn straight_ahead_in_symmetric_fov_is_centre() {
        let fov = Fov::symmetric_deg(90.0, 90.0);
        assert_eq!(
            gaze_to_view_uv([0.0, 0.0, 0.0, 1.0], &fov),
            Some([0.5, 0.5])
        );
    }

    #[test]
    fn gaze_at_left_edge_is_u0() {
        // Asymmetric fov, like a real left eye: 50° out to the left, 40° in.
        let fov = Fov {
            angle_left_rad: (-50f32).to_radians(),
            angle_right_rad: 40f32.to_radians(),
            angle_up_rad: 45f32.to_radians(),
            angle_down_rad: (-45f32).to_radians(),
        };
        // Turning left is a positive rotation about +Y; by -angle_left the
        // forward axis lies exactly on the left frustum edge.
        let q = quat_from_axis_angle([0.0, 1.0, 0.0], -fov.angle_left_rad);
        let [u, v] = gaze_to_view_uv(q, &fov).unwrap_or([f32::NAN; 2]);
        assert!(close(u, 0.0), "u = {u}");
        assert!(close(v, 0.5), "v = {v}");
        // And the right edge is u = 1.
        let q = quat_from_axis_angle([0.0, 1.0, 0.0], -fov.angle_right_rad);
        let [u, _] = gaze_to_view_uv(q, &fov).unwrap_or([f32::NAN; 2]);
        assert!(close(u, 1.0), "u = {u}");
    }

    #[test]
    fn gaze_up_and_down_edges_and_hand_value() {
        let fov = Fov::symmetric_deg(90.0, 90.0);
        // Looking up is a positive rotation about +X: -Z turns towards +Y.
        let up = quat_from_axis_angle([1.0, 0.0, 0.0], fov.angle_up_rad);
        let [u, v] = gaze_to_view_uv(up, &fov).unwrap_or([f32::NAN; 2]);
        assert!(close(u, 0.5) && close(v, 0.0), "({u}, {v})");
        let down = quat_from_axis_angle([1.0, 0.0, 0.0], fov.angle_down_rad);
        let [_, v] = gaze_to_view_uv(down, &fov).unwrap_or([f32::NAN; 2]);
        assert!(close(v, 1.0), "v = {v}");
        // 22.5° to the right in a ±45° view: tan(22.5°) = √2 − 1 of the
        // tangent half-width 1, so u = (1 + √2 − 1) / 2 = √2 / 2.
        let right = quat_from_axis_angle([0.0, 1.0, 0.0], (-22.5f32).to_radians());
        let [u, v] = gaze_to_view_uv(right, &fov).unwrap_or([f32::NAN; 2]);
        assert!(close(u, std::f32::consts::SQRT_2 / 2.0), "u = {u}");
        assert!(close(v, 0.5), "v = {v}");
    }

    #[test]
    fn gaze_behind_is_none() {
        let fov = Fov::symmetric_deg(90.0, 90.0);
        let back = quat_from_axis_angle([0.0, 1.0, 0.0], std::f32::consts::PI);
        assert_eq!(gaze_to_view_uv(back, &fov), None);
    }

    #[test]
    fn relative_pose_brings_gaze_into_view_space() {
        // View turned 30° left; gaze turned 30° left too: straight ahead in
        // the view.
        let turn = quat_from_axis_angle([0.0, 1.0, 0.0], 30f32.to_radians());
        let view = Pose {
            position_m: [-0.032, 1.6, 0.0],
            orientation: turn,
        };
        let gaze = Pose {
            position_m: [0.0, 1.6, 0.0],
            orientation: turn,
        };
        let rel = gaze.relative_to(&view);
        let fov = Fov::symmetric_deg(90.0, 90.0);
        let [u, v] = gaze_to_view_uv(rel.orientation, &fov).unwrap_or([f32::NAN; 2]);
        assert!(close(u, 0.5) && close(v, 0.5), "({u}, {v})");
        // The gaze origin is 32 mm right of the eye, in the view's axes:
        // (0.032·cos30°, 0, 0.032·sin30°)… rotated back by −30° about Y.
        let c = 30f32.to_radians().cos();
        let s = 30f32.to_radians().sin();
        assert!(
            close3(rel.position_m, [0.032 * c, 0.0, 0.032 * s]),
            "{:?}",
            rel.position_m
        );
        assert!(close3(Pose::IDENTITY.forward(), [0.0, 0.0, -1.0]));
    }

    #[test]
    fn pixel_rays_span_the_fov() {
        let fov = Fov::symmetric_deg(90.0, 60.0);
        let p = fov.projection();
        // Centre pixel of an odd-sized image looks straight ahead.
        assert!(close3(p.pixel_ray(2, 1, 5, 3), [0.0, 0.0, -1.0]));
        // Pixel (0, 0) of a 4×2 image: centre at u = 1/8, v = 1/4.
        // tx = -1 + 0.125·2 = -0.75; ty = tan30° − 0.25·2·tan30° = tan30°/2.
        let t30 = 30f32.to_radians().tan();
        let (tx, ty) = (-0.75f32, t30 / 2.0);
        let n = (tx * tx + ty * ty + 1.0).sqrt();
        assert!(close3(p.pixel_ray(0, 0, 4, 2), [tx / n, ty / n, -1.0 / n]));
        // Bottom-right pixel mirrors it.
        assert!(close3(
            p.pixel_ray(3, 1, 4, 2),
            [-tx / n, -ty / n, -1.0 / n]
        ));
        // The ray and uv_of_direction are inverse maps.
        let [u, v] = p
            .uv_of_direction(p.pixel_ray(0, 0, 4, 2))
            .unwrap_or([f32::NAN; 2]);
        assert!(close(u, 0.125) && close(v, 0.25), "({u}, {v})");
        // scale_offset is the same map.
        let [ox, oy, sx, sy] = p.scale_offset();
        assert!(close(ox + 0.125 * sx, tx) && close(oy + 0.25 * sy, ty));
    }

    #[test]
    fn asymmetric_fov_centre_pixel_is_off_axis() {
        let fov = Fov {
            angle_left_rad: (-50f32).to_radians(),
            angle_right_rad: 40f32.to_radians(),
            angle_up_rad: 45f32.to_radians(),
            angle_down_rad: (-45f32).to_radians(),
        };
        let p = fov.projection();
        let [tx, ty] = p.tangent_at_uv(0.5, 0.5);
        let expect_tx = ((-50f32).to_radians().tan() + 40f32.to_radians().tan()) / 2.0;
        assert!(close(tx, expect_tx) && close(ty, 0.0), "({tx}, {ty})");
        assert!(close(fov.horizontal_deg(), 90.0) && close(fov.vertical_deg(), 90.0));
    }
}
