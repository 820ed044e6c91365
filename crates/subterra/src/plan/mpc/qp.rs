//! The QP of one SQP iteration in Clarabel's form, and the solver kept between solves.
//!
//! Clarabel solves `min ½zᵀPz + qᵀz  s.t.  Az + s = b, s ∈ K` with `K` a zero cone (the
//! dynamics, equalities) followed by a non-negative cone (every inequality, `Az <= b`). The
//! sparsity of `P` and `A` depends only on the horizon and the obstacle rows per stage, so
//! the solver is built once and later QPs only overwrite its values (`update_data`), which
//! skips the ordering and symbolic factorisation of the KKT system.

use std::panic::{catch_unwind, AssertUnwindSafe};

use clarabel::algebra::CscMatrix;
use clarabel::solver::{DefaultSettings, DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT};

/// A sparse matrix in compressed-column form (what Clarabel takes).
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct Csc {
    pub rows: usize,
    pub cols: usize,
    pub colptr: Vec<usize>,
    pub rowval: Vec<usize>,
    pub nzval: Vec<f64>,
}

impl Csc {
    fn to_clarabel(&self) -> CscMatrix<f64> {
        CscMatrix::new(self.rows, self.cols, self.colptr.clone(), self.rowval.clone(), self.nzval.clone())
    }

    fn same_pattern(&self, other: &Csc) -> bool {
        self.rows == other.rows && self.cols == other.cols && self.colptr == other.colptr && self.rowval == other.rowval
    }
}

/// Builds a [`Csc`] from entries pushed in increasing row order (entries of one column then
/// come out with increasing rows, as the format needs); no entry may repeat.
#[derive(Debug, Clone, Default)]
pub(crate) struct CscBuilder {
    entries: Vec<(usize, usize, f64)>,
    rows: usize,
    counts: Vec<usize>,
}

impl CscBuilder {
    /// Starts an empty matrix.
    pub(super) fn clear(&mut self) {
        self.entries.clear();
        self.rows = 0;
    }

    /// Adds `value` at `(row, col)`.
    #[inline]
    pub(super) fn push(&mut self, row: usize, col: usize, value: f64) {
        self.entries.push((row, col, value));
        self.rows = self.rows.max(row + 1);
    }

    /// The matrix with `rows x cols`, written into `out` (its buffers are reused).
    pub(super) fn finish(&mut self, rows: usize, cols: usize, out: &mut Csc) {
        out.rows = rows.max(self.rows);
        out.cols = cols;
        self.counts.clear();
        self.counts.resize(cols + 1, 0);
        for &(_, c, _) in &self.entries {
            self.counts[c + 1] += 1;
        }
        for c in 0..cols {
            self.counts[c + 1] += self.counts[c];
        }
        out.colptr.clear();
        out.colptr.extend_from_slice(&self.counts);
        out.rowval.clear();
        out.rowval.resize(self.entries.len(), 0);
        out.nzval.clear();
        out.nzval.resize(self.entries.len(), 0.0);
        // Counting sort by column; stable, so rows stay increasing within a column.
        for &(r, c, v) in &self.entries {
            let at = self.counts[c];
            out.rowval[at] = r;
            out.nzval[at] = v;
            self.counts[c] += 1;
        }
    }
}

/// One QP: `P` (upper triangle), `q`, `A`, `b`, and how many leading rows are equalities.
#[derive(Debug, Clone, Default)]
pub(crate) struct QpProblem {
    pub p: Csc,
    pub q: Vec<f64>,
    pub a: Csc,
    pub b: Vec<f64>,
    pub equalities: usize,
}

/// How a QP ended, in the terms the tracker needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum QpOutcome {
    /// Solved to the full tolerances.
    Solved,
    /// A usable point at reduced accuracy (Clarabel's `AlmostSolved`, or an iteration or
    /// time limit).
    Inexact,
    /// No usable point: infeasible, numerical failure, or a panic inside the solver.
    Failed,
}

/// Solvers kept for the most recently seen sparsity patterns.
const CACHED_SOLVERS: usize = 4;

/// The sparsity of a QP: `P`'s and `A`'s patterns (no values) and the equality count.
#[derive(Debug, Clone, PartialEq)]
struct Pattern {
    p: Csc,
    a: Csc,
    equalities: usize,
}

impl Pattern {
    fn of(qp: &QpProblem) -> Self {
        let strip = |m: &Csc| Csc { rows: m.rows, cols: m.cols, colptr: m.colptr.clone(), rowval: m.rowval.clone(), nzval: Vec::new() };
        Self { p: strip(&qp.p), a: strip(&qp.a), equalities: qp.equalities }
    }

