//! The master's PDO set-up against simulated drives built from hand-written
//! EDS files with vendor quirks: a default mapping that differs from what
//! the master needs (configured and read back), a read-only mapping that
//! suffices (used) or lacks an object (refused, naming it), an object the
//! drive cannot map, a second axis at +0x800, limits narrower than the
//! path, segmented SDO and the abort names.

use std::collections::BTreeMap;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use super::bus::Dir;
use super::canopen::pdo::{Mapped, COB_INVALID};
use super::canopen::{
    self, abort_name, AxisRef, MapSource, Master, MasterConfig, Outcome, SdoDone, SdoServer,
    SdoStep, SdoTransfer, ServerAction, StopKind,
};
use super::eds::DeviceDescription;
use super::log_bus::{read_log, LogBus};
use super::sim::{SimBus, SimConfig, SimProfile};
use super::{Envelope, Plan};

const CYCLE_US: u64 = 4000;
const CPM: f64 = 10_000.0;

/// One object section of an EDS.
fn var(index: &str, name: &str, dtype: &str, access: &str, value: &str, map: bool) -> String {
    format!(
        "[{index}]\nParameterName={name}\nObjectType=0x7\nDataType={dtype}\nAccessType={access}\nDefaultValue={value}\nPDOMapping={}\n\n",
        map as u8
    )
}

/// A PDO's communication and mapping parameters, vendor style.
fn pdo(comm: &str, map: &str, cob: &str, access: &str, entries: &[&str]) -> String {
    pdo_n(comm, map, cob, access, entries, entries.len())
}

/// As [`pdo`], with `count` of the declared entries in use (0: no default mapping).
fn pdo_n(comm: &str, map: &str, cob: &str, access: &str, entries: &[&str], count: usize) -> String {
    let mut s = format!(
        "[{comm}]\nParameterName=PDO communication parameter\nObjectType=0x9\nSubNumber=3\n\n"
    );
    s += &var(
        &format!("{comm}sub0"),
        "Highest sub-index",
        "0x0005",
        "ro",
        "2",
        false,
    );
    s += &var(&format!("{comm}sub1"), "COB-ID", "0x0007", "rw", cob, false);
    s += &var(
        &format!("{comm}sub2"),
        "Transmission type",
        "0x0005",
        "rw",
        "1",
        false,
    );
    s += &format!(
        "[{map}]\nParameterName=PDO mapping parameter\nObjectType=0x9\nSubNumber={}\n\n",
        entries.len() + 1
    );
    s += &var(
        &format!("{map}sub0"),
        "Number of mapped objects",
        "0x0005",
        access,
        &count.to_string(),
        false,
    );
    for (i, e) in entries.iter().enumerate() {
        s += &var(
            &format!("{map}sub{}", i + 1),
            "Mapped object",
            "0x0007",
            access,
            e,
            false,
        );
    }
    s
}

/// The CiA 402 objects of the axis at `offset` (0 or 0x800).
fn axis_objects(offset: u16, statusword_type: &str, target_mappable: bool) -> String {
    let i = |base: u16| format!("{:04X}", base + offset);
    var(&i(0x6040), "Controlword", "0x0006", "rww", "0", true)
        + &var(&i(0x6041), "Statusword", statusword_type, "ro", "0", true)
        + &var(&i(0x6060), "Modes of operation", "0x0002", "rw", "0", true)
        + &var(
            &i(0x6061),
            "Modes of operation display",
            "0x0002",
            "ro",
            "0",
            true,
        )
        + &var(
            &i(0x6064),
            "Position actual value",
            "0x0004",
            "ro",
            "0",
            true,
        )
        + &var(
            &i(0x606C),
            "Velocity actual value",
            "0x0004",
            "ro",
            "0",
            true,
        )
        + &var(
            &i(0x607A),
            "Target position",
            "0x0004",
            "rww",
            "0",
            target_mappable,
        )
}

const HEAD: &str = "[FileInfo]\nFileName=vendor.eds\n\n[DeviceInfo]\nVendorName=Quirky Drives\nProductName=QD-2\n\n\
[1000]\nParameterName=Device type\nObjectType=0x7\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x00020192\nPDOMapping=0\n\n\
[1017]\nParameterName=Producer heartbeat time\nObjectType=0x7\nDataType=0x0006\nAccessType=rw\nDefaultValue=0\nPDOMapping=0\n\n";

