//! `tessera-proxy`: a TCP proxy that adds latency, for `bench/stream.sh` (which flies
//! through it at 50 and 150 ms) and for trying the client against a slow server by
//! hand. The proxies that damage or log what they relay are the library's, for tests.

use anyhow::Context;
use clap::Parser;
use std::net::{SocketAddr, ToSocketAddrs};
use std::process::ExitCode;
use std::time::Duration;
use tessera_proxy::{Config, Delay, Proxy, Responses};

#[derive(Debug, Parser)]
#[command(
    name = "tessera-proxy",
    version,
    about = "A TCP proxy that holds each response for a while before its first byte (added latency)",
    long_about = "A TCP proxy that holds each response for a while before its first byte \
        (added latency).\n\n\
        Every connection it accepts gets its own connection to the upstream. Requests go \
        upstream unchanged; each response from upstream waits --delay-ms before its first \
        byte goes on, and the rest of it follows as it arrives. The proxy does not parse \
        HTTP: a response is what the upstream sends after being silent for --gap-ms (or \
        first on a connection).\n\n\
        Once it listens it prints `listening on ADDR` on standard output. It runs until it \
        is killed (SIGTERM or Ctrl-C).\n\n\
        Example: tessera-proxy --upstream 127.0.0.1:8080 --delay-ms 150"
)]
struct Cli {
    /// The server to relay to, as HOST:PORT (a host name is resolved once, at start).
    #[arg(long, value_name = "HOST:PORT")]
    upstream: String,
    /// Where to listen; port 0 picks a free port (the `listening on` line says which).
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:0")]
    listen: SocketAddr,
    /// How long each response is held before its first byte; 0 relays unchanged.
    #[arg(long, value_name = "MS", default_value_t = 0)]
    delay_ms: u64,
    /// Upstream silence that ends a response: the bytes after such a pause are a new
    /// response, held again.
    #[arg(long, value_name = "MS", default_value_t = Delay::DEFAULT_GAP.as_millis() as u64)]
    gap_ms: u64,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(&cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: &Cli) -> anyhow::Result<()> {
    let upstream = resolve(&cli.upstream)?;
    let delay = Delay {
        hold: Duration::from_millis(cli.delay_ms),
        gap: Duration::from_millis(cli.gap_ms),
    };
    let config = Config {
        listen: cli.listen,
        responses: if delay.hold.is_zero() {
            Responses::Relay
        } else {
            Responses::Delay(delay)
        },
        ..Config::new(upstream)
    };
    // One thread, as the Python proxy this replaces had: it waits and copies, and the
    // benchmark's client and server need the cores.
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    rt.block_on(async {
        let proxy = Proxy::start(config)
            .await
            .with_context(|| format!("cannot listen on {}", cli.listen))?;
        println!("listening on {}", proxy.addr());
        std::future::pending::<()>().await;
        Ok(())
    })
}

/// The first address `HOST:PORT` resolves to.
fn resolve(upstream: &str) -> anyhow::Result<SocketAddr> {
    upstream
        .to_socket_addrs()
        .with_context(|| format!("--upstream {upstream}: not a HOST:PORT that resolves"))?
        .next()
        .with_context(|| format!("--upstream {upstream}: resolves to no address"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn the_command_line_is_consistent() {
        Cli::command().debug_assert();
    }

    /// What bench/stream.sh passes: the server's address, a delay; the defaults
    /// listen on a free loopback port with the 20 ms gap.
    #[test]
    fn parses_what_the_benchmark_passes() {
        let cli = Cli::try_parse_from([
            "tessera-proxy",
            "--upstream",
            "127.0.0.1:8080",
            "--delay-ms",
            "150",
        ])
        .unwrap();
        assert_eq!(
            resolve(&cli.upstream).unwrap(),
            "127.0.0.1:8080".parse().unwrap()
        );
        assert_eq!(cli.listen, "127.0.0.1:0".parse().unwrap());
        assert_eq!((cli.delay_ms, cli.gap_ms), (150, 20));
    }

    #[test]
    fn an_upstream_without_a_port_is_refused() {
        let err = resolve("127.0.0.1").unwrap_err();
        assert!(
            format!("{err:#}").contains("--upstream 127.0.0.1"),
            "{err:#}"
        );
    }
}
