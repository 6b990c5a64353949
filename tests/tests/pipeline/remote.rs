//! A remote artifact cache on a real S3 server (SeaweedFS on loopback, started by scripts/test):
//! the tiny make's store pushed and pulled through `osms push` and `osms pull`, each killed
//! again and again midway; two stores pushing the same keys at once; push and pull waiting for
//! the store's lock like gc; a fresh project's `osms make --remote` that builds nothing and
//! writes the same report; the same over WebDAV; a damaged object, bad credentials, a missing
//! bucket and an unreachable server as clear errors.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use osms_store::Store;
use osms_tests::s3;

use super::{Made, shipped};

/// One project directory (pipeline.toml with the remote, report/ beside it) and its store.
struct Project {
    dir: PathBuf,
    store: PathBuf,
}

struct Osms<'a> {
    server: &'a s3::Server,
}

impl Osms<'_> {
    fn command(&self, project: &Project, args: &[&str]) -> Command {
        let mut c = Command::new(env!("CARGO_BIN_EXE_osms-shipped"));
        c.arg("--pipeline")
            .arg(project.dir.join("pipeline.toml"))
            .arg("--store")
            .arg(&project.store)
            .args(args)
            .env("OSMS_NO_PROGRESS", "1")
            .env_remove("OSMS_LOG")
            .env_remove("OSMS_CONFIG")
            .env("XDG_CONFIG_HOME", project.dir.join("no-user-config"))
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        for (k, v) in self.server.env() {
            c.env(k, v);
        }
        c
    }

    fn run(&self, project: &Project, args: &[&str]) -> Output {
        self.command(project, args).output().expect("run osms")
    }

    fn ok(&self, project: &Project, args: &[&str]) -> serde_json::Value {
        let o = self.run(project, args);
        assert!(
            o.status.success(),
            "osms {args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        serde_json::from_slice(&o.stdout).unwrap_or(serde_json::Value::Null)
    }

    /// Starts `args` and kills it (SIGKILL) after `after`; whether it had ended by itself.
    fn killed_after(&self, project: &Project, args: &[&str], after: Duration) -> bool {
        let mut child = self.command(project, args).spawn().expect("spawn osms");
        let started = Instant::now();
        while started.elapsed() < after {
            if child.try_wait().expect("wait").is_some() {
                return true;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        child.kill().expect("kill");
        child.wait().expect("reap");
        false
    }
}

fn project(root: &Path, name: &str, remote_url: &str, store: Option<&Path>) -> Project {
    let dir = root.join(name);
    std::fs::create_dir_all(&dir).expect("project dir");
    std::fs::write(
        dir.join("pipeline.toml"),
        format!("{}\n[remotes.ci]\nurl = \"{remote_url}\"\n", shipped()),
    )
    .expect("pipeline.toml");
    Project {
        store: store.map_or_else(|| dir.join("store"), Path::to_path_buf),
        dir,
    }
}

fn refs(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

/// Every file under `dir`, relative path -> bytes.
fn files(dir: &Path) -> std::collections::BTreeMap<PathBuf, Vec<u8>> {
    let mut out = std::collections::BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).expect("read_dir") {
            let p = e.expect("entry").path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(dir).expect("under dir").to_path_buf();
                out.insert(rel, std::fs::read(&p).expect("read"));
            }
        }
    }
    out
}

/// `osms verify` finds nothing wrong in `project`'s store.
fn verified(osms: &Osms, project: &Project) {
    let v = osms.ok(project, &["verify", "--json"]);
    assert_eq!(v["problems"], serde_json::json!([]), "{v}");
}

/// Every record in `project`'s store is `made`'s for its key, and every object it names has
/// `made`'s bytes; how many records there are.
fn same_as_source(made: &Made, project: &Project) -> usize {
    let store = Store::open(&project.store).expect("store");
    let (records, unreadable) = store.records().expect("records");
    assert!(unreadable.is_empty());
    for r in &records {
        assert_eq!(
            made.store.record(&r.key).expect("source record").as_ref(),
            Some(r)
        );
        for h in std::iter::once(&r.content_hash).chain(&r.parts) {
            assert_eq!(
                store.get(h).expect("pulled object"),
                made.store.get(h).expect("source object")
            );
        }
    }
    records.len()
}

