//! A scene as a command line or a configuration names it: a built-in scene's name,
//! otherwise the path of a scene file.

use std::path::Path;

use crate::scene::{Scene, SceneError};

/// A scene named neither a built-in nor a readable, valid scene file; the source says
/// what is wrong with the file.
#[derive(Debug, thiserror::Error)]
#[error("not a built-in scene ({}), read as a file", Scene::BUILTIN.join(", "))]
pub struct SceneSpecError(#[source] pub SceneError);

/// The built-in scene called `spec`, otherwise the scene file at path `spec`.
pub fn load_scene(spec: &str) -> Result<Scene, SceneSpecError> {
    match Scene::builtin(spec) {
        Some(scene) => Ok(scene),
        None => Scene::load(Path::new(spec)).map_err(SceneSpecError),
    }
}
