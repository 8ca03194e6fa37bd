//! Camera controllers for the window: orbit (drag to turn around the model, scroll to zoom)
//! and fly (WASD/QE to move, drag to look, scroll to change speed).

use glam::Vec3;
use vds_runtime::Camera;

/// Which controller is active.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Turn around a target.
    Orbit,
    /// Move freely.
    Fly,
}

/// The camera state both controllers share: an eye, a yaw/pitch, and for orbiting a target
/// distance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Controls {
    /// Active controller.
    pub mode: Mode,
    /// Orbit target.
    pub target: Vec3,
    /// Orbit distance.
    pub distance: f32,
    /// Eye position (fly mode; derived in orbit mode).
    pub eye: Vec3,
    /// Heading in radians (around +Y).
    pub yaw: f32,
    /// Elevation in radians.
    pub pitch: f32,
    /// Fly speed in scene units per second.
    pub speed: f32,
    /// Size of the model (for near planes and speeds).
    pub scale: f32,
    /// Vertical field of view in degrees.
    pub fov_y_degrees: f32,
}

impl Controls {
    /// Orbiting the bounding sphere (`center`, `radius`), framed.
    pub fn framing(center: [f32; 3], radius: f32) -> Controls {
        let radius = radius.max(1e-6);
        let fov_y_degrees = 45.0f32;
        let mut controls = Controls {
            mode: Mode::Orbit,
            target: Vec3::from(center),
            distance: radius / (fov_y_degrees.to_radians() / 2.0).sin(),
            eye: Vec3::ZERO,
            yaw: 0.6,
            pitch: 0.35,
            speed: radius * 0.5,
            scale: radius,
            fov_y_degrees,
        };
        controls.eye = controls.orbit_eye();
        controls
    }

    fn direction(&self) -> Vec3 {
        Vec3::new(
            self.pitch.cos() * self.yaw.sin(),
            self.pitch.sin(),
            self.pitch.cos() * self.yaw.cos(),
        )
    }

    fn orbit_eye(&self) -> Vec3 {
        self.target + self.direction() * self.distance
    }

    /// The camera for a viewport of `width` × `height`.
    pub fn camera(&self, width: u32, height: u32) -> Camera {
        let (eye, target) = match self.mode {
            Mode::Orbit => (self.orbit_eye(), self.target),
            Mode::Fly => (self.eye, self.eye - self.direction()),
        };
        Camera {
            eye: eye.into(),
            target: target.into(),
            up: [0.0, 1.0, 0.0],
            fov_y_degrees: self.fov_y_degrees,
            width,
            height,
            near: self.scale * 1e-4,
        }
    }

    /// A mouse drag by (`dx`, `dy`) pixels.
    pub fn drag(&mut self, dx: f32, dy: f32) {
        self.yaw -= dx * 0.005;
        self.pitch = (self.pitch + dy * 0.005).clamp(-1.55, 1.55);
        if self.mode == Mode::Orbit {
            self.eye = self.orbit_eye();
        }
    }

    /// A scroll by `lines` (positive: towards the model / faster).
    pub fn scroll(&mut self, lines: f32) {
        match self.mode {
            Mode::Orbit => {
                self.distance = (self.distance * 0.9f32.powf(lines)).max(self.scale * 1e-3)
            }
            Mode::Fly => self.speed *= 1.25f32.powf(lines),
        }
    }

    /// Fly movement for `seconds` with keys held: forward/back, right/left, up/down in -1..=1.
    pub fn fly(&mut self, forward: f32, right: f32, up: f32, seconds: f32) {
        if self.mode != Mode::Fly {
            return;
        }
        let ahead = -self.direction();
        let side = ahead.cross(Vec3::Y).normalize_or_zero();
        self.eye += (ahead * forward + side * right + Vec3::Y * up) * self.speed * seconds;
    }

    /// Switches between orbit and fly, keeping the current view.
    pub fn toggle_mode(&mut self) {
        match self.mode {
            Mode::Orbit => {
                self.eye = self.orbit_eye();
                self.mode = Mode::Fly;
            }
            Mode::Fly => {
                self.target = self.eye - self.direction() * self.distance;
                self.mode = Mode::Orbit;
            }
        }
    }
}
