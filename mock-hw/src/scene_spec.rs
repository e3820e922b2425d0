//! A scene as a command line or a configuration names it: a built-in scene's name,
//! otherwise the path of a scene file.

use std::path::Path;

use crate::scene::{Scene, SceneError};

/// A scene named neither a built-in nor a readable, valid scene file.
#[derive(Debug, thiserror::Error)]
pub enum SceneSpecError {
    /// No built-in scene has the name and no file is at the path (the error says why
    /// once, not as a chained cause).
    #[error(
        "`{spec}` is neither a built-in scene ({}) nor a scene file: {error}",
        Scene::BUILTIN.join(", ")
    )]
    Unknown { spec: String, error: std::io::Error },
    /// A file is at the path, and it is not a valid scene.
    #[error(transparent)]
    File(#[from] SceneError),
}

/// The built-in scene called `spec`, otherwise the scene file at path `spec`.
pub fn load_scene(spec: &str) -> Result<Scene, SceneSpecError> {
    if let Some(scene) = Scene::builtin(spec) {
        return Ok(scene);
    }
    match Scene::load(Path::new(spec)) {
        Ok(scene) => Ok(scene),
        Err(SceneError::Io { error, .. }) if error.kind() == std::io::ErrorKind::NotFound => {
            Err(SceneSpecError::Unknown {
                spec: spec.to_string(),
                error,
            })
        }
        Err(error) => Err(error.into()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unknown_name_lists_the_built_in_scenes_and_a_bad_file_names_its_fault() {
        let unknown = load_scene("gold-foil").unwrap_err().to_string();
        assert!(
            unknown.contains("`gold-foil` is neither a built-in scene"),
            "{unknown}"
        );
        assert!(unknown.contains(Scene::BUILTIN[0]), "{unknown}");

        let dir = std::env::temp_dir().join(format!("gonio-scene-spec-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("bad.toml");
        std::fs::write(&file, "this is = not = toml\n").unwrap();
        let bad = load_scene(file.to_str().unwrap()).unwrap_err();
        std::fs::remove_dir_all(&dir).unwrap();
        assert!(matches!(bad, SceneSpecError::File(_)), "{bad:?}");
        let text = bad.to_string();
        assert!(!text.contains("built-in"), "{text}");
        assert!(text.starts_with("scene "), "{text}");
    }
}
