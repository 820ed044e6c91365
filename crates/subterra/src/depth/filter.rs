//! Bayes filters over the voxel states: a particle filter (the paper's) and an exact
//! histogram filter over the same model.
//!
//! Particles carry nothing but their state, so the particle set is kept as a count per
//! state: propagating each of the `c` particles in state `s` by one draw, weighting every
//! particle by its new state's likelihood and resampling with pointers over the particles
//! ordered by state is the textbook filter, step for step, in O(N + S) time and memory.
//!
//! The draw uses a defensive proposal for the free state: from `s` a particle goes to
//! `s_free` with `q(s) = max(T(s -> s_free), q_min)` and otherwise to a voxel drawn from
//! `T(s, ·)` restricted to the grid; its weight carries the ratio `T/q` of the branch
//! taken (`T(s->free)/q(s)` or `(1 - T(s->free))/(1 - q(s))`). With `q_min = 0` this is the
//! paper's bootstrap filter exactly; with `q_min > 0` the estimate is still unbiased, but
//! the free state, which the model reaches with probability ~3e-5 per frame, is no longer
//! missed by chance on an empty frame.

use rand::Rng;
use rand::SeedableRng;
use rand_distr::{Binomial, Distribution};
use rand_pcg::Pcg64Mcg;
use rand_xoshiro::Xoshiro256PlusPlus;

use super::transition::TransitionModel;
use crate::config::Resampling;

