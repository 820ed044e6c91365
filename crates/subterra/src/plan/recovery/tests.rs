//! Behaviour of the recovery machine: the ladder in order, triggers, relaxation, route
//! switches, back-out along the trail, and input and config errors.

use super::*;

fn input(t: f64, x: f64, d: f64, plan: PlanFeedback) -> RecoveryInput {
    RecoveryInput {
        time_s: t,
        position: DVec2::new(x, 0.0),
        yaw_rad: 0.0,
        distance_to_target_m: d,
        straight_distance_m: d,
        plan,
        clearance_heading_rad: Some(1.0),
        room_to_turn: true,
        route_switched: false,
    }
}

fn machine() -> RecoveryMachine {
    RecoveryMachine::new(RecoveryConfig::default(), DVec2::ZERO).unwrap()
}

#[test]
fn progress_keeps_tracking_and_goal_ends_the_run() {
    let mut m = machine();
    for k in 0..350 {
        let t = k as f64 * 0.1;
        let d = 15.0 - t * 0.5; // 0.5 m/s toward the goal
        let out = m.step(&input(t, t * 0.5, d.max(0.0), PlanFeedback::Found)).unwrap();
        if d > 0.5 {
            assert_eq!(out.behaviour, Behaviour::Track, "t = {t}");
        }
    }
    assert_eq!(m.behaviour(), Behaviour::GoalReached);
    assert_eq!(m.transitions().len(), 1);
    assert!(m.transitions()[0].reason.contains("goal reached"));
}

#[test]
fn plan_failures_climb_the_whole_ladder_in_order() {
    let mut m = machine();
    let mut seen = Vec::new();
    let mut t = 0.0;
    let mut x = 0.0;
    for _ in 0..400 {
        let out = m.step(&input(t, x, 10.0, PlanFeedback::NoPath)).unwrap();
        if seen.last() != Some(&out.behaviour) {
            seen.push(out.behaviour);
        }
        match out.behaviour {
            // Rotating: report the heading as reached at once.
            Behaviour::BackOut => x -= 0.05,
            Behaviour::Failed => break,
            _ => {}
        }
        t += 0.1;
        if out.behaviour == Behaviour::Rotate {
            // The robot turns to the asked heading.
            let out = m.step(&RecoveryInput { time_s: t, yaw_rad: 1.0, ..input(t, x, 10.0, PlanFeedback::NoPath) }).unwrap();
            assert_eq!(out.behaviour, Behaviour::Track);
            t += 0.1;
        }
    }
    use Behaviour::*;
    // Goal: clear, rotate, raise x3 (0.6 -> 0.9), back out; then home: the same, then failed.
    let ladder = [ClearMap, Track, Rotate, Track, RaiseThresholds, Track, RaiseThresholds, Track, RaiseThresholds, Track, BackOut, Track];
    // The switch to home is track -> track, so it does not show in `seen`.
    let mut expected = vec![Track];
    expected.extend_from_slice(&ladder);
    expected.extend_from_slice(&ladder);
    expected.push(Failed);
    assert_eq!(seen, expected);
    let home_switch = m.transitions().iter().position(|tr| tr.reason.contains("returning home")).unwrap();
    assert!(m.transitions()[..home_switch].iter().any(|tr| (tr.r_inst - 0.9).abs() < 1e-12));
    assert_eq!(m.transitions()[home_switch].r_inst, 0.6, "thresholds reset for the way home");
    assert_eq!(m.target(), Target::Home);
    assert!(m.transitions().iter().all(|tr| !tr.reason.is_empty()));
}

#[test]
fn clear_map_is_asked_once_on_the_first_trigger() {
    let mut m = machine();
    let mut clears = 0;
    for k in 0..5 {
        let out = m.step(&input(k as f64 * 0.1, 0.0, 10.0, PlanFeedback::NoPath)).unwrap();
        clears += out.clear_map as u32;
        if k == 4 {
            assert!(out.clear_map);
            assert_eq!(out.behaviour, Behaviour::ClearMap);
        }
    }
    assert_eq!(clears, 1);
}

