//! The flat bounding-volume hierarchy of the bounded primitives' loosened boxes ([`FlatBvh`]):
//! its binned surface-area build, the f32 slab test of a ray against its nodes ([`Ray32`]),
//! the nearest-hit traversal of single rays and the frustum query of fans.

use glam::DVec3;

use super::fan::Frustum;
use super::leaf::{LeafHit, Solid};
use super::PrimitiveId;

/// Largest number of primitives in a BVH leaf.
const BVH_LEAF_SIZE: usize = 2;
/// Depth of the traversal stack; the builder never makes a deeper tree.
const BVH_STACK: usize = 64;
/// Depth from which the builder splits at the median (so the depth stays below `BVH_STACK`).
const BVH_MEDIAN_DEPTH: usize = 32;
/// Centroid bins of the surface-area split.
const BVH_BINS: usize = 12;

/// Whether a hit at `t` on primitive `id` beats `best` (nearest first, then the lower id),
/// `t <= limit`. The order of testing then never changes the answer.
fn improves(t: f64, id: PrimitiveId, limit: f64, best: Option<(PrimitiveId, LeafHit)>) -> bool {
    t <= limit && best.is_none_or(|(bid, b)| t < b.t || (t == b.t && id < bid))
}

/// f32 bound on the distance of a node worth visiting, loosened so that f32 rounding never
/// culls an f64 hit at `limit`.
fn cutoff32(limit: f64) -> f32 {
    if limit.is_finite() {
        (limit as f32) * (1.0 + 1.0e-5) + 1.0e-4
    } else {
        f32::MAX
    }
}

/// 1 / component, kept finite for the slab test (`|d| < 1e-30` counts as 1e-30).
fn inv_component(d: f64) -> f32 {
    const TINY: f64 = 1.0e-30;
    let d = if d.abs() < TINY { TINY.copysign(d) } else { d };
    (1.0 / d) as f32
}

/// A BVH node: its (loosened, f32) box and either two children or a run of primitives.
#[derive(Debug, Clone, Copy, Default)]
struct FlatNode {
    min: [f32; 3],
    /// Interior: index of the first child (the second follows); leaf: first index into `items`.
    first: u32,
    max: [f32; 3],
    /// 0 for an interior node, else the number of primitives of the leaf.
    count: u32,
}

/// A bounding-volume hierarchy over the bounded primitives, stored flat (depth-first,
/// children adjacent), built with binned surface-area splits.
#[derive(Debug, Clone, Default)]
pub(super) struct FlatBvh {
    nodes: Vec<FlatNode>,
    /// Primitive ids in leaf order.
    items: Vec<u32>,
    /// Loosened f64 box (min, max) of every primitive, by id.
    pub(super) boxes: Vec<(DVec3, DVec3)>,
}

/// A ray in f32 for box tests: origin and finite inverse direction.
struct Ray32 {
    o: [f32; 3],
    inv: [f32; 3],
}

impl Ray32 {
    fn new(o: DVec3, d: DVec3) -> Ray32 {
        Ray32 { o: [o.x as f32, o.y as f32, o.z as f32], inv: [inv_component(d.x), inv_component(d.y), inv_component(d.z)] }
    }

    /// Entry distance into the node's box when it is entered before `cutoff`.
    #[inline(always)]
    fn enter(&self, n: &FlatNode, cutoff: f32) -> Option<f32> {
        let tx1 = (n.min[0] - self.o[0]) * self.inv[0];
        let tx2 = (n.max[0] - self.o[0]) * self.inv[0];
        let ty1 = (n.min[1] - self.o[1]) * self.inv[1];
        let ty2 = (n.max[1] - self.o[1]) * self.inv[1];
        let tz1 = (n.min[2] - self.o[2]) * self.inv[2];
        let tz2 = (n.max[2] - self.o[2]) * self.inv[2];
        let t_near = tx1.min(tx2).max(ty1.min(ty2)).max(tz1.min(tz2)).max(0.0);
        let t_far = tx1.max(tx2).min(ty1.max(ty2)).min(tz1.max(tz2)).min(cutoff);
        (t_near <= t_far).then_some(t_near)
    }
}

