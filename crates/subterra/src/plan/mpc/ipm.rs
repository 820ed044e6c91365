//! The tracker's own QP solver: a primal-dual interior-point method (Mehrotra's
//! predictor-corrector) whose Newton systems are solved by a banded `LDLᵀ`.
//!
//! The QP is `min ½zᵀPz + qᵀz  s.t.  Ez = e,  Gz <= h`, with `E` the leading `equalities`
//! rows of [`QpProblem`]'s `A` and `G` the rest. With the inequality slacks `s >= 0` and
//! multipliers `λ >= 0` eliminated, each Newton step solves the quasi-definite system
//!
//! ```text
//! [ P + GᵀWG + ρI   Eᵀ  ] [Δz]   [r_z]
//! [ E              -δI  ] [Δy] = [r_y]      W = diag(λ / s)
//! ```
//!
//! (`ρ = δ =` [`REGULARIZATION`], far below the tolerances; a pivot of the wrong sign or too
//! small is replaced, and the solves with such a factor are refined against the system
//! without regularisation). The tracker lays its variables and dynamics rows out stage by stage
//! (`assemble.rs`); with each equality row placed among the variables at the middle of the
//! columns it touches, every entry of this matrix lies within a few stages' width of the
//! diagonal (11 unknowns at horizon 20), so the factorisation costs `O(n·bw²)` instead of a
//! general sparse `LDLᵀ` over the full KKT system with a row per inequality. A
//! quasi-definite matrix has an `LDLᵀ` factorisation in any symmetric order (Vanderbei
//! 1995), so no pivoting is needed.
//!
//! Start: the minimiser of `½zᵀPz + qᵀz + ½‖Gz - h‖²` subject to `Ez = e` (the system with
//! `W = I`), slacks `s = max(h - Gz, 1)` and multipliers `λ = 1/s`. Stop: the residuals `‖Pz + q + Eᵀy + Gᵀλ‖∞ <= tol·(1 + ‖q‖∞)`,
//! `‖Ez - e‖∞, ‖Gz + s - h‖∞ <= tol·(1 + ‖b‖∞)` and the gap `sᵀλ <= tol·max(1, |½zᵀPz +
//! qᵀz|)` with `tol` = [`TOLERANCE`] ([`QpStatus::Solved`]); at the iteration limit, the
//! same with [`REDUCED_TOLERANCE`] gives [`QpStatus::Inexact`], anything else
//! [`QpStatus::Failed`]. Every operation is deterministic: the same QP gives the same bits.

use super::qp::{QpStatus, QpProblem};

/// Feasibility and gap tolerance of a solved QP (as the Clarabel path's `QP_TOLERANCE`).
const TOLERANCE: f64 = 1e-6;
/// The tolerance of a usable point at the iteration limit ([`QpStatus::Inexact`]).
const REDUCED_TOLERANCE: f64 = 1e-4;
/// Static regularisation of the Newton system's diagonal (`ρ`, `δ`).
const REGULARIZATION: f64 = 1e-9;
/// A pivot of the wrong sign or smaller than this is replaced by it (dynamic regularisation;
/// refinement corrects the error).
const MIN_PIVOT: f64 = 1e-12;
/// Iterative-refinement steps per Newton solve, at most.
const REFINEMENT_STEPS: usize = 3;
/// Where an equality row may sit, in columns from the middle of those it touches; the layout
/// takes the narrowest band.
const LAYOUT_SHIFTS: [f64; 9] = [-3.75, -2.75, -1.75, -0.75, 0.25, 1.25, 2.25, 3.25, 4.25];
/// Steps stop short of the boundary by this fraction.
const STEP_FRACTION: f64 = 0.99;

