//! `sonar-bridge certs`: a private certificate authority and the certificates of the robots and
//! laptops that talk to each other over mutual TLS. Every bridge trusts only certificates signed
//! by the authority (`ca.pem`); a robot serves only the certificate names its allow lists give.
//!
//! In the directory: `ca.pem` (give it to every machine), `ca.key` (the authority's key: keep it
//! on the machine that issues certificates, nowhere else), and `NAME.pem` + `NAME.key` per peer
//! (copy both to that machine only). Keys are written owner-only (0600) and never overwritten.

use std::fs::OpenOptions;
use std::io::Write;
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

use rcgen::{
    BasicConstraints, CertificateParams, DistinguishedName, DnType, ExtendedKeyUsagePurpose, IsCa,
    Issuer, KeyPair, KeyUsagePurpose, SanType,
};

use crate::channel::check_robot_name;

/// The authority's certificate and key in the directory.
pub const CA_CERT: &str = "ca.pem";
pub const CA_KEY: &str = "ca.key";
/// The authority's name in the certificates it signs.
const CA_NAME: &str = "sonar-bridge certificate authority";

/// Why certificates were not made.
#[derive(Debug, thiserror::Error)]
pub enum CertError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("certificate: {0}")]
    Rcgen(#[from] rcgen::Error),
    #[error("{0}")]
    Invalid(String),
}

/// One peer to certify: its name (the certificate's common name, which allow lists name) and
/// the host names or addresses others connect to it by (a robot's; a laptop needs none).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Peer {
    pub name: String,
    pub hosts: Vec<String>,
}

impl std::str::FromStr for Peer {
    type Err = String;
    /// `NAME` or `NAME=HOST[,HOST…]`, e.g. `robot1=192.168.1.20,robot1.local`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let (name, hosts) = s.split_once('=').unwrap_or((s, ""));
        check_robot_name(name).map_err(|e| format!("peer name: {e}"))?;
        let hosts: Vec<String> = hosts
            .split(',')
            .map(str::trim)
            .filter(|h| !h.is_empty())
            .map(str::to_owned)
            .collect();
        Ok(Self {
            name: name.to_owned(),
            hosts,
        })
    }
}

/// What [`make`] wrote.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Made {
    /// The authority was made now (not read from the directory).
    pub new_authority: bool,
    /// Each peer's certificate and key.
    pub peers: Vec<(PathBuf, PathBuf)>,
}

/// Makes (or reuses) the authority in `dir` and a certificate valid for `days` per peer.
pub fn make(dir: &Path, peers: &[Peer], days: u32) -> Result<Made, CertError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    for peer in peers {
        for file in [cert_path(dir, &peer.name), key_path(dir, &peer.name)] {
            if file.exists() {
                return Err(CertError::Invalid(format!(
                    "{} exists: certificates are never overwritten (remove it to make a new one)",
                    file.display()
                )));
            }
        }
    }
    let (ca_cert, ca_key) = (dir.join(CA_CERT), dir.join(CA_KEY));
    let (issuer, new_authority) = match (ca_cert.exists(), ca_key.exists()) {
        (true, true) => {
            let key = KeyPair::from_pem(&read(&ca_key)?)?;
            (Issuer::from_ca_cert_pem(&read(&ca_cert)?, key)?, false)
        }
        (false, false) => {
            let key = KeyPair::generate()?;
            let mut params = CertificateParams::default();
            params.distinguished_name = name(CA_NAME);
            params.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
            params.key_usages = vec![
                KeyUsagePurpose::KeyCertSign,
                KeyUsagePurpose::CrlSign,
                KeyUsagePurpose::DigitalSignature,
            ];
            // The authority outlives the certificates it signs.
            validity(&mut params, days.saturating_mul(5));
            let cert = params.self_signed(&key)?;
            write_new(&ca_key, &key.serialize_pem(), 0o600)?;
            write_new(&ca_cert, &cert.pem(), 0o644)?;
            (Issuer::new(params, key), true)
        }
        _ => {
            return Err(CertError::Invalid(format!(
                "{} and {} go together: one is missing",
                ca_cert.display(),
                ca_key.display()
            )));
        }
    };
    let mut made = Vec::new();
    for peer in peers {
        let key = KeyPair::generate()?;
        let mut params = CertificateParams::default();
        params.distinguished_name = name(&peer.name);
        params.subject_alt_names = std::iter::once(&peer.name)
            .chain(&peer.hosts)
            .map(|h| san(h))
            .collect::<Result<_, _>>()?;
        params.key_usages = vec![
            KeyUsagePurpose::DigitalSignature,
            KeyUsagePurpose::KeyEncipherment,
        ];
        // Every bridge both listens (robot) and connects (remote): one certificate does both.
        params.extended_key_usages = vec![
            ExtendedKeyUsagePurpose::ServerAuth,
            ExtendedKeyUsagePurpose::ClientAuth,
        ];
        params.use_authority_key_identifier_extension = true;
        validity(&mut params, days);
        let cert = params.signed_by(&key, &issuer)?;
        let (cert_file, key_file) = (cert_path(dir, &peer.name), key_path(dir, &peer.name));
        write_new(&key_file, &key.serialize_pem(), 0o600)?;
        write_new(&cert_file, &cert.pem(), 0o644)?;
        made.push((cert_file, key_file));
    }
    Ok(Made {
        new_authority,
        peers: made,
    })
}