/// Vendor quirks: `$NODEID + 0x200` with spaces, a one-object default
/// RPDO (controlword only), a TPDO without the position, statusword
/// declared UNSIGNED32, a long device name (segmented SDO).
fn quirky_eds() -> String {
    let one = |e| [e, "0x00000000", "0x00000000"];
    String::from(HEAD)
        + &var(
            "1008",
            "Manufacturer device name",
            "0x0009",
            "const",
            "Quirky Drives QD-2 servo",
            false,
        )
        + &pdo_n(
            "1400",
            "1600",
            "$NODEID + 0x200",
            "rw",
            &one("0x60400010"),
            1,
        )
        + &pdo_n(
            "1800",
            "1A00",
            "0x180 + $NODEID",
            "rw",
            &one("0x60410020"),
            1,
        )
        + &axis_objects(0, "0x0007", true)
}

/// A drive whose mapping is fixed (AccessType ro): RPDO1 carries the
/// mode of operation too, TPDO1 the mode display too; with `enough` false the
/// RPDO lacks the target position.
fn read_only_eds(enough: bool) -> String {
    let rpdo: &[&str] = if enough {
        &["0x60400010", "0x60600008", "0x607A0020"]
    } else {
        &["0x60400010"]
    };
    String::from(HEAD)
        + &pdo("1400", "1600", "$NODEID+0x200", "ro", rpdo)
        + &pdo(
            "1800",
            "1A00",
            "$NODEID+0x180",
            "ro",
            &["0x60410010", "0x60640020", "0x60610008"],
        )
        + &axis_objects(0, "0x0006", true)
}

/// A two-axis drive: axis 2's objects at 0x6840…, RPDO2/TPDO2 for it; no
/// default mapping at all (count 0).
fn two_axis_eds() -> String {
    let zero: &[&str] = &["0x00000000", "0x00000000", "0x00000000"];
    String::from(HEAD)
        + &pdo_n("1400", "1600", "$NODEID+0x200", "rw", zero, 0)
        + &pdo_n("1800", "1A00", "$NODEID+0x180", "rw", zero, 0)
        + &pdo_n("1401", "1601", "$NODEID+0x300", "rw", zero, 0)
        + &pdo_n("1801", "1A01", "$NODEID+0x280", "rw", zero, 0)
        + &axis_objects(0, "0x0006", true)
        + &axis_objects(0x800, "0x0006", true)
}

fn env() -> Envelope {
    Envelope {
        max_comp_mm: 0.05,
        max_step_mm: 0.5,
        max_step_change_mm: 0.05,
        max_following_mm: 0.3,
    }
}

/// 0.4 s: x a slow ramp, y and z still.
fn plan() -> Plan {
    let mut p = Plan::default();
    for k in 0..100 {
        let t = k as f64 * CYCLE_US as f64 * 1e-6;
        p.cmd_mm.push([10.0 + 0.5 * t * t, 20.0, 5.0]);
        p.comp_mm.push([0.0; 3]);
    }
    p
}

struct Setup {
    nodes: [u8; 3],
    axes: [u8; 3],
    eds: Vec<(u8, String)>,
}

/// Run the master against simulated drives built from the same files,
/// logging the bus; the outcome, the log's frames and the sim.
fn run(s: &Setup, p: &Plan) -> (Outcome, Vec<super::CanFrame>, SimBus) {
    let mut descriptions = BTreeMap::new();
    let mut profiles = BTreeMap::new();
    for (node, text) in &s.eds {
        let d = DeviceDescription::parse(&format!("vendor-{node}.eds"), text, *node).unwrap();
        profiles.insert(*node, SimProfile::from_description(&d));
        descriptions.insert(*node, d);
    }
    let start = |a: usize| ((p.cmd_mm[0][a] + p.comp_mm[0][a]) * CPM).round() as i32;
    let sim = SimBus::new(SimConfig {
        nodes: s.nodes,
        start_counts: [start(0), start(1), start(2)],
        lag_s: 0.002,
        max_speed_mm_s: 500.0,
        counts_per_mm: CPM,
        quick_stop_decel_mm_s2: 5000.0,
        faults: vec![],
        drive_axes: s.axes,
        profiles,
    });
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("bus.log");
    let mut bus = LogBus::new(sim, &log).unwrap();
    let cfg = MasterConfig {
        cycle_us: CYCLE_US,
        nodes: s.nodes,
        drive_axes: s.axes,
        descriptions,
        counts_per_mm: CPM,
        heartbeat_ms: 20,
        heartbeat_timeout_us: 60_000,
        sdo_timeout_us: 100_000,
        transition_timeout_cycles: 25,
        stop_hold_cycles: 3,
        keep_traffic: true,
    };
    let flag = Arc::new(AtomicBool::new(false));
    let o = Master::new(cfg)
        .unwrap()
        .run(&mut bus, p, &env(), &flag)
        .unwrap();
    let frames = read_log(&log).unwrap();
    (o, frames, bus.into_inner())
}

