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

use super::ipm::BandedIpm;
use super::QpSolverKind;
use crate::error::{Error, Result};

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
#[non_exhaustive]
pub enum QpStatus {
    /// Solved to the full tolerances.
    Solved,
    /// A usable point at reduced accuracy (Clarabel's `AlmostSolved`, or an iteration or
    /// time limit).
    Inexact,
    /// No usable point: infeasible, numerical failure, or a panic inside the solver.
    Failed,
}

impl QpStatus {
    /// `"solved"`, `"inexact"` or `"failed"`.
    pub fn as_str(self) -> &'static str {
        match self {
            QpStatus::Solved => "solved",
            QpStatus::Inexact => "inexact",
            QpStatus::Failed => "failed",
        }
    }
}

/// Largest QP [`MpcQp::solve`] accepts, in variables and in rows (a horizon of
/// `MAX_HORIZON` steps has 1400 variables).
const MAX_QP_SIZE: usize = 1 << 16;

/// One QP of the tracker's SQP iterations as its solver gets it ([`MpcTracker::last_qp`]):
/// `min ½zᵀPz + qᵀz` subject to `A z = b` in the first `equalities` rows and `A z <= b` in
/// the rest, with `P` (its upper triangle) and `A` in compressed columns (`colptr`, `rowval`,
/// `nzval`, as SciPy's `csc_matrix` `indptr`, `indices`, `data`). For inspecting what the
/// tracker solved and for comparing solvers on it.
///
/// [`MpcTracker::last_qp`]: crate::plan::MpcTracker::last_qp
#[derive(Debug, Clone, PartialEq)]
pub struct MpcQp {
    /// `P`'s column pointers (`n + 1`).
    pub p_colptr: Vec<usize>,
    /// `P`'s row indices, increasing within each column, none below the diagonal.
    pub p_rowval: Vec<usize>,
    /// `P`'s values.
    pub p_nzval: Vec<f64>,
    /// The linear cost (`n`).
    pub q: Vec<f64>,
    /// `A`'s column pointers (`n + 1`).
    pub a_colptr: Vec<usize>,
    /// `A`'s row indices, increasing within each column.
    pub a_rowval: Vec<usize>,
    /// `A`'s values.
    pub a_nzval: Vec<f64>,
    /// The right-hand side (one per row of `A`).
    pub b: Vec<f64>,
    /// How many leading rows are equalities (the dynamics).
    pub equalities: usize,
}

/// What [`MpcQp::solve`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct MpcQpSolution {
    /// The primal solution (empty when the status is `Failed`).
    pub z: Vec<f64>,
    /// How the solve ended.
    pub status: QpStatus,
    /// Interior-point iterations (of both solvers when the banded one handed over to Clarabel).
    pub iterations: u32,
    /// Time in the solver \[s\].
    pub time_s: f64,
}

impl MpcQp {
    pub(super) fn of(qp: &QpProblem) -> Self {
        Self {
            p_colptr: qp.p.colptr.clone(),
            p_rowval: qp.p.rowval.clone(),
            p_nzval: qp.p.nzval.clone(),
            q: qp.q.clone(),
            a_colptr: qp.a.colptr.clone(),
            a_rowval: qp.a.rowval.clone(),
            a_nzval: qp.a.nzval.clone(),
            b: qp.b.clone(),
            equalities: qp.equalities,
        }
    }

