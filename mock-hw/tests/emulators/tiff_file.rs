//! The capture files themselves, decoded with the `tiff` crate directly (not through
//! gonio's reader): 16-bit RGB, Deflate with horizontal differencing (which tifffile,
//! Pillow, OpenCV and ImageMagick decode with no extra codec), a 12-bit sensor's counts
//! in the top 12 bits, and levels in the same stored units.

use gonio_mock_hw::render::{self, render_frame};
use gonio_mock_hw::scene::Scene;
use tiff::decoder::{Decoder, DecodingResult};
use tiff::tags::Tag;

const SMALL: &str = include_str!("../scene_small.toml");

/// The small scene with a 12-bit sensor, a diffuse sample and stuck pixels.
fn twelve_bit_scene() -> Scene {
    let text = SMALL
        .replace("bit_depth = 16", "bit_depth = 12")
        .replace("white_level = 65535", "white_level = 4095")
        .replace("black_level = 0", "black_level = 64");
    Scene::from_toml_str(&format!(
        "{text}\n[sample]\nmodel = \"lambertian\"\nkd = [40.0, 50.0, 30.0]\n\
         [effects]\nseed = 3\n[effects.hot_pixels]\ncount = 5\n"
    ))
    .unwrap()
}

#[test]
fn twelve_bit_counts_are_stored_in_the_top_bits_of_a_plain_deflate_tiff() {
    let scene = twelve_bit_scene();
    let levels = render::file_levels(&scene);
    assert_eq!(levels.significant_bits, 12);
    assert_eq!(
        (levels.black_level, levels.white_level),
        (64 * 16, 4095 * 16)
    );
    assert!(!levels.nonlinear);

    let frame = render_frame(&scene, -30.0, 0.0005);
    let bytes = frame.encode_tiff().unwrap();
    let mut decoder = Decoder::new(std::io::Cursor::new(bytes)).unwrap();
    assert_eq!(decoder.colortype().unwrap(), tiff::ColorType::RGB(16));
    // 8: Adobe Deflate; 2: horizontal differencing.
    assert_eq!(decoder.get_tag_u32(Tag::Compression).unwrap(), 8);
    assert_eq!(decoder.get_tag_u32(Tag::Predictor).unwrap(), 2);
    let DecodingResult::U16(stored) = decoder.read_image().unwrap() else {
        panic!("not 16-bit");
    };
    assert_eq!(stored.len(), frame.data().len());

    // Every value is a 12-bit count times 16.
    assert!(stored.iter().all(|v| v % 16 == 0));
    for (s, count) in stored.iter().zip(frame.data()) {
        assert_eq!(*s, count << 4);
    }
    // Reference values: the unlit background reads the black level, a stuck pixel the
    // white level, both as the sidecar states them.
    let at = |x: u32, y: u32| {
        let i = 3 * (y as usize * frame.width() as usize + x as usize);
        [stored[i], stored[i + 1], stored[i + 2]]
    };
    assert_eq!(at(0, 0), [1024; 3]);
    let stuck = stored
        .chunks_exact(3)
        .filter(|px| px.iter().all(|&v| u32::from(v) == levels.white_level))
        .count();
    assert!(stuck >= 5, "{stuck} pixels at the white level 65520");
    // The lit white strip spans much of the 16-bit range.
    let white = at(200, 89);
    assert!(
        white.iter().all(|&v| v > 4 * 1024 && v < 65520),
        "{white:?}"
    );
}
