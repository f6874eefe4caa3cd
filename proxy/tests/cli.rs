//! The `tessera-proxy` binary as `bench/stream.sh` uses it: started with port 0, it
//! prints `listening on ADDR` once it accepts connections and relays bytes there
//! unchanged; a bad upstream is refused with a message and exit status 1.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::process::{Child, Command, Stdio};

/// Kills the proxy when the test ends, however it ends.
struct Running(Child);

impl Drop for Running {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn proxy(args: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_tessera-proxy"));
    c.args(args);
    c
}

#[test]
fn prints_its_address_and_relays_unchanged() {
    // An upstream that sends back, reversed, everything a connection sent it.
    let upstream = TcpListener::bind("127.0.0.1:0").unwrap();
    let up_addr = upstream.local_addr().unwrap().to_string();
    std::thread::spawn(move || {
        for s in upstream.incoming() {
            let mut s = s.unwrap();
            let mut got = Vec::new();
            s.read_to_end(&mut got).unwrap();
            got.reverse();
            s.write_all(&got).unwrap();
        }
    });
    for delay in ["0", "5"] {
        let mut child = proxy(&["--upstream", &up_addr, "--delay-ms", delay])
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        let stdout = child.stdout.take().unwrap();
        let running = Running(child);
        let mut line = String::new();
        BufReader::new(stdout).read_line(&mut line).unwrap();
        let addr = line
            .trim_end()
            .strip_prefix("listening on ")
            .unwrap_or_else(|| panic!("first line {line:?}"));
        assert!(
            addr.starts_with("127.0.0.1:") && !addr.ends_with(":0"),
            "{addr}"
        );
        let mut c = TcpStream::connect(addr).unwrap();
        let sent: Vec<u8> = (0..200_000u32).map(|i| (i * 7 % 251) as u8).collect();
        c.write_all(&sent).unwrap();
        c.shutdown(Shutdown::Write).unwrap();
        let mut back = Vec::new();
        c.read_to_end(&mut back).unwrap();
        back.reverse();
        assert!(
            back == sent,
            "--delay-ms {delay}: {} bytes came back changed",
            back.len()
        );
        drop(running);
    }
}

#[test]
fn a_bad_upstream_is_refused() {
    let out = proxy(&["--upstream", "no-port-here"]).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--upstream no-port-here"), "{err}");
    let out = proxy(&[]).output().unwrap();
    assert_eq!(
        out.status.code(),
        Some(2),
        "clap: a missing --upstream is a usage error"
    );
}