    /// Solves the QP with `solver` (at most `max_iterations` interior-point iterations, as
    /// `solver.qp_max_iterations`), as the tracker would. Errors (naming the field) if the
    /// matrices are not valid compressed columns of the sizes `q` and `b` give, `P` has an
    /// entry below its diagonal, a value is not finite, `equalities` exceeds the rows, or the
    /// QP is larger than 65536 variables or rows.
    pub fn solve(&self, solver: QpSolverKind, max_iterations: u32) -> Result<MpcQpSolution> {
        let (n, m) = (self.q.len(), self.b.len());
        if n == 0 || n > MAX_QP_SIZE || m > MAX_QP_SIZE {
            return Err(Error::input("qp", format!("must have 1 to {MAX_QP_SIZE} variables and at most {MAX_QP_SIZE} rows, got {n} and {m}")));
        }
        if !(1..=1000).contains(&max_iterations) {
            return Err(Error::input("max_iterations", format!("must be in 1..=1000, got {max_iterations}")));
        }
        if self.equalities > m {
            return Err(Error::input("equalities", format!("must be at most the {m} rows, got {}", self.equalities)));
        }
        let p = checked_csc("P", (&self.p_colptr, &self.p_rowval, &self.p_nzval), n, n)?;
        if let Some(c) = (0..n).find(|&c| p.rowval[p.colptr[c]..p.colptr[c + 1]].iter().any(|&r| r > c)) {
            return Err(Error::input("P", format!("must hold the upper triangle only; column {c} has an entry below the diagonal")));
        }
        let a = checked_csc("A", (&self.a_colptr, &self.a_rowval, &self.a_nzval), m, n)?;
        for (name, v) in [("q", &self.q), ("b", &self.b)] {
            if let Some(bad) = v.iter().find(|x| !x.is_finite()) {
                return Err(Error::input(name, format!("must be finite, got {bad}")));
            }
        }
        let qp = QpProblem { p, q: self.q.clone(), a, b: self.b.clone(), equalities: self.equalities };
        let mut solver = QpSolver::new(max_iterations, solver);
        let mut z = Vec::new();
        let started = std::time::Instant::now();
        let (status, iterations) = solver.solve(&qp, &mut z);
        let time_s = started.elapsed().as_secs_f64();
        if status == QpStatus::Failed {
            z.clear();
        }
        Ok(MpcQpSolution { z, status, iterations, time_s })
    }
}

/// A compressed-column matrix of `rows x cols` from its parts, checked (`what` names it).
fn checked_csc(what: &str, (colptr, rowval, nzval): (&[usize], &[usize], &[f64]), rows: usize, cols: usize) -> Result<Csc> {
    if colptr.len() != cols + 1 || colptr[0] != 0 || colptr.windows(2).any(|w| w[0] > w[1]) || colptr[cols] != rowval.len() || rowval.len() != nzval.len() {
        return Err(Error::input(what, format!("must be {rows} x {cols} in compressed columns: {} column pointers (non-decreasing from 0 to the {} entries), got {} pointers and {} values", cols + 1, rowval.len(), colptr.len(), nzval.len())));
    }
    for c in 0..cols {
        let col = &rowval[colptr[c]..colptr[c + 1]];
        if col.iter().any(|&r| r >= rows) || col.windows(2).any(|w| w[0] >= w[1]) {
            let sized_by = if what == "P" { "q" } else { "b" };
            return Err(Error::input(what, format!("column {c}: row indices must be increasing and below {rows} (the length of `{sized_by}`)")));
        }
    }
    if let Some(bad) = nzval.iter().find(|x| !x.is_finite()) {
        return Err(Error::input(what, format!("values must be finite, got {bad}")));
    }
    Ok(Csc { rows, cols, colptr: colptr.to_vec(), rowval: rowval.to_vec(), nzval: nzval.to_vec() })
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
    kind: QpSolverKind,
    banded: BandedIpm,
    /// The banded solver's point, kept while Clarabel tries again.
    banded_z: Vec<f64>,
}