#[test]
fn no_progress_triggers_after_a_full_window_only() {
    let mut m = machine();
    let mut first = None;
    for k in 0..200 {
        let t = k as f64 * 0.1;
        let d = 10.0 - 0.02 * t; // 0.16 m per 8 s window: too slow
        let out = m.step(&input(t, 0.0, d, PlanFeedback::Found)).unwrap();
        if out.behaviour == Behaviour::ClearMap {
            first = Some(t);
            break;
        }
    }
    let t = first.expect("no trigger");
    assert!((8.0..=8.15).contains(&t), "triggered at {t}");
    assert!(m.transitions()[0].reason.starts_with("no progress: 0.16 m"));
}

/// Drives at 0.5 m/s toward a target 10 m off; at `t = 3 s` the plan switches to a route
/// 4 m longer (and, with `again`, at 6 s back to one 4 m longer still). The first switch
/// is progress along the new route; a second within the window is not.
fn drive_with_switches(again: bool) -> Option<f64> {
    let mut m = machine();
    for k in 0..160 {
        let t = k as f64 * 0.1;
        let extra = if t >= 6.0 && again { 8.0 } else if t >= 3.0 { 4.0 } else { 0.0 };
        let switched = (k == 30) || (again && k == 60);
        let d = 10.0 - 0.5 * t + extra;
        let out = m.step(&RecoveryInput { route_switched: switched, ..input(t, 0.0, d, PlanFeedback::Found) }).unwrap();
        if out.behaviour != Behaviour::Track {
            return Some(t);
        }
    }
    None
}

#[test]
fn a_switch_to_a_longer_route_is_not_lost_progress_but_dithering_is() {
    assert_eq!(drive_with_switches(false), None, "one switch: progress along the new route");
    let t = drive_with_switches(true).expect("two switches in one window: no progress");
    assert!((8.0..=9.0).contains(&t), "triggered at {t}");
    // Without the flag, the same jump is a stall.
    let mut m = machine();
    let stalled = (0..160).map(|k| k as f64 * 0.1).find(|&t| {
        let d = 10.0 - 0.5 * t + if t >= 3.0 { 4.0 } else { 0.0 };
        m.step(&input(t, 0.0, d, PlanFeedback::Found)).unwrap().behaviour != Behaviour::Track
    });
    assert!(stalled.is_some());
}

#[test]
fn sustained_progress_relaxes_raised_thresholds() {
    let cfg = RecoveryConfig::default();
    let mut m = machine();
    let mut t = 0.0;
    // Three triggers: clear, rotate (reached at once), raise.
    while m.transitions().iter().filter(|tr| tr.to == Behaviour::RaiseThresholds).count() == 0 {
        let yaw = if m.behaviour() == Behaviour::Rotate { 1.0 } else { 0.0 };
        m.step(&RecoveryInput { yaw_rad: yaw, ..input(t, 0.0, 10.0, PlanFeedback::NoPath) }).unwrap();
        t += 0.1;
    }
    let out = m.step(&input(t, 0.0, 10.0, PlanFeedback::Found)).unwrap();
    assert!((out.r_inst - (cfg.r_inst + cfg.r_inst_step)).abs() < 1e-12);
    let raised_at = t;
    let mut d = 10.0;
    while t < raised_at + cfg.relax_after_s + 0.5 {
        t += 0.1;
        d -= 0.05;
        m.step(&input(t, 0.0, d, PlanFeedback::Found)).unwrap();
    }
    let out = m.step(&input(t + 0.1, 0.0, d - 0.05, PlanFeedback::Found)).unwrap();
    assert_eq!((out.r_inst, out.r_total), (cfg.r_inst, cfg.r_total));
    assert!(m.transitions().iter().any(|tr| tr.reason.contains("past where it got stuck")), "{:?}", m.transitions().last());
}

/// Drives 5 m along +x, gets stuck, and backs out with `room_to_turn(x)`; the distance
/// backed out.
fn back_out_until(room_to_turn: impl Fn(f64) -> bool) -> f64 {
    let mut m = machine();
    let mut t = 0.0;
    for k in 0..100 {
        t = k as f64 * 0.1;
        m.step(&input(t, 0.05 * k as f64, 10.0 - 0.05 * k as f64, PlanFeedback::Found)).unwrap();
    }
    let mut x = 4.95;
    let mut started = None;
    for _ in 0..2000 {
        t += 0.1;
        let yaw = if m.behaviour() == Behaviour::Rotate { 1.0 } else { 0.0 };
        let out = m.step(&RecoveryInput { yaw_rad: yaw, room_to_turn: room_to_turn(x), ..input(t, x, 5.05, PlanFeedback::NoPath) }).unwrap();
        if out.behaviour == Behaviour::BackOut {
            started.get_or_insert(x);
            x -= 0.02;
        } else if let Some(x0) = started {
            return x0 - x;
        }
    }
    panic!("never backed out");
}

