//! `--input`, `--out` and `--shards` on object storage,
//! against a real S3-compatible server (moto's server mode, from PyPI)
//! started on 127.0.0.1 by the test. Skipped with a message where
//! `moto_server` is not installed; `.ci/run` installs it.
//!
//! Asserted: a batch from s3:// to s3:// writes the same artifacts, byte for
//! byte, as the same batch on local disk; Parquet inputs stay in the bucket
//! and are read by ranged GETs (stubs, no local copy); no temporary key is
//! left behind; a no-change re-run downloads nothing and uploads only what
//! changed; 2 shards on s3:// aggregated equal one run; a missing bucket is a
//! clear error.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// The artifacts compared between the local and the object-store batch
/// (manifest.json differs by design: a remote input's cache key is its
/// ETag, not its bytes).
const COMPARED: [&str; 5] = [
    "fleet/observations.parquet",
    "fleet/diagnosis.json",
    "fleet/diagnosis.parquet",
    "fleet/report.html",
    "failures.json",
];

struct Moto {
    child: Child,
    port: u16,
}

impl Drop for Moto {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn moto_binary() -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|d| d.join("moto_server"))
        .find(|p| p.is_file())
}

fn start_moto() -> Option<Moto> {
    let Some(bin) = moto_binary() else {
        eprintln!(
            "SKIPPED: moto_server is not installed (pip install 'moto[server]'); the object-store test needs a local S3 server"
        );
        return None;
    };
    let port = TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let child = Command::new(bin)
        .args(["-H", "127.0.0.1", "-p", &port.to_string()])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start moto_server");
    let moto = Moto { child, port };
    let t0 = Instant::now();
    while http(port, "GET", "/", b"").is_none() {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "moto_server did not answer on 127.0.0.1:{port} within 60 s"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    Some(moto)
}

/// A bare HTTP/1.1 request (moto accepts unsigned requests): the response
/// text, or None when the server is not up.
fn http(port: u16, method: &str, path: &str, body: &[u8]) -> Option<String> {
    let mut s = TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(30))).ok()?;
    write!(
        s,
        "{method} {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
        body.len()
    )
    .ok()?;
    s.write_all(body).ok()?;
    let mut text = String::new();
    s.read_to_string(&mut text).ok()?;
    Some(text)
}

fn sparkout_s3(port: u16, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sparkout"))
        .args(args)
        .env("SPARKOUT_LOG", "warn")
        .env("AWS_ENDPOINT", format!("http://127.0.0.1:{port}"))
        .env("AWS_ALLOW_HTTP", "true")
        .env("AWS_ACCESS_KEY_ID", "test")
        .env("AWS_SECRET_ACCESS_KEY", "test")
        .env("AWS_REGION", "us-east-1")
        // Every Parquet input stays in the bucket (read by ranged GETs).
        .env("SPARKOUT_STREAM_MIN_BYTES", "0")
        .output()
        .expect("run sparkout")
}

