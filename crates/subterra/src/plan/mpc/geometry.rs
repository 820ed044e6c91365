//! Risk-grid look-ups, lethal cells grouped into convex polygons, and the signed distance
//! between the robot's rectangle and a convex polygon.
//!
//! **Grouping.** The cells with `risk >= lethal_risk` inside a square window around the
//! robot are labelled into 8-connected regions (flood fill in row-major order, so labels are
//! deterministic). Each region is one piece to start with. A piece's polygon is the convex
//! hull of the corners of its cells (Andrew's monotone chain on integer corner coordinates,
//! exact). When that hull covers more free area than `max_overhang` cells per cell of the
//! piece's longer bounding-box side (a mean overhang of the hull beyond the cells), the piece
//! is cut in two at the middle of that side and each half is treated the same way; single
//! cells are always kept. So a convex blob or a straight wall is one polygon, an L or a ring
//! is cut into nearly convex parts, and the polygons cover every lethal cell of the window
//! and hardly any free one. Polygons come out region by region, lower halves first.
//!
//! **Signed distance** between two convex polygons (the robot's rectangle `R` at a pose, an
//! obstacle `P`): when a separating axis exists among the edge normals of both, the exact
//! distance is the smallest vertex-to-edge distance between them; otherwise it is minus the
//! penetration depth, the smallest overlap over those axes (the separating-axis theorem).
//! The witness is a point of the robot (`w`) and the unit normal `n` pointing from the
//! obstacle to the robot: moving the robot by `δ` along `n` changes the distance by `δ`.

use glam::DVec2;

use crate::plan::grid::RiskGrid;

/// A convex polygon in the world frame, vertices counter-clockwise.
#[derive(Debug, Clone, PartialEq)]
pub struct ConvexPolygon {
    /// Vertices \[m\], counter-clockwise, no three collinear.
    pub vertices: Vec<DVec2>,
    /// Mean of the vertices \[m\].
    pub centre: DVec2,
    /// Largest distance from `centre` to a vertex \[m\].
    pub radius_m: f64,
}

impl ConvexPolygon {
    /// A polygon from counter-clockwise vertices (at least three, no three collinear).
    pub fn new(vertices: Vec<DVec2>) -> Self {
        let centre = vertices.iter().copied().sum::<DVec2>() / vertices.len() as f64;
        let radius_m = vertices.iter().map(|v| v.distance(centre)).fold(0.0, f64::max);
        Self { vertices, centre, radius_m }
    }
}

/// The robot's footprint rectangle at a pose: its corners in the world frame,
/// counter-clockwise from the front right.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Footprint {
    pub corners: [DVec2; 4],
}

impl Footprint {
    /// The `length x width` rectangle centred on `position` with body x along `heading_rad`.
    pub(super) fn at(position: DVec2, heading_rad: f64, length_m: f64, width_m: f64) -> Self {
        let (sin, cos) = heading_rad.sin_cos();
        let heading = DVec2::new(cos, sin);
        let (hl, hw) = (0.5 * length_m, 0.5 * width_m);
        let body = [DVec2::new(hl, -hw), DVec2::new(hl, hw), DVec2::new(-hl, hw), DVec2::new(-hl, -hw)];
        Self { corners: body.map(|b| position + heading.rotate(b)) }
    }
}

/// Signed distance between a footprint and a polygon with its witness.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Separation {
    /// Signed distance \[m\]: > 0 apart, < 0 overlapping (minus the penetration depth).
    pub distance_m: f64,
    /// Unit normal from the obstacle toward the robot.
    pub normal: DVec2,
    /// The robot's witness point, world frame \[m\].
    pub witness: DVec2,
}

/// Closest point of segment `[a, b]` to `p`.
#[inline]
fn closest_on_segment(p: DVec2, a: DVec2, b: DVec2) -> DVec2 {
    let e = b - a;
    let t = ((p - a).dot(e) / e.length_squared()).clamp(0.0, 1.0);
    a + t * e
}

/// Outward unit normal of the counter-clockwise edge `a -> b`.
#[inline]
fn outward(a: DVec2, b: DVec2) -> DVec2 {
    let e = (b - a).normalize();
    DVec2::new(e.y, -e.x)
}