    fn matches(&self, qp: &QpProblem) -> bool {
        self.equalities == qp.equalities && self.p.same_pattern(&qp.p) && self.a.same_pattern(&qp.a)
    }
}

/// Clarabel solvers for the last few sparsity patterns (most recent first): a QP whose
/// pattern was seen recently overwrites that solver's values instead of building a new one
/// (ordering and symbolic factorisation are the expensive part of a build). With presolve
/// and equilibration off, a reused solver computes exactly what a new one would.
pub(crate) struct QpSolver {
    cache: Vec<(Pattern, DefaultSolver<f64>)>,
    max_iter: u32,
}

impl std::fmt::Debug for QpSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("QpSolver").field("cached", &self.cache.len()).field("max_iter", &self.max_iter).finish()
    }
}

/// Clarabel's absolute and relative duality-gap and feasibility tolerances for the QPs:
/// tighter than the tracker needs (mm and mm/s), looser than Clarabel's 1e-8 default
/// (one or two interior-point iterations fewer).
const QP_TOLERANCE: f64 = 1e-6;
/// Most iterative-refinement steps per KKT solve (Clarabel: 10).
const REFINEMENT_STEPS: u32 = 2;
/// Iterative refinement runs only when a KKT solve's residual is above this, relative and
/// absolute (Clarabel: 1e-13, 1e-12): a tenth of `QP_TOLERANCE`. These QPs are small and
/// well scaled, the direct solve is mostly that good already, and each refinement step
/// costs another solve (refining always: 20% more time on the benchmark run).
const REFINEMENT_TOLERANCE: f64 = 1e-7;

impl QpSolver {
    /// No solver yet; QPs stop after `max_iter` interior-point iterations.
    pub(super) fn new(max_iter: u32) -> Self {
        Self { cache: Vec::new(), max_iter }
    }

    /// Forgets the solvers (the next QP builds a new one).
    pub(super) fn reset(&mut self) {
        self.cache.clear();
    }

    fn settings(&self) -> DefaultSettings<f64> {
        let mut s = DefaultSettingsBuilder::<f64>::default().build().unwrap_or_default();
        s.verbose = false;
        s.max_iter = self.max_iter;
        s.tol_gap_abs = QP_TOLERANCE;
        s.tol_gap_rel = QP_TOLERANCE;
        s.tol_feas = QP_TOLERANCE;
        s.max_threads = 1;
        s.iterative_refinement_max_iter = REFINEMENT_STEPS;
        s.iterative_refinement_reltol = REFINEMENT_TOLERANCE;
        s.iterative_refinement_abstol = REFINEMENT_TOLERANCE;
        // Presolve drops rows and equilibration rescales per problem: both would make the
        // kept solver's structure or scaling depend on the first QP it saw.
        s.presolve_enable = false;
        s.equilibrate_enable = false;
        s.input_sparse_dropzeros = false;
        s
    }

