//! The camera as the cut sees it: a pinhole with square pixels, its orthonormal basis, focal
//! length in pixels and frustum, precomputed once per frame.

use glam::Vec3;

/// A perspective camera, as a user or a camera path gives it.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Camera {
    /// Eye position.
    pub eye: [f32; 3],
    /// A point the camera looks at.
    pub target: [f32; 3],
    /// Up direction (need not be orthogonal to the view direction, must not be parallel).
    pub up: [f32; 3],
    /// Vertical field of view in degrees.
    pub fov_y_degrees: f32,
    /// Viewport width in pixels.
    pub width: u32,
    /// Viewport height in pixels.
    pub height: u32,
    /// Distance of the near plane from the eye.
    pub near: f32,
}

impl Camera {
    /// A camera looking at a sphere (`center`, `radius`) from direction `from` (pointing from
    /// the centre towards the eye), placed so the sphere fills the vertical field of view.
    pub fn framing(
        center: [f32; 3],
        radius: f32,
        from: [f32; 3],
        width: u32,
        height: u32,
    ) -> Camera {
        let fov_y_degrees = 45.0f32;
        let distance = radius.max(f32::MIN_POSITIVE) / (fov_y_degrees.to_radians() / 2.0).sin();
        let eye = Vec3::from(center) + Vec3::from(from).normalize_or(Vec3::Z) * distance;
        let up = if Vec3::from(from).normalize_or(Vec3::Z).abs().y > 0.99 {
            Vec3::Z
        } else {
            Vec3::Y
        };
        Camera {
            eye: eye.into(),
            target: center,
            up: up.into(),
            fov_y_degrees,
            width,
            height,
            near: distance * 1e-4,
        }
    }

    /// The per-frame form of this camera. Degenerate inputs (eye on the target, up parallel
    /// to the view direction, zero-sized viewport) fall back to usable defaults instead of
    /// producing NaNs.
    pub fn view(&self) -> View {
        let eye = Vec3::from(self.eye);
        let forward = (Vec3::from(self.target) - eye).normalize_or(Vec3::NEG_Z);
        let mut right = forward.cross(Vec3::from(self.up)).normalize_or_zero();
        if right == Vec3::ZERO {
            right = forward.any_orthonormal_vector();
        }
        let up = right.cross(forward);
        let width = self.width.max(1);
        let height = self.height.max(1);
        let fov = self.fov_y_degrees.clamp(1e-3, 179.0).to_radians();
        let tan_y = (fov / 2.0).tan();
        let tan_x = tan_y * width as f32 / height as f32;
        View {
            eye,
            right,
            up,
            forward,
            focal_px: height as f32 / 2.0 / tan_y,
            tan_x,
            tan_y,
            side_scale_x: 1.0 / (1.0 + tan_x * tan_x).sqrt(),
            side_scale_y: 1.0 / (1.0 + tan_y * tan_y).sqrt(),
            near: self.near.max(0.0),
            width,
            height,
        }
    }
}

/// A camera prepared for per-node tests.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    /// Eye position.
    pub eye: Vec3,
    /// Unit right vector (camera x).
    pub right: Vec3,
    /// Unit up vector (camera y).
    pub up: Vec3,
    /// Unit view direction (camera z).
    pub forward: Vec3,
    /// Focal length in pixels: a unit of camera-space height at depth 1 spans this many
    /// pixels.
    pub focal_px: f32,
    /// Tangent of half the horizontal field of view.
    pub tan_x: f32,
    /// Tangent of half the vertical field of view.
    pub tan_y: f32,
    side_scale_x: f32,
    side_scale_y: f32,
    /// Near-plane distance.
    pub near: f32,
    /// Viewport width in pixels.
    pub width: u32,
    /// Viewport height in pixels.
    pub height: u32,
}