fn ok(o: Output) -> String {
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(o.status.success(), "{text}");
    text
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Robot runs (with AE logs: the streamed input) and servo runs with an
/// injected lag, so the diagnosis has something to name.
fn fleet(root: &Path) {
    let r = s(root);
    ok(super::common::sparkout(&[
        "generate", "robot", "--runs", "2", "--seed", "5", "--out", r,
    ]));
    ok(super::common::sparkout(&[
        "generate",
        "servo",
        "--runs",
        "4",
        "--seed",
        "6",
        "--out",
        r,
        "--effect",
        "servo_lag=k_s=0.004",
    ]));
}

fn assert_same(a: &Path, b: &Path, what: &str) {
    for f in COMPARED {
        let x = std::fs::read(a.join(f)).unwrap_or_else(|e| panic!("{}: {e}", a.join(f).display()));
        let y = std::fs::read(b.join(f)).unwrap_or_else(|e| panic!("{}: {e}", b.join(f).display()));
        assert!(x == y, "{what}: {f} differs from the local batch");
    }
}

#[test]
fn a_batch_on_object_storage_equals_the_local_batch() {
    let Some(moto) = start_moto() else {
        return;
    };
    let port = moto.port;
    let bucket = http(port, "PUT", "/fleet", b"").expect("create bucket");
    assert!(bucket.starts_with("HTTP/1.1 200"), "{bucket}");
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("runs");
    fleet(&root);
    let work = dir.path().join("work");

    // The same batch on local disk.
    let local = dir.path().join("local");
    ok(super::common::sparkout(&[
        "run",
        "--input",
        s(&root),
        "--out",
        s(&local),
    ]));

    // Upload, run bucket → bucket, download.
    let text = ok(sparkout_s3(port, &["sync", s(&root), "s3://fleet/in"]));
    assert!(text.contains("uploaded"), "{text}");
    let text = ok(sparkout_s3(
        port,
        &[
            "run",
            "--input",
            "s3://fleet/in",
            "--out",
            "s3://fleet/out",
            "--work",
            s(&work),
        ],
    ));
    assert!(text.contains("published"), "{text}");
    let back = dir.path().join("back");
    ok(sparkout_s3(port, &["sync", "s3://fleet/out", s(&back)]));
    assert_same(&local, &back, "s3 → s3");
    assert!(back.join("manifest.json").is_file());

    // The AE logs were not downloaded: a stub stands for each, and the
    // ingest read its row groups by ranged GETs.
    let staged: Vec<PathBuf> = walk(&work)
        .into_iter()
        .filter(|p| p.to_string_lossy().contains("/input-"))
        .collect();
    assert!(
        staged.iter().any(|p| p.ends_with("ae.parquet.remote.json")),
        "no AE stub in {staged:?}"
    );
    assert!(
        !staged.iter().any(|p| p.ends_with("ae.parquet")),
        "an AE log was downloaded: {staged:?}"
    );

    // Nothing under a temporary key.
    let listing = http(port, "GET", "/fleet?list-type=2", b"").unwrap();
    assert!(
        listing.contains("<Key>out/manifest.json</Key>"),
        "{listing}"
    );
    assert!(!listing.contains(".sparkout-tmp"), "{listing}");

    // A no-change re-run: nothing downloaded, the stages cached.
    let text = ok(sparkout_s3(
        port,
        &[
            "run",
            "--input",
            "s3://fleet/in",
            "--out",
            "s3://fleet/out",
            "--work",
            s(&work),
        ],
    ));
    assert!(text.contains("0 downloaded"), "{text}");
    assert!(text.contains(" unchanged"), "{text}");

    // Two shards on the bucket, aggregated from the bucket.
    for i in 0..2 {
        ok(sparkout_s3(
            port,
            &[
                "run",
                "--input",
                "s3://fleet/in",
                "--out",
                &format!("s3://fleet/shards/{i}"),
                "--shard",
                &format!("{i}/2"),
                "--work",
                s(&work),
            ],
        ));
    }
    ok(sparkout_s3(
        port,
        &[
            "aggregate",
            "--shards",
            "s3://fleet/shards/0",
            "s3://fleet/shards/1",
            "--out",
            "s3://fleet/agg",
            "--work",
            s(&work),
        ],
    ));
    let agg = dir.path().join("agg");
    ok(sparkout_s3(port, &["sync", "s3://fleet/agg", s(&agg)]));
    assert_same(&local, &agg, "2 shards on s3, aggregated");

    // A bucket that does not exist: a clear error, exit 1, nothing written.
    let o = sparkout_s3(
        port,
        &[
            "run",
            "--input",
            "s3://no-such-bucket/in",
            "--out",
            s(&dir.path().join("never")),
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("cannot list `s3://no-such-bucket/in`"),
        "{err}"
    );
    assert!(!dir.path().join("never").join("manifest.json").exists());
}

#[test]
fn an_unknown_scheme_is_refused_by_name() {
    let o = super::common::sparkout(&["run", "--input", "ftp://host/runs", "--out", "/tmp/x"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("unknown storage scheme `ftp://`"), "{err}");
}

fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if let Ok(rd) = std::fs::read_dir(dir) {
        for e in rd.flatten() {
            let p = e.path();
            if p.is_dir() {
                out.extend(walk(&p));
            } else {
                out.push(p);
            }
        }
    }
    out
}