/// The solver and its buffers, kept between QPs; the layout is recomputed when the
/// sparsity changes.
#[derive(Debug, Default)]
pub(super) struct BandedIpm {
    /// The layout's pattern: `A`'s column pointers and row indices, `P`'s, and the equality count.
    pattern: (Vec<usize>, Vec<usize>, Vec<usize>, Vec<usize>, usize),
    /// Position in the banded system of each unknown: the variables, then the equality rows.
    pos: Vec<usize>,
    /// Half bandwidth of the system.
    bw: usize,
    /// By position, the first column of the row's nonzeros (its envelope; the factor keeps it).
    first: Vec<usize>,
    /// Where each entry goes in `band`: `P`'s nonzeros (in `P`'s order), each unknown's
    /// diagonal, the equality rows' entries (in `A`'s row order), and per inequality row the
    /// pairs `(slot, k_a, k_b)` of its `W·g_a·g_b` terms (`k`: index into `vals`), starting at
    /// `pair_start[row]`.
    p_slot: Vec<usize>,
    diag_slot: Vec<usize>,
    e_slot: Vec<usize>,
    pairs: Vec<(usize, usize, usize)>,
    pair_start: Vec<usize>,
    /// `1/D` of the factor.
    inv_pivot: Vec<f64>,
    /// `A` by rows: start of each row in `cols`/`vals`.
    row_start: Vec<usize>,
    cols: Vec<usize>,
    vals: Vec<f64>,
    /// The factor: row `i`'s entries for columns `i - bw ..= i` at `i·(bw+1) + (j + bw - i)`
    /// (the diagonal holds `D`).
    band: Vec<f64>,
    /// `L[i][k]·D[k]` of the row being factorised.
    scaled: Vec<f64>,
    /// Whether each position holds an equality row (its pivot is negative).
    is_equality: Vec<bool>,
    /// Whether the last factorisation replaced a pivot (its solves are then refined).
    perturbed: bool,
    /// Scratch: the next free slot of each row while `A` is turned into rows.
    fill: Vec<usize>,
    /// Iterates: primal `z`, equality multipliers `y`, inequality multipliers `λ` and slacks `s`.
    z: Vec<f64>,
    y: Vec<f64>,
    lam: Vec<f64>,
    s: Vec<f64>,
    /// `W = λ/s`.
    w: Vec<f64>,
    /// Residuals: dual, equality, inequality; and scratch.
    rd: Vec<f64>,
    re: Vec<f64>,
    ri: Vec<f64>,
    rhs: Vec<f64>,
    sol: Vec<f64>,
    res: Vec<f64>,
    corr: Vec<f64>,
    /// The right-hand side in the system's order while it is solved.
    perm: Vec<f64>,
    dz: Vec<f64>,
    dy: Vec<f64>,
    dlam: Vec<f64>,
    ds: Vec<f64>,
    gz: Vec<f64>,
    rc: Vec<f64>,
}

