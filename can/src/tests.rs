//! The master against simulated drives on the virtual clock: a full replay,
//! every injected fault, the envelope, SYNC timing, the log round trip.

use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use super::bus::{CanBus, Dir};
use super::canopen::{self, cw, Master, MasterConfig, Outcome, StopKind};
use super::log_bus::{read_log, LogBus};
use super::sim::{SimBus, SimConfig, SimFault};
use super::{Envelope, Plan};

const CYCLE_US: u64 = 4000;
const CPM: f64 = 10_000.0;
const NODES: [u8; 3] = [1, 2, 3];

fn env() -> Envelope {
    Envelope {
        max_comp_mm: 0.05,
        max_step_mm: 0.5,
        max_step_change_mm: 0.05,
        max_following_mm: 0.3,
    }
}

/// 1 s of a smooth path: x a cosine bump from rest, y a ramp, z constant, a small dz.
fn plan() -> Plan {
    let n = 251;
    let mut p = Plan {
        t0_s: 0.0,
        ..Default::default()
    };
    for k in 0..n {
        let t = k as f64 * CYCLE_US as f64 * 1e-6;
        p.cmd_mm.push([
            // Starts from rest: a path that starts moving would be a jump
            // in the per-cycle step, which the envelope rightly refuses.
            10.0 + 2.5 * (1.0 - (2.0 * std::f64::consts::PI * t).cos()),
            20.0 + 10.0 * t,
            5.0,
        ]);
        p.comp_mm
            .push([0.0, 0.0, 0.01 * (2.0 * std::f64::consts::PI * t).sin()]);
    }
    p
}

fn master_cfg() -> MasterConfig {
    MasterConfig {
        cycle_us: CYCLE_US,
        nodes: NODES,
        drive_axes: [1, 1, 1],
        descriptions: Default::default(),
        counts_per_mm: CPM,
        heartbeat_ms: 20,
        heartbeat_timeout_us: 60_000,
        sdo_timeout_us: 100_000,
        transition_timeout_cycles: 25,
        stop_hold_cycles: 3,
        keep_traffic: true,
    }
}

fn sim(plan: &Plan, faults: Vec<SimFault>, flag: Arc<AtomicBool>) -> SimBus {
    let start = |a: usize| ((plan.cmd_mm[0][a] + plan.comp_mm[0][a]) * CPM).round() as i32;
    SimBus::new(SimConfig {
        nodes: NODES,
        start_counts: [start(0), start(1), start(2)],
        lag_s: 0.002,
        max_speed_mm_s: 500.0,
        counts_per_mm: CPM,
        quick_stop_decel_mm_s2: 5000.0,
        faults,
        drive_axes: [1, 1, 1],
        profiles: Default::default(),
    })
    .with_interrupt(flag)
}

fn run(plan: &Plan, faults: Vec<SimFault>) -> Outcome {
    let flag = Arc::new(AtomicBool::new(false));
    let mut bus = sim(plan, faults, flag.clone());
    Master::new(master_cfg())
        .unwrap()
        .run(&mut bus, plan, &env(), &flag)
        .unwrap()
}

/// Every motion-commanding RPDO (controlword Enable operation) obeys the
/// envelope's step limits against the previous RPDO of the same node, and
/// no other RPDO moves the target; returns how many there were per node.
fn assert_frames_inside_envelope(o: &Outcome) -> [usize; 3] {
    let e = env();
    let mut prev: [Option<i32>; 3] = [None; 3];
    let mut prev_step = [0i32; 3];
    let mut streamed = [0usize; 3];
    for (dir, f) in &o.traffic {
        if *dir != Dir::Tx || f.id & 0x780 != canopen::RPDO1_BASE {
            continue;
        }
        let a = NODES.iter().position(|&n| n as u32 == f.id & 0x7F).unwrap();
        let (word, target) = canopen::decode_pdo(f).unwrap();
        if let Some(p) = prev[a] {
            let step = target - p;
            if word == cw::ENABLE_OPERATION {
                assert!(
                    (step as f64 / CPM).abs() <= e.max_step_mm + 1e-12,
                    "step {step} at {}",
                    f.t_us
                );
                assert!(
                    ((step - prev_step[a]) as f64 / CPM).abs() <= e.max_step_change_mm + 1e-12,
                    "step change at {}",
                    f.t_us
                );
            } else {
                // Enable/stop frames never move the target.
                assert_eq!(
                    step, 0,
                    "controlword 0x{word:04X} moved the target at {}",
                    f.t_us
                );
            }
            prev_step[a] = step;
        }
        if word == cw::ENABLE_OPERATION {
            streamed[a] += 1;
        }
        prev[a] = Some(target);
    }
    streamed
}

