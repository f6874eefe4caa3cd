//! What the client asked for: the target of every `GET` request line it sends.

use std::sync::{Arc, Mutex, PoisonError};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};

/// The targets (`/v1/datasets/…?…`) of the `GET` requests a proxy has carried, so a
/// test can count what a client asked for without instrumenting the client. Cheap to
/// clone: clones share one log.
#[derive(Clone, Debug, Default)]
pub struct RequestLog(Arc<Mutex<Vec<String>>>);

impl RequestLog {
    /// The targets recorded so far: in the order they were sent on each connection,
    /// connections interleaved as their request lines arrived.
    pub fn targets(&self) -> Vec<String> {
        self.0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }

    fn push(&self, target: String) {
        self.0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .push(target);
    }
}

/// Carries the client's bytes upstream unchanged, recording in `log` (when there is
/// one) the target of every line that starts with `GET `, whichever reads its bytes
/// arrive in. Ends when the client stops sending or the upstream stops taking bytes.
pub(crate) async fn relay_requests(
    mut cr: OwnedReadHalf,
    mut sw: OwnedWriteHalf,
    log: Option<RequestLog>,
) {
    let Some(log) = log else {
        let _ = tokio::io::copy(&mut cr, &mut sw).await;
        return;
    };
    let mut buf = vec![0u8; 1 << 14];
    let mut line = Vec::new();
    loop {
        let n = match cr.read(&mut buf).await {
            Ok(0) | Err(_) => break,
            Ok(n) => n,
        };
        for &b in &buf[..n] {
            if b == b'\n' {
                let text = String::from_utf8_lossy(&line);
                if let Some(target) = text.strip_prefix("GET ") {
                    let target = target.split(' ').next().unwrap_or_default();
                    log.push(target.to_string());
                }
                line.clear();
            } else {
                line.push(b);
            }
        }
        if sw.write_all(&buf[..n]).await.is_err() {
            break;
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::logging;
    use crate::testing::{get, http_upstream, read_response, response};
    use tokio::io::{AsyncWriteExt, BufReader};
    use tokio::net::TcpStream;

    /// Requests on two connections, one of them split across writes in the middle of
    /// its request line, one a HEAD: the log holds the GET targets in order, the
    /// upstream gets every byte as sent, the client every response as answered.
    #[tokio::test]
    async fn records_every_get_target_and_relays_requests_unchanged() {
        let answer = response("text/plain", b"ok");
        let upstream = http_upstream(vec![answer.clone()]).await;
        let (proxy, log) = logging(upstream.addr).await.unwrap();
        let mut sent = Vec::new();

        let (r, mut w) = TcpStream::connect(proxy.addr()).await.unwrap().into_split();
        let mut r = BufReader::new(r);
        let split = get("/v1/datasets/terrain/levels/3/tiles?ranges=0-15");
        let head = b"HEAD /v1/datasets/terrain HTTP/1.1\r\nhost: proxy.test\r\n\r\n".to_vec();
        for parts in [
            vec![get("/a")],
            vec![split[..10].to_vec(), split[10..].to_vec()],
            vec![head],
        ] {
            for p in &parts {
                w.write_all(p).await.unwrap();
                w.flush().await.unwrap();
                sent.extend_from_slice(p);
            }
            let (h, b) = read_response(&mut r).await;
            assert_eq!([h.as_bytes(), &b].concat(), answer);
        }

        let (r, mut w) = TcpStream::connect(proxy.addr()).await.unwrap().into_split();
        w.write_all(&get("/b?x=1")).await.unwrap();
        sent.extend_from_slice(&get("/b?x=1"));
        read_response(&mut BufReader::new(r)).await;

        assert_eq!(
            log.targets(),
            [
                "/a",
                "/v1/datasets/terrain/levels/3/tiles?ranges=0-15",
                "/b?x=1"
            ]
        );
        assert_eq!(*upstream.received.lock().unwrap(), sent);
        assert_eq!(proxy.stats().connections, 2);
    }
}