impl BandedIpm {
    /// Solves `qp` with at most `max_iter` iterations, writing the primal solution into `out`
    /// when it is usable. Returns the outcome and the iterations taken.
    pub(super) fn solve(&mut self, qp: &QpProblem, max_iter: u32, out: &mut Vec<f64>) -> (QpStatus, u32) {
        let (n, m, me) = (qp.q.len(), qp.b.len(), qp.equalities);
        if qp.p.cols != n || qp.a.cols != n || qp.a.rows != m || me > m || n == 0 {
            return (QpStatus::Failed, 0);
        }
        self.layout(qp);
        let mi = m - me;
        for v in [&mut self.z, &mut self.dz] {
            v.clear();
            v.resize(n, 0.0);
        }
        for v in [&mut self.y, &mut self.dy, &mut self.re] {
            v.clear();
            v.resize(me, 0.0);
        }
        for v in [&mut self.lam, &mut self.s, &mut self.w, &mut self.dlam, &mut self.ds, &mut self.ri, &mut self.gz, &mut self.rc] {
            v.clear();
            v.resize(mi, 0.0);
        }
        self.rd.clear();
        self.rd.resize(n, 0.0);

        // Start: minimise ½zᵀPz + qᵀz + ½‖Gz - h‖² subject to Ez = e (W = I), then shift.
        self.w.fill(1.0);
        if !self.factor(qp) {
            return (QpStatus::Failed, 0);
        }
        let mut rhs = std::mem::take(&mut self.rhs);
        rhs.clear();
        rhs.extend(qp.q.iter().map(|v| -v));
        for i in 0..mi {
            self.add_gt(me + i, qp.b[me + i], &mut rhs);
        }
        rhs.extend_from_slice(&qp.b[..me]);
        self.solve_refined(qp, &rhs);
        self.rhs = rhs;
        self.z.copy_from_slice(&self.sol[..n]);
        self.y.copy_from_slice(&self.sol[n..]);
        // Slacks at least 1, multipliers centred on them (s∘λ = 1).
        for i in 0..mi {
            self.s[i] = (qp.b[me + i] - self.row_dot(me + i, &self.z)).max(1.0);
            self.lam[i] = 1.0 / self.s[i];
        }

        let q_norm = inf_norm(&qp.q);
        let b_norm = inf_norm(&qp.b);
        let mut iterations = 0;
        loop {
            let (dual, primal, gap, objective) = self.residuals(qp);
            if !(dual.is_finite() && primal.is_finite() && gap.is_finite()) {
                return (QpStatus::Failed, iterations);
            }
            let converged = |tol: f64| dual <= tol * (1.0 + q_norm) && primal <= tol * (1.0 + b_norm) && gap <= tol * objective.abs().max(1.0);
            if converged(TOLERANCE) {
                out.clear();
                out.extend_from_slice(&self.z);
                return (QpStatus::Solved, iterations);
            }
            if iterations >= max_iter {
                if converged(REDUCED_TOLERANCE) {
                    out.clear();
                    out.extend_from_slice(&self.z);
                    return (QpStatus::Inexact, iterations);
                }
                return (QpStatus::Failed, iterations);
            }
            iterations += 1;
            for i in 0..mi {
                self.w[i] = self.lam[i] / self.s[i];
            }
            if !self.factor(qp) {
                return (QpStatus::Failed, iterations);
            }
            // Predictor (affine scaling): r_c = s∘λ.
            for i in 0..mi {
                self.rc[i] = self.s[i] * self.lam[i];
            }
            self.newton(qp);
            let alpha = self.step_to_boundary();
            let mu = if mi > 0 { gap / mi as f64 } else { 0.0 };
            let mu_aff = if mi > 0 {
                (0..mi).map(|i| (self.s[i] + alpha * self.ds[i]) * (self.lam[i] + alpha * self.dlam[i])).sum::<f64>() / mi as f64
            } else {
                0.0
            };
            let sigma = if mu > 0.0 { (mu_aff / mu).clamp(0.0, 1.0).powi(3) } else { 0.0 };
            // Corrector: r_c = s∘λ + Δs_aff∘Δλ_aff - σμ.
            for i in 0..mi {
                self.rc[i] = self.s[i] * self.lam[i] + self.ds[i] * self.dlam[i] - sigma * mu;
            }
            self.newton(qp);
            let alpha = (STEP_FRACTION * self.step_to_boundary()).min(1.0);
            if alpha <= 0.0 {
                return (QpStatus::Failed, iterations);
            }
            for (v, d) in self.z.iter_mut().zip(&self.dz) {
                *v += alpha * d;
            }
            for (v, d) in self.y.iter_mut().zip(&self.dy) {
                *v += alpha * d;
            }
            for (v, d) in self.lam.iter_mut().zip(&self.dlam) {
                *v += alpha * d;
            }
            for (v, d) in self.s.iter_mut().zip(&self.ds) {
                *v += alpha * d;
            }
        }
    }

