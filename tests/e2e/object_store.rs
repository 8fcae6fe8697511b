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

use super::common::ok;

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
    // moto refuses an anonymous DELETE; any credentials do.
    let auth = if method == "DELETE" {
        "Authorization: AWS test:test\r\n"
    } else {
        ""
    };
    write!(
        s,
        "{method} {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n{auth}Content-Length: {}\r\nConnection: close\r\n\r\n",
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

/// `aggregate` of bucket shards into `out_url`, then the result downloaded
/// to `dest` for comparison.
fn aggregate_and_fetch(port: u16, shards: &[&str], out_url: &str, work: &Path, dest: &Path) {
    let mut args = vec!["aggregate", "--shards"];
    args.extend_from_slice(shards);
    args.extend_from_slice(&["--out", out_url, "--work", s(work)]);
    ok(sparkout_s3(port, &args));
    ok(sparkout_s3(port, &["sync", out_url, s(dest)]));
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
    let staged: Vec<PathBuf> = super::common::files_under(&work)
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
    let agg = dir.path().join("agg");
    aggregate_and_fetch(
        port,
        &["s3://fleet/shards/0", "s3://fleet/shards/1"],
        "s3://fleet/agg",
        &work,
        &agg,
    );
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

/// Every key under `prefix` in `bucket`, from a ListObjectsV2 response.
fn keys(port: u16, bucket: &str, prefix: &str) -> Vec<String> {
    let listing = http(
        port,
        "GET",
        &format!("/{bucket}?list-type=2&prefix={prefix}"),
        b"",
    )
    .unwrap();
    listing
        .split("<Key>")
        .skip(1)
        .filter_map(|s| s.split("</Key>").next())
        .map(str::to_string)
        .collect()
}

/// Publishing compares with what the bucket holds, not with a state file:
/// a deleted prefix is published again whole, a second location gets every
/// file, nothing is written into the folder being synced, objects an
/// earlier publish wrote and this one no longer has are removed (and
/// nothing else), the manifest names URLs, bad output credentials stop the
/// batch before it computes, and shards staged into their own work
/// directories download only their own runs and are still one night.
#[test]
fn publishing_checks_the_bucket_and_shards_fetch_only_their_runs() {
    let Some(moto) = start_moto() else {
        return;
    };
    let port = moto.port;
    for b in ["/fleet", "/second"] {
        let r = http(port, "PUT", b, b"").expect("create bucket");
        assert!(r.starts_with("HTTP/1.1 200"), "{r}");
    }
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("runs");
    fleet(&root);
    let work = dir.path().join("work");

    // A folder synced: nothing of sparkout's is left in it.
    ok(sparkout_s3(port, &["sync", s(&root), "s3://fleet/in"]));
    let leftovers: Vec<PathBuf> = super::common::files_under(&root)
        .into_iter()
        .filter(|p| p.to_string_lossy().contains(".sparkout"))
        .collect();
    assert!(
        leftovers.is_empty(),
        "state written into the source folder: {leftovers:?}"
    );
    let n_in = keys(port, "fleet", "in/").len();
    // The same folder to a second location: every file goes.
    let text = ok(sparkout_s3(port, &["sync", s(&root), "s3://second/in"]));
    let n_files = super::common::files_under(&root).len();
    assert!(text.contains(&format!("{n_files} uploaded")), "{text}");
    // Unchanged: nothing sent again.
    let text = ok(sparkout_s3(port, &["sync", s(&root), "s3://second/in"]));
    assert!(text.contains("0 uploaded"), "{text}");

    let run_out = |out: &str| {
        ok(sparkout_s3(
            port,
            &[
                "run",
                "--input",
                "s3://fleet/in",
                "--out",
                out,
                "--work",
                s(&work),
            ],
        ))
    };
    run_out("s3://fleet/out");
    let published = keys(port, "fleet", "out/");
    assert!(
        published.iter().any(|k| k == "out/manifest.json"),
        "{published:?}"
    );
    // The prefix deleted behind sparkout's back: the next publish sends
    // everything again although the local work directory is unchanged.
    for k in &published {
        http(port, "DELETE", &format!("/fleet/{k}"), b"").unwrap();
    }
    assert!(keys(port, "fleet", "out/").is_empty());
    let text = run_out("s3://fleet/out");
    assert!(!text.contains(" 0 uploaded"), "{text}");
    let mut again = keys(port, "fleet", "out/");
    again.sort();
    let mut was = published.clone();
    was.sort();
    assert_eq!(again, was, "the re-publish did not restore every object");

    // The published manifest names URLs, never the node's work directory.
    let back = dir.path().join("back");
    ok(sparkout_s3(port, &["sync", "s3://fleet/out", s(&back)]));
    let manifest = std::fs::read_to_string(back.join("manifest.json")).unwrap();
    assert!(manifest.contains("s3://fleet/in"), "{manifest}");
    assert!(manifest.contains("s3://fleet/out"), "{manifest}");
    assert!(!manifest.contains(s(&work)), "{manifest}");

    // Stale objects: a file gone from the published folder is removed from
    // the bucket after the manifest; an object sparkout did not write stays.
    let pubdir = dir.path().join("pub");
    std::fs::create_dir_all(pubdir.join("sub")).unwrap();
    std::fs::write(pubdir.join("a.txt"), "a").unwrap();
    std::fs::write(pubdir.join("sub/b.txt"), "b").unwrap();
    ok(sparkout_s3(port, &["sync", s(&pubdir), "s3://second/p"]));
    http(port, "PUT", "/second/p/users-own.txt", b"mine").unwrap();
    std::fs::remove_file(pubdir.join("sub/b.txt")).unwrap();
    let text = ok(sparkout_s3(port, &["sync", s(&pubdir), "s3://second/p"]));
    assert!(text.contains("1 removed"), "{text}");
    let left = keys(port, "second", "p/");
    assert!(left.iter().any(|k| k == "p/a.txt"), "{left:?}");
    assert!(left.iter().any(|k| k == "p/users-own.txt"), "{left:?}");
    assert!(!left.iter().any(|k| k == "p/sub/b.txt"), "{left:?}");
    // Nothing outside the prefix was touched.
    assert_eq!(keys(port, "second", "in/").len(), n_in);

    // An output bucket that cannot be written: refused before staging or
    // computing anything.
    let o = sparkout_s3(
        port,
        &[
            "run",
            "--input",
            "s3://fleet/in",
            "--out",
            "s3://no-such-bucket/out",
            "--work",
            s(&work),
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("cannot write under `s3://no-such-bucket/out`"),
        "{err}"
    );
    assert!(
        !err.contains("staged"),
        "staged before checking the output: {err}"
    );

    // Two shards, each with its own work directory (two nodes).
    for i in 0..2 {
        let w = dir.path().join(format!("node{i}"));
        let text = ok(sparkout_s3(
            port,
            &[
                "run",
                "--input",
                "s3://fleet/in",
                "--out",
                &format!("s3://fleet/sh/{i}"),
                "--shard",
                &format!("{i}/2"),
                "--work",
                s(&w),
            ],
        ));
        assert!(text.contains("of other shards' runs not fetched"), "{text}");
        // Only this shard's runs' files were downloaded: every run.toml is
        // here, but the data of the other shard's runs is a stub.
        let staged: Vec<PathBuf> = super::common::files_under(&w)
            .into_iter()
            .filter(|p| p.to_string_lossy().contains("/input-"))
            .collect();
        let owned: Vec<String> = {
            let m: serde_json::Value = serde_json::from_slice(
                &std::fs::read(
                    w.join(
                        std::fs::read_dir(&w)
                            .unwrap()
                            .flatten()
                            .find(|e| e.file_name().to_string_lossy().starts_with("out-"))
                            .unwrap()
                            .path()
                            .join("shard.json"),
                    ),
                )
                .unwrap(),
            )
            .unwrap();
            assert_eq!(
                m["input_root"], "s3://fleet/in",
                "shard.json records the input URL"
            );
            m["runs"]
                .as_array()
                .unwrap()
                .iter()
                .map(|r| r["run_dir"].as_str().unwrap().to_string())
                .collect()
        };
        assert!(!owned.is_empty() && owned.len() < 6, "{owned:?}");
        for p in &staged {
            let name = p.file_name().unwrap().to_string_lossy();
            if name == "run.toml" || name.starts_with(".sparkout") || name.ends_with(".remote.json")
            {
                continue;
            }
            assert!(
                owned.iter().any(|d| p.starts_with(d)),
                "{} was downloaded by shard {i} but belongs to another shard",
                p.display()
            );
        }
    }
    // Shard 1 again on a fresh node: it resumes from what its earlier
    // publish left in the bucket and recomputes nothing.
    let fresh = dir.path().join("node1-fresh");
    let text = ok(sparkout_s3(
        port,
        &[
            "run",
            "--input",
            "s3://fleet/in",
            "--out",
            "s3://fleet/sh/1",
            "--shard",
            "1/2",
            "--work",
            s(&fresh),
        ],
    ));
    assert!(text.contains("resumed"), "{text}");
    assert!(text.contains("(everything cached)"), "{text}");
    let agg = dir.path().join("agg2");
    aggregate_and_fetch(
        port,
        &["s3://fleet/sh/0", "s3://fleet/sh/1"],
        "s3://fleet/agg2",
        &work,
        &agg,
    );
    assert_same(&back, &agg, "2 shards on their own nodes, aggregated");

    // A fleet history in the bucket: each night staged from it (the first
    // from an empty prefix) and published back grown by one night, also
    // from a fresh work directory.
    for (night, w) in [("2026-11-20", "h1"), ("2026-11-21", "h2")] {
        let text = ok(sparkout_s3(
            port,
            &[
                "run",
                "--input",
                "s3://fleet/in",
                "--out",
                &format!("s3://fleet/n/{night}"),
                "--history",
                "s3://fleet/history",
                "--night",
                night,
                "--work",
                s(&dir.path().join(w)),
            ],
        ));
        assert!(text.contains("published"), "{text}");
    }
    let hist = keys(port, "fleet", "history/");
    for night in ["2026-11-20", "2026-11-21"] {
        assert!(
            hist.iter().any(|k| k.contains(&format!("night={night}/"))),
            "night {night} missing from the bucket history: {hist:?}"
        );
    }
    let n2 = dir.path().join("n2");
    ok(sparkout_s3(
        port,
        &["sync", "s3://fleet/n/2026-11-21", s(&n2)],
    ));
    let trend = std::fs::read_to_string(n2.join("trend/trend.json")).unwrap();
    assert!(
        trend.contains("2026-11-20") && trend.contains("2026-11-21"),
        "the second night's trend did not see the first night from the bucket: {trend}"
    );
}