#[test]
fn backout_goes_on_until_there_is_room_to_turn() {
    // Room everywhere: the nominal 2 m.
    assert!((back_out_until(|_| true) - 2.0).abs() < 0.05);
    // A corridor: no room to turn until x < 1.5 (3.45 m back).
    let d = back_out_until(|x| x < 1.5);
    assert!((d - 3.45).abs() < 0.05, "{d}");
    // Never room (the trail is 5 m long): at the trail's end, before the 8 m limit.
    assert!(back_out_until(|_| false) <= 5.0);
}

#[test]
fn backout_follows_the_trail_backwards() {
    let mut m = machine();
    // Drive 5 m along +x, then get stuck for good.
    let mut t = 0.0;
    for k in 0..100 {
        t = k as f64 * 0.1;
        m.step(&input(t, 0.05 * k as f64, 10.0 - 0.05 * k as f64, PlanFeedback::Found)).unwrap();
    }
    let mut x = 4.95;
    let mut carrots = Vec::new();
    for _ in 0..400 {
        t += 0.1;
        let yaw = if m.behaviour() == Behaviour::Rotate { 1.0 } else { 0.0 };
        let out = m.step(&RecoveryInput { yaw_rad: yaw, ..input(t, x, 5.05, PlanFeedback::NoPath) }).unwrap();
        if out.behaviour == Behaviour::BackOut {
            let c = out.backout_carrot.unwrap();
            assert!(c.x < x && c.x >= x - 1.0, "carrot {c} behind the robot at x = {x}");
            carrots.push(c.x);
            x -= 0.05;
        } else if !carrots.is_empty() {
            break;
        }
    }
    assert!(carrots.windows(2).all(|w| w[1] <= w[0]), "carrots move back along the trail");
    let done = m.transitions().iter().find(|tr| tr.from == Behaviour::BackOut).unwrap();
    assert!(done.reason.starts_with("backed out 2.0"), "{}", done.reason);
}

#[test]
fn bad_inputs_and_configs_name_the_field() {
    let mut m = machine();
    m.step(&input(1.0, 0.0, 5.0, PlanFeedback::Found)).unwrap();
    let err = m.step(&input(0.5, 0.0, 5.0, PlanFeedback::Found)).unwrap_err();
    assert!(err.to_string().contains("time_s"));
    let err = m.step(&input(2.0, f64::NAN, 5.0, PlanFeedback::Found)).unwrap_err();
    assert!(err.to_string().contains("position"));
    let err = m.step(&input(2.0, 0.0, -1.0, PlanFeedback::Found)).unwrap_err();
    assert!(err.to_string().contains("distance_to_target_m"));
    let bad = RecoveryConfig { r_inst_ceiling: 0.5, ..RecoveryConfig::default() };
    assert!(RecoveryMachine::new(bad, DVec2::ZERO).unwrap_err().to_string().contains("recovery.r_inst_ceiling"));
    let bad = RecoveryConfig { progress_window_s: f64::NAN, ..RecoveryConfig::default() };
    assert!(RecoveryMachine::new(bad, DVec2::ZERO).unwrap_err().to_string().contains("recovery.progress_window_s"));
    assert!(RecoveryMachine::new(RecoveryConfig::default(), DVec2::NAN).is_err());
}

#[test]
fn wrap_angle_stays_in_range() {
    for a in [-7.0, -PI, -1.0, 0.0, 1.0, PI, 4.0, 100.0] {
        let w = wrap_angle(a);
        assert!(w > -PI - 1e-12 && w <= PI + 1e-12);
        assert!(((a - w) / (2.0 * PI)).fract().abs() < 1e-9 || ((a - w) / (2.0 * PI)).fract().abs() > 1.0 - 1e-9);
    }
}