/// A face of the configuration-space obstacle of a polygon: an edge of the polygon (its
/// outward normal) or an edge of the robot's rectangle (minus its outward normal).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Face {
    /// Edge `i -> i+1` of the polygon.
    Polygon(usize),
    /// Edge `i -> i+1` of the footprint's corners.
    Robot(usize),
}

/// The separation of the footprint along one face: `min over the other shape's vertices`
/// of the distance outside the face's edge line, with the normal (obstacle to robot) and
/// the robot's witness point.
fn face_separation(robot: &Footprint, polygon: &ConvexPolygon, face: Face) -> Separation {
    let r = &robot.corners;
    let p = &polygon.vertices;
    let deepest = |n: DVec2, a: DVec2, vertices: &[DVec2]| {
        let mut best = (f64::INFINITY, 0usize);
        for (i, v) in vertices.iter().enumerate() {
            let d = n.dot(*v - a);
            if d < best.0 {
                best = (d, i);
            }
        }
        best
    };
    match face {
        Face::Polygon(i) => {
            let (a, b) = (p[i], p[(i + 1) % p.len()]);
            let n = outward(a, b);
            let (d, j) = deepest(n, a, r);
            Separation { distance_m: d, normal: n, witness: r[j] }
        }
        Face::Robot(i) => {
            let (a, b) = (r[i], r[(i + 1) % 4]);
            let m = outward(a, b);
            let (d, j) = deepest(m, a, p);
            // The robot's witness: the foot of the obstacle's deepest vertex on the edge's line.
            Separation { distance_m: d, normal: -m, witness: p[j] - d * m }
        }
    }
}

/// The two robot corners deepest toward the polygon along `normal` (obstacle to robot), each
/// with `normal·corner - max over the polygon's vertices of normal·vertex`: how far the corner
/// is beyond the polygon's supporting line of that normal. Keeping every corner beyond that
/// line by `m` keeps the whole rectangle at distance `>= m` from the polygon; at the normal of
/// [`separation`] the smaller value is the signed distance itself. Two corners, because when
/// an edge of the robot is parallel to the line both are about as deep and a heading change
/// moves one in and the other out.
pub(crate) fn supporting_corners(robot: &Footprint, polygon: &ConvexPolygon, normal: DVec2) -> [(f64, DVec2); 2] {
    let support = polygon.vertices.iter().map(|v| normal.dot(*v)).fold(f64::NEG_INFINITY, f64::max);
    let mut best = [(f64::INFINITY, DVec2::ZERO); 2];
    for &c in &robot.corners {
        let d = normal.dot(c) - support;
        if d < best[0].0 {
            best[1] = best[0];
            best[0] = (d, c);
        } else if d < best[1].0 {
            best[1] = (d, c);
        }
    }
    best
}

/// The signed distance between the footprint and the polygon (`MpcTracker`'s docs).
pub(crate) fn separation(robot: &Footprint, polygon: &ConvexPolygon) -> Separation {
    let faces = (0..polygon.vertices.len()).map(Face::Polygon).chain((0..4).map(Face::Robot));
    let mut axis = Separation { distance_m: f64::NEG_INFINITY, normal: DVec2::X, witness: DVec2::ZERO };
    for face in faces {
        let sep = face_separation(robot, polygon, face);
        if sep.distance_m > axis.distance_m {
            axis = sep;
        }
    }
    if axis.distance_m <= 0.0 {
        return axis;
    }
    let r = &robot.corners;
    let p = &polygon.vertices;
    // Apart: the exact distance is the smallest vertex-to-edge distance.
    let mut best = (f64::INFINITY, DVec2::ZERO, DVec2::ZERO); // (d², robot point, obstacle point)
    for &v in r {
        for i in 0..p.len() {
            let q = closest_on_segment(v, p[i], p[(i + 1) % p.len()]);
            let d2 = v.distance_squared(q);
            if d2 < best.0 {
                best = (d2, v, q);
            }
        }
    }
    for &v in p {
        for i in 0..4 {
            let q = closest_on_segment(v, r[i], r[(i + 1) % 4]);
            let d2 = v.distance_squared(q);
            if d2 < best.0 {
                best = (d2, q, v);
            }
        }
    }
    let d = best.0.sqrt();
    Separation { distance_m: d, normal: (best.1 - best.2) / d, witness: best.1 }
}

