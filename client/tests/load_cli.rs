//! `tessera load merge` and `tessera report` run as the real binary against hostile
//! input (DECISIONS.md "Load tester limits"): shards given twice and implausible fields
//! are refused with one line naming the file, and output to a reader that has gone away
//! (`| head -1`) ends the command quietly, never in a panic. `tessera-load` is
//! `tessera load` alone: the same arguments, output and exit statuses.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use tessera_client::loadtest::replay_report::{Http, LatencyFrom, Mode, ReplayReport};

/// A small report of shard `shard`, written as `dir/NAME/load.json`.
fn shard(dir: &Path, name: &str, shard: &str, edit: impl FnOnce(&mut ReplayReport)) -> PathBuf {
    let mut r = ReplayReport {
        shard: shard.into(),
        scheduled: 100,
        sent: 100,
        completed: 100,
        seconds: 2.0,
        target_rate: Some(50.0),
        connections: 4,
        ..ReplayReport::empty(Mode::Rate, Http::Http1, LatencyFrom::Scheduled)
    };
    edit(&mut r);
    let out = dir.join(name);
    r.write_json(&out).unwrap();
    out
}

fn tessera(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_tessera"))
        .args(args)
        .output()
        .unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn merge_refuses_a_shard_given_twice_and_implausible_fields() {
    let dir = tempfile::tempdir().unwrap();
    let a = shard(dir.path(), "a", "0/2", |_| {});
    let b = shard(dir.path(), "b", "1/2", |_| {});
    let merge = |paths: &[&Path]| {
        let mut args: Vec<&std::ffi::OsStr> = vec!["load".as_ref(), "merge".as_ref()];
        args.extend(paths.iter().map(|p| p.as_os_str()));
        args.push("--json".as_ref());
        tessera(&args)
    };
    let ok = merge(&[&a, &b]);
    assert!(ok.status.success(), "{}", stderr(&ok));
    let v: serde_json::Value = serde_json::from_slice(&ok.stdout).unwrap();
    assert_eq!(v["completed"], 200);
    // The same shard twice was counted twice.
    let twice = merge(&[&a, &b, &a]);
    assert_eq!(twice.status.code(), Some(1));
    assert!(stderr(&twice).contains("again"), "{}", stderr(&twice));
    assert!(twice.stdout.is_empty());
    // A timeline second of 4·10⁹ aborted on a 1.4 TB allocation.
    let far = shard(dir.path(), "far", "1/2", |r| {
        r.timeline = vec![tessera_client::loadtest::replay_report::Second {
            second: 4_000_000_000,
            ..Default::default()
        }];
    });
    let o = merge(&[&a, &far]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains("far/load.json") && e.contains("timeline[0].second 4000000000"),
        "{e}"
    );
    // completed u64::MAX wrapped silently.
    let wrap = shard(dir.path(), "wrap", "1/2", |r| r.completed = u64::MAX);
    let o = merge(&[&a, &wrap]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(
        e.contains("wrap/load.json") && e.contains("completed 18446744073709551615"),
        "{e}"
    );
    assert!(!e.contains("panicked"), "{e}");
}

#[test]
fn tessera_load_is_tessera_load() {
    let dir = tempfile::tempdir().unwrap();
    let a = shard(dir.path(), "a", "0/2", |_| {});
    let b = shard(dir.path(), "b", "1/2", |_| {});
    let load_bin = |args: &[&std::ffi::OsStr]| {
        Command::new(env!("CARGO_BIN_EXE_tessera-load"))
            .args(args)
            .output()
            .unwrap()
    };
    for tail in [
        vec![a.as_os_str(), b.as_os_str(), "--json".as_ref()],
        vec![a.as_os_str(), b.as_os_str()],
        vec![a.as_os_str(), b.as_os_str(), a.as_os_str()],
    ] {
        let mut merge: Vec<&std::ffi::OsStr> = vec!["merge".as_ref()];
        merge.extend(&tail);
        let alone = load_bin(&merge);
        let mut load_merge: Vec<&std::ffi::OsStr> = vec!["load".as_ref()];
        load_merge.extend(&merge);
        let within = tessera(&load_merge);
        assert_eq!(
            alone.status.code(),
            within.status.code(),
            "{}",
            stderr(&alone)
        );
        assert_eq!(alone.stdout, within.stdout);
        assert_eq!(stderr(&alone), stderr(&within));
    }
    // The load tester's own checks of its arguments.
    let o = load_bin(&["--replay".as_ref(), "--rate".as_ref()]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let o = load_bin(&["--rate".as_ref(), "10".as_ref()]);
    assert!(stderr(&o).contains("--replay"), "{}", stderr(&o));
}

/// Runs `tessera ARGS` with its standard output a pipe whose reader has already
/// gone (as `| head -1` leaves it once `head` has its line): every write fails with
/// EPIPE, deterministically.
fn tessera_into_a_closed_pipe(args: &[&std::ffi::OsStr]) -> Output {
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    Command::new(env!("CARGO_BIN_EXE_tessera"))
        .args(args)
        .stdout(writer)
        .stderr(Stdio::piped())
        .output()
        .unwrap()
}

/// The quiet end of a command whose reader went away: 141 (128 + SIGPIPE, what a
/// shell reports), nothing on stderr, and no panic (which was status 101 and
/// "failed printing to stdout: Broken pipe").
fn assert_quiet_end(o: &Output) {
    let e = stderr(o);
    assert!(!e.contains("panicked"), "{e}");
    assert_eq!(o.status.code(), Some(141), "{e}");
    assert!(e.is_empty(), "{e}");
}

#[test]
fn load_merge_into_a_closed_pipe_ends_quietly_and_still_writes_its_files() {
    let dir = tempfile::tempdir().unwrap();
    let a = shard(dir.path(), "a", "0/2", |_| {});
    let b = shard(dir.path(), "b", "1/2", |_| {});
    let out = dir.path().join("merged");
    for json in [false, true] {
        let mut args: Vec<&std::ffi::OsStr> = vec![
            "load".as_ref(),
            "merge".as_ref(),
            a.as_os_str(),
            b.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ];
        if json {
            args.push("--json".as_ref());
        }
        let o = tessera_into_a_closed_pipe(&args);
        assert_quiet_end(&o);
        // The report is written although it could not be printed.
        assert_eq!(
            ReplayReport::read(&out.join("load.json"))
                .unwrap()
                .completed,
            200
        );
        std::fs::remove_dir_all(&out).unwrap();
    }
}

#[test]
fn report_into_a_closed_pipe_ends_quietly() {
    let dir = tempfile::tempdir().unwrap();
    let stats = dir.path().join("stats.jsonl");
    let lines: Vec<String> = (0..5)
        .map(|f| format!(r#"{{"frame":{f},"tiles":3,"triangles":100,"deficit":0.5}}"#))
        .collect();
    std::fs::write(&stats, lines.join("\n") + "\n").unwrap();
    let out = dir.path().join("out");
    let o = tessera_into_a_closed_pipe(&[
        "report".as_ref(),
        stats.as_os_str(),
        "-o".as_ref(),
        out.as_os_str(),
    ]);
    assert_quiet_end(&o);
    assert!(out.join("stats.png").is_file());
}

#[test]
fn report_drops_a_last_line_cut_short_with_a_warning_and_refuses_a_bad_middle_one() {
    let dir = tempfile::tempdir().unwrap();
    let stats = dir.path().join("stats.jsonl");
    let out = dir.path().join("out");
    let frame = |f: u32| format!(r#"{{"frame":{f},"tiles":3,"triangles":100,"deficit":0.5}}"#);
    let report = || {
        tessera(&[
            "report".as_ref(),
            stats.as_os_str(),
            "-o".as_ref(),
            out.as_os_str(),
        ])
    };
    // Five frames and the sixth cut by kill -9 after 17 bytes: the report is made
    // of the five, and says what it dropped (it used to refuse the whole file).
    let mut text: String = (0..5).map(|f| frame(f) + "\n").collect();
    text.push_str(&frame(5)[..17]);
    std::fs::write(&stats, &text).unwrap();
    let o = report();
    let e = stderr(&o);
    assert!(o.status.success(), "{e}");
    assert!(
        e.contains("warning:") && e.contains("line 6 is cut short") && e.contains("17 bytes"),
        "{e}"
    );
    assert!(String::from_utf8_lossy(&o.stdout).starts_with("5 frames"));
    // A bad line in the middle is damage: an error naming it, no report.
    let mut text: String = (0..5).map(|f| frame(f) + "\n").collect();
    text.replace_range(
        text.find("\"frame\":2").unwrap()..text.find("\"frame\":3").unwrap() - 2,
        "\"frame",
    );
    std::fs::write(&stats, &text).unwrap();
    let o = report();
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("line 3 is not JSON"), "{}", stderr(&o));
}
