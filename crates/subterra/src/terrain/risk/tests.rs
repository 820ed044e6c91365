//! Tests of the map builder's numeric helpers: the libm-free floors, the plane fit and the
//! settling of the footprint.

use super::binning::{floor_i64, floor_small, FLOOR_SMALL_LIMIT};
use super::geometry::fit_plane;
use super::tilt::{heading_stencil, settle_tan2};
use super::RobotConfig;

#[test]
fn floor_without_libm() {
    for x in [-2.5, -2.0, -1e-300, 0.0, 0.3, 1.0, 1.9999999999999998, 7.5e15] {
        assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
    }
}

#[test]
fn floor_small_is_floor() {
    let mut xs = vec![-2.5, -2.0, -1.5, -0.5, -1e-300, -0.0, 0.0, 0.3, 0.5, 1.0, 1.5, 2.5, 1.9999999999999998, -1.0000000000000002, 1e15 + 0.5, -1e15 - 0.5];
    let mut state = 5u64;
    for i in 0..200_000 {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let u = (state >> 11) as f64 / (1u64 << 53) as f64;
        let scale = [1.0, 100.0, 1e6, 1e12, 1e15][i % 5];
        let x = (u - 0.5) * 2.0 * scale;
        // Also integers, halves and their neighbours.
        let k = x.round();
        xs.extend([x, k, k + 0.5, f64::from_bits(k.to_bits() + 1), f64::from_bits(k.to_bits().wrapping_sub(1))]);
    }
    for x in xs {
        if x.abs() < FLOOR_SMALL_LIMIT {
            assert_eq!(floor_small(x), x.floor() as i64, "{x}");
            assert_eq!(floor_small(x), floor_i64(x), "{x}");
        }
    }
}

#[test]
fn plane_fit_by_hand() {
    // z = 0.1 x - 0.2 y + 1 on a 3x3 grid of unit cells: slope sqrt(0.05), no residual.
    let mut s = [0.0; 10];
    for i in 0..3 {
        for j in 0..3 {
            let (x, y) = (i as f64, j as f64);
            let z = 0.1 * x - 0.2 * y + 1.0;
            let m = [1.0, x, y, z, x * x, x * y, y * y, x * z, y * z, z * z];
            for k in 0..10 {
                s[k] += m[k];
            }
        }
    }
    let (grad, rms) = fit_plane(&s, 1.0, 1.0).unwrap();
    assert!((grad - 0.05f64.sqrt()).abs() < 1e-9 && rms < 1e-6, "{grad} {rms}");
}

#[test]
fn collinear_ground_cells_have_no_plane() {
    // Window sums of cells at absolute positions far from the origin (as the map's
    // summed-area tables give them), centred at (xc, yc).
    fn sums(cells: &[(f64, f64, f64)]) -> [f64; 10] {
        let mut s = [0.0; 10];
        for &(x, y, z) in cells {
            for (k, v) in [1.0, x, y, z, x * x, x * y, y * y, x * z, y * z, z * z].into_iter().enumerate() {
                s[k] += v;
            }
        }
        s
    }
    let (x0, y0) = (123.45, -678.95);
    // One column of cells 0.1 m apart, rising 3 cm/m: no plane.
    let column: Vec<_> = (0..9).map(|k| (x0, y0 + 0.1 * k as f64, 0.03 * 0.1 * k as f64)).collect();
    assert_eq!(fit_plane(&sums(&column), x0, y0 + 0.4), None);
    let row: Vec<_> = (0..9).map(|k| (x0 + 0.1 * k as f64, y0, 0.01 * k as f64)).collect();
    assert_eq!(fit_plane(&sums(&row), x0 + 0.4, y0), None);
    // The same column plus one cell beside its end: a plane, with the column's slope.
    let mut l_shape = column.clone();
    l_shape.push((x0 + 0.1, y0, 0.0));
    let (grad, rms) = fit_plane(&sums(&l_shape), x0, y0 + 0.4).expect("an L of cells spans a plane");
    assert!((grad - 0.03).abs() < 1e-6 && rms < 1e-9, "{grad} {rms}");
}

#[test]
fn settling_on_a_plane_and_on_a_bump() {
    let robot = RobotConfig::default();
    let stencil = heading_stencil(&robot, 0.1, 0.0);
    assert_eq!(stencil.offsets, [(5, 3), (5, -3), (-5, 3), (-5, -3)]);
    // A plane rising 0.2 per metre along x: every support has that slope.
    let h = stencil.offsets.map(|(i, _)| 0.2 * i as f64 * 0.1);
    assert!((settle_tan2(&stencil.triangles, &h) - 0.04).abs() < 1e-12);
    // Front-left wheel on a 0.1 m block: the body rocks on the FL-RR diagonal, resting
    // either on FL, FR, RR (rolled: ∇ = (0, 0.1/0.6)) or on FL, RL, RR (pitched:
    // ∇ = (0.1/1.0, 0)); FL, FR, RL would leave RR in the air. The worst is the roll.
    let h = [0.1, 0.0, 0.0, 0.0];
    let tan2 = settle_tan2(&stencil.triangles, &h);
    assert!((tan2 - (0.1f64 / 0.6).powi(2)).abs() < 1e-12, "{tan2}");
}
