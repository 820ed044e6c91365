//! A second flight world beside the APF-PF paper's hall: a [`warehouse`] of shelf racks and
//! a "forest" of dense thin poles, so that flight figures do not rest on one hall.
//!
//! The hall is 24 x 12 m with a 6 m ceiling. Its west part holds four rows of shelf racks
//! (boxes, 0.9-1.1 m deep, 2.6-4.2 m tall) along x, with three aisles 2.3-2.7 m wide between
//! them; each rack row is cut by one cross-aisle. Thin sprinkler pipes and rack uprights
//! (poles of 40-100 mm) stand in the aisles, off their centreline, leaving at least
//! `WAREHOUSE_PASSAGE_M` on one side. The east part is the forest: 18-26 floor-to-ceiling
//! poles of 30-200 mm at least `WAREHOUSE_FOREST_GAP_M` apart (surface to surface). Regions
//! `A`, `C` and `E` sit at the west end of the three aisles, `B`, `D` and `F` beyond the
//! forest at the east wall (within 1 m of their aisle's line across), all at 1.25 m; routes
//! A-B, C-D and E-F run down an aisle and through the forest, B-A and D-C fly it back.

use rand::{RngExt, SeedableRng};

use super::helpers::{boxed, dist2, perimeter_walls, plane, region, route, uni, uni_count, Rng};
use super::HIGHBAY_FLIGHT_HEIGHT_M;
use crate::spec::{CylinderSpec, WorldSpec};

/// Hall length along x [m].
pub const WAREHOUSE_LENGTH_M: f64 = 24.0;
/// Hall width along y [m].
pub const WAREHOUSE_WIDTH_M: f64 = 12.0;
/// Ceiling height [m].
const CEILING_M: f64 = 6.0;
/// x extent of the rack rows [m].
const RACKS_X_M: (f64, f64) = (3.0, 13.5);
/// x extent of the pole forest [m].
const FOREST_X_M: (f64, f64) = (15.0, 21.5);
/// Least free width kept beside every pole in an aisle [m]: the 540 mm frame with a margin.
pub const WAREHOUSE_PASSAGE_M: f64 = 0.85;
/// Least surface-to-surface gap between two forest poles [m].
pub const WAREHOUSE_FOREST_GAP_M: f64 = 1.1;
/// Least horizontal clearance of any obstacle from a region centre [m].
const REGION_CLEARANCE_M: f64 = 0.9;
/// Radius of the regions [m].
pub const WAREHOUSE_REGION_RADIUS_M: f64 = 0.5;
/// Placement attempts per forest pole.
const MAX_ATTEMPTS: usize = 500;
/// Wall thickness [m].
const WALL_THICKNESS_M: f64 = 0.2;