    /// Recomputes the layout (positions and bandwidth) if the sparsity changed, and `A` by rows.
    fn layout(&mut self, qp: &QpProblem) {
        let (n, m, me) = (qp.q.len(), qp.b.len(), qp.equalities);
        // A by rows (values change every QP).
        self.row_start.clear();
        self.row_start.resize(m + 1, 0);
        for &r in &qp.a.rowval {
            self.row_start[r + 1] += 1;
        }
        for r in 0..m {
            self.row_start[r + 1] += self.row_start[r];
        }
        let nnz = qp.a.rowval.len();
        self.cols.clear();
        self.cols.resize(nnz, 0);
        self.vals.clear();
        self.vals.resize(nnz, 0.0);
        self.fill.clear();
        self.fill.extend_from_slice(&self.row_start[..m]);
        for c in 0..n {
            for k in qp.a.colptr[c]..qp.a.colptr[c + 1] {
                let r = qp.a.rowval[k];
                let at = self.fill[r];
                self.cols[at] = c;
                self.vals[at] = qp.a.nzval[k];
                self.fill[r] += 1;
            }
        }
        let same = self.pattern.0 == qp.a.colptr && self.pattern.1 == qp.a.rowval && self.pattern.2 == qp.p.colptr && self.pattern.3 == qp.p.rowval && self.pattern.4 == me;
        if same && self.pos.len() == n + me {
            return;
        }
        self.pattern = (qp.a.colptr.clone(), qp.a.rowval.clone(), qp.p.colptr.clone(), qp.p.rowval.clone(), me);
        // Each equality row sits among the variables near the middle of the columns it
        // touches: at the shift from the middle that gives the narrowest band.
        let spans: Vec<(f64, usize)> = (0..me)
            .map(|r| {
                let row = &self.cols[self.row_start[r]..self.row_start[r + 1]];
                let (lo, hi) = row.iter().fold((usize::MAX, 0), |(lo, hi), &c| (lo.min(c), hi.max(c)));
                (if row.is_empty() { n as f64 } else { (lo + hi) as f64 / 2.0 }, r)
            })
            .collect();
        let mut best: Option<(usize, Vec<usize>, Vec<usize>)> = None;
        let mut keys: Vec<(f64, usize)> = Vec::with_capacity(n + me);
        let mut pos = vec![0; n + me];
        let mut first = Vec::new();
        for shift in LAYOUT_SHIFTS {
            keys.clear();
            keys.extend((0..n).map(|j| (j as f64, j)));
            keys.extend(spans.iter().map(|&(mid, r)| (mid + shift, n + r)));
            keys.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            for (at, &(_, u)) in keys.iter().enumerate() {
                pos[u] = at;
            }
            let work = self.envelope(qp, &pos, &mut first);
            if best.as_ref().is_none_or(|(w, _, _)| work < *w) {
                best = Some((work, pos.clone(), first.clone()));
            }
        }
        let Some((_, pos, first)) = best else { return };
        self.bw = first.iter().enumerate().map(|(i, &f)| i - f).max().unwrap_or(0);
        self.first = first;
        self.is_equality.clear();
        self.is_equality.resize(n + me, false);
        for r in 0..me {
            self.is_equality[pos[n + r]] = true;
        }
        self.pos = pos;
        let (bw, w) = (self.bw, self.bw + 1);
        let pos = &self.pos;
        let slot = |u: usize, v: usize| {
            let (i, j) = (pos[u].max(pos[v]), pos[u].min(pos[v]));
            i * w + j + bw - i
        };
        self.p_slot.clear();
        for c in 0..n {
            self.p_slot.extend(qp.p.rowval[qp.p.colptr[c]..qp.p.colptr[c + 1]].iter().map(|&r| slot(r, c)));
        }
        self.diag_slot.clear();
        self.diag_slot.extend((0..n + me).map(|u| slot(u, u)));
        self.e_slot.clear();
        self.e_slot.extend((0..me).flat_map(|r| (self.row_start[r]..self.row_start[r + 1]).map(move |k| (r, k))).map(|(r, k)| slot(n + r, self.cols[k])));
        self.pairs.clear();
        self.pair_start.clear();
        for r in me..m {
            self.pair_start.push(self.pairs.len());
            for a in self.row_start[r]..self.row_start[r + 1] {
                for b in self.row_start[r]..=a {
                    self.pairs.push((slot(self.cols[a], self.cols[b]), a, b));
                }
            }
        }
        self.pair_start.push(self.pairs.len());
    }

    /// The envelope of the Newton system with the unknowns at `pos`: into `first`, the first
    /// column of each row's nonzeros (the factor's row has none before it either); returns
    /// the factorisation's work, `Σ (i - first_i)²`.
    fn envelope(&self, qp: &QpProblem, pos: &[usize], first: &mut Vec<usize>) -> usize {
        let (n, me) = (qp.q.len(), qp.equalities);
        first.clear();
        first.extend(0..n + me);
        let mut entry = |u: usize, v: usize| {
            let (i, j) = (pos[u].max(pos[v]), pos[u].min(pos[v]));
            first[i] = first[i].min(j);
        };
        for c in 0..n {
            for &r in &qp.p.rowval[qp.p.colptr[c]..qp.p.colptr[c + 1]] {
                entry(r, c);
            }
        }
        for r in 0..qp.b.len() {
            let row = &self.cols[self.row_start[r]..self.row_start[r + 1]];
            for (a, &ca) in row.iter().enumerate() {
                if r < me {
                    entry(n + r, ca);
                } else {
                    for &cb in &row[..a] {
                        entry(ca, cb);
                    }
                }
            }
        }
        first.iter().enumerate().map(|(i, &f)| (i - f) * (i - f)).sum()
    }