/// A uniform f64 in `[0, 1)` from 53 random bits.
#[inline]
fn unit_f64(r: u64) -> f64 {
    (r >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// The filter's random stream: xoshiro256++ (rust-random's `rand_xoshiro`), seeded from the
/// caller's seeded generator. Its state advances without a multiply, so successive draws
/// do not wait on each other as a multiplicative generator's do.
type FilterRng = Xoshiro256PlusPlus;

/// The proposal of one source state: the 32-bit threshold below which a particle goes to
/// `s_free`, and the importance ratios `T/q` of the two branches.
#[derive(Debug, Clone, Copy)]
struct Proposal {
    /// `q(s)`, the probability of proposing `s_free`.
    q: f64,
    free_threshold: u32,
    always_free: bool,
    free_ratio: f64,
    voxel_ratio: f64,
}

/// Particle filter with `N` particles kept as counts per state.
#[derive(Debug, Clone)]
pub(super) struct ParticleFilter {
    particles: usize,
    resampling: Resampling,
    counts: Vec<u32>,
    /// Importance weight per state after propagation (Σ of `T/q` of the particles there).
    mass: Vec<f64>,
    proposals: Vec<Proposal>,
    rng: FilterRng,
    /// Scratch: the voxel targets drawn for one source state.
    targets: Vec<u32>,
}

impl ParticleFilter {
    /// `particles` spread evenly over the model's states (particle `p` starts in state
    /// `p mod S`); `free_proposal_min` is `q_min` of the module docs, in `[0, 1)`.
    pub(super) fn new(model: &TransitionModel, particles: usize, resampling: Resampling, free_proposal_min: f64, rng: Pcg64Mcg) -> Self {
        let states = model.state_count();
        let mut counts = vec![0u32; states];
        for p in 0..particles {
            counts[p % states] += 1;
        }
        let proposals = (0..states)
            .map(|s| {
                let t = model.p_free(s);
                let q = t.max(free_proposal_min);
                Proposal {
                    q,
                    free_threshold: (q * 4_294_967_296.0).min(u32::MAX as f64) as u32,
                    always_free: q >= 1.0,
                    free_ratio: if q > 0.0 { t / q } else { 0.0 },
                    voxel_ratio: if q < 1.0 { (1.0 - t) / (1.0 - q) } else { 0.0 },
                }
            })
            .collect();
        let mut rng = rng;
        let rng = FilterRng::seed_from_u64(rng.next_u64());
        Self { particles, resampling, counts, mass: vec![0.0; states], proposals, rng, targets: Vec::new() }
    }

    /// Particles per state.
    #[cfg(test)]
    pub(super) fn counts(&self) -> &[u32] {
        &self.counts
    }

    /// Moves every particle by one draw from the proposal, accumulating its weight `T/q`.
    ///
    /// The particles of one state are exchangeable, so instead of one free-or-voxel coin per
    /// particle the number that goes free is one `Binomial(c, q)` draw, and the rest draw
    /// voxel targets in a batch: the same joint distribution of where they land.
    pub(super) fn propagate(&mut self, model: &TransitionModel) {
        self.mass.fill(0.0);
        let free = self.counts.len() - 1;
        let mut targets = std::mem::take(&mut self.targets);
        for (s, &c) in self.counts.iter().enumerate() {
            if c == 0 {
                continue;
            }
            let p = self.proposals[s];
            if s == free {
                for _ in 0..c {
                    if p.always_free || ((self.rng.next_u64() >> 32) as u32) < p.free_threshold {
                        self.mass[free] += p.free_ratio;
                    } else {
                        self.mass[model.sample_voxel(s, &mut self.rng)] += p.voxel_ratio;
                    }
                }
                continue;
            }
            let going_free = if p.always_free {
                c as u64
            } else if p.q > 0.0 {
                // q is in (0, 1) here, so the distribution exists; 0 would only lose mass.
                Binomial::new(c as u64, p.q).map_or(0, |b| b.sample(&mut self.rng))
            } else {
                0
            };
            self.mass[free] += going_free as f64 * p.free_ratio;
            let to_voxels = c as usize - going_free as usize;
            if to_voxels == 0 {
                continue;
            }
            targets.resize(to_voxels, 0);
            model.voxel_sampler(s).fill(&mut self.rng, &mut targets);
            for &to in &targets {
                self.mass[to as usize] += p.voxel_ratio;
            }
        }
        self.targets = targets;
    }

    /// Weights the propagated particles by `log_likelihood` (per state) and resamples.
    pub(super) fn weight_and_resample(&mut self, log_likelihood: &[f64]) {
        let max = self
            .mass
            .iter()
            .zip(log_likelihood)
            .filter(|(&m, _)| m > 0.0)
            .map(|(_, &l)| l)
            .fold(f64::NEG_INFINITY, f64::max);
        let mut total = 0.0;
        for (m, &l) in self.mass.iter_mut().zip(log_likelihood) {
            if *m > 0.0 {
                *m *= (l - max).exp();
            }
            total += *m;
        }
        self.counts.fill(0);
        let n = self.particles;
        match self.resampling {
            Resampling::Systematic => {
                // Pointers (u0 + p)·step, p = 0..N, walked in state order: the pointers below a
                // cumulative weight C are the p < C/step - u0, so each state's share follows
                // from its cumulative weight alone (O(S), no per-pointer loop).
                let step = total / n as f64;
                let u0 = unit_f64(self.rng.next_u64());
                let inv_step = 1.0 / step;
                let below = |cumulative: f64| -> usize { ((cumulative * inv_step - u0).ceil().max(0.0) as usize).min(n) };
                let mut cumulative = 0.0;
                let mut taken = 0;
                let last = self.mass.len() - 1;
                for (c, &m) in self.counts[..last].iter_mut().zip(&self.mass) {
                    cumulative += m;
                    let upto = below(cumulative);
                    *c = (upto - taken) as u32;
                    taken = upto;
                }
                self.counts[last] = (n - taken) as u32;
            }
            Resampling::Multinomial => {
                let mut cumulative = Vec::with_capacity(self.mass.len());
                let mut acc = 0.0;
                for &m in &self.mass {
                    acc += m;
                    cumulative.push(acc);
                }
                for _ in 0..n {
                    let u = unit_f64(self.rng.next_u64()) * total;
                    let s = cumulative.partition_point(|&c| c <= u).min(cumulative.len() - 1);
                    self.counts[s] += 1;
                }
            }
        }
        // A pointer can land on a state of zero mass only through rounding at the very end;
        // move it to the nearest state with mass so no particle sits where weight is zero.
        if let Some(last_with_mass) = self.mass.iter().rposition(|&m| m > 0.0) {
            let stray: u32 = self.counts[last_with_mass + 1..].iter().sum();
            if stray > 0 {
                self.counts[last_with_mass + 1..].fill(0);
                self.counts[last_with_mass] += stray;
            }
        }
    }

    /// Writes the belief (particle histogram / N) into `out`.
    pub(super) fn belief(&self, out: &mut [f64]) {
        let inv = 1.0 / self.particles as f64;
        for (o, &c) in out.iter_mut().zip(&self.counts) {
            *o = c as f64 * inv;
        }
    }
}

/// Exact histogram Bayes filter.
#[derive(Debug, Clone)]
pub(super) struct HistogramFilter {
    belief: Vec<f64>,
    predicted: Vec<f64>,
}

impl HistogramFilter {
    /// Uniform belief over `states`.
    pub(super) fn new(states: usize) -> Self {
        Self { belief: vec![1.0 / states as f64; states], predicted: vec![0.0; states] }
    }

    /// The belief.
    pub(super) fn belief(&self) -> &[f64] {
        &self.belief
    }

    /// Prediction through the transition model.
    pub(super) fn predict(&mut self, model: &TransitionModel) {
        model.predict(&self.belief, &mut self.predicted);
    }

    /// Bayes update with per-state log-likelihoods, normalised with log-sum-exp.
    pub(super) fn update(&mut self, log_likelihood: &[f64]) {
        let max = self
            .predicted
            .iter()
            .zip(log_likelihood)
            .filter(|(&p, _)| p > 0.0)
            .map(|(p, l)| p.ln() + l)
            .fold(f64::NEG_INFINITY, f64::max);
        let mut total = 0.0;
        for ((b, &p), &l) in self.belief.iter_mut().zip(&self.predicted).zip(log_likelihood) {
            *b = if p > 0.0 { (p.ln() + l - max).exp() } else { 0.0 };
            total += *b;
        }
        let inv = 1.0 / total;
        self.belief.iter_mut().for_each(|b| *b *= inv);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    use crate::camera::PinholeCamera;
    use crate::config::{GridConfig, TransitionConfig};
    use crate::depth::grid::DepthVoxelGrid;

    /// A model with `states` states (a 1x1-pixel image, `states - 1` depth bins).
    fn model(states: usize) -> TransitionModel {
        let camera = PinholeCamera::new(1.0, 1.0, 0.0, 0.0, 1, 1).unwrap();
        let grid = DepthVoxelGrid::new(
            camera,
            GridConfig { block_width_px: 1, block_height_px: 1, depth_bin_m: 1.0, depth_min_m: 0.0, depth_max_m: (states - 1) as f64 },
        )
        .unwrap();
        TransitionModel::new(&grid, &TransitionConfig { sigma_s_voxels: 1.0, sigma_z_m: 1.0, free_state_depth: crate::config::FreeStateDepth::Horizon }).unwrap()
    }

    fn filter(states: usize, n: usize, resampling: Resampling, seed: u64) -> ParticleFilter {
        let mut f = ParticleFilter::new(&model(states), n, resampling, 0.0, Pcg64Mcg::seed_from_u64(seed));
        // No transition: the propagated weights are the particle counts.
        f.mass = f.counts.iter().map(|&c| c as f64).collect();
        f
    }

    #[test]
    fn systematic_resampling_keeps_proportions() {
        // Weight four states 1:1:2:0 with equal particle counts.
        let mut f = filter(4, 400, Resampling::Systematic, 1);
        f.weight_and_resample(&[0.0, 0.0, 2f64.ln(), f64::NEG_INFINITY]);
        // Systematic resampling gives each state floor or ceil of its expected count.
        assert_eq!(f.counts(), &[100, 100, 200, 0]);
    }

    #[test]
    fn multinomial_resampling_is_unbiased() {
        let mut totals = [0u64; 3];
        for seed in 0..50 {
            let mut f = filter(3, 1000, Resampling::Multinomial, seed);
            f.weight_and_resample(&[0.0, 3f64.ln(), f64::NEG_INFINITY]);
            assert_eq!(f.counts().iter().sum::<u32>(), 1000);
            assert_eq!(f.counts()[2], 0);
            for (t, &c) in totals.iter_mut().zip(f.counts()) {
                *t += c as u64;
            }
        }
        // The middle state starts with one more particle (1000 = 334 + 333 + 333).
        let expected = 50_000.0 * 333.0 * 3.0 / (334.0 + 999.0);
        assert!((totals[1] as f64 - expected).abs() < 0.02 * expected, "{totals:?}");
    }

    #[test]
    fn defensive_proposal_is_unbiased() {
        // The expected weight reaching each state after one propagation equals N·Σ_s b(s)T(s, ·),
        // whatever q_min is.
        let m = model(4);
        let n = 200_000;
        for q_min in [0.0, 0.3] {
            let mut f = ParticleFilter::new(&m, n, Resampling::Systematic, q_min, Pcg64Mcg::seed_from_u64(1));
            f.propagate(&m);
            for to in 0..4 {
                let expected: f64 = (0..4)
                    .map(|s| f.counts[s] as f64 * m.probability(crate::depth::StateId(s as u32), crate::depth::StateId(to as u32)))
                    .sum();
                // Five standard deviations of a Poisson count (the weights are near 1).
                assert!((f.mass[to] - expected).abs() < 5.0 * expected.sqrt() + 1.0, "q_min {q_min}, state {to}: {} vs {expected}", f.mass[to]);
            }
        }
    }

    #[test]
    fn flight_propagation_follows_the_rows() {
        // The batch path (binomial free count, branch-free class-table draws) on the flight
        // grid: all particles in one voxel, the propagated weight per target against N·T(s, ·).
        use crate::config::PerceptionConfig;
        let grid = DepthVoxelGrid::new(PinholeCamera::d435(), PerceptionConfig::flight().grid).unwrap();
        let m = TransitionModel::new(&grid, &PerceptionConfig::flight().transition).unwrap();
        let n = 400_000;
        for (from, q_min) in [(0usize, 0.05), (700, 0.05), (1429, 0.0), (12 * 11 + 3, 0.3)] {
            let mut f = ParticleFilter::new(&m, n, Resampling::Systematic, q_min, Pcg64Mcg::seed_from_u64(from as u64));
            f.counts.fill(0);
            f.counts[from] = n as u32;
            f.propagate(&m);
            let p = f.proposals[from];
            let free = grid.free_state().0 as usize;
            for (to, &mass) in f.mass.iter().enumerate() {
                let t = m.probability(crate::depth::StateId(from as u32), crate::depth::StateId(to as u32));
                let expected = n as f64 * t;
                // Each particle reaching `to` carries the ratio of its branch; the number that
                // does is binomial with mean expected / ratio.
                let ratio = if to == free { p.free_ratio } else { p.voxel_ratio };
                let sd = ratio * (expected / ratio).sqrt();
                assert!((mass - expected).abs() < 5.0 * sd + 4.0 * ratio, "from {from}, q_min {q_min}, to {to}: {mass} vs {expected}");
            }
            let total: f64 = f.mass.iter().sum();
            assert!((total / n as f64 - 1.0).abs() < 0.01, "{total}");
        }
    }

    #[test]
    fn histogram_update_is_bayes_rule() {
        let mut h = HistogramFilter::new(3);
        h.predicted = vec![0.5, 0.25, 0.25];
        h.update(&[-1000.0, -1000.0 + 2f64.ln(), -1000.0]);
        let expected = [0.5 / 1.25, 0.5 / 1.25, 0.25 / 1.25];
        for (b, e) in h.belief().iter().zip(expected) {
            assert!((b - e).abs() < 1e-12, "{b} vs {e}");
        }
    }
}