    /// Solves `qp`, writing the primal solution into `z`. Returns the outcome and the
    /// interior-point iterations.
    pub(super) fn solve(&mut self, qp: &QpProblem, z: &mut Vec<f64>) -> (QpOutcome, u32) {
        // The matching solver, moved to the front; else a new one there.
        match self.cache.iter().position(|(pattern, _)| pattern.matches(qp)) {
            Some(i) => {
                let entry = self.cache.remove(i);
                self.cache.insert(0, entry);
            }
            None => {
                let settings = self.settings();
                let mut cones = Vec::with_capacity(2);
                if qp.equalities > 0 {
                    cones.push(SupportedConeT::ZeroConeT(qp.equalities));
                }
                cones.push(SupportedConeT::NonnegativeConeT(qp.b.len() - qp.equalities));
                let built = catch_unwind(AssertUnwindSafe(|| DefaultSolver::new(&qp.p.to_clarabel(), &qp.q, &qp.a.to_clarabel(), &qp.b, &cones, settings).ok()));
                let Ok(Some(solver)) = built else { return (QpOutcome::Failed, 0) };
                self.cache.insert(0, (Pattern::of(qp), solver));
                self.cache.truncate(CACHED_SOLVERS);
            }
        }
        let solver = &mut self.cache[0].1;
        let run = catch_unwind(AssertUnwindSafe(|| {
            solver.update_data(&qp.p.nzval, &qp.q, &qp.a.nzval, &qp.b).ok()?;
            solver.solve();
            Some((solver.solution.status, solver.solution.iterations))
        }));
        let Ok(Some((status, iterations))) = run else {
            // A panic may have left the solver half-updated: drop it.
            self.cache.remove(0);
            return (QpOutcome::Failed, 0);
        };
        let outcome = match status {
            SolverStatus::Solved => QpOutcome::Solved,
            SolverStatus::AlmostSolved | SolverStatus::MaxIterations | SolverStatus::MaxTime => QpOutcome::Inexact,
            _ => QpOutcome::Failed,
        };
        let x = &self.cache[0].1.solution.x;
        if outcome == QpOutcome::Failed || x.len() != qp.q.len() || x.iter().any(|v| !v.is_finite()) {
            return (QpOutcome::Failed, iterations);
        }
        z.clear();
        z.extend_from_slice(x);
        (outcome, iterations)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builder_sorts_columns_and_keeps_row_order() {
        let mut b = CscBuilder::default();
        b.push(0, 1, 1.0);
        b.push(0, 0, 2.0);
        b.push(1, 1, 3.0);
        b.push(2, 0, 4.0);
        let mut m = Csc::default();
        b.finish(3, 2, &mut m);
        assert_eq!(m.colptr, vec![0, 2, 4]);
        assert_eq!(m.rowval, vec![0, 2, 0, 1]);
        assert_eq!(m.nzval, vec![2.0, 4.0, 1.0, 3.0]);
    }

    #[test]
    fn solves_a_box_qp_by_hand_and_reuses_the_solver() {
        // min ½(z0² + z1²) - z0 - 3 z1  s.t. z0 + z1 = 2, z1 <= 1.5  ->  z = (0.5, 1.5).
        let mut qp = QpProblem::default();
        let mut b = CscBuilder::default();
        b.push(0, 0, 1.0);
        b.push(1, 1, 1.0);
        b.finish(2, 2, &mut qp.p);
        qp.q = vec![-1.0, -3.0];
        b.clear();
        b.push(0, 0, 1.0);
        b.push(0, 1, 1.0);
        b.push(1, 1, 1.0);
        b.finish(2, 2, &mut qp.a);
        qp.b = vec![2.0, 1.5];
        qp.equalities = 1;
        let mut solver = QpSolver::new(50);
        let mut z = Vec::new();
        assert_eq!(solver.solve(&qp, &mut z).0, QpOutcome::Solved);
        assert!((z[0] - 0.5).abs() < 1e-4 && (z[1] - 1.5).abs() < 1e-4, "{z:?}");
        // Same pattern, new values: z1 <= 0.5 -> z = (1.5, 0.5).
        qp.b[1] = 0.5;
        assert_eq!(solver.solve(&qp, &mut z).0, QpOutcome::Solved);
        assert!((z[0] - 1.5).abs() < 1e-4 && (z[1] - 0.5).abs() < 1e-4, "{z:?}");
        // Infeasible: z1 <= 0.5 and -z1 <= -1.
        b.clear();
        b.push(0, 0, 1.0);
        b.push(0, 1, 1.0);
        b.push(1, 1, 1.0);
        b.push(2, 1, -1.0);
        b.finish(3, 2, &mut qp.a);
        qp.b = vec![2.0, 0.5, -1.0];
        assert_eq!(solver.solve(&qp, &mut z).0, QpOutcome::Failed);
    }

    #[test]
    fn a_cached_solver_gives_the_bits_of_a_new_one() {
        // Two patterns in turn: the second visit of each reuses its cached solver.
        let problem = |rows: usize, shift: f64| {
            let mut qp = QpProblem::default();
            let mut b = CscBuilder::default();
            b.push(0, 0, 2.0);
            b.push(1, 1, 1.0 + shift);
            b.finish(2, 2, &mut qp.p);
            qp.q = vec![-1.0 - shift, -3.0];
            b.clear();
            for r in 0..rows {
                b.push(r, 0, 1.0);
                b.push(r, 1, 0.5 + r as f64);
            }
            b.finish(rows, 2, &mut qp.a);
            qp.b = (0..rows).map(|r| 1.0 + 0.1 * r as f64 + shift).collect();
            qp
        };
        let mut cached = QpSolver::new(50);
        let mut z = Vec::new();
        for round in 0..3 {
            for rows in [1, 2] {
                let qp = problem(rows, 0.1 * round as f64);
                let (outcome, _) = cached.solve(&qp, &mut z);
                let mut fresh_z = Vec::new();
                QpSolver::new(50).solve(&qp, &mut fresh_z);
                assert_eq!(outcome, QpOutcome::Solved);
                assert_eq!(z, fresh_z, "round {round}, {rows} rows");
            }
        }
        assert_eq!(cached.cache.len(), 2);
    }
}