    /// Assembles the regularised Newton system for the current `W` and factorises it in
    /// place. `false` if a pivot is not finite.
    fn factor(&mut self, qp: &QpProblem) -> bool {
        let (n, me) = (qp.q.len(), qp.equalities);
        let size = n + me;
        let w = self.bw + 1;
        self.band.clear();
        self.band.resize(size * w, 0.0);
        let band = &mut self.band;
        for (&at, &v) in self.p_slot.iter().zip(&qp.p.nzval) {
            band[at] += v;
        }
        for (u, &at) in self.diag_slot.iter().enumerate() {
            band[at] += if u < n { REGULARIZATION } else { -REGULARIZATION };
        }
        for (&at, &v) in self.e_slot.iter().zip(&self.vals) {
            band[at] += v;
        }
        for (i, wr) in self.w.iter().enumerate() {
            for &(at, a, b) in &self.pairs[self.pair_start[i]..self.pair_start[i + 1]] {
                band[at] += wr * self.vals[a] * self.vals[b];
            }
        }
        self.scaled.clear();
        self.scaled.resize(size, 0.0);
        self.inv_pivot.clear();
        self.inv_pivot.resize(size, 0.0);
        self.perturbed = false;
        let bw = self.bw;
        for i in 0..size {
            let lo = self.first[i];
            // Row i's envelope: columns lo..=i, contiguous.
            let (before, rest) = self.band.split_at_mut(i * w);
            let row = &mut rest[lo + bw - i..w];
            for j in lo..i {
                let kl = lo.max(self.first[j]);
                let rowj = &before[j * w + kl + bw - j..j * w + bw + 1];
                let acc = row[j - lo] - dot(&self.scaled[kl..j], &rowj[..j - kl]);
                self.scaled[j] = acc;
                row[j - lo] = acc * self.inv_pivot[j];
            }
            let (l, d) = row.split_at_mut(i - lo);
            let mut pivot = d[0] - dot(&self.scaled[lo..i], l);
            let sign = if self.is_equality[i] { -1.0 } else { 1.0 };
            if !pivot.is_finite() {
                return false;
            }
            if pivot * sign < MIN_PIVOT {
                pivot = sign * MIN_PIVOT;
                self.perturbed = true;
            }
            d[0] = pivot;
            self.inv_pivot[i] = 1.0 / pivot;
        }
        true
    }

    /// Solves the factorised system for `rhs` (unknowns in natural order), into `sol`.
    fn solve_factored(&mut self, rhs: &[f64], sol: &mut [f64]) {
        let size = rhs.len();
        let (bw, w) = (self.bw, self.bw + 1);
        let x = &mut self.perm;
        x.clear();
        x.resize(size, 0.0);
        for (u, &v) in rhs.iter().enumerate() {
            x[self.pos[u]] = v;
        }
        // L y = b, then D, then Lᵀ x = y (row i of L subtracts x_i from the earlier unknowns).
        for i in 0..size {
            let lo = self.first[i];
            let row = &self.band[i * w + lo + bw - i..i * w + bw];
            x[i] -= dot(row, &x[lo..i]);
        }
        for (x, inv) in x.iter_mut().zip(&self.inv_pivot) {
            *x *= inv;
        }
        for i in (0..size).rev() {
            let lo = self.first[i];
            let row = &self.band[i * w + lo + bw - i..i * w + bw];
            let xi = x[i];
            for (xk, l) in x[lo..i].iter_mut().zip(row) {
                *xk -= l * xi;
            }
        }
        for (u, out) in sol.iter_mut().enumerate() {
            *out = x[self.pos[u]];
        }
    }