/// The interval `(lo, hi)` of offsets `o` for which the footprint `robot` (corners relative
/// to its centre, i.e. placed at the origin with its heading) centred at `point + o·dir` is
/// within `inflate` of `polygon`, if any. The centre is that close exactly when it lies in the
/// configuration-space obstacle `polygon ⊕ (-robot)` grown by `inflate`; that set is taken as
/// the intersection of the half-planes of its faces (the polygon's edges and the robot's
/// axes) each pushed out by `inflate`, which is conservative at its corners (a polygon instead
/// of rounded corners), and a line meets a convex polygon in one interval.
pub(crate) fn blocked_offsets(robot: &Footprint, polygon: &ConvexPolygon, point: DVec2, dir: DVec2, inflate: f64) -> Option<(f64, f64)> {
    let p = &polygon.vertices;
    let axis = (robot.corners[0] - robot.corners[3]).normalize_or_zero();
    let robot_normals = [axis, -axis, axis.perp(), -axis.perp()];
    let polygon_normals = (0..p.len()).map(|i| outward(p[i], p[(i + 1) % p.len()]));
    let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
    for n in polygon_normals.chain(robot_normals) {
        // Support of the configuration-space obstacle along n, grown by `inflate`.
        let support_p = p.iter().map(|v| n.dot(*v)).fold(f64::NEG_INFINITY, f64::max);
        let support_r = robot.corners.iter().map(|c| -n.dot(*c)).fold(f64::NEG_INFINITY, f64::max);
        let limit = support_p + support_r + inflate - n.dot(point);
        // Inside this face's half-plane: o·(n·dir) <= limit.
        let slope = n.dot(dir);
        if slope.abs() < 1e-12 {
            if limit < 0.0 {
                return None;
            }
        } else if slope > 0.0 {
            hi = hi.min(limit / slope);
        } else {
            lo = lo.max(limit / slope);
        }
    }
    (lo < hi).then_some((lo, hi))
}

/// Reusable buffers of [`lethal_polygons`].
#[derive(Debug, Default, Clone)]
pub(crate) struct PolygonScratch {
    labels: Vec<u32>,
    stack: Vec<(usize, usize)>,
    /// Cells `(gy, gx)` (grid indices), grouped by region.
    cells: Vec<(i64, i64)>,
    /// Start of each region's cells in `cells`.
    starts: Vec<usize>,
    /// Pieces still to look at: ranges of `cells`.
    pieces: Vec<(usize, usize)>,
    points: Vec<(i64, i64)>,
    hull: Vec<(i64, i64)>,
}

