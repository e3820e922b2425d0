//! The sample on the cylinder (server/src/lanes/hardware.md, "Sample changes"): the
//! one the daemon knows is mounted, if any, and on the emulator the emulated
//! instrument's mounted scene, which mounting a sample changes.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use anyhow::Context;
use gonio_mock_hw::camera::SampleMount;
use gonio_mock_hw::scene::Scene;

use super::files::is_safe_name;
use super::sync::lock;

/// The scenes the emulated instrument holds, by sample name, and its mount.
pub struct EmulatedSamples {
    mount: SampleMount,
    /// Scene (builtin name or path) by sample name, besides the builtin scenes.
    scenes: BTreeMap<String, String>,
}

impl EmulatedSamples {
    /// The samples of `scenes` (the mounted one among them), and the builtin scenes
    /// under their own names. Every name must be a sample name.
    pub fn new(mount: SampleMount, scenes: BTreeMap<String, String>) -> anyhow::Result<Self> {
        if let Some(bad) = scenes.keys().find(|name| !is_safe_name(name)) {
            anyhow::bail!(
                "camera.samples: {bad:?} is not a sample name \
                 (1-64 letters, digits, '-', '_' or '.', not starting with '.')"
            );
        }
        Ok(Self { mount, scenes })
    }

    /// The scene that shows `sample`, as configured or builtin, read.
    fn load(&self, sample: &str) -> anyhow::Result<Scene> {
        let spec = scene_of(&self.scenes, sample)
            .with_context(|| format!("the emulated instrument holds no sample {sample:?}"))?;
        gonio_mock_hw::scene_spec::load_scene(spec)
            .with_context(|| format!("scene of sample {sample}"))
    }
}

/// The scene (builtin name or path) that shows `sample`: its entry in `scenes`, else
/// the builtin scene of that name.
pub fn scene_of<'a>(scenes: &'a BTreeMap<String, String>, sample: &str) -> Option<&'a str> {
    scenes.get(sample).map(String::as_str).or_else(|| {
        Scene::BUILTIN
            .iter()
            .copied()
            .find(|builtin| *builtin == sample)
    })
}

/// What the daemon knows of the sample on the cylinder.
pub struct Mount {
    /// The sample known to be mounted: `None` until the operator confirms one, or the
    /// carousel or the emulated instrument says which.
    known: Mutex<Option<String>>,
    emulated: Option<EmulatedSamples>,
}

impl Mount {
    /// Real hardware: nothing is known to be mounted when the daemon starts.
    pub fn unknown() -> Self {
        Self {
            known: Mutex::new(None),
            emulated: None,
        }
    }

    /// The emulated instrument, with `sample` mounted; with a carousel, none is known
    /// to be before the camera until the carousel is turned to a slot.
    pub fn emulated(sample: &str, samples: EmulatedSamples) -> Self {
        let known = (!samples.mount.has_carousel()).then(|| sample.to_owned());
        Self {
            known: Mutex::new(known),
            emulated: Some(samples),
        }
    }

    /// Whether `sample` is known to be the one mounted.
    pub fn is_mounted(&self, sample: &str) -> bool {
        lock(&self.known).as_deref() == Some(sample)
    }

    /// The samples the instrument can hold, where it knows them (`None`: any name).
    pub fn holdable(&self) -> Option<Vec<String>> {
        self.emulated.as_ref().map(|emulated| {
            let mut names: Vec<String> = emulated.scenes.keys().cloned().collect();
            names.extend(Scene::BUILTIN.iter().map(|s| (*s).to_owned()));
            names.sort();
            names.dedup();
            names
        })
    }

    /// Records that `sample` is mounted now. On the emulator without a carousel this
    /// mounts its scene (read from its file or the builtin ones), so the camera renders
    /// it from the next capture on.
    pub fn mount(&self, sample: &str) -> anyhow::Result<()> {
        // With a carousel the emulated instrument shows the sample of the slot it is at.
        let swaps = self.emulated.as_ref().filter(|e| !e.mount.has_carousel());
        if let Some(emulated) = swaps {
            emulated.mount.mount(emulated.load(sample)?);
        }
        *lock(&self.known) = Some(sample.to_owned());
        Ok(())
    }

    /// Forgets which sample is mounted (a carousel that may have moved).
    pub fn forget(&self) {
        *lock(&self.known) = None;
    }

    /// The scene of `sample` on the emulated instrument (`None` on real hardware): with
    /// a carousel, the scene of its slot (the carousel may not be there yet); else the
    /// scene the camera renders now (the sample confirmed mounted).
    pub fn emulated_scene(&self, sample: &str) -> anyhow::Result<Option<Arc<Scene>>> {
        let Some(emulated) = &self.emulated else {
            return Ok(None);
        };
        if !emulated.mount.has_carousel() {
            return Ok(Some(emulated.mount.scene()));
        }
        Ok(Some(Arc::new(emulated.load(sample)?)))
    }
}