    /// `out = K·x` with `K` the Newton system without regularisation.
    fn kkt_mul(&self, qp: &QpProblem, x: &[f64], out: &mut [f64]) {
        let (n, me) = (qp.q.len(), qp.equalities);
        out.fill(0.0);
        for c in 0..n {
            for k in qp.p.colptr[c]..qp.p.colptr[c + 1] {
                let (r, v) = (qp.p.rowval[k], qp.p.nzval[k]);
                out[r] += v * x[c];
                if r != c {
                    out[c] += v * x[r];
                }
            }
        }
        for r in 0..qp.b.len() {
            let (start, end) = (self.row_start[r], self.row_start[r + 1]);
            if r < me {
                let mut dot = 0.0;
                for k in start..end {
                    out[self.cols[k]] += self.vals[k] * x[n + r];
                    dot += self.vals[k] * x[self.cols[k]];
                }
                out[n + r] = dot;
            } else {
                let g = self.w[r - me] * (start..end).map(|k| self.vals[k] * x[self.cols[k]]).sum::<f64>();
                for k in start..end {
                    out[self.cols[k]] += self.vals[k] * g;
                }
            }
        }
    }

    /// Solves the Newton system for `rhs` into `sol`, refined against the unregularised system.
    fn solve_refined(&mut self, qp: &QpProblem, rhs: &[f64]) {
        let size = rhs.len();
        let mut sol = std::mem::take(&mut self.sol);
        let mut res = std::mem::take(&mut self.res);
        let mut corr = std::mem::take(&mut self.corr);
        sol.clear();
        sol.resize(size, 0.0);
        res.clear();
        res.resize(size, 0.0);
        corr.clear();
        corr.resize(size, 0.0);
        self.solve_factored(rhs, &mut sol);
        let scale = inf_norm(rhs).max(1.0);
        let steps = if self.perturbed { REFINEMENT_STEPS } else { 0 };
        for _ in 0..steps {
            self.kkt_mul(qp, &sol, &mut res);
            for (r, &b) in res.iter_mut().zip(rhs) {
                *r = b - *r;
            }
            if inf_norm(&res) <= 1e-12 * scale {
                break;
            }
            self.solve_factored(&res, &mut corr);
            for (x, c) in sol.iter_mut().zip(&corr) {
                *x += c;
            }
        }
        self.sol = sol;
        self.res = res;
        self.corr = corr;
    }

    /// One Newton direction for the current `W` and `r_c`, into `dz, dy, dλ, ds`.
    fn newton(&mut self, qp: &QpProblem) {
        let (n, me) = (qp.q.len(), qp.equalities);
        let mi = self.s.len();
        let mut rhs = std::mem::take(&mut self.rhs);
        rhs.clear();
        rhs.extend(self.rd.iter().map(|v| -v));
        // r_z = -r_d - Gᵀ(W∘r_i - r_c/s).
        for i in 0..mi {
            let t = self.w[i] * self.ri[i] - self.rc[i] / self.s[i];
            self.add_gt(me + i, -t, &mut rhs);
        }
        rhs.extend(self.re.iter().map(|v| -v));
        self.solve_refined(qp, &rhs);
        self.rhs = rhs;
        self.dz.copy_from_slice(&self.sol[..n]);
        self.dy.copy_from_slice(&self.sol[n..n + me]);
        for i in 0..mi {
            let g = self.row_dot(me + i, &self.dz);
            self.ds[i] = -self.ri[i] - g;
            self.dlam[i] = self.w[i] * (self.ri[i] + g) - self.rc[i] / self.s[i];
        }
    }

    /// The largest `α <= 1` keeping `s + αΔs` and `λ + αΔλ` non-negative.
    fn step_to_boundary(&self) -> f64 {
        let mut alpha: f64 = 1.0;
        for (v, d) in self.s.iter().zip(&self.ds).chain(self.lam.iter().zip(&self.dlam)) {
            if *d < 0.0 {
                alpha = alpha.min(-v / d);
            }
        }
        alpha
    }