/// The SDO writes the master sent to `node`: (index, sub, value).
fn sdo_writes(frames: &[super::CanFrame], node: u8) -> Vec<(u16, u8, u32)> {
    frames
        .iter()
        .filter(|f| {
            f.id == 0x600 + node as u32
                && f.payload()[0] & 0xE0 == 0x20
                && f.payload()[0] & 0x02 != 0
        })
        .map(|f| {
            let d = f.payload();
            (
                u16::from_le_bytes([d[1], d[2]]),
                d[3],
                u32::from_le_bytes([d[4], d[5], d[6], d[7]]),
            )
        })
        .collect()
}

fn masked(w: &[(u16, u8, u32)], index_range: std::ops::RangeInclusive<u16>) -> Vec<(u16, u8, u32)> {
    w.iter()
        .filter(|(i, _, _)| index_range.contains(i))
        .copied()
        .collect()
}

#[test]
fn a_default_mapping_that_differs_is_configured_and_read_back() {
    let s = Setup {
        nodes: [1, 2, 3],
        axes: [1, 1, 1],
        eds: vec![(1, quirky_eds())],
    };
    let p = plan();
    let (o, frames, sim) = run(&s, &p);
    assert!(o.stop.is_none(), "{:?}", o.stop);
    assert!(o.reached_operation_enabled);
    assert_eq!(o.cycles_streamed, p.cmd_mm.len());
    // CiA 301 order on the wire: invalidate, count 0, entries, count,
    // transmission type, validate; never a store (0x1010).
    let w = sdo_writes(&frames, 1);
    assert_eq!(
        masked(&w, 0x1400..=0x1600),
        vec![
            (0x1400, 1, 0x8000_0201),
            (0x1600, 0, 0),
            (0x1600, 1, 0x6040_0010),
            (0x1600, 2, 0x607A_0020),
            (0x1600, 0, 2),
            (0x1400, 2, 1),
            (0x1400, 1, 0x201),
        ]
    );
    // The TPDO with the statusword as wide as the file declares it (UNSIGNED32).
    assert!(w.contains(&(0x1A00, 1, 0x6041_0020)), "{w:x?}");
    assert!(w.contains(&(0x1A00, 2, 0x6064_0020)), "{w:x?}");
    // Interpolation period from the cycle is only written where declared.
    assert!(!w.iter().any(|x| x.0 == 0x60C2));
    for n in [1u8, 2, 3] {
        assert!(
            !sdo_writes(&frames, n).iter().any(|x| x.0 == 0x1010),
            "node {n}: parameters stored"
        );
    }
    // Read back after writing: an upload of 0x1600 sub 0, 1, 2.
    let reads: Vec<(u16, u8)> = frames
        .iter()
        .filter(|f| f.id == 0x601 && f.payload()[0] == 0x40)
        .map(|f| {
            (
                u16::from_le_bytes([f.payload()[1], f.payload()[2]]),
                f.payload()[3],
            )
        })
        .collect();
    for r in [
        (0x1600, 0),
        (0x1600, 1),
        (0x1600, 2),
        (0x1A00, 0),
        (0x1A00, 1),
        (0x1A00, 2),
    ] {
        assert!(reads.contains(&r), "{r:x?} not read back: {reads:x?}");
    }
    // The drive holds the master's mapping.
    let (r, t) = sim.pdo_maps(1, 1).unwrap();
    assert_eq!(
        r.entries,
        vec![Mapped::new(0x6040, 0, 16), Mapped::new(0x607A, 0, 32)]
    );
    assert_eq!(
        t.entries,
        vec![Mapped::new(0x6041, 0, 32), Mapped::new(0x6064, 0, 32)]
    );
    assert_eq!(r.cob_id & COB_INVALID, 0);
    assert_eq!(o.pdos[0].rpdo_source, MapSource::Configured);
    // Its 8-byte TPDOs were decoded: the feedback followed the path.
    assert!(o.samples.iter().all(|s| s.act[0].is_some()));
    assert!(o.max_following_mm < 0.3);
    // The name came by segmented upload (24 bytes).
    assert_eq!(
        o.device_names.get(&1).map(|s| s.as_str()),
        Some("Quirky Drives QD-2 servo")
    );
    assert!(
        frames
            .iter()
            .any(|f| f.id == 0x601 && f.payload()[0] & 0xEF == 0x60),
        "no upload segment request"
    );
    // The log is in time order, segments and all.
    assert!(
        frames.windows(2).all(|w| w[0].t_us <= w[1].t_us),
        "log out of time order"
    );
}

