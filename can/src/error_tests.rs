//! The error type held by its variants: each refusal is the variant that
//! carries what a caller acts on, with the message the CLI prints.

use crate::error::Error;
use crate::{canopen, BusSpec, Envelope, SimFault};

#[test]
fn each_refusal_is_its_variant_with_the_data_to_act_on() {
    let e = BusSpec::parse("ether").unwrap_err();
    assert!(
        matches!(&e, Error::BadOption { flag: "--bus", value, .. } if value == "ether"),
        "{e:?}"
    );
    assert_eq!(
        e.to_string(),
        "--bus `ether`: use sim, log:FILE or socketcan:IFACE"
    );

    let e = SimFault::parse("heartbeat@soon", 1).unwrap_err();
    assert!(
        matches!(&e, Error::BadOption { flag: "--sim-fault", value, .. } if value == "heartbeat@soon"),
        "{e:?}"
    );

    let env = Envelope {
        max_comp_mm: 0.5,
        max_step_mm: -1.0,
        max_step_change_mm: 0.5,
        max_following_mm: 0.5,
    };
    let e = env.validate().unwrap_err();
    assert!(
        matches!(e, Error::EnvelopeLimit { limit: "--max-step-mm", value } if value == -1.0),
        "{e:?}"
    );

    let changed = canopen::DRIVE_EDS.replace("0x60400010", "0x60400020");
    let e = canopen::check_eds(&changed).unwrap_err();
    assert!(
        matches!(&e, Error::EdsMapping { section: "1600sub1", got: Some(g), expected: "0x60400010" } if g == "0x60400020"),
        "{e:?}"
    );
}

#[test]
fn an_io_failure_keeps_its_path_and_its_cause() {
    let dir = tempfile::tempdir().unwrap();
    let existing = dir.path().join("bus.log");
    std::fs::write(&existing, "").unwrap();
    let e = crate::log_bus::LogWriter::create(&existing).err().unwrap();
    assert!(
        matches!(&e, Error::LogExists { path } if *path == existing),
        "{e:?}"
    );

    // The parent is a file: the directory cannot be made.
    let e = crate::log_bus::LogWriter::create(&existing.join("x.log"))
        .err()
        .unwrap();
    let Error::Io {
        action: "cannot create",
        path,
        source,
    } = &e
    else {
        panic!("{e:?}")
    };
    assert_eq!(*path, existing);
    // The cause is the source (the binary's `{:#}` prints message: cause).
    assert_eq!(
        std::error::Error::source(&e).map(|s| s.to_string()),
        Some(source.to_string())
    );
    assert_eq!(
        e.to_string(),
        format!("cannot create {}", existing.display())
    );
}

#[test]
fn a_bad_option_names_its_flag_and_value() {
    let mut o = crate::ReplayOptions::new(std::path::Path::new("run"), BusSpec::Sim);
    o.nodes = [1, 1, 3];
    let e = o.validate().unwrap_err();
    assert!(
        matches!(&e, Error::BadOption { flag: "--nodes", value, .. } if value == "1,1,3"),
        "{e:?}"
    );
    assert!(e.to_string().starts_with("--nodes [1, 1, 3]"), "{e}");
}