/// Convex polygons covering the cells with `risk >= lethal` within the square of half-side
/// `radius_m` around `centre` (`MpcTracker`'s docs): each 8-connected region is split at the middle
/// of its bounding box's longer side until the convex hull of each piece covers at most
/// `max_overhang_cells` free cells per cell of the piece's longer side.
pub(crate) fn lethal_polygons(
    grid: &RiskGrid<'_>,
    centre: DVec2,
    radius_m: f64,
    lethal: f32,
    max_overhang_cells: f64,
    scratch: &mut PolygonScratch,
    out: &mut Vec<ConvexPolygon>,
) {
    out.clear();
    let res = grid.resolution_m;
    let lo = ((centre - radius_m - grid.origin_m) / res).floor();
    let hi = ((centre + radius_m - grid.origin_m) / res).floor();
    if !(lo.is_finite() && hi.is_finite()) || hi.x < 0.0 || hi.y < 0.0 || lo.x >= grid.nx as f64 || lo.y >= grid.ny as f64 {
        return;
    }
    let x0 = lo.x.max(0.0) as usize;
    let y0 = lo.y.max(0.0) as usize;
    let x1 = (hi.x as usize).min(grid.nx - 1);
    let y1 = (hi.y as usize).min(grid.ny - 1);
    let (w, h) = (x1 - x0 + 1, y1 - y0 + 1);
    let lethal_at = |wx: usize, wy: usize| grid.risk[(y0 + wy) * grid.nx + x0 + wx] >= lethal;

    // 8-connected regions, labelled in row-major order of their first cell; each region's
    // cells are collected in the order the flood fill reaches them.
    let labels = &mut scratch.labels;
    labels.clear();
    labels.resize(w * h, 0);
    scratch.cells.clear();
    scratch.starts.clear();
    let mut next = 0u32;
    for wy in 0..h {
        for wx in 0..w {
            if labels[wy * w + wx] != 0 || !lethal_at(wx, wy) {
                continue;
            }
            next += 1;
            scratch.starts.push(scratch.cells.len());
            labels[wy * w + wx] = next;
            scratch.stack.push((wx, wy));
            while let Some((cx, cy)) = scratch.stack.pop() {
                scratch.cells.push(((y0 + cy) as i64, (x0 + cx) as i64));
                for ny in cy.saturating_sub(1)..=(cy + 1).min(h - 1) {
                    for nx in cx.saturating_sub(1)..=(cx + 1).min(w - 1) {
                        if labels[ny * w + nx] == 0 && lethal_at(nx, ny) {
                            labels[ny * w + nx] = next;
                            scratch.stack.push((nx, ny));
                        }
                    }
                }
            }
        }
    }
    scratch.starts.push(scratch.cells.len());

    for region in 0..next as usize {
        scratch.pieces.clear();
        scratch.pieces.push((scratch.starts[region], scratch.starts[region + 1]));
        while let Some((start, end)) = scratch.pieces.pop() {
            let cells = &mut scratch.cells[start..end];
            // Row-major order: each row's cells are contiguous, leftmost first.
            cells.sort_unstable();
            let (mut gx_min, mut gx_max) = (i64::MAX, i64::MIN);
            scratch.points.clear();
            let mut i = 0;
            while i < cells.len() {
                let gy = cells[i].0;
                let first = cells[i].1;
                while i + 1 < cells.len() && cells[i + 1].0 == gy {
                    i += 1;
                }
                let last = cells[i].1 + 1;
                gx_min = gx_min.min(first);
                gx_max = gx_max.max(last);
                scratch.points.extend([(first, gy), (last, gy), (first, gy + 1), (last, gy + 1)]);
                i += 1;
            }
            let (gy_min, gy_max) = (cells[0].0, cells[cells.len() - 1].0 + 1);
            convex_hull(&mut scratch.points, &mut scratch.hull);
            let twice_area: i64 = (0..scratch.hull.len())
                .map(|k| {
                    let (a, b) = (scratch.hull[k], scratch.hull[(k + 1) % scratch.hull.len()]);
                    a.0 * b.1 - a.1 * b.0
                })
                .sum();
            let free_cells = 0.5 * twice_area as f64 - cells.len() as f64;
            let (span_x, span_y) = (gx_max - gx_min, gy_max - gy_min);
            if cells.len() == 1 || free_cells <= max_overhang_cells * span_x.max(span_y) as f64 {
                let vertices = scratch.hull.iter().map(|&(x, y)| grid.origin_m + res * DVec2::new(x as f64, y as f64)).collect();
                out.push(ConvexPolygon::new(vertices));
                continue;
            }
            // Split at the middle of the longer side; the lower half is looked at first.
            let (mid, along_x) = if span_x >= span_y { (gx_min + span_x / 2, true) } else { (gy_min + span_y / 2, false) };
            let key = |c: &(i64, i64)| if along_x { c.1 } else { c.0 };
            let split = start + partition_in_place(&mut scratch.cells[start..end], |c| key(c) < mid);
            scratch.pieces.push((split, end));
            scratch.pieces.push((start, split));
        }
    }
}