#[test]
fn a_read_only_mapping_that_carries_what_is_needed_is_used() {
    let s = Setup {
        nodes: [1, 2, 3],
        axes: [1, 1, 1],
        eds: vec![(1, read_only_eds(true))],
    };
    let p = plan();
    let (o, frames, sim) = run(&s, &p);
    assert!(o.stop.is_none(), "{:?}", o.stop);
    assert_eq!(o.cycles_streamed, p.cmd_mm.len());
    assert_eq!(o.pdos[0].rpdo_source, MapSource::DriveOwn);
    assert_eq!(o.pdos[0].tpdo_source, MapSource::DriveOwn);
    assert!(
        o.warnings
            .iter()
            .any(|w| w.contains("read-only") && w.contains("0x06010002")),
        "{:?}",
        o.warnings
    );
    // The drive's own 7-byte RPDO: controlword, mode 8, target.
    let rpdo = frames.iter().rev().find(|f| f.id == 0x201).unwrap();
    assert_eq!(rpdo.len, 7);
    assert_eq!(rpdo.payload()[2], 8);
    let (r, _) = sim.pdo_maps(1, 1).unwrap();
    assert_eq!(r.entries.len(), 3);
    // The COB-ID invalidated before the refused write is valid again.
    assert_eq!(r.cob_id, 0x201);
    // The other (standard) drives were configured as usual.
    assert_eq!(o.pdos[1].rpdo_source, MapSource::Configured);
}

#[test]
fn a_read_only_mapping_without_the_target_is_refused_naming_it() {
    let s = Setup {
        nodes: [1, 2, 3],
        axes: [1, 1, 1],
        eds: vec![(1, read_only_eds(false))],
    };
    let (o, frames, _) = run(&s, &plan());
    let (kind, why) = o.stop.clone().unwrap();
    assert_eq!(kind, StopKind::Refused);
    assert!(why.contains("0x607A"), "{why}");
    assert!(why.contains("vendor-1.eds"), "{why}");
    assert!(why.contains("attempt to write a read only object"), "{why}");
    assert!(!o.reached_operation_enabled);
    assert_eq!(o.cycles_streamed, 0);
    // Never started: no NMT start, no enable.
    assert!(!frames.iter().any(|f| f.id == 0 && f.payload()[0] == 0x01));
}

#[test]
fn an_object_the_drive_cannot_map_is_refused_with_the_abort_name() {
    let text = quirky_eds().replace(
        "[607A]\nParameterName=Target position\nObjectType=0x7\nDataType=0x0004\nAccessType=rww\nDefaultValue=0\nPDOMapping=1",
        "[607A]\nParameterName=Target position\nObjectType=0x7\nDataType=0x0004\nAccessType=rww\nDefaultValue=0\nPDOMapping=0",
    );
    let s = Setup {
        nodes: [1, 2, 3],
        axes: [1, 1, 1],
        eds: vec![(1, text)],
    };
    let (o, _, _) = run(&s, &plan());
    let (kind, why) = o.stop.clone().unwrap();
    assert_eq!(kind, StopKind::Refused, "{why}");
    assert!(why.contains("0x607A"), "{why}");
    assert!(
        why.contains("0x06040041") && why.contains("object cannot be mapped to the PDO"),
        "{why}"
    );
    assert!(!o.reached_operation_enabled);
}

