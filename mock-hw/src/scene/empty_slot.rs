//! What the camera sees where a sample carousel holds nothing before it: the same
//! instrument with a sample strip that reflects nothing.

use super::material::Material;
use super::{Sample, Scene, SceneError};

impl Scene {
    /// The same instrument with no sample before the camera (an empty carousel slot,
    /// or a carousel between slots): the sample strip reflects nothing.
    pub fn without_sample(&self) -> Result<Scene, SceneError> {
        let sample = Sample::Lambertian { kd: [0.0; 3] };
        let material = Material::new(&sample, &self.domain)?;
        Ok(Scene {
            name: format!("{} (no sample)", self.name),
            sample,
            material,
            ..self.clone()
        })
    }
}