/// The warehouse for `seed` (module docs).
pub fn warehouse(seed: u64) -> WorldSpec {
    let mut rng = Rng::seed_from_u64(seed);
    let (l, w, h) = (WAREHOUSE_LENGTH_M, WAREHOUSE_WIDTH_M, CEILING_M);
    let mut boxes = perimeter_walls(0.0, l, 0.0, w, 0.0, h, WALL_THICKNESS_M);
    let mut cylinders = Vec::new();

    // Four rack rows across y with three aisles between them, centred across the hall.
    let depths: Vec<f64> = (0..4).map(|_| uni(&mut rng, 0.9, 1.1)).collect();
    let aisles: Vec<f64> = (0..3).map(|_| uni(&mut rng, 2.3, 2.7)).collect();
    let used: f64 = depths.iter().sum::<f64>() + aisles.iter().sum::<f64>();
    let mut y = 0.5 * (w - used); // centred across the hall
    let mut aisle_centres = Vec::with_capacity(3);
    let mut aisle_spans = Vec::with_capacity(3);
    for row in 0..4 {
        let depth = depths[row];
        let height = uni(&mut rng, 2.6, 4.2);
        // One cross-aisle 1.6-2.2 m wide per row, away from the row's ends.
        let gap = uni(&mut rng, 1.6, 2.2);
        let gap_x = uni(&mut rng, RACKS_X_M.0 + 2.0, RACKS_X_M.1 - 2.0 - gap);
        let yc = y + 0.5 * depth;
        for (x0, x1) in [(RACKS_X_M.0, gap_x), (gap_x + gap, RACKS_X_M.1)] {
            boxes.push(boxed([0.5 * (x0 + x1), yc, 0.5 * height], [x1 - x0, depth, height], 0.0, "shelf"));
        }
        y += depth;
        if row < 3 {
            let width = aisles[row];
            aisle_centres.push(y + 0.5 * width);
            aisle_spans.push((y, y + width));
            y += width;
        }
    }

    // Poles in the aisles: 1-3 per aisle, off the centreline toward one side, leaving the
    // passage on the other.
    for &(y0, y1) in &aisle_spans {
        for _ in 0..uni_count(&mut rng, 1, 4) {
            let r = 0.5 * uni(&mut rng, 0.04, 0.10);
            let x = uni(&mut rng, RACKS_X_M.0 + 1.0, RACKS_X_M.1 - 1.0);
            let toward_low = rng.random::<f64>() < 0.5;
            let (lo, hi) = if toward_low { (y0 + r + 0.05, y1 - WAREHOUSE_PASSAGE_M - r) } else { (y0 + WAREHOUSE_PASSAGE_M + r, y1 - r - 0.05) };
            let py = uni(&mut rng, lo.min(hi), hi.max(lo));
            let (a, b) = ([x, py, 0.0], [x, py, h]);
            cylinders.push(CylinderSpec { a, b, radius: r, tag: "pole".into(), dark: false });
        }
    }

    // Regions: the west ends of the aisles and the east wall beyond the forest.
    let west_x = 1.2;
    let east_x = l - 1.2;
    let names = [("A", "B"), ("C", "D"), ("E", "F")];
    let mut centres: Vec<[f64; 2]> = Vec::new();
    let mut regions = Vec::new();
    for (k, (west, east)) in names.iter().enumerate() {
        let yc = aisle_centres[k];
        let east_y = uni(&mut rng, yc - 1.0, yc + 1.0);
        for (name, c) in [(*west, [west_x, yc]), (*east, [east_x, east_y])] {
            centres.push(c);
            regions.push(region(name, [c[0], c[1], HIGHBAY_FLIGHT_HEIGHT_M], WAREHOUSE_REGION_RADIUS_M));
        }
    }

    // The forest: poles of 30-200 mm at least WAREHOUSE_FOREST_GAP_M apart and clear of the
    // regions and the walls.
    let mut forest: Vec<([f64; 2], f64)> = Vec::new();
    for _ in 0..uni_count(&mut rng, 18, 27) {
        let r = 0.5 * uni(&mut rng, 0.03, 0.20);
        for _ in 0..MAX_ATTEMPTS {
            let p = [uni(&mut rng, FOREST_X_M.0, FOREST_X_M.1), uni(&mut rng, 0.8 + r, w - 0.8 - r)];
            let clear = forest.iter().all(|&(q, rq)| dist2(p, q) - r - rq >= WAREHOUSE_FOREST_GAP_M)
                && centres.iter().all(|&c| dist2(p, c) - r >= REGION_CLEARANCE_M);
            if clear {
                forest.push((p, r));
                break;
            }
        }
    }
    for (p, r) in forest {
        cylinders.push(CylinderSpec { a: [p[0], p[1], 0.0], b: [p[0], p[1], h], radius: r, tag: "pole".into(), dark: false });
    }

    WorldSpec {
        name: "warehouse".into(),
        cylinders,
        boxes,
        planes: vec![plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], "floor"), plane([0.0, 0.0, h], [0.0, 0.0, -1.0], "ceiling")],
        regions,
        routes: vec![route("A", "B"), route("C", "D"), route("E", "F"), route("B", "A"), route("D", "C")],
        ..WorldSpec::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spec::BoxSpec;

    fn bits(spec: &WorldSpec) -> String {
        format!("{spec:?}")
    }

    #[test]
    fn a_seed_gives_the_same_world_and_seeds_differ() {
        assert_eq!(bits(&warehouse(5)), bits(&warehouse(5)));
        assert_ne!(bits(&warehouse(5)), bits(&warehouse(6)));
    }

    #[test]
    fn every_aisle_pole_leaves_the_passage_and_the_forest_its_gaps() {
        for seed in 0..50 {
            let spec = warehouse(seed);
            assert_eq!(spec.regions.len(), 6);
            assert_eq!(spec.routes.len(), 5);
            let shelves: Vec<&BoxSpec> = spec.boxes.iter().filter(|b| b.tag == "shelf").collect();
            assert_eq!(shelves.len(), 8, "seed {seed}: four rows cut by a cross-aisle each");
            let poles: Vec<&CylinderSpec> = spec.cylinders.iter().collect();
            for p in &poles {
                let c = [p.a[0], p.a[1]];
                // Clear of the shelves.
                for s in &shelves {
                    let dx = (c[0] - s.centre[0]).abs() - 0.5 * s.size[0];
                    let dy = (c[1] - s.centre[1]).abs() - 0.5 * s.size[1];
                    assert!(dx.max(dy) > p.radius, "seed {seed}: a pole inside a shelf at {c:?}");
                }
                // Clear of every region.
                for r in &spec.regions {
                    assert!(dist2(c, [r.centre[0], r.centre[1]]) - p.radius >= REGION_CLEARANCE_M - 1e-9, "seed {seed}: a pole by region {}", r.name);
                }
            }
            let forest: Vec<&&CylinderSpec> = poles.iter().filter(|p| p.a[0] >= FOREST_X_M.0).collect();
            assert!(forest.len() >= 15, "seed {seed}: {} forest poles", forest.len());
            for (i, p) in forest.iter().enumerate() {
                for q in &forest[i + 1..] {
                    let gap = dist2([p.a[0], p.a[1]], [q.a[0], q.a[1]]) - p.radius - q.radius;
                    assert!(gap >= WAREHOUSE_FOREST_GAP_M - 1e-9, "seed {seed}: forest gap {gap}");
                }
            }
        }
    }
}