#[test]
fn a_second_axis_at_0x800_drives_a_machine_axis() {
    let s = Setup {
        nodes: [1, 1, 3],
        axes: [1, 2, 1],
        eds: vec![(1, two_axis_eds())],
    };
    let p = plan();
    let (o, frames, sim) = run(&s, &p);
    assert!(o.stop.is_none(), "{:?}", o.stop);
    assert_eq!(o.cycles_streamed, p.cmd_mm.len());
    let (r, t) = sim.pdo_maps(1, 2).unwrap();
    assert_eq!(r.cob_id, 0x301);
    assert_eq!(
        r.entries,
        vec![Mapped::new(0x6840, 0, 16), Mapped::new(0x687A, 0, 32)]
    );
    assert_eq!(
        t.entries,
        vec![Mapped::new(0x6841, 0, 16), Mapped::new(0x6864, 0, 32)]
    );
    assert_eq!(o.pdos[1].drive, AxisRef::new(1, 2));
    // y's setpoints went out on RPDO2 of node 1; one heartbeat producer.
    assert!(frames.iter().any(|f| f.id == 0x301));
    assert!(frames.iter().any(|f| f.id == 0x281));
    assert!(sdo_writes(&frames, 1).contains(&(0x6860, 0, 8)));
}

#[test]
fn drive_limits_narrower_than_the_path_refuse_and_wider_ones_warn() {
    let limits = |lo: &str, hi: &str, vmax: &str| {
        quirky_eds()
            + "[607D]\nParameterName=Software position limit\nObjectType=0x8\nSubNumber=3\n\n"
            + &var("607Dsub0", "Highest sub-index", "0x0005", "ro", "2", false)
            + &var("607Dsub1", "Min position limit", "0x0004", "rw", lo, false)
            + &var("607Dsub2", "Max position limit", "0x0004", "rw", hi, false)
            + &var("607F", "Max profile velocity", "0x0007", "rw", vmax, false)
    };
    let p = plan();
    // x runs 10.0 → 10.08 mm = 100000 → 100800 counts.
    let (o, _, _) = run(
        &Setup {
            nodes: [1, 2, 3],
            axes: [1, 1, 1],
            eds: vec![(1, limits("0", "100500", "1000000000"))],
        },
        &p,
    );
    let (kind, why) = o.stop.clone().unwrap();
    assert_eq!(kind, StopKind::Refused);
    assert!(why.contains("0x607D") && why.contains("100500"), "{why}");
    // The path's peak speed (0.4 mm/s = 4000 counts/s) above the drive's.
    let (o, _, _) = run(
        &Setup {
            nodes: [1, 2, 3],
            axes: [1, 1, 1],
            eds: vec![(1, limits("0", "200000", "1000"))],
        },
        &p,
    );
    let (kind, why) = o.stop.clone().unwrap();
    assert_eq!(kind, StopKind::Refused);
    assert!(why.contains("0x607F"), "{why}");
    // Wide limits: runs, with a warning that the envelope is what limits.
    let (o, _, _) = run(
        &Setup {
            nodes: [1, 2, 3],
            axes: [1, 1, 1],
            eds: vec![(1, limits("0", "200000", "1000000000"))],
        },
        &p,
    );
    assert!(o.stop.is_none(), "{:?}", o.stop);
    assert!(
        o.warnings.iter().any(|w| w.contains("0x607F")),
        "{:?}",
        o.warnings
    );
}

#[test]
fn a_missing_object_is_refused_before_anything_is_sent() {
    let text = quirky_eds().replace("[1A00sub0]", "[1A00sub0x]");
    let d = DeviceDescription::parse("vendor.eds", &text, 1).unwrap();
    let mut descriptions = BTreeMap::new();
    descriptions.insert(1, d);
    let err = Master::new(MasterConfig {
        cycle_us: CYCLE_US,
        nodes: [1, 2, 3],
        drive_axes: [1, 1, 1],
        descriptions,
        counts_per_mm: CPM,
        heartbeat_ms: 20,
        heartbeat_timeout_us: 60_000,
        sdo_timeout_us: 100_000,
        transition_timeout_cycles: 25,
        stop_hold_cycles: 3,
        keep_traffic: true,
    })
    .err()
    .unwrap();
    assert!(
        matches!(&err, crate::Error::EdsMissingObject { file, index: 0x1A00, sub: 0, .. } if file == "vendor.eds"),
        "{err:?}"
    );
    let err = err.to_string();
    assert!(
        err.contains("vendor.eds") && err.contains("0x1A00:00"),
        "{err}"
    );
}

