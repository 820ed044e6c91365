//! Step 4 of `MpcTracker`'s docs: the QP around the nominal, its variables laid out stage by
//! stage, assembled into the solver's compressed-column matrices.

use super::{MpcConfig, UnicycleInput, Workspace};

/// QP variables per stage: `[a_k, ω_k, x, y, θ, v (of state k+1), σo_{k+1}]`.
const STAGE_VARS: usize = 7;
/// Right-hand side of an unused obstacle row, `-σo <= this` \[m\]: never binding.
const UNUSED_ROW_RHS_M: f64 = 1e3;

/// Index of input `ch` (0: a, 1: ω) of step `k` in `z`.
#[inline]
pub(super) fn iu(k: usize, ch: usize) -> usize {
    STAGE_VARS * k + ch
}

/// Index of component `i` of state `k >= 1` (`[x, y, θ, v]`) in `z`.
#[inline]
fn ix(k: usize, i: usize) -> usize {
    STAGE_VARS * (k - 1) + 2 + i
}

/// Index of the obstacle slack of state `k >= 1`.
#[inline]
fn iso(k: usize) -> usize {
    STAGE_VARS * (k - 1) + 6
}

/// Step 4 of `MpcTracker`'s docs: the QP around the nominal, into `ws.qp`. Variables stage by
/// stage, `z = [δa_k, δω_k, δx_{k+1}, δy_{k+1}, δθ_{k+1}, δv_{k+1}, σv_{k+1}, σo_{k+1}]_{k<N}`,
/// so `P` is block diagonal (plus the input-rate couplings) and the KKT system banded; only
/// used obstacle rows enter `A`.
pub(super) fn build_qp(c: &MpcConfig, ws: &mut Workspace, previous_input: Option<UnicycleInput>) {
    let n = c.horizon;
    let nz = STAGE_VARS * n;
    let w = &c.weights;
    let qp = &mut ws.qp;
    // P (upper triangle) as its diagonal and three kinds of off-diagonal entries.
    let diag = &mut ws.p_diag;
    diag.clear();
    diag.resize(nz, 0.0);
    let off = &mut ws.p_off;
    off.clear();
    // Per stage k: P[a_{k-1}, a_k], P[ω_{k-1}, ω_k], P[x_{k+1}, y_{k+1}].
    off.resize(n, [0.0; 3]);
    qp.q.clear();
    qp.q.resize(nz, 0.0);
    let q = &mut qp.q;

    for (k, &u) in ws.u.iter().enumerate() {
        for (ch, value, effort, rate) in [(0, u.accel_m_s2, w.accel, w.accel_rate), (1, u.yaw_rate_rad_s, w.yaw_rate, w.yaw_rate_rate)] {
            let i = iu(k, ch);
            diag[i] += 2.0 * effort;
            q[i] += 2.0 * effort * value;
            let before = if k > 0 {
                let b = ws.u[k - 1];
                Some((if ch == 0 { b.accel_m_s2 } else { b.yaw_rate_rad_s }, Some(iu(k - 1, ch))))
            } else {
                previous_input.map(|b| (if ch == 0 { b.accel_m_s2 } else { b.yaw_rate_rad_s }, None))
            };
            if let Some((prev, prev_index)) = before {
                let e = value - prev;
                diag[i] += 2.0 * rate;
                q[i] += 2.0 * rate * e;
                if let Some(j) = prev_index {
                    diag[j] += 2.0 * rate;
                    q[j] -= 2.0 * rate * e;
                    off[k][ch] = -2.0 * rate;
                }
            }
        }
    }
    for k in 1..=n {
        let t = ws.targets[k - 1];
        let s = ws.x[k];
        let f = t.factor;
        let nrm = t.tangent.perp();
        let e = s.position() - t.point;
        let (ec, el) = (nrm.dot(e), t.tangent.dot(e));
        let (px, py) = (ix(k, 0), ix(k, 1));
        diag[px] += 2.0 * f * (w.contour * nrm.x * nrm.x + w.lag * t.tangent.x * t.tangent.x);
        diag[py] += 2.0 * f * (w.contour * nrm.y * nrm.y + w.lag * t.tangent.y * t.tangent.y);
        off[k - 1][2] = 2.0 * f * (w.contour * nrm.x * nrm.y + w.lag * t.tangent.x * t.tangent.y);
        q[px] += 2.0 * f * (w.contour * ec * nrm.x + w.lag * el * t.tangent.x);
        q[py] += 2.0 * f * (w.contour * ec * nrm.y + w.lag * el * t.tangent.y);
        diag[ix(k, 2)] += 2.0 * f * w.heading;
        q[ix(k, 2)] += 2.0 * f * w.heading * (s.heading_rad - t.heading_rad);
        diag[ix(k, 3)] += 2.0 * f * w.speed;
        q[ix(k, 3)] += 2.0 * f * w.speed * (s.speed_m_s - t.speed_m_s);
        diag[iso(k)] += 2.0 * w.slack_quadratic;
        q[iso(k)] += w.slack_linear;
    }
    // P in compressed columns; rows increase within each column.
    let p = &mut qp.p;
    p.rows = nz;
    p.cols = nz;
    p.colptr.clear();
    p.rowval.clear();
    p.nzval.clear();
    for (col, &d) in diag.iter().enumerate() {
        p.colptr.push(p.rowval.len());
        let k = col / STAGE_VARS;
        match col % STAGE_VARS {
            ch @ (0 | 1) if k > 0 => {
                p.rowval.push(col - STAGE_VARS);
                p.nzval.push(off[k][ch]);
            }
            3 => {
                p.rowval.push(col - 1);
                p.nzval.push(off[k][2]);
            }
            _ => {}
        }
        p.rowval.push(col);
        p.nzval.push(d);
    }
    p.colptr.push(p.rowval.len());

    // A and b: the dynamics (equalities) first, then every inequality.
    let b = &mut qp.b;
    b.clear();
    let a = &mut ws.builder;
    a.clear();
    let mut row = 0;
    for k in 0..n {
        let jac = &ws.jacobians[k];
        for i in 0..4 {
            // δx_{k+1} - A_k δx_k - B_k δu_k = 0 over the Jacobians' structural entries
            // (δx_0 = 0: the start is given).
            if k > 0 {
                for j in 0..4 {
                    if i == j || (i < 2 && j >= 2) {
                        a.push(row, ix(k, j), -jac.a[i][j]);
                    }
                }
            }
            for ch in 0..2 {
                if i < 2 || (i == 2 && ch == 1) || (i == 3 && ch == 0) {
                    a.push(row, iu(k, ch), -jac.b[i][ch]);
                }
            }
            a.push(row, ix(k + 1, i), 1.0);
            b.push(0.0);
            row += 1;
        }
    }
    qp.equalities = row;
    let lim = &c.limits;
    for k in 0..n {
        let u = ws.u[k];
        for (ch, value, max) in [(0, u.accel_m_s2, lim.max_accel_m_s2), (1, u.yaw_rate_rad_s, lim.max_yaw_rate_rad_s)] {
            a.push(row, iu(k, ch), 1.0);
            b.push(max - value);
            a.push(row + 1, iu(k, ch), -1.0);
            b.push(max + value);
            row += 2;
        }
    }
    let rows_per_stage = 2 * c.obstacles.max_per_stage;
    let uniform_rows = ws.rows.chunks(rows_per_stage.max(1)).map(|stage| stage.iter().take_while(|r| r.used).count()).max().unwrap_or(0);
    for k in 1..=n {
        let t = ws.targets[k - 1];
        let v = ws.x[k].speed_m_s;
        // vlo_k <= v_k <= vhi_k (hard, widened to the braking envelope);  σo >= 0.
        a.push(row, ix(k, 3), 1.0);
        b.push(t.speed_hi - v);
        a.push(row + 1, ix(k, 3), -1.0);
        b.push(v - t.speed_lo);
        a.push(row + 2, iso(k), -1.0);
        b.push(0.0);
        row += 3;
        // Every stage gets `uniform_rows` obstacle rows, the most any stage uses: the pattern
        // then depends on that one number and the cached solvers are reused.
        for r in &ws.rows[(k - 1) * rows_per_stage..(k - 1) * rows_per_stage + uniform_rows] {
            // -(n·δp + lever·δθ) - σo <= d̄ - margin; an unused row only bounds σo below by
            // -UNUSED_ROW_RHS_M.
            a.push(row, ix(k, 0), -r.normal.x);
            a.push(row, ix(k, 1), -r.normal.y);
            a.push(row, ix(k, 2), -r.lever_m);
            a.push(row, iso(k), -1.0);
            b.push(if r.used { r.distance_m - c.obstacles.margin_m } else { UNUSED_ROW_RHS_M });
            row += 1;
        }
    }
    a.finish(row, nz, &mut qp.a);
}
