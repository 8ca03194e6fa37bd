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

/// The most bytes a camera-path file may hold: 64 MiB is over 300,000 cameras.
const MAX_FILE_BYTES: u64 = 64 << 20;

/// The largest camera coordinate accepted: 2⁶², a factor 4 beyond the largest model
/// coordinate import accepts, where every distance the criteria square stays finite.
const MAX_CAMERA_COORDINATE: f32 = (1u64 << 62) as f32;

/// Where the cameras of a played path come from (what `vds-view` and `vds-cut` take).
#[derive(Debug, Clone, Copy)]
pub enum PathSource<'a> {
    /// A path file ([`CameraPath::read`]).
    File(&'a std::path::Path),
    /// [`CameraPath::orbit`].
    Orbit,
    /// [`CameraPath::fly_through`].
    FlyThrough,
}

impl<'a> PathSource<'a> {
    /// What the command lines' `--camera-path FILE`, `--fly` and (the default) `--orbit` ask
    /// for: a file when one is given, else a fly-through or an orbit.
    pub fn from_flags(camera_path: Option<&'a std::path::Path>, fly: bool) -> Self {
        match camera_path {
            Some(file) => PathSource::File(file),
            None if fly => PathSource::FlyThrough,
            None => PathSource::Orbit,
        }
    }
}

impl CameraPath {
    /// The path `source` names, generated paths around the sphere (`center`, `radius`) in
    /// `frames` steps at `width`×`height`. The error names the file.
    pub fn from_source(
        source: PathSource<'_>,
        center: [f32; 3],
        radius: f32,
        frames: u32,
        (width, height): (u32, u32),
    ) -> Result<CameraPath, String> {
        match source {
            PathSource::File(file) => CameraPath::read(file)
                .map_err(|why| format!("{}: not a usable camera path: {why}", file.display())),
            PathSource::Orbit => Ok(CameraPath::orbit(center, radius, frames, width, height)),
            PathSource::FlyThrough => Ok(CameraPath::fly_through(
                center, radius, frames, width, height,
            )),
        }
    }

    /// Reads and checks a path file ([`CameraPath::from_json`]): a regular file (a FIFO
    /// would block; it is opened non-blocking and checked), at most 64 MiB.
    pub fn read(path: &std::path::Path) -> Result<CameraPath, String> {
        use std::io::Read;
        let mut options = std::fs::File::options();
        options.read(true);
        #[cfg(unix)]
        {
            use std::os::unix::fs::OpenOptionsExt;
            options.custom_flags(libc::O_NONBLOCK);
        }
        let file = options.open(path).map_err(|e| e.to_string())?;
        if !file.metadata().map_err(|e| e.to_string())?.is_file() {
            return Err("not a regular file".into());
        }
        let mut text = String::new();
        file.take(MAX_FILE_BYTES + 1)
            .read_to_string(&mut text)
            .map_err(|e| format!("not UTF-8 text: {e}"))?;
        if text.len() as u64 > MAX_FILE_BYTES {
            return Err(format!("longer than {MAX_FILE_BYTES} bytes"));
        }
        CameraPath::from_json(&text)
    }

    /// Parses a path file's JSON and checks every camera: coordinates finite, the eye off
    /// the target, `up` not along the view direction, a field of view strictly between 0 and
    /// 180 degrees, a viewport of 1 to 16384 pixels a side, a near distance finite and
    /// positive. A path with no camera is refused too. The error names the camera.
    pub fn from_json(text: &str) -> Result<CameraPath, String> {
        let path: CameraPath = serde_json::from_str(text).map_err(|e| e.to_string())?;
        if path.cameras.is_empty() {
            return Err("the path has no cameras".into());
        }
        for (i, camera) in path.cameras.iter().enumerate() {
            check_camera(camera).map_err(|why| format!("camera {i}: {why}"))?;
        }
        Ok(path)
    }

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

/// What [`CameraPath::from_json`] requires of one camera.
fn check_camera(c: &Camera) -> Result<(), String> {
    let within = |v: [f32; 3]| v.iter().all(|x| x.abs() <= MAX_CAMERA_COORDINATE);
    if !(within(c.eye) && within(c.target) && c.up.iter().all(|x| x.is_finite())) {
        return Err(format!(
            "eye and target must be finite and within ±{MAX_CAMERA_COORDINATE:e}, up finite"
        ));
    }
    // The same normalisations `Camera::view` makes, which would otherwise fall back to
    // defaults silently.
    let Some(forward) = (Vec3::from(c.target) - Vec3::from(c.eye)).try_normalize() else {
        return Err("the eye is on the target".into());
    };
    if forward.cross(Vec3::from(c.up)).try_normalize().is_none() {
        return Err("up is zero or along the view direction".into());
    }
    if !(c.fov_y_degrees > 0.0 && c.fov_y_degrees < 180.0) {
        return Err(format!(
            "fov_y_degrees {} is not strictly between 0 and 180",
            c.fov_y_degrees
        ));
    }
    if !(1..=16384).contains(&c.width) || !(1..=16384).contains(&c.height) {
        return Err(format!(
            "viewport {}x{} is not 1 to 16384 pixels a side",
            c.width, c.height
        ));
    }
    if !(c.near.is_finite() && c.near > 0.0) {
        return Err(format!("near {} is not finite and positive", c.near));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one(camera: &str) -> Result<CameraPath, String> {
        CameraPath::from_json(&format!(r#"{{"cameras": [{camera}]}}"#))
    }

    const GOOD: &str = r#"{"eye":[0,0,5],"target":[0,0,0],"up":[0,1,0],"fov_y_degrees":45,"width":64,"height":48,"near":0.01}"#;

    #[cfg(unix)]
    #[test]
    fn reading_a_fifo_is_refused_without_blocking() {
        let dir = std::env::temp_dir().join(format!("vds-path-fifo-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let fifo = dir.join("path.json");
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(made.success());
        let error = CameraPath::read(&fifo).unwrap_err();
        std::fs::remove_dir_all(&dir).unwrap();
        assert!(error.contains("not a regular file"), "{error}");
    }

    #[test]
    fn a_sound_path_parses() {
        assert_eq!(one(GOOD).unwrap().cameras.len(), 1);
    }

    #[test]
    fn paths_with_unusable_cameras_are_refused_naming_the_camera() {
        assert!(CameraPath::from_json(r#"{"cameras": []}"#).is_err());
        for (from, to, why) in [
            (r#""eye":[0,0,5]"#, r#""eye":[0,0,0]"#, "on the target"),
            (r#""up":[0,1,0]"#, r#""up":[0,0,1]"#, "up"),
            (r#""fov_y_degrees":45"#, r#""fov_y_degrees":180"#, "fov"),
            (r#""fov_y_degrees":45"#, r#""fov_y_degrees":0"#, "fov"),
            (r#""width":64"#, r#""width":0"#, "viewport"),
            (r#""height":48"#, r#""height":100000"#, "viewport"),
            (r#""near":0.01"#, r#""near":0"#, "near"),
            (r#""near":0.01"#, r#""near":-1"#, "near"),
            (r#""eye":[0,0,5]"#, r#""eye":[0,0,1e39]"#, ""),
            (r#""eye":[0,0,5]"#, r#""eye":[0,0,1e30]"#, "within"),
        ] {
            let bad = GOOD.replace(from, to);
            let error = one(&format!("{GOOD},{bad}")).unwrap_err();
            assert!(
                error.contains(why) && (why.is_empty() || error.starts_with("camera 1")),
                "{to}: {error}"
            );
        }
    }
}