#[test]
fn segmented_sdo_both_ways_and_abort_names() {
    // Client against server directly: a 20-byte download, then its upload.
    let mut server = SdoServer::default();
    let mut stored: Vec<u8> = Vec::new();
    let data: Vec<u8> = (1..=20).collect();
    let (mut tr, mut req) = SdoTransfer::download(0x2000, 1, data.clone());
    let mut segments = 0;
    let done = loop {
        let reply = match server.on_request(&req) {
            ServerAction::Write(i, s, d) => {
                stored = d;
                server.downloaded(i, s, Ok(()))
            }
            ServerAction::Reply(r) => r,
            other => panic!("{other:?}"),
        };
        match tr.on_response(&reply) {
            SdoStep::Send(next) => {
                segments += 1;
                req = next;
            }
            SdoStep::Done(d) => break d,
            other => panic!("{other:?}"),
        }
    };
    assert_eq!(done, SdoDone::Downloaded);
    assert_eq!(stored, data);
    assert_eq!(segments, 3, "20 bytes = 7 + 7 + 6");
    let (mut tr, mut req) = SdoTransfer::upload(0x2000, 1);
    let got = loop {
        let reply = match server.on_request(&req) {
            ServerAction::Read(i, s) => server.uploaded(i, s, Ok(stored.clone())),
            ServerAction::Reply(r) => r,
            other => panic!("{other:?}"),
        };
        match tr.on_response(&reply) {
            SdoStep::Send(next) => req = next,
            SdoStep::Done(SdoDone::Uploaded(v)) => break v,
            other => panic!("{other:?}"),
        }
    };
    assert_eq!(got, data);
    // A toggle bit out of step is refused by the client with 0x05030000.
    let (mut tr, _) = SdoTransfer::upload(0x1008, 0);
    let init = [0x41, 0x08, 0x10, 0, 20, 0, 0, 0];
    assert!(matches!(tr.on_response(&init), SdoStep::Send(_)));
    assert_eq!(
        tr.on_response(&[0x10, b'a', 0, 0, 0, 0, 0, 0]),
        SdoStep::Failed(0x0503_0000)
    );
    for (code, name) in [
        (0x0602_0000, "object does not exist"),
        (0x0504_0000, "SDO protocol timed out"),
        (0x0601_0002, "attempt to write a read only object"),
        (0x0609_0011, "sub-index does not exist"),
        (0x0604_0041, "object cannot be mapped to the PDO"),
    ] {
        assert!(
            abort_name(code).contains(name),
            "0x{code:08X}: {}",
            abort_name(code)
        );
        assert_eq!(super::decode::abort_name(code), abort_name(code));
    }
    assert_eq!(abort_name(0x1234_5678), "unknown abort code");
}

#[test]
fn interpolation_period_is_exact_where_a_byte_allows() {
    assert_eq!(canopen::interpolation_period(4000), (4, -3));
    assert_eq!(canopen::interpolation_period(1500), (15, -4));
    assert_eq!(canopen::interpolation_period(2000), (2, -3));
    assert_eq!(canopen::interpolation_period(250_000), (250, -3));
}

#[test]
fn the_shipped_profile_gets_the_interpolation_period_and_its_limits_read() {
    // No --eds: every node is the shipped profile, which declares 0x60C2,
    // 0x607D and 0x607F.
    let s = Setup {
        nodes: [1, 2, 3],
        axes: [1, 1, 1],
        eds: vec![],
    };
    let (o, frames, _) = run(&s, &plan());
    assert!(o.stop.is_none(), "{:?}", o.stop);
    let w = sdo_writes(&frames, 2);
    assert!(
        w.contains(&(0x60C2, 1, 4)) && w.contains(&(0x60C2, 2, 0xFD)),
        "{w:x?}"
    );
    assert!(o
        .traffic
        .iter()
        .any(|(d, f)| *d == Dir::Tx && f.id == 0x602 && f.payload()[..4] == [0x40, 0x7F, 0x60, 0]));
}