fn first_quick_stop(o: &Outcome) -> [u64; 3] {
    let mut t = [u64::MAX; 3];
    for (dir, f) in &o.traffic {
        if *dir == Dir::Tx && f.id & 0x780 == canopen::RPDO1_BASE {
            let a = NODES.iter().position(|&n| n as u32 == f.id & 0x7F).unwrap();
            if canopen::decode_pdo(f).unwrap().0 == cw::QUICK_STOP {
                t[a] = t[a].min(f.t_us);
            }
        }
    }
    t
}

#[test]
fn full_replay_reaches_operation_enabled_and_streams_every_setpoint() {
    let p = plan();
    let o = run(&p, vec![]);
    assert!(o.stop.is_none(), "{:?}", o.stop);
    assert!(o.reached_operation_enabled);
    assert_eq!(o.cycles_streamed, p.cmd_mm.len());
    // Every setpoint went out, in order, to every axis, exactly as planned.
    let mut sent: [Vec<i32>; 3] = Default::default();
    for (dir, f) in &o.traffic {
        if *dir == Dir::Tx && f.id & 0x780 == canopen::RPDO1_BASE {
            let a = (f.id & 0x7F) as usize - 1;
            let (w, target) = canopen::decode_pdo(f).unwrap();
            if w == cw::ENABLE_OPERATION {
                sent[a].push(target);
            }
        }
    }
    for a in 0..3 {
        let expect: Vec<i32> = p
            .cmd_mm
            .iter()
            .zip(&p.comp_mm)
            .map(|(c, d)| ((c[a] + d[a]) * CPM).round() as i32)
            .collect();
        // The first Enable-operation frame is the enable command itself (holding).
        assert_eq!(
            &sent[a][sent[a].len() - expect.len()..],
            &expect[..],
            "axis {a}"
        );
    }
    // Feedback came back for every cycle and followed within the lag.
    assert!(o.samples.iter().all(|s| s.act.iter().all(|x| x.is_some())));
    assert!(
        o.max_following_mm > 0.0 && o.max_following_mm < 0.3,
        "{}",
        o.max_following_mm
    );
    let streamed = assert_frames_inside_envelope(&o);
    assert!(streamed.iter().all(|&n| n >= p.cmd_mm.len()));
    // Normal end: NMT back to pre-operational.
    let last = o
        .traffic
        .iter()
        .rev()
        .find(|(d, _)| *d == Dir::Tx)
        .unwrap()
        .1;
    assert_eq!(last.id, canopen::NMT_ID);
}

#[test]
fn sync_period_is_exact_on_the_virtual_clock() {
    let p = plan();
    let o = run(&p, vec![]);
    let syncs: Vec<u64> = o
        .traffic
        .iter()
        .filter(|(d, f)| *d == Dir::Tx && f.id == canopen::SYNC_ID)
        .map(|(_, f)| f.t_us)
        .collect();
    assert_eq!(syncs.len() as u64, o.sync_frames);
    assert!(syncs.len() > p.cmd_mm.len());
    assert_eq!(syncs[0], 0);
    for w in syncs.windows(2) {
        assert_eq!(w[1] - w[0], CYCLE_US);
    }
}