/// Writes bytes that are not the object under an object's name on the server, through its
/// filer (`url`), past S3 and WebDAV.
fn plant(url: &str) {
    let planted = Command::new("curl")
        .args(["-sf", "-X", "PUT", "--data-binary", "not the world"])
        .arg(url)
        .output()
        .expect("curl");
    assert!(
        planted.status.success(),
        "{}",
        String::from_utf8_lossy(&planted.stderr)
    );
}

/// `args` (a pull of `object`'s stage) exits 1 naming the remote and the damaged object, and
/// the store holds neither the object nor a record.
fn refused_damaged(osms: &Osms, project: &Project, args: &[String], object: &osms_store::Hash) {
    let o = osms.run(project, &refs(args));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("remote `ci`")
            && err.contains("damaged object")
            && err.contains(&object.to_hex()),
        "{err}"
    );
    let store = Store::open(&project.store).expect("store");
    assert!(!store.object_path(object).exists());
    assert!(store.records().expect("records").0.is_empty());
}

pub(super) fn a_remote_cache_serves_a_fresh_store(made: &Made) {
    let Some(server) = s3::server("the remote cache on a real S3 server") else {
        return;
    };
    let osms = Osms { server: &server };
    let tmp = tempfile::tempdir().expect("tmp");
    // A prefix of its own per run: the server may outlive one test run (a developer's).
    let run = format!(
        "{}-{}",
        std::process::id(),
        tmp.path().display().to_string().len()
    );
    let url = |what: &str| format!("s3://{}/{run}/{what}", server.bucket);
    let tiny = ["-p", "tiny", "--seed", "0"];
    let with = |args: &[&str]| -> Vec<String> {
        args.iter()
            .chain(tiny.iter())
            .map(|s| s.to_string())
            .collect()
    };

    // The source: the tiny make's store, its report written by a make that finds everything.
    let source = project(tmp.path(), "source", &url("cache"), Some(made.store.root()));
    let made_again = osms.ok(&source, &refs(&with(&["make", "--json"])));
    assert!(
        made_again["instances"]
            .as_array()
            .expect("instances")
            .iter()
            .all(|i| i["outcome"] == "cached"),
        "{made_again}"
    );
    let report = files(&source.dir.join("report"));
    assert!(report.contains_key(Path::new("index.md")));

    // A push killed a dozen times at points spread over a whole push's time, then run to the
    // end: the remote never holds a record whose objects are not all there (a pull of
    // everything, which checks every object against its name, succeeds), nor a damaged object.
    let probe = project(tmp.path(), "probe", &url("probe"), Some(made.store.root()));
    let started = Instant::now();
    let pushed = osms.ok(&probe, &refs(&with(&["push", "-r", "ci", "--json"])));
    let push_time = started.elapsed();
    assert!(
        pushed["objects_sent"].as_u64().expect("sent") > 100,
        "{pushed}"
    );
    assert_eq!(pushed["objects_present"], 0, "{pushed}");
    let kills = 12;
    let mut ended = 0;
    for k in 0..kills {
        let after = push_time.mul_f64((k as f64 + 0.5) / kills as f64);
        ended +=
            usize::from(osms.killed_after(&source, &refs(&with(&["push", "-r", "ci"])), after));
    }
    assert!(
        ended < kills,
        "every push ended before its kill: the storm tested nothing"
    );
    // What the killed pushes left: whatever records are there, their objects are whole.
    let midway = project(tmp.path(), "midway", &url("cache"), None);
    let o = osms.run(&midway, &refs(&with(&["pull", "-r", "ci"])));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.success() || err.contains("has no build of"),
        "a pull after the killed pushes: {err}"
    );
    verified(&osms, &midway);
    let resumed = osms.ok(&source, &refs(&with(&["push", "-r", "ci", "--json"])));
    assert_eq!(
        resumed["objects_sent"].as_u64().expect("sent")
            + resumed["objects_present"].as_u64().expect("present"),
        pushed["objects_sent"].as_u64().expect("sent"),
        "{resumed}"
    );

    // A pull into an empty store, killed a dozen times likewise, then run to the end: the
    // store verifies clean and holds the source's bytes.
    let timing = project(tmp.path(), "timing", &url("cache"), None);
    let started = Instant::now();
    let pulled = osms.ok(&timing, &refs(&with(&["pull", "-r", "ci", "--json"])));
    let pull_time = started.elapsed();
    assert!(
        pulled["instances"]
            .as_array()
            .expect("instances")
            .iter()
            .all(|i| i["outcome"] == "pulled"),
        "{pulled}"
    );
    let target = project(tmp.path(), "target", &url("cache"), None);
    let mut ended = 0;
    for k in 0..kills {
        let after = pull_time.mul_f64((k as f64 + 0.5) / kills as f64);
        ended +=
            usize::from(osms.killed_after(&target, &refs(&with(&["pull", "-r", "ci"])), after));
        verified(&osms, &target);
    }
    assert!(
        ended < kills,
        "every pull ended before its kill: the storm tested nothing"
    );
    osms.ok(&target, &refs(&with(&["pull", "-r", "ci"])));
    verified(&osms, &target);
    let pulled_count = pulled["instances"].as_array().expect("instances").len();
    assert_eq!(same_as_source(made, &target), pulled_count);

    // Two machines pushing the same keys at once (the source's store and the pulled copy, to a
    // prefix of their own, twice): both succeed and the remote ends with one consistent record
    // per key, whole objects behind it, as a pull into an empty store checks.
    for round in 0..2 {
        let prefix = url(&format!("twins-{round}"));
        let a = project(
            tmp.path(),
            &format!("twin-a-{round}"),
            &prefix,
            Some(made.store.root()),
        );
        let b = project(
            tmp.path(),
            &format!("twin-b-{round}"),
            &prefix,
            Some(&target.store),
        );
        let pushes: Vec<_> = [&a, &b]
            .iter()
            .map(|p| {
                osms.command(p, &refs(&with(&["push", "-r", "ci"])))
                    .spawn()
                    .expect("spawn")
            })
            .collect();
        for child in pushes {
            let o = child.wait_with_output().expect("wait");
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        }
        let reader = project(tmp.path(), &format!("twin-reader-{round}"), &prefix, None);
        osms.ok(&reader, &refs(&with(&["pull", "-r", "ci"])));
        verified(&osms, &reader);
        assert_eq!(same_as_source(made, &reader), pulled_count);
    }

    // A push or pull holds the store's lock for its whole run, as `osms gc` and `osms make`
    // do: with the lock held by another process, each waits, says so, then finishes; so gc
    // can neither delete an object a push is reading nor clear a pull's staged objects.
    for (what, store) in [
        ("pull", tmp.path().join("locked-pull-store")),
        ("push", target.store.clone()),
    ] {
        let locked = project(
            tmp.path(),
            &format!("locked-{what}"),
            &url("cache"),
            Some(&store),
        );
        if what == "pull" {
            Store::open(&store).expect("store");
        }
        let ready = tmp.path().join(format!("{what}-lock-held"));
        let mut holder = Command::new("flock")
            .arg(store.join("lock"))
            .arg("-c")
            .arg(format!("touch {}; sleep 2", ready.display()))
            .spawn()
            .expect("flock (util-linux)");
        while !ready.exists() {
            std::thread::sleep(Duration::from_millis(10));
        }
        let o = osms.run(&locked, &refs(&with(&[what, "-r", "ci"])));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{what}: {err}");
        assert!(
            err.contains("waiting for another osms process to release the store lock"),
            "{what}: {err}"
        );
        assert!(holder.wait().expect("flock").success());
        verified(&osms, &locked);
    }

    // and writes the source's report to the byte.
    let fresh = project(tmp.path(), "fresh", &url("cache"), None);
    let made_fresh = osms.ok(&fresh, &refs(&with(&["make", "--remote", "ci", "--json"])));
    let instances = made_fresh["instances"].as_array().expect("instances");
    assert!(!instances.is_empty());
    for i in instances {
        assert_eq!(i["outcome"], "pulled", "{i}");
    }
    assert_eq!(
        files(&fresh.dir.join("report")),
        report,
        "the pulled make's report/"
    );

    // A damaged object on the server (written through its filer, past S3) is refused on pull:
    // the error names the remote and the object, and the store never holds those bytes.
    let world = made.hashes.get("world").expect("world");
    let hex = world.to_hex();
    plant(&format!(
        "{}/buckets/{}/{run}/cache/cas/{}/{hex}",
        server.filer,
        server.bucket,
        &hex[..2]
    ));
    let damaged = project(tmp.path(), "damaged", &url("cache"), None);
    refused_damaged(
        &osms,
        &damaged,
        &with(&["pull", "world", "-r", "ci"]),
        world,
    );
    // The next push mends it (its size is wrong), and the pull goes through.
    osms.ok(&source, &refs(&with(&["push", "world", "-r", "ci"])));
    osms.ok(&damaged, &refs(&with(&["pull", "world", "-r", "ci"])));

    // The same cache over WebDAV (the server's gateway on the same files): a push that makes
    // its directories as it goes, a second push that sends nothing, a pull byte for byte, an
    // object damaged through the filer refused, and a closed port as `unreachable`.
    let dav_url = format!("{}/{run}/dav", server.webdav);
    let dav = project(tmp.path(), "dav", &dav_url, Some(made.store.root()));
    let sent = osms.ok(&dav, &refs(&with(&["push", "-r", "ci", "--json"])));
    assert!(sent["objects_sent"].as_u64().expect("sent") > 100, "{sent}");
    let again = osms.ok(&dav, &refs(&with(&["push", "-r", "ci", "--json"])));
    assert_eq!(again["objects_sent"], 0, "{again}");
    let dav_reader = project(tmp.path(), "dav-reader", &dav_url, None);
    osms.ok(&dav_reader, &refs(&with(&["pull", "-r", "ci"])));
    verified(&osms, &dav_reader);
    assert_eq!(same_as_source(made, &dav_reader), pulled_count);
    plant(&format!(
        "{}/{run}/dav/cas/{}/{hex}",
        server.filer,
        &hex[..2]
    ));
    let dav_damaged = project(tmp.path(), "dav-damaged", &dav_url, None);
    refused_damaged(
        &osms,
        &dav_damaged,
        &with(&["pull", "world", "-r", "ci"]),
        world,
    );
    let closed = std::net::TcpListener::bind("127.0.0.1:0").expect("port");
    let port = closed.local_addr().expect("addr").port();
    drop(closed);
    let dav_closed = project(
        tmp.path(),
        "dav-closed",
        &format!("http://127.0.0.1:{port}/x"),
        None,
    );
    let o = osms.run(&dav_closed, &refs(&with(&["pull", "world", "-r", "ci"])));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("remote `ci`") && err.contains("unreachable"),
        "{err}"
    );

    // Bad remotes: each a clear error naming the remote and what to check, exit 1, nothing
    // written to the store.
    let fails = |project: &Project, env: &[(&str, &str)], expect: &[&str]| {
        let mut c = osms.command(project, &refs(&with(&["pull", "world", "-r", "ci"])));
        for (k, v) in env {
            c.env(k, v);
        }
        let o = c.output().expect("run osms");
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        for e in expect {
            assert!(err.contains(e), "`{e}` in {err}");
        }
        assert!(
            !err.contains(&server.secret_key),
            "a credential in an error: {err}"
        );
        assert!(!err.contains("panicked"), "{err}");
    };
    let bad = project(tmp.path(), "bad", &url("cache"), None);
    fails(
        &bad,
        &[("AWS_SECRET_ACCESS_KEY", "not-the-secret")],
        &[
            "remote `ci`",
            "refused the credentials",
            "AWS_SECRET_ACCESS_KEY",
        ],
    );
    let closed = std::net::TcpListener::bind("127.0.0.1:0").expect("port");
    let port = closed.local_addr().expect("addr").port();
    drop(closed);
    fails(
        &bad,
        &[("AWS_ENDPOINT_URL", &format!("http://127.0.0.1:{port}"))],
        &["remote `ci`", "unreachable", "AWS_ENDPOINT_URL"],
    );
    // An endpoint variable set to nothing: object_store would panic signing the request.
    fails(
        &bad,
        &[("AWS_ENDPOINT_URL", "")],
        &["remote `ci`", "AWS_ENDPOINT_URL is ``, not a URL"],
    );
    let nobucket = project(tmp.path(), "nobucket", "s3://no-such-bucket-osms/x", None);
    fails(
        &nobucket,
        &[],
        &["remote `ci`", "no bucket `no-such-bucket-osms`"],
    );
    for p in [&bad, &nobucket] {
        let store = Store::open(&p.store).expect("store");
        assert!(store.records().expect("records").0.is_empty());
    }
}