fn half_area(lo: DVec3, hi: DVec3) -> f64 {
    let e = (hi - lo).max(DVec3::ZERO);
    e.x * e.y + e.y * e.z + e.z * e.x
}

impl FlatBvh {
    pub(super) fn build(boxes: Vec<(DVec3, DVec3)>) -> FlatBvh {
        let n = boxes.len();
        let mut bvh = FlatBvh { nodes: Vec::with_capacity(2 * n), items: (0..n as u32).collect(), boxes };
        if n > 0 {
            bvh.nodes.push(FlatNode::default());
            bvh.subdivide(0, 0, n, 0);
        }
        bvh
    }

    fn centroid(&self, id: u32) -> DVec3 {
        let (lo, hi) = self.boxes[id as usize];
        (lo + hi) * 0.5
    }

    fn subdivide(&mut self, node: usize, start: usize, end: usize, depth: usize) {
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        let mut clo = lo;
        let mut chi = hi;
        for &id in &self.items[start..end] {
            let (a, b) = self.boxes[id as usize];
            lo = lo.min(a);
            hi = hi.max(b);
            let c = (a + b) * 0.5;
            clo = clo.min(c);
            chi = chi.max(c);
        }
        // The f64 boxes are loosened far beyond f32 rounding: plain conversion stays conservative.
        self.nodes[node].min = [lo.x as f32, lo.y as f32, lo.z as f32];
        self.nodes[node].max = [hi.x as f32, hi.y as f32, hi.z as f32];
        let count = end - start;
        if count <= BVH_LEAF_SIZE || depth + 2 >= BVH_STACK {
            self.nodes[node].first = start as u32;
            self.nodes[node].count = count as u32;
            return;
        }
        let extent = chi - clo;
        let axis = if extent.x >= extent.y && extent.x >= extent.z {
            0
        } else if extent.y >= extent.z {
            1
        } else {
            2
        };
        let mut mid = start + count / 2;
        let binned = depth < BVH_MEDIAN_DEPTH && extent[axis] > 0.0;
        if binned {
            let scale = BVH_BINS as f64 / extent[axis];
            let bin_of = |c: DVec3| (((c[axis] - clo[axis]) * scale) as usize).min(BVH_BINS - 1);
            let mut bins = [(0usize, DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)); BVH_BINS];
            for &id in &self.items[start..end] {
                let (a, b) = self.boxes[id as usize];
                let bin = &mut bins[bin_of((a + b) * 0.5)];
                bin.0 += 1;
                bin.1 = bin.1.min(a);
                bin.2 = bin.2.max(b);
            }
            // Cost of splitting after bin s: left area x count + right area x count.
            let mut right_cost = [0.0; BVH_BINS];
            let (mut n, mut a, mut b) = (0usize, DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
            for s in (1..BVH_BINS).rev() {
                n += bins[s].0;
                a = a.min(bins[s].1);
                b = b.max(bins[s].2);
                right_cost[s] = if n > 0 { half_area(a, b) * n as f64 } else { 0.0 };
            }
            let (mut n, mut a, mut b) = (0usize, DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
            let mut best = (f64::INFINITY, 0usize);
            for s in 1..BVH_BINS {
                n += bins[s - 1].0;
                a = a.min(bins[s - 1].1);
                b = b.max(bins[s - 1].2);
                if n == 0 || n == count {
                    continue;
                }
                let cost = half_area(a, b) * n as f64 + right_cost[s];
                if cost < best.0 {
                    best = (cost, s);
                }
            }
            if best.1 > 0 {
                let split = best.1;
                let (mut i, mut j) = (start, end);
                while i < j {
                    if bin_of(self.centroid(self.items[i])) < split {
                        i += 1;
                    } else {
                        j -= 1;
                        self.items.swap(i, j);
                    }
                }
                mid = i;
            }
        }
        if !binned || mid == start || mid == end {
            mid = start + count / 2;
            let boxes = &self.boxes;
            let key = |id: &u32| {
                let (a, b) = boxes[*id as usize];
                a[axis] + b[axis]
            };
            self.items[start..end].sort_by(|x, y| key(x).total_cmp(&key(y)).then(x.cmp(y)));
        }
        let left = self.nodes.len();
        self.nodes.push(FlatNode::default());
        self.nodes.push(FlatNode::default());
        self.nodes[node].first = left as u32;
        self.nodes[node].count = 0;
        self.subdivide(left, start, mid, depth + 1);
        self.subdivide(left + 1, mid, end, depth + 1);
    }

    /// Nearest primitive hit along the unit ray within `max_t` (nearest, then lowest id).
    pub(super) fn cast(&self, solids: &[Solid], o: DVec3, d: DVec3, max_t: f64) -> Option<(PrimitiveId, LeafHit)> {
        let root = self.nodes.first()?;
        let ray = Ray32::new(o, d);
        let mut cutoff = cutoff32(max_t);
        ray.enter(root, cutoff)?;
        let mut best: Option<(PrimitiveId, LeafHit)> = None;
        let mut limit = max_t;
        let mut stack = [(0u32, 0.0f32); BVH_STACK];
        let mut sp = 0usize;
        let mut node = 0usize;
        loop {
            let n = self.nodes[node];
            if n.count > 0 {
                let first = n.first as usize;
                for &id in &self.items[first..first + n.count as usize] {
                    if let Some(hit) = solids[id as usize].cast(o, d) {
                        if improves(hit.t, id, limit, best) {
                            limit = hit.t;
                            cutoff = cutoff32(limit);
                            best = Some((id, hit));
                        }
                    }
                }
            } else {
                let a = n.first as usize;
                let ta = ray.enter(&self.nodes[a], cutoff);
                let tb = ray.enter(&self.nodes[a + 1], cutoff);
                match (ta, tb) {
                    (Some(ta), Some(tb)) => {
                        let (near, far, t_far) = if ta <= tb { (a, a + 1, tb) } else { (a + 1, a, ta) };
                        stack[sp] = (far as u32, t_far);
                        sp += 1;
                        node = near;
                        continue;
                    }
                    (Some(_), None) => {
                        node = a;
                        continue;
                    }
                    (None, Some(_)) => {
                        node = a + 1;
                        continue;
                    }
                    (None, None) => {}
                }
            }
            loop {
                if sp == 0 {
                    return best;
                }
                sp -= 1;
                let (next, t) = stack[sp];
                if t <= cutoff {
                    node = next as usize;
                    break;
                }
            }
        }
    }

    /// Ids of the primitives whose boxes may meet `frustum`, through the tree.
    pub(super) fn visible(&self, frustum: &Frustum, out: &mut Vec<u32>) {
        if self.nodes.is_empty() {
            return;
        }
        let mut stack = Vec::with_capacity(BVH_STACK);
        stack.push(0usize);
        while let Some(node) = stack.pop() {
            let n = self.nodes[node];
            let lo = DVec3::new(f64::from(n.min[0]), f64::from(n.min[1]), f64::from(n.min[2]));
            let hi = DVec3::new(f64::from(n.max[0]), f64::from(n.max[1]), f64::from(n.max[2]));
            if !frustum.meets(lo, hi) {
                continue;
            }
            if n.count > 0 {
                let first = n.first as usize;
                for &id in &self.items[first..first + n.count as usize] {
                    let (a, b) = self.boxes[id as usize];
                    if frustum.meets(a, b) {
                        out.push(id);
                    }
                }
            } else {
                stack.push(n.first as usize + 1);
                stack.push(n.first as usize);
            }
        }
    }
}
