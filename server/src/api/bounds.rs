//! What a scan or sweep request is checked against: the configured limits, the
//! camera's shutter range, the samples the instrument can hold and the carousel slots
//! beyond the arm's travel, as the daemon knows them now.

use crate::shared::Shared;
use crate::sync::lock;
use crate::validate::Bounds;

/// The bounds of a request arriving now.
pub fn bounds(shared: &Shared) -> Bounds {
    let (camera, travel) = {
        let status = lock(&shared.hardware);
        (status.camera.clone(), status.arm.carousel_travel)
    };
    let carousel = shared.config.carousel.as_ref();
    let unreachable = carousel
        .zip(travel)
        .map(|(carousel, travel)| carousel.beyond_travel(travel))
        .unwrap_or_default();
    Bounds {
        limits: shared.config.limits,
        shutter_min_s: camera.shutter_min_s,
        shutter_max_s: camera.shutter_max_s,
        max_steps: shared.config.max_steps_per_request,
        samples: holdable(shared),
        unreachable,
    }
}

/// The samples the instrument can hold: the carousel's, of those the emulator has a
/// scene for; `None` where any name goes (real hardware without a carousel).
fn holdable(shared: &Shared) -> Option<Vec<String>> {
    let slots = shared
        .config
        .carousel
        .as_ref()
        .map(|c| c.slots.keys().cloned().collect::<Vec<_>>());
    match (slots, shared.mount.holdable()) {
        (Some(slots), Some(scenes)) => Some(
            slots
                .into_iter()
                .filter(|name| scenes.contains(name))
                .collect(),
        ),
        (slots, scenes) => slots.or(scenes),
    }
}
