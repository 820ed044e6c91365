//! Seeded property tests of the APF-PF pipeline (proptest): invariants that must hold for
//! any frame, camera and seed.

use proptest::prelude::*;
use subterra::config::{FilterMode, PerceptionConfig};
use subterra::depth::{DepthImage, DepthPerception};
use subterra::{Isometry3, PinholeCamera};

fn small_config(mode: FilterMode) -> PerceptionConfig {
    let mut c = PerceptionConfig::flight();
    c.grid.block_width_px = 8;
    c.grid.block_height_px = 6;
    c.filter.particles = 500;
    c.filter.mode = mode;
    c
}

fn frame_strategy() -> impl Strategy<Value = (u32, u32, Vec<u16>)> {
    (9u32..40, 7u32..30).prop_flat_map(|(w, h)| {
        let n = (w * h) as usize;
        // Mostly in-range depths, some zeros and some beyond the horizon.
        let px = prop_oneof![3 => 100u16..1200, 1 => Just(0u16), 1 => 1200u16..5000];
        (Just(w), Just(h), prop::collection::vec(px, n))
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, rng_seed: proptest::test_runner::RngSeed::Fixed(11), ..ProptestConfig::default() })]

    #[test]
    fn belief_sums_to_one_and_counts_match((w, h, pixels) in frame_strategy(), seed in 0u64..1000, histogram in any::<bool>()) {
        let camera = PinholeCamera::new(20.0, 20.0, w as f64 / 2.0, h as f64 / 2.0, w, h).unwrap();
        let mode = if histogram { FilterMode::Histogram } else { FilterMode::Particle };
        let mut p = DepthPerception::new(camera, Isometry3::body_from_forward_optical(), small_config(mode), seed).unwrap();
        for _ in 0..3 {
            let out = p.update(DepthImage::U16 { pixels: &pixels, scale_m_per_unit: 0.001 }, w, h).unwrap();
            let total: f64 = p.belief().iter().sum();
            prop_assert!((total - 1.0).abs() < 1e-9, "belief sums to {}", total);
            prop_assert!(p.belief().iter().all(|b| (0.0..=1.0 + 1e-12).contains(b)));
            let in_range = pixels.iter().filter(|&&r| (100..1200).contains(&r)).count() as u64;
            prop_assert_eq!(out.in_range_pixels, in_range);
            prop_assert_eq!(p.last_counts().unwrap().counts.iter().map(|&c| c as u64).sum::<u64>(), in_range);
            prop_assert!((0.0..=1.0).contains(&out.p_free));
        }
    }

    #[test]
    fn same_seed_same_bits((w, h, pixels) in frame_strategy(), seed in 0u64..1000) {
        let camera = PinholeCamera::new(20.0, 20.0, w as f64 / 2.0, h as f64 / 2.0, w, h).unwrap();
        let config = small_config(FilterMode::Particle);
        let mut a = DepthPerception::new(camera, Isometry3::body_from_forward_optical(), config, seed).unwrap();
        let mut b = DepthPerception::new(camera, Isometry3::body_from_forward_optical(), config, seed).unwrap();
        for _ in 0..3 {
            let image = DepthImage::U16 { pixels: &pixels, scale_m_per_unit: 0.001 };
            let (oa, ob) = (a.update(image, w, h).unwrap(), b.update(image, w, h).unwrap());
            prop_assert_eq!(&oa.belief_states, &ob.belief_states);
            prop_assert_eq!(oa.belief_probabilities.iter().map(|p| p.to_bits()).collect::<Vec<_>>(),
                            ob.belief_probabilities.iter().map(|p| p.to_bits()).collect::<Vec<_>>());
        }
    }
}

/// A frame with no return at all is an observation ("nothing in range"), not an error.
#[test]
fn all_nan_frame_drives_p_free_up() {
    let camera = PinholeCamera::d435();
    let mut p = DepthPerception::new(camera, Isometry3::body_from_forward_optical(), PerceptionConfig::flight(), 0).unwrap();
    let nan = vec![f32::NAN; camera.pixel_count()];
    let mut last = 0.0;
    for _ in 0..3 {
        last = p.update(DepthImage::F32 { pixels: &nan }, 640, 480).unwrap().p_free;
    }
    assert!(last > 0.95, "P(free) = {last}");
}