/// Each fault ends in a quick stop of every drive within 2 cycles of the
/// moment it is detectable, with no frame outside the envelope.
#[test]
fn every_injected_fault_quick_stops_within_two_cycles() {
    let p = plan();
    let at = 500_000u64;
    let cases = [
        (
            SimFault::HeartbeatStops { node: 2, at_us: at },
            StopKind::Heartbeat,
        ),
        (
            SimFault::Emcy {
                node: 3,
                at_us: at,
                code: 0x2310,
            },
            StopKind::Emcy,
        ),
        (SimFault::BusOff { at_us: at }, StopKind::BusOff),
        (
            SimFault::FollowingError {
                node: 1,
                at_us: at,
                mm: 1.0,
            },
            StopKind::FollowingError,
        ),
        (SimFault::Interrupt { at_us: at }, StopKind::Interrupt),
        (SimFault::RefuseEnable { node: 2 }, StopKind::Refused),
    ];
    for (fault, kind) in cases {
        let o = run(&p, vec![fault.clone()]);
        let (k, why) = o
            .stop
            .clone()
            .unwrap_or_else(|| panic!("{fault:?}: no stop"));
        assert_eq!(k, kind, "{fault:?}: {why}");
        let qs = first_quick_stop(&o);
        assert!(
            qs.iter().all(|&t| t != u64::MAX),
            "{fault:?}: not every drive got a quick stop"
        );
        let qs = *qs.iter().max().unwrap();
        // When the fault became detectable.
        let t_fault = match fault {
            SimFault::HeartbeatStops { node, .. } => {
                let last = o
                    .traffic
                    .iter()
                    .filter(|(d, f)| *d == Dir::Rx && f.id == canopen::HEARTBEAT_BASE + node as u32)
                    .map(|(_, f)| f.t_us)
                    .max()
                    .unwrap();
                assert!(last <= at);
                last + master_cfg().heartbeat_timeout_us
            }
            SimFault::RefuseEnable { .. } => o.detected_us.unwrap(),
            _ => at,
        };
        assert!(qs >= t_fault, "{fault:?}: quick stop before the fault?");
        assert!(
            qs - t_fault <= 2 * CYCLE_US,
            "{fault:?}: quick stop {} µs after the fault",
            qs - t_fault
        );
        assert!(why.len() > 10, "the log must say why: {why}");
        assert_frames_inside_envelope(&o);
        if kind == StopKind::Refused {
            assert!(!o.reached_operation_enabled);
            assert_eq!(o.cycles_streamed, 0);
        } else {
            assert!(o.cycles_streamed > 100 && o.cycles_streamed < p.cmd_mm.len());
        }
        // After the stop nothing moves: no Enable-operation frame after the quick stop.
        assert!(!o.traffic.iter().any(|(d, f)| *d == Dir::Tx
            && f.id & 0x780 == canopen::RPDO1_BASE
            && f.t_us > qs
            && canopen::decode_pdo(f).unwrap().0 == cw::ENABLE_OPERATION));
    }
}

#[test]
fn out_of_envelope_and_nan_setpoints_never_reach_the_bus() {
    // (setpoint, axis, on the compensation?, value); the other axes keep
    // the good path's values, so only the bad axis can differ on the bus.
    let bad_cases: [(usize, usize, bool, f64); 4] = [
        (120, 0, false, f64::NAN),
        (130, 2, true, f64::INFINITY),
        (140, 0, true, 0.2),   // |comp| > 0.05
        (150, 0, false, 40.0), // a 25+ mm jump
    ];
    for (k, axis, on_comp, value) in bad_cases {
        let mut p = plan();
        let (mut cmd, mut comp) = (p.cmd_mm[k], p.comp_mm[k]);
        if on_comp {
            comp[axis] = value;
        } else {
            cmd[axis] = value;
        }
        p.cmd_mm[k] = cmd;
        p.comp_mm[k] = comp;
        assert!(
            super::preflight(&p, &env(), CPM, CYCLE_US).is_err(),
            "preflight must refuse {k}"
        );
        let o = run(&p, vec![]);
        let (kind, why) = o.stop.clone().unwrap();
        assert_eq!(kind, StopKind::Envelope, "{why}");
        assert!(why.contains(&format!("setpoint {k} ")), "{why}");
        assert_eq!(
            o.cycles_streamed, k,
            "setpoints before {k} streamed, none after"
        );
        let streamed = assert_frames_inside_envelope(&o);
        // k setpoints + the enable command frame(s), nothing of setpoint k.
        let good = plan();
        for a in 0..3 {
            let bad = ((cmd[a] + comp[a]) * CPM).round();
            let sent_bad = o.traffic.iter().any(|(d, f)| {
                *d == Dir::Tx
                    && f.id == canopen::RPDO1_BASE + NODES[a] as u32
                    && bad.is_finite()
                    && canopen::decode_pdo(f).unwrap().1 as f64 == bad
                    && bad != ((good.cmd_mm[k][a] + good.comp_mm[k][a]) * CPM).round()
            });
            assert!(!sent_bad, "case {k}: the bad setpoint reached the bus");
            assert!(streamed[a] <= k + 2);
        }
        // The quick stop went out in the same cycle the violation was found.
        assert_eq!(o.quick_stop_us, o.detected_us);
    }
}