/// Moves the items satisfying `low` to the front (order inside each side is not kept);
/// returns how many there are.
fn partition_in_place<T>(items: &mut [T], low: impl Fn(&T) -> bool) -> usize {
    let mut split = 0;
    for i in 0..items.len() {
        if low(&items[i]) {
            items.swap(split, i);
            split += 1;
        }
    }
    split
}

/// Andrew's monotone chain: the counter-clockwise hull of `points` (sorted in place),
/// without collinear vertices, starting at the lowest-leftmost point.
fn convex_hull(points: &mut [(i64, i64)], hull: &mut Vec<(i64, i64)>) {
    points.sort_unstable();
    hull.clear();
    let cross = |o: (i64, i64), a: (i64, i64), b: (i64, i64)| (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0);
    for &p in points.iter() {
        while hull.len() >= 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0 {
            hull.pop();
        }
        hull.push(p);
    }
    let lower = hull.len() + 1;
    for &p in points.iter().rev().skip(1) {
        while hull.len() >= lower && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0 {
            hull.pop();
        }
        hull.push(p);
    }
    hull.pop();
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(x0: f64, y0: f64, side: f64) -> ConvexPolygon {
        ConvexPolygon::new(vec![
            DVec2::new(x0, y0),
            DVec2::new(x0 + side, y0),
            DVec2::new(x0 + side, y0 + side),
            DVec2::new(x0, y0 + side),
        ])
    }

    #[test]
    fn grid_lookup_and_validation() {
        let risk = [0.0, 0.5, f32::NAN, 1.0, 0.2, 0.3];
        let g = RiskGrid::new(&risk, 3, 2, 0.5, DVec2::new(-1.0, 2.0)).unwrap();
        assert_eq!(g.risk_at(DVec2::new(-0.4, 2.1)), Some(0.5));
        assert_eq!(g.risk_at(DVec2::new(-0.6, 2.1)), Some(0.0));
        assert_eq!(g.risk_at(DVec2::new(0.4, 2.4)), None); // NaN: unknown
        assert_eq!(g.risk_at(DVec2::new(-0.9, 2.9)), Some(1.0));
        assert_eq!(g.risk_at(DVec2::new(-1.1, 2.1)), None);
        assert!(RiskGrid::new(&risk, 2, 2, 0.5, DVec2::ZERO).unwrap_err().to_string().contains("`risk`"));
        assert!(RiskGrid::new(&risk, 3, 2, 0.0, DVec2::ZERO).unwrap_err().to_string().contains("`resolution`"));
        assert!(RiskGrid::new(&risk, 3, 2, 0.1, DVec2::new(f64::NAN, 0.0)).unwrap_err().to_string().contains("`origin`"));
        let bad = [0.0, 1.5];
        assert!(RiskGrid::new(&bad, 2, 1, 0.1, DVec2::ZERO).unwrap_err().to_string().contains("[0, 1]"));
    }

    #[test]
    fn separation_by_hand() {
        // Robot 2 x 1 at the origin facing +x; a unit square 1.5 m ahead of its front face.
        let robot = Footprint::at(DVec2::ZERO, 0.0, 2.0, 1.0);
        let s = separation(&robot, &square(2.5, -0.5, 1.0));
        assert!((s.distance_m - 1.5).abs() < 1e-12 && (s.normal - DVec2::new(-1.0, 0.0)).length() < 1e-12, "{s:?}");
        assert!((s.witness.x - 1.0).abs() < 1e-12);
        // Corner to corner: the square's lower-left corner at (2, 1.5), 1 m right and 1 m above (1, 0.5).
        let s = separation(&robot, &square(2.0, 1.5, 1.0));
        assert!((s.distance_m - 2f64.sqrt()).abs() < 1e-12, "{s:?}");
        assert!((s.witness - DVec2::new(1.0, 0.5)).length() < 1e-12);
        // Overlap by 0.25 m through the front face.
        let s = separation(&robot, &square(0.75, -0.2, 1.0));
        assert!((s.distance_m + 0.25).abs() < 1e-12 && (s.normal - DVec2::new(-1.0, 0.0)).length() < 1e-12, "{s:?}");
        // Rotated robot: a quarter turn makes it 1 wide along x, so the square at x = 2.5 is 2 m away.
        let robot = Footprint::at(DVec2::ZERO, std::f64::consts::FRAC_PI_2, 2.0, 1.0);
        let s = separation(&robot, &square(2.5, -0.5, 1.0));
        assert!((s.distance_m - 2.0).abs() < 1e-12, "{s:?}");
    }

    #[test]
    fn blocked_offsets_by_hand() {
        // Robot 2 x 1 facing +x at the origin; a unit square whose near edge is 0.2 m above
        // the robot's left side (y from 0.7 to 1.7, x from -0.5 to 0.5); offsets along +y.
        let robot = Footprint::at(DVec2::ZERO, 0.0, 2.0, 1.0);
        let square = square(-0.5, 0.7, 1.0);
        // Within 0.1 of it: the centre's y in (0.7 - 0.5 - 0.1, 1.7 + 0.5 + 0.1) = (0.1, 2.3).
        let (lo, hi) = blocked_offsets(&robot, &square, DVec2::ZERO, DVec2::Y, 0.1).unwrap();
        assert!((lo - 0.1).abs() < 1e-12 && (hi - 2.3).abs() < 1e-12, "{lo} {hi}");
        // Sliding along x past it: x in (-0.5 - 1 - 0.3, 0.5 + 1 + 0.3) only if y overlaps.
        let (lo, hi) = blocked_offsets(&robot, &square, DVec2::new(0.0, 0.5), DVec2::X, 0.3).unwrap();
        assert!((lo + 1.8).abs() < 1e-12 && (hi - 1.8).abs() < 1e-12, "{lo} {hi}");
        assert!(blocked_offsets(&robot, &square, DVec2::new(0.0, -1.0), DVec2::X, 0.3).is_none());
    }

    #[test]
    fn separation_gradient_matches_finite_differences() {
        let poly = ConvexPolygon::new(vec![DVec2::new(1.0, 0.8), DVec2::new(2.0, 0.6), DVec2::new(2.3, 1.5), DVec2::new(1.2, 1.9)]);
        for &(x, y, th) in &[(0.0, 0.0, 0.3), (0.4, 0.5, 1.2), (1.4, 0.7, -0.4), (-0.5, 2.5, 2.0)] {
            let f = |x: f64, y: f64, th: f64| separation(&Footprint::at(DVec2::new(x, y), th, 0.99, 0.67), &poly).distance_m;
            let s = separation(&Footprint::at(DVec2::new(x, y), th, 0.99, 0.67), &poly);
            let e = 1e-6;
            let gx = (f(x + e, y, th) - f(x - e, y, th)) / (2.0 * e);
            let gy = (f(x, y + e, th) - f(x, y - e, th)) / (2.0 * e);
            let gt = (f(x, y, th + e) - f(x, y, th - e)) / (2.0 * e);
            // d(witness)/dθ for a body-fixed witness: the arm from the centre turned by 90°.
            let dw_dth = (s.witness - DVec2::new(x, y)).perp();
            assert!((gx - s.normal.x).abs() < 1e-6 && (gy - s.normal.y).abs() < 1e-6, "({x},{y},{th}): {gx} {gy} vs {:?}", s.normal);
            assert!((gt - s.normal.dot(dw_dth)).abs() < 1e-5, "({x},{y},{th}): {gt} vs {}", s.normal.dot(dw_dth));
        }
    }

    /// Whether the centre of every lethal cell is inside (or on) some polygon.
    fn covers_all(risk: &[f32], nx: usize, origin: DVec2, res: f64, polys: &[ConvexPolygon]) -> bool {
        (0..risk.len()).filter(|&i| risk[i] >= 0.9).all(|i| {
            let c = origin + res * DVec2::new((i % nx) as f64 + 0.5, (i / nx) as f64 + 0.5);
            polys.iter().any(|p| (0..p.vertices.len()).all(|k| outward(p.vertices[k], p.vertices[(k + 1) % p.vertices.len()]).dot(c - p.vertices[k]) <= 0.0))
        })
    }

    #[test]
    fn lethal_regions_become_covering_hulls() {
        // 10 x 10 grid at 0.1 m: an L of lethal cells and a separate single cell.
        let mut risk = vec![0.0f32; 100];
        for ix in 2..7 {
            risk[3 * 10 + ix] = 1.0;
        }
        for iy in 3..8 {
            risk[iy * 10 + 2] = 1.0;
        }
        risk[9 * 10 + 9] = 0.95;
        let origin = DVec2::new(-0.5, -0.5);
        let grid = RiskGrid::new(&risk, 10, 10, 0.1, origin).unwrap();
        let mut scratch = PolygonScratch::default();
        let mut polys = Vec::new();
        lethal_polygons(&grid, DVec2::ZERO, 10.0, 0.9, 1.0, &mut scratch, &mut polys);
        // The L's hull would cover 8 free cells over a 5-cell side (more than 1 per cell):
        // it is split; then the single cell.
        assert!(covers_all(&risk, 10, origin, 0.1, &polys), "{polys:?}");
        assert!(polys.len() >= 3, "{polys:?}");
        let last = polys.last().unwrap();
        assert_eq!(last.vertices.len(), 4);
        for v in &last.vertices {
            assert!([0.4, 0.5].iter().any(|e| (v.x - e).abs() < 1e-12) && [0.4, 0.5].iter().any(|e| (v.y - e).abs() < 1e-12), "{last:?}");
        }
        // A convex block is one polygon, its exact rectangle.
        let mut risk = vec![0.0f32; 100];
        for iy in 4..7 {
            for ix in 1..9 {
                risk[iy * 10 + ix] = 1.0;
            }
        }
        let grid = RiskGrid::new(&risk, 10, 10, 0.1, origin).unwrap();
        lethal_polygons(&grid, DVec2::ZERO, 10.0, 0.9, 1.0, &mut scratch, &mut polys);
        assert_eq!(polys.len(), 1, "{polys:?}");
        assert_eq!(polys[0].vertices.len(), 4);
        assert!((polys[0].centre - DVec2::new(0.0, 0.05)).length() < 1e-12, "{:?}", polys[0]);
        // A window far away sees nothing.
        lethal_polygons(&grid, DVec2::new(50.0, 50.0), 1.0, 0.9, 1.0, &mut scratch, &mut polys);
        assert!(polys.is_empty());
    }

    #[test]
    fn a_ring_is_split_until_no_hull_covers_its_hole() {
        // A 20 x 20 ring two cells thick around a 16 x 16 free hole.
        let n = 24;
        let mut risk = vec![0.0f32; n * n];
        for iy in 2..22 {
            for ix in 2..22 {
                if !(4..20).contains(&ix) || !(4..20).contains(&iy) {
                    risk[iy * n + ix] = 1.0;
                }
            }
        }
        let origin = DVec2::new(-1.2, -1.2);
        let grid = RiskGrid::new(&risk, n, n, 0.1, origin).unwrap();
        let (mut scratch, mut polys) = (PolygonScratch::default(), Vec::new());
        lethal_polygons(&grid, DVec2::ZERO, 10.0, 0.9, 1.0, &mut scratch, &mut polys);
        assert!(covers_all(&risk, n, origin, 0.1, &polys));
        // The hole's centre region (0.6 m around the middle) is free of every polygon.
        for p in &polys {
            let inside = (0..p.vertices.len()).all(|k| outward(p.vertices[k], p.vertices[(k + 1) % p.vertices.len()]).dot(DVec2::ZERO - p.vertices[k]) <= 0.0);
            assert!(!inside, "{p:?}");
            let robot = Footprint::at(DVec2::ZERO, 0.0, 0.6, 0.6);
            assert!(separation(&robot, p).distance_m > 0.45, "{p:?}");
        }
    }

    #[test]
    fn hull_drops_collinear_points() {
        let mut pts = vec![(0, 0), (1, 0), (2, 0), (2, 1), (0, 1), (1, 1)];
        let mut hull = Vec::new();
        convex_hull(&mut pts, &mut hull);
        assert_eq!(hull, vec![(0, 0), (2, 0), (2, 1), (0, 1)]);
    }
}
