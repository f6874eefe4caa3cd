//! HTTPS: a rustls server configuration from `--tls-cert` and `--tls-key` (PEM), with
//! the pure-Rust `ring` crypto provider and ALPN offering `h2` then `http/1.1`.
//!
//! Every failure names the file and what is wrong with it, so `serve` stops with a
//! clear message (and a non-zero exit) instead of serving plain HTTP or panicking.

use anyhow::Context;
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use std::path::PathBuf;
use std::sync::Arc;

/// The PEM files of `--tls-cert` and `--tls-key`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TlsFiles {
    pub cert: PathBuf,
    pub key: PathBuf,
}

/// The ALPN protocols offered, most preferred first.
pub const ALPN: [&[u8]; 2] = [b"h2", b"http/1.1"];

/// Loads the certificate chain and key of `files` into a server configuration.
pub fn server_config(files: &TlsFiles) -> anyhow::Result<Arc<rustls::ServerConfig>> {
    let cert_path = &files.cert;
    let key_path = &files.key;
    // Read first, so a missing or unreadable file is reported as such (the PEM
    // parser's own errors do not say which file they were reading).
    let cert_pem = std::fs::read(cert_path)
        .with_context(|| format!("--tls-cert {}: cannot read", cert_path.display()))?;
    let key_pem = std::fs::read(key_path)
        .with_context(|| format!("--tls-key {}: cannot read", key_path.display()))?;
    let certs = CertificateDer::pem_slice_iter(&cert_pem)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| {
            anyhow::anyhow!(
                "--tls-cert {}: not a PEM certificate chain: {e}",
                cert_path.display()
            )
        })?;
    anyhow::ensure!(
        !certs.is_empty(),
        "--tls-cert {}: no certificate in it (want PEM `-----BEGIN CERTIFICATE-----` blocks)",
        cert_path.display()
    );
    let key = PrivateKeyDer::from_pem_slice(&key_pem).map_err(|e| {
        anyhow::anyhow!(
            "--tls-key {}: no PEM private key in it (PKCS#8, PKCS#1 or SEC1): {e}",
            key_path.display()
        )
    })?;
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let mut config = rustls::ServerConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .context("TLS: the crypto provider supports no protocol version")?
        .with_no_client_auth()
        .with_single_cert(certs, key)
        .map_err(|e| {
            anyhow::anyhow!(
                "--tls-cert {} with --tls-key {}: {e} (is the key the certificate's own?)",
                cert_path.display(),
                key_path.display()
            )
        })?;
    config.alpn_protocols = ALPN.iter().map(|p| p.to_vec()).collect();
    Ok(Arc::new(config))
}