    /// Updates the residuals; returns their infinity norms (dual, primal), the gap `sᵀλ` and
    /// the objective.
    fn residuals(&mut self, qp: &QpProblem) -> (f64, f64, f64, f64) {
        let (n, me) = (qp.q.len(), qp.equalities);
        let mi = self.s.len();
        let mut objective = 0.0;
        self.rd.copy_from_slice(&qp.q);
        for c in 0..n {
            for k in qp.p.colptr[c]..qp.p.colptr[c + 1] {
                let (r, v) = (qp.p.rowval[k], qp.p.nzval[k]);
                self.rd[r] += v * self.z[c];
                if r != c {
                    self.rd[c] += v * self.z[r];
                }
            }
        }
        for (j, &zj) in self.z.iter().enumerate() {
            objective += zj * (0.5 * (self.rd[j] - qp.q[j]) + qp.q[j]);
        }
        let mut rd = std::mem::take(&mut self.rd);
        for r in 0..me {
            self.add_gt(r, self.y[r], &mut rd);
            self.re[r] = self.row_dot(r, &self.z) - qp.b[r];
        }
        for i in 0..mi {
            self.add_gt(me + i, self.lam[i], &mut rd);
            self.gz[i] = self.row_dot(me + i, &self.z);
            self.ri[i] = self.gz[i] + self.s[i] - qp.b[me + i];
        }
        self.rd = rd;
        let gap: f64 = self.s.iter().zip(&self.lam).map(|(s, l)| s * l).sum();
        (inf_norm(&self.rd), inf_norm(&self.re).max(inf_norm(&self.ri)), gap, objective)
    }

    /// Row `r` of `A` times `x`.
    #[inline]
    fn row_dot(&self, r: usize, x: &[f64]) -> f64 {
        (self.row_start[r]..self.row_start[r + 1]).map(|k| self.vals[k] * x[self.cols[k]]).sum()
    }

    /// `out += scale·(row r of A)ᵀ`.
    #[inline]
    fn add_gt(&self, r: usize, scale: f64, out: &mut [f64]) {
        for k in self.row_start[r]..self.row_start[r + 1] {
            out[self.cols[k]] += scale * self.vals[k];
        }
    }
}

/// `Σ a_k·b_k` (`a` no longer than `b`), in four independent partial sums.
#[inline(always)]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let (mut s0, mut s1, mut s2, mut s3) = (0.0, 0.0, 0.0, 0.0);
    let mut ca = a.chunks_exact(4);
    let mut cb = b.chunks_exact(4);
    for (x, y) in (&mut ca).zip(&mut cb) {
        s0 += x[0] * y[0];
        s1 += x[1] * y[1];
        s2 += x[2] * y[2];
        s3 += x[3] * y[3];
    }
    for (x, y) in ca.remainder().iter().zip(cb.remainder()) {
        s0 += x * y;
    }
    (s0 + s1) + (s2 + s3)
}

fn inf_norm(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |m, x| m.max(x.abs()))
}

#[cfg(test)]
impl BandedIpm {
    /// The half bandwidth of the last layout.
    pub(super) fn half_bandwidth(&self) -> usize {
        self.bw
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::mpc::qp::small_qp;

    #[test]
    fn solves_a_small_qp_by_hand() {
        let mut ipm = BandedIpm::default();
        let mut z = Vec::new();
        // Unconstrained optimum on the line z0 + z1 = 2: z = (0, 2); z1 <= 1.5 binds -> (0.5, 1.5).
        let (outcome, iterations) = ipm.solve(&small_qp(1.5, None), 50, &mut z);
        assert_eq!(outcome, QpStatus::Solved);
        assert!(iterations <= 20, "{iterations}");
        assert!((z[0] - 0.5).abs() < 1e-5 && (z[1] - 1.5).abs() < 1e-5, "{z:?}");
        // Not binding: z1 <= 3 -> (0, 2).
        assert_eq!(ipm.solve(&small_qp(3.0, None), 50, &mut z).0, QpStatus::Solved);
        assert!(z[0].abs() < 1e-5 && (z[1] - 2.0).abs() < 1e-5, "{z:?}");
    }

    #[test]
    fn an_infeasible_qp_fails_and_leaves_the_output_alone() {
        let mut ipm = BandedIpm::default();
        let mut z = vec![7.0];
        // z1 <= 0.5 and z1 >= 1.
        let (outcome, _) = ipm.solve(&small_qp(0.5, Some(-1.0)), 50, &mut z);
        assert_eq!(outcome, QpStatus::Failed);
        assert_eq!(z, vec![7.0]);
    }

    #[test]
    fn malformed_sizes_fail_without_panicking() {
        let mut qp = small_qp(1.5, None);
        qp.q.push(0.0);
        assert_eq!(BandedIpm::default().solve(&qp, 50, &mut Vec::new()).0, QpStatus::Failed);
        let mut qp = small_qp(1.5, None);
        qp.equalities = 5;
        assert_eq!(BandedIpm::default().solve(&qp, 50, &mut Vec::new()).0, QpStatus::Failed);
    }
}
