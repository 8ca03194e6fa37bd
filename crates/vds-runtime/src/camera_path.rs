//! Camera paths: the sequences of cameras that benchmarks, tests and the headless viewer play
//! back. A path file is JSON: `{"cameras": [Camera, ...]}`, each camera as in [`Camera`]
//! (`eye`, `target`, `up` as `[x, y, z]`, `fov_y_degrees`, `width`, `height`, `near`).

use std::f32::consts::TAU;

use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::view::Camera;

/// A camera per frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraPath {
    /// The cameras, in playback order.
    pub cameras: Vec<Camera>,
}

impl CameraPath {
    /// An orbit around a bounding sphere (`center`, `radius`) in `frames` steps, swinging in
    /// height and distance (between 1.3 and 3.1 radii) so the cut both refines and coarsens.
    pub fn orbit(
        center: [f32; 3],
        radius: f32,
        frames: u32,
        width: u32,
        height: u32,
    ) -> CameraPath {
        let c = Vec3::from(center);
        let cameras = (0..frames)
            .map(|i| {
                let a = TAU * i as f32 / frames.max(1) as f32;
                let distance = radius * (2.2 + 0.9 * (2.0 * a).sin());
                let direction = Vec3::new(a.cos(), 0.35 * (3.0 * a).sin(), a.sin()).normalize();
                Camera {
                    eye: (c + direction * distance).into(),
                    target: center,
                    up: [0.0, 1.0, 0.0],
                    fov_y_degrees: 45.0,
                    width,
                    height,
                    near: radius * 1e-4,
                }
            })
            .collect();
        CameraPath { cameras }
    }

    /// A loop flown *through* a scene bounded by a sphere: at 60% of its radius, bobbing in
    /// height, looking ahead along the path and somewhat inwards — the walkthrough of a plant
    /// or a ship's interior, where near parts need full detail and far ones do not.
    pub fn fly_through(
        center: [f32; 3],
        radius: f32,
        frames: u32,
        width: u32,
        height: u32,
    ) -> CameraPath {
        let c = Vec3::from(center);
        let eye_at =
            |a: f32| c + radius * Vec3::new(0.6 * a.cos(), 0.2 * (2.0 * a).sin(), 0.6 * a.sin());
        let cameras = (0..frames)
            .map(|i| {
                let a = TAU * i as f32 / frames.max(1) as f32;
                let eye = eye_at(a);
                let ahead = (eye_at(a + 0.01) - eye).normalize();
                let inwards = (c - eye).normalize_or_zero();
                let look = (ahead + 0.5 * inwards).normalize();
                Camera {
                    eye: eye.into(),
                    target: (eye + look * radius * 0.5).into(),
                    up: [0.0, 1.0, 0.0],
                    fov_y_degrees: 60.0,
                    width,
                    height,
                    near: radius * 1e-4,
                }
            })
            .collect();
        CameraPath { cameras }
    }
}
