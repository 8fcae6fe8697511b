//! `sparkout can decode`: a CiA 402 start-up as a commissioning engineer
//! records it (candump -l log format, and the screen format with -ta),
//! decoded to the right events; a bad line names file and line.

use crate::common::sparkout;

/// NMT reset, boot-up, SDO reads of 0x1000 and 0x1018, mode 0x6060 = 8,
/// controlword 0x06 → 0x07 → 0x0F with the statusword on TPDO1, an SDO
/// abort, an EMCY and a heartbeat.
const STARTUP: [(&str, &str); 14] = [
    ("000", "8105"),
    ("705", "00"),
    ("605", "4000100000000000"),
    ("585", "4300100092010200"),
    ("605", "4018100100000000"),
    ("585", "4318100178563412"),
    ("605", "2F60600008000000"),
    ("585", "6060600000000000"),
    ("205", "0600000000000000"),
    ("185", "2102000000000000"),
    ("205", "0700000000000000"),
    ("185", "2302000000000000"),
    ("605", "4000200000000000"),
    ("585", "8000200000000206"),
];

fn write_logs(dir: &std::path::Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let mut log = String::new();
    let mut screen = String::new();
    for (i, (id, data)) in STARTUP.iter().enumerate() {
        let t = format!("(1700000000.{:06})", i * 1000);
        log.push_str(&format!("{t} can0 {id}#{data}\n"));
        let bytes: Vec<String> = (0..data.len() / 2)
            .map(|k| data[2 * k..2 * k + 2].to_string())
            .collect();
        screen.push_str(&format!(
            "{t}  can0  {id}   [{}]  {}\n",
            bytes.len(),
            bytes.join(" ")
        ));
    }
    log.push_str("(1700000001.000000) can0 085#1043080000000000\n");
    screen.push_str("(1700000001.000000)  can0  085   [8]  10 43 08 00 00 00 00 00\n");
    log.push_str("(1700000001.100000) can0 705#05\n");
    screen.push_str("(1700000001.100000)  can0  705   [1]  05\n");
    let (a, b) = (dir.join("startup.log"), dir.join("startup.txt"));
    std::fs::write(&a, log).unwrap();
    std::fs::write(&b, screen).unwrap();
    (a, b)
}

#[test]
fn a_cia402_start_up_decodes_to_its_events_in_both_formats() {
    let d = tempfile::tempdir().unwrap();
    let (log, screen) = write_logs(d.path());
    let mut all = Vec::new();
    for f in [&log, &screen] {
        let o = sparkout(&["can", "decode", f.to_str().unwrap(), "--format", "jsonl"]);
        assert_eq!(
            o.status.code(),
            Some(0),
            "{}",
            String::from_utf8_lossy(&o.stderr)
        );
        let events: Vec<serde_json::Value> = String::from_utf8_lossy(&o.stdout)
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        all.push(events);
    }
    assert_eq!(all[0], all[1], "the two formats decode alike");
    let e = &all[0];
    assert_eq!(e.len(), 16);
    let kinds: Vec<&str> = e.iter().map(|x| x["kind"].as_str().unwrap()).collect();
    assert_eq!(
        kinds,
        [
            "nmt",
            "bootup",
            "sdo_request",
            "sdo_response",
            "sdo_request",
            "sdo_response",
            "sdo_request",
            "sdo_response",
            "rpdo1",
            "tpdo1",
            "rpdo1",
            "tpdo1",
            "sdo_request",
            "sdo_abort",
            "emcy",
            "heartbeat"
        ]
    );
    assert_eq!(e[0]["text"], "NMT reset node → node 5");
    assert_eq!(e[3]["value"], 0x00020192, "device type from 0x1000");
    assert_eq!(e[5]["index"], 0x1018);
    assert_eq!(
        e[6]["value"], 8,
        "mode 0x6060 = cyclic synchronous position"
    );
    assert!(e[8]["text"].as_str().unwrap().contains("shutdown"));
    assert_eq!(e[9]["state"], "ready to switch on");
    assert!(e[10]["text"].as_str().unwrap().contains("switch on"));
    assert_eq!(e[11]["state"], "ready to switch on → switched on");
    assert_eq!(e[13]["value"], 0x06020000);
    assert!(e[13]["text"]
        .as_str()
        .unwrap()
        .contains("object does not exist in the object dictionary"));
    assert!(e[14]["text"].as_str().unwrap().contains("temperature"));
    // The readable listing says the same.
    let o = sparkout(&["can", "decode", log.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("16 frames decoded"), "{text}");
    assert!(text.contains("boot-up of node 5"), "{text}");
}

#[test]
fn a_bad_line_is_named_and_an_output_is_never_overwritten() {
    let d = tempfile::tempdir().unwrap();
    let (log, _) = write_logs(d.path());
    let bad = d.path().join("bad.log");
    let mut text = std::fs::read_to_string(&log).unwrap();
    text.push_str("(1700000002.000000) can0 18#3\n");
    std::fs::write(&bad, text).unwrap();
    let o = sparkout(&["can", "decode", bad.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("bad.log") && e.contains("row 17"), "{e}");
    let out = d.path().join("events.jsonl");
    std::fs::write(&out, b"keep").unwrap();
    let o = sparkout(&[
        "can",
        "decode",
        log.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(std::fs::read(&out).unwrap(), b"keep");
}