impl View {
    /// Where this view will be `frames` frames from now if it keeps moving as it moved since
    /// `previous` (one frame ago): the eye keeps its velocity, the basis keeps turning about
    /// the same axis at the same rate. For fetching pages ahead of the camera.
    pub(crate) fn extrapolated(&self, previous: &View, frames: f32) -> View {
        let basis = |v: &View| glam::Mat3::from_cols(v.right, v.up, v.forward);
        // Both bases have the same handedness, so the turn between them is a proper rotation.
        let turn = basis(self) * basis(previous).transpose();
        let (axis, angle) = glam::Quat::from_mat3(&turn).to_axis_angle();
        let ahead = glam::Quat::from_axis_angle(axis, angle * frames);
        let mut view = *self;
        view.eye = self.eye + (self.eye - previous.eye) * frames;
        if angle.is_finite() && axis.is_finite() {
            view.right = (ahead * self.right).normalize();
            view.up = (ahead * self.up).normalize();
            view.forward = (ahead * self.forward).normalize();
        }
        view
    }

    /// `p` in camera coordinates: x right, y up, z along the view direction.
    #[inline]
    pub fn to_camera(&self, p: Vec3) -> Vec3 {
        let d = p - self.eye;
        Vec3::new(d.dot(self.right), d.dot(self.up), d.dot(self.forward))
    }

    /// Pixel coordinates of `p` (x right, y down, origin at the top-left corner), or `None`
    /// when `p` is not in front of the eye.
    pub fn project(&self, p: Vec3) -> Option<[f64; 2]> {
        let c = self.to_camera(p);
        (c.z > 0.0).then(|| {
            let (x, y, z) = (f64::from(c.x), f64::from(c.y), f64::from(c.z));
            let f = f64::from(self.focal_px);
            [
                f64::from(self.width) / 2.0 + f * x / z,
                f64::from(self.height) / 2.0 - f * y / z,
            ]
        })
    }

    /// True when `p` lies inside the view frustum (beyond the near plane, within the four
    /// side planes).
    pub fn contains(&self, p: Vec3) -> bool {
        let c = self.to_camera(p);
        c.z >= self.near && c.x.abs() <= c.z * self.tan_x && c.y.abs() <= c.z * self.tan_y
    }

    /// True when a sphere given in camera coordinates lies entirely outside the frustum:
    /// behind the near plane or beyond one side plane by more than its radius.
    #[inline]
    pub fn sphere_outside(&self, center: Vec3, radius: f32) -> bool {
        let Vec3 { x, y, z } = center;
        // Signed distance to the side plane x = z·tan_x is (x − z·tan_x)/√(1 + tan_x²).
        self.near - z > radius
            || (x.abs() - z * self.tan_x) * self.side_scale_x > radius
            || (y.abs() - z * self.tan_y) * self.side_scale_y > radius
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(eye: [f32; 3], target: [f32; 3]) -> View {
        Camera {
            eye,
            target,
            up: [0.0, 1.0, 0.0],
            fov_y_degrees: 45.0,
            width: 640,
            height: 480,
            near: 0.01,
        }
        .view()
    }

    #[test]
    fn extrapolation_continues_a_steady_move_and_turn() {
        // A camera circling the origin by 2° a frame, looking at it: ten frames ahead is
        // where the circle goes in ten more frames.
        let at = |degrees: f32| {
            let a = degrees.to_radians();
            camera([10.0 * a.cos(), 0.0, 10.0 * a.sin()], [0.0; 3])
        };
        let (before, now, later) = (at(0.0), at(2.0), at(22.0));
        let ahead = now.extrapolated(&before, 10.0);
        // The eye keeps its velocity (a straight line, so off the circle by the chord's sag).
        let expected_eye = now.eye + (now.eye - before.eye) * 10.0;
        assert!((ahead.eye - expected_eye).length() < 1e-4);
        // The basis turns by the same 20° about the same axis.
        for (got, want) in [
            (ahead.forward, later.forward),
            (ahead.right, later.right),
            (ahead.up, later.up),
        ] {
            assert!((got - want).length() < 1e-4, "{got} against {want}");
        }
        // Standing still extrapolates to standing still.
        let still = now.extrapolated(&now, 10.0);
        assert_eq!(still.eye, now.eye);
        assert!((still.forward - now.forward).length() < 1e-6);
    }
}