impl std::fmt::Debug for QpSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("QpSolver").field("cached", &self.cache.len()).field("max_iter", &self.max_iter).field("kind", &self.kind).finish()
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
    pub(super) fn new(max_iter: u32, kind: QpSolverKind) -> Self {
        Self { cache: Vec::new(), max_iter, kind, banded: BandedIpm::default(), banded_z: Vec::new() }
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
    /// interior-point iterations. With [`QpSolverKind::Banded`], a QP the banded solver does
    /// not solve to full accuracy goes to Clarabel; if Clarabel fails too, the banded
    /// solver's reduced-accuracy point (if any) is returned.
    pub(super) fn solve(&mut self, qp: &QpProblem, z: &mut Vec<f64>) -> (QpStatus, u32) {
        if self.kind == QpSolverKind::Clarabel {
            return self.solve_clarabel(qp, z);
        }
        let (outcome, iterations) = self.banded.solve(qp, self.max_iter, &mut self.banded_z);
        if outcome == QpStatus::Solved {
            z.clear();
            z.extend_from_slice(&self.banded_z);
            return (outcome, iterations);
        }
        let (fallback, more) = self.solve_clarabel(qp, z);
        if fallback == QpStatus::Failed && outcome == QpStatus::Inexact {
            z.clear();
            z.extend_from_slice(&self.banded_z);
            return (outcome, iterations + more);
        }
        (fallback, iterations + more)
    }

    /// Solves `qp` with Clarabel (see [`QpSolver::solve`]).
    fn solve_clarabel(&mut self, qp: &QpProblem, z: &mut Vec<f64>) -> (QpStatus, u32) {
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
                let Ok(Some(solver)) = built else { return (QpStatus::Failed, 0) };
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
            return (QpStatus::Failed, 0);
        };
        let outcome = match status {
            SolverStatus::Solved => QpStatus::Solved,
            SolverStatus::AlmostSolved | SolverStatus::MaxIterations | SolverStatus::MaxTime => QpStatus::Inexact,
            _ => QpStatus::Failed,
        };
        let x = &self.cache[0].1.solution.x;
        if outcome == QpStatus::Failed || x.len() != qp.q.len() || x.iter().any(|v| !v.is_finite()) {
            return (QpStatus::Failed, iterations);
        }
        z.clear();
        z.extend_from_slice(x);
        (outcome, iterations)
    }
}

/// `min ½(z0² + z1²) - z0 - 3 z1  s.t.  z0 + z1 = 2,  z1 <= bound` (and `-z1 <= lower` if
/// given): the small QP the solvers' tests solve by hand.
#[cfg(test)]
pub(super) fn small_qp(bound: f64, lower: Option<f64>) -> QpProblem {
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
    qp.b = vec![2.0, bound];
    if let Some(lower) = lower {
        b.push(2, 1, -1.0);
        qp.b.push(lower);
    }
    b.finish(qp.b.len(), 2, &mut qp.a);
    qp.equalities = 1;
    qp
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
        let mut qp = small_qp(1.5, None);
        let mut solver = QpSolver::new(50, QpSolverKind::Clarabel);
        let mut z = Vec::new();
        assert_eq!(solver.solve(&qp, &mut z).0, QpStatus::Solved);
        assert!((z[0] - 0.5).abs() < 1e-4 && (z[1] - 1.5).abs() < 1e-4, "{z:?}");
        // Same pattern, new values: z1 <= 0.5 -> z = (1.5, 0.5).
        qp.b[1] = 0.5;
        assert_eq!(solver.solve(&qp, &mut z).0, QpStatus::Solved);
        assert!((z[0] - 1.5).abs() < 1e-4 && (z[1] - 0.5).abs() < 1e-4, "{z:?}");
        // Infeasible: z1 <= 0.5 and -z1 <= -1.
        assert_eq!(solver.solve(&small_qp(0.5, Some(-1.0)), &mut z).0, QpStatus::Failed);
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
        let mut cached = QpSolver::new(50, QpSolverKind::Clarabel);
        let mut z = Vec::new();
        for round in 0..3 {
            for rows in [1, 2] {
                let qp = problem(rows, 0.1 * round as f64);
                let (outcome, _) = cached.solve(&qp, &mut z);
                let mut fresh_z = Vec::new();
                QpSolver::new(50, QpSolverKind::Clarabel).solve(&qp, &mut fresh_z);
                assert_eq!(outcome, QpStatus::Solved);
                assert_eq!(z, fresh_z, "round {round}, {rows} rows");
            }
        }
        assert_eq!(cached.cache.len(), 2);
    }
}
