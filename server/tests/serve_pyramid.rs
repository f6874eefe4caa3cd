//! `tessera-server serve` end to end: the raw pyramid file
//! (`/v1/datasets/{name}/pyramid`) with HTTP Range, multipart ranges, `If-Range`
//! and revalidation (API.md).
//!
//! Pyramids are shared by every test (`serve_support`); every test starts its own
//! server on an ephemeral port (killed when the test ends) and checks responses
//! against the pyramid file read independently with the shared reader.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serve_support::{Resp, Server, etag_is_strong, find, fixtures};

// ---------------------------------------------------------------------------
// The raw pyramid file with HTTP Range

/// Parses a `multipart/byteranges` body into `(Content-Range, bytes)` parts.
fn multipart_parts(body: &[u8], boundary: &str) -> Vec<(String, Vec<u8>)> {
    let delim = format!("--{boundary}");
    let mut parts = Vec::new();
    let mut rest = body;
    // Skip the preamble up to the first delimiter.
    let start = find(rest, delim.as_bytes()).expect("first boundary");
    rest = &rest[start + delim.len()..];
    loop {
        if rest.starts_with(b"--") {
            break; // closing delimiter
        }
        let rest_after_crlf = rest.strip_prefix(b"\r\n").expect("CRLF after boundary");
        let head_end = find(rest_after_crlf, b"\r\n\r\n").expect("part head");
        let head = std::str::from_utf8(&rest_after_crlf[..head_end]).unwrap();
        let content_range = head
            .split("\r\n")
            .filter_map(|l| l.split_once(':'))
            .find(|(k, _)| k.trim().eq_ignore_ascii_case("content-range"))
            .map(|(_, v)| v.trim().to_string())
            .expect("Content-Range in part");
        let data = &rest_after_crlf[head_end + 4..];
        let next = find(data, format!("\r\n{delim}").as_bytes()).expect("next boundary");
        parts.push((content_range, data[..next].to_vec()));
        rest = &data[next + 2 + delim.len()..];
    }
    parts
}

#[test]
fn pyramid_file_with_http_range() {
    let f = fixtures();
    let file = std::fs::read(&f.synth).unwrap();
    let size = file.len();
    let srv = Server::start(&[&f.synth], &[]);
    let url = "/v1/datasets/synth/pyramid";

    let full = srv.get(url).expect(200);
    assert_eq!(full.body.len(), size);
    assert!(full.body == file, "full GET differs from the file");
    assert_eq!(full.must("accept-ranges"), "bytes");
    assert_eq!(full.must("content-length").parse::<usize>().unwrap(), size);
    let etag = full.must("etag").to_string();
    etag_is_strong(&etag);

    let range = |spec: &str, extra: &[(&str, &str)]| {
        let mut h = vec![("range", spec)];
        h.extend_from_slice(extra);
        srv.get_with(url, &h)
    };
    let check_206 = |r: &Resp, a: usize, b: usize| {
        assert_eq!(r.status, 206, "{}", r.text());
        assert_eq!(r.must("content-range"), format!("bytes {a}-{b}/{size}"));
        assert_eq!(r.body.len(), b - a + 1);
        assert!(r.body == file[a..=b], "bytes {a}-{b} differ");
        assert_eq!(
            r.must("content-length").parse::<usize>().unwrap(),
            b - a + 1
        );
    };
    check_206(&range("bytes=100-199", &[]), 100, 199);
    check_206(&range("bytes=-50", &[]), size - 50, size - 1);
    check_206(
        &range(&format!("bytes={}-", size - 10), &[]),
        size - 10,
        size - 1,
    );
    // An end past the file is clamped.
    check_206(
        &range(&format!("bytes={}-{}", size - 5, size + 100), &[]),
        size - 5,
        size - 1,
    );

    // Multiple ranges: multipart/byteranges with both parts.
    let multi = range("bytes=0-9,20-29", &[]);
    assert_eq!(multi.status, 206, "{}", multi.text());
    let ct = multi.must("content-type");
    assert!(ct.starts_with("multipart/byteranges"), "{ct}");
    let boundary = ct
        .split(';')
        .find_map(|p| p.trim().strip_prefix("boundary="))
        .unwrap_or_else(|| panic!("no boundary in {ct}"))
        .trim_matches('"')
        .to_string();
    let parts = multipart_parts(&multi.body, &boundary);
    assert_eq!(parts.len(), 2, "{parts:?}");
    assert_eq!(parts[0].0, format!("bytes 0-9/{size}"));
    assert_eq!(parts[0].1, file[0..10]);
    assert_eq!(parts[1].0, format!("bytes 20-29/{size}"));
    assert_eq!(parts[1].1, file[20..30]);

    // Unsatisfiable.
    let r = range(&format!("bytes={size}-"), &[]);
    assert_eq!(r.status, 416, "{}", r.text());
    assert_eq!(r.must("content-range"), format!("bytes */{size}"));

    // Revalidation.
    let nm = srv.get_with(url, &[("if-none-match", &etag)]);
    assert_eq!(nm.status, 304);
    assert!(nm.body.is_empty());

    // If-Range: our ETag → the range; another (or a weak one) → the whole file.
    check_206(&range("bytes=100-199", &[("if-range", &etag)]), 100, 199);
    let stale = range("bytes=100-199", &[("if-range", "\"someone-else\"")]);
    assert_eq!(stale.status, 200);
    assert!(
        stale.body == file,
        "If-Range mismatch must send the whole file"
    );
}