#[test]
fn path_far_from_the_axes_is_refused_before_streaming() {
    let p = plan();
    let flag = Arc::new(AtomicBool::new(false));
    let mut bus = sim(&p, vec![], flag.clone());
    // The master thinks the path starts 5 mm away from where the axes are.
    let mut shifted = p.clone();
    for c in &mut shifted.cmd_mm {
        c[0] += 5.0;
    }
    let o = Master::new(master_cfg())
        .unwrap()
        .run(&mut bus, &shifted, &env(), &flag)
        .unwrap();
    let (kind, why) = o.stop.unwrap();
    assert_eq!(kind, StopKind::Envelope);
    assert!(why.contains("position the axis at the path start"), "{why}");
    assert_eq!(o.cycles_streamed, 0);
}

#[test]
fn log_backend_round_trips_the_whole_bus_traffic() {
    let p = plan();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("replay.log");
    let flag = Arc::new(AtomicBool::new(false));
    let mut bus = LogBus::new(sim(&p, vec![], flag.clone()), &path).unwrap();
    assert!(bus.describe().starts_with("log:"));
    let o = Master::new(master_cfg())
        .unwrap()
        .run(&mut bus, &p, &env(), &flag)
        .unwrap();
    assert!(o.stop.is_none());
    let back = read_log(&path).unwrap();
    let traffic: Vec<_> = o.traffic.iter().map(|(_, f)| *f).collect();
    assert_eq!(back.len(), traffic.len());
    assert_eq!(back, traffic);
    // No temporary file left beside it.
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 1, "{names:?}");
}

#[test]
fn shipped_eds_matches_the_master_and_a_changed_one_is_refused() {
    canopen::check_eds(canopen::DRIVE_EDS).unwrap();
    let changed = canopen::DRIVE_EDS.replace("DefaultValue=0x607A0020", "DefaultValue=0x607A0010");
    let err = canopen::check_eds(&changed).unwrap_err().to_string();
    assert!(err.contains("1600sub2"), "{err}");
}

#[test]
fn shipped_dbc_describes_the_pdo_frames_the_master_sends() {
    let dbc = include_str!("../configs/can/cia402_pdo.dbc");
    for n in NODES {
        let r = format!(
            "BO_ {} RPDO1_node{n}: 6 Master",
            canopen::RPDO1_BASE + n as u32
        );
        let t = format!(
            "BO_ {} TPDO1_node{n}: 6 Drive{n}",
            canopen::TPDO1_BASE + n as u32
        );
        assert!(dbc.contains(&r), "{r}");
        assert!(dbc.contains(&t), "{t}");
    }
    // Layout: 16-bit word at bit 0, signed 32-bit position at bit 16, 1/CPM mm.
    assert!(dbc.contains(" SG_ TargetPosition : 16|32@1- (0.0001,0)"));
    assert!(dbc.contains(" SG_ ActualPosition : 16|32@1- (0.0001,0)"));
    assert!(dbc.contains(" SG_ Controlword : 0|16@1+ (1,0)"));
    assert_eq!(1.0 / 0.0001, CPM);
    let f = canopen::rpdo1(1, cw::ENABLE_OPERATION, -12345);
    assert_eq!(f.payload(), &[0x0F, 0x00, 0xC7, 0xCF, 0xFF, 0xFF]);
}

#[test]
fn sdo_codec_round_trips() {
    use super::canopen::{SdoRequest, SdoResponse};
    let reqs = [
        SdoRequest::Download {
            index: 0x6060,
            sub: 0,
            data: vec![8],
        },
        SdoRequest::Download {
            index: 0x1017,
            sub: 0,
            data: vec![20, 0],
        },
        SdoRequest::Download {
            index: 0x607A,
            sub: 0,
            data: vec![1, 2, 3, 4],
        },
        SdoRequest::Upload {
            index: 0x6064,
            sub: 0,
        },
    ];
    for r in reqs {
        assert_eq!(SdoRequest::parse(&r.frame(5)), Some(r.clone()));
    }
    assert_eq!(
        SdoRequest::Download {
            index: 0x6060,
            sub: 0,
            data: vec![8]
        }
        .frame(1)
        .payload()[0],
        0x2F
    );
    let resps = [
        SdoResponse::Downloaded {
            index: 0x6060,
            sub: 0,
        },
        SdoResponse::Uploaded {
            index: 0x6041,
            sub: 0,
            value: 0x0237,
            len: 2,
        },
        SdoResponse::Uploaded {
            index: 0x6064,
            sub: 0,
            value: 0xFFFF_FFFE,
            len: 4,
        },
        SdoResponse::Abort {
            index: 0x6060,
            sub: 0,
            code: 0x0602_0000,
        },
    ];
    for r in resps {
        assert_eq!(SdoResponse::parse(&r.frame(5)), Some(r.clone()));
    }
}