pub fn cert_path(dir: &Path, name: &str) -> PathBuf {
    dir.join(format!("{name}.pem"))
}

pub fn key_path(dir: &Path, name: &str) -> PathBuf {
    dir.join(format!("{name}.key"))
}

fn name(common_name: &str) -> DistinguishedName {
    let mut dn = DistinguishedName::new();
    dn.push(DnType::CommonName, common_name);
    dn
}

/// An address as an IP entry, anything else as a DNS name.
fn san(host: &str) -> Result<SanType, CertError> {
    Ok(match host.parse::<std::net::IpAddr>() {
        Ok(ip) => SanType::IpAddress(ip),
        Err(_) => SanType::DnsName(host.to_owned().try_into()?),
    })
}

/// Valid from a day ago (clocks differ) for `days` days.
fn validity(params: &mut CertificateParams, days: u32) {
    let now = time::OffsetDateTime::now_utc();
    params.not_before = now - time::Duration::days(1);
    params.not_after = now + time::Duration::days(i64::from(days));
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> CertError + '_ {
    move |source| CertError::Io {
        path: path.to_owned(),
        source,
    }
}

fn read(path: &Path) -> Result<String, CertError> {
    std::fs::read_to_string(path).map_err(io(path))
}

/// Writes a file that must not exist yet, with `mode` from its creation on (a key is never
/// readable by others, not even for a moment).
fn write_new(path: &Path, text: &str, mode: u32) -> Result<(), CertError> {
    let mut file = OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(mode)
        .open(path)
        .map_err(io(path))?;
    file.write_all(text.as_bytes()).map_err(io(path))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use std::os::unix::fs::PermissionsExt;

    use super::*;

    #[test]
    fn an_authority_signs_peers_now_and_later_and_overwrites_nothing() {
        let dir = std::env::temp_dir().join(format!("sonar-certs-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let robot: Peer = "robot1=10.0.0.5,robot1.local".parse().unwrap();
        assert_eq!(robot.hosts, ["10.0.0.5", "robot1.local"]);
        let made = make(&dir, &[robot.clone(), "laptop".parse().unwrap()], 30).unwrap();
        assert!(made.new_authority);
        assert_eq!(made.peers.len(), 2);
        let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode(&dir.join(CA_KEY)), 0o600);
        assert_eq!(mode(&key_path(&dir, "laptop")), 0o600);
        assert!(
            read(&cert_path(&dir, "robot1"))
                .unwrap()
                .contains("BEGIN CERTIFICATE")
        );
        // A later peer is signed by the same authority, read back from the directory.
        let ca_before = read(&dir.join(CA_CERT)).unwrap();
        let later = make(&dir, &["laptop2".parse().unwrap()], 30).unwrap();
        assert!(!later.new_authority);
        assert_eq!(read(&dir.join(CA_CERT)).unwrap(), ca_before);
        // Nothing is overwritten.
        let err = make(&dir, &[robot], 30).unwrap_err().to_string();
        assert!(err.contains("never overwritten"), "{err}");
        assert!("a/b".parse::<Peer>().is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
