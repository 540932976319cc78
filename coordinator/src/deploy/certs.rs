//! `baton deploy certs --ca DIR NAME…`: a certificate authority for a cell and a certificate per process, made with
//! rcgen. Each certificate's common name is its process's identity — an agent's name, the coordinator's, an
//! operator's — which mutual TLS proves to the router and the router's access control matches
//! (`cert_common_names`). Every certificate serves both ends of a TLS link (a router listens, an agent connects).
//!
//! Files: `DIR/ca.pem` and `DIR/ca.key` (made once, reused by every later call, so that certificates issued at
//! different times trust each other), and per name `DIR/NAME.pem` + `DIR/NAME.key` (PEM) and `DIR/NAME.json5`, the
//! Zenoh configuration its process connects with (`--zenoh-config`: its certificate, its key and the CA, by absolute
//! path, on mutual TLS). Keys are written readable by their owner only. A name that has its certificate already
//! keeps it, unless `renew`.

use std::fs;
use std::io::Write;
use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context};
use rcgen::{
    BasicConstraints, CertificateParams, DistinguishedName, DnType, ExtendedKeyUsagePurpose, IsCa, Issuer, KeyPair,
    KeyUsagePurpose,
};

/// The common name of a cell's CA.
pub const CA_NAME: &str = "Baton cell CA";

/// How many years a CA and a process's certificate are valid from the day they are made.
const CA_YEARS: i32 = 20;
const CERT_YEARS: i32 = 5;

/// What `certs` did for one name.
#[derive(Debug, PartialEq, Eq)]
pub struct Issued {
    pub name: String,
    pub cert: PathBuf,
    pub key: PathBuf,
    /// Made now (false: its certificate was there already and is kept).
    pub made: bool,
    /// The Zenoh configuration its process connects with.
    pub config: PathBuf,
}

/// What `certs` did: whether it made the CA, and each name's certificate.
#[derive(Debug)]
pub struct Made {
    pub ca: PathBuf,
    pub ca_made: bool,
    pub issued: Vec<Issued>,
}

/// Makes (or reuses) the CA in `dir`, and a certificate for each of `names` with `sans` as further names its
/// holder answers at (a router's host names and addresses).
pub fn certs(dir: &Path, names: &[String], sans: &[String], renew: bool) -> anyhow::Result<Made> {
    if names.is_empty() {
        bail!("name at least one process: baton deploy certs --ca DIR NAME…");
    }
    for n in names {
        if !baton_proto::cluster::keys::is_valid_name(n) {
            bail!("`{n}` is not a name Baton takes: letters, digits, `_` and `-`, at most 64");
        }
        if n == "ca" {
            bail!("`ca` is the authority's own file name: name the process otherwise");
        }
    }
    fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    // The configurations name the files by absolute path: a process may start anywhere.
    let dir = &fs::canonicalize(dir).with_context(|| format!("cannot find {}", dir.display()))?;
    let (ca_pem, ca_key) = (dir.join("ca.pem"), dir.join("ca.key"));
    let ca_made = match (ca_pem.exists(), ca_key.exists()) {
        (true, true) => false,
        (false, false) => {
            make_ca(&ca_pem, &ca_key)?;
            true
        }
        _ => bail!(
            "{} holds half a CA (ca.pem or ca.key without the other): restore it, or use another folder",
            dir.display()
        ),
    };
    let key_text = fs::read_to_string(&ca_key).with_context(|| format!("cannot read {}", ca_key.display()))?;
    let cert_text = fs::read_to_string(&ca_pem).with_context(|| format!("cannot read {}", ca_pem.display()))?;
    let ca_keypair =
        KeyPair::from_pem(&key_text).map_err(|e| anyhow!("{}: not a private key: {e}", ca_key.display()))?;
    let issuer = Issuer::from_ca_cert_pem(&cert_text, ca_keypair)
        .map_err(|e| anyhow!("{}: not a CA certificate: {e}", ca_pem.display()))?;
    let mut issued = Vec::new();
    for name in names {
        let (cert, key) = (dir.join(format!("{name}.pem")), dir.join(format!("{name}.key")));
        let made = renew || !(cert.exists() && key.exists());
        if made {
            let mut alt = vec![name.clone()];
            alt.extend(sans.iter().cloned());
            let mut params = CertificateParams::new(alt).map_err(|e| anyhow!("{name}: {e}"))?;
            params.distinguished_name = DistinguishedName::new();
            params.distinguished_name.push(DnType::CommonName, name.as_str());
            params.key_usages = vec![KeyUsagePurpose::DigitalSignature, KeyUsagePurpose::KeyEncipherment];
            params.extended_key_usages = vec![ExtendedKeyUsagePurpose::ServerAuth, ExtendedKeyUsagePurpose::ClientAuth];
            validity(&mut params, CERT_YEARS);
            let keypair = KeyPair::generate().map_err(|e| anyhow!("cannot make a key: {e}"))?;
            let signed = params.signed_by(&keypair, &issuer).map_err(|e| anyhow!("cannot sign `{name}`: {e}"))?;
            write_key(&key, &keypair.serialize_pem())?;
            fs::write(&cert, signed.pem()).with_context(|| format!("cannot write {}", cert.display()))?;
        }
        let config = dir.join(format!("{name}.json5"));
        let text = client_config(name, &dir.join("ca.pem"), &cert, &key);
        fs::write(&config, text).with_context(|| format!("cannot write {}", config.display()))?;
        issued.push(Issued { name: name.clone(), cert, key, made, config });
    }
    Ok(Made { ca: ca_pem, ca_made, issued })
}

/// The Zenoh configuration of process `name` connecting on the cell's mutual TLS.
fn client_config(name: &str, ca: &Path, cert: &Path, key: &Path) -> String {
    let path = |p: &Path| serde_json::Value::String(p.display().to_string()).to_string();
    format!(
        "// `{name}` on the cell's mutual TLS (written by `baton deploy certs`): give it to the process as \
         --zenoh-config.\n{{\n  transport: {{\n    link: {{\n      tls: {{\n        root_ca_certificate: {},\n        \
         connect_certificate: {},\n        connect_private_key: {},\n        enable_mtls: true,\n      }},\n    }},\n  }},\n}}\n",
        path(ca),
        path(cert),
        path(key)
    )
}

fn make_ca(cert: &Path, key: &Path) -> anyhow::Result<()> {
    let mut params = CertificateParams::default();
    params.distinguished_name.push(DnType::CommonName, CA_NAME);
    params.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
    params.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign, KeyUsagePurpose::DigitalSignature];
    validity(&mut params, CA_YEARS);
    let keypair = KeyPair::generate().map_err(|e| anyhow!("cannot make the CA's key: {e}"))?;
    let ca = params.self_signed(&keypair).map_err(|e| anyhow!("cannot make the CA: {e}"))?;
    write_key(key, &keypair.serialize_pem())?;
    fs::write(cert, ca.pem()).with_context(|| format!("cannot write {}", cert.display()))
}

/// Valid from yesterday (clocks differ) for `years`.
fn validity(params: &mut CertificateParams, years: i32) {
    let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default().as_secs();
    let (y, m, d) = civil_date((now / 86_400) as i64 - 1);
    params.not_before = rcgen::date_time_ymd(y, m, d);
    params.not_after = rcgen::date_time_ymd(y + years, m, d.min(28));
}

/// The proleptic Gregorian date of a day counted from 1970-01-01 (Howard Hinnant's `civil_from_days`).
fn civil_date(days: i64) -> (i32, u8, u8) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u8;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u8;
    let y = (yoe + era * 400 + i64::from(m <= 2)) as i32;
    (y, m, d)
}

/// A private key, readable by its owner only from the moment it exists.
fn write_key(path: &Path, pem: &str) -> anyhow::Result<()> {
    let mut f = fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .mode(0o600)
        .open(path)
        .with_context(|| format!("cannot write {}", path.display()))?;
    // An older file keeps its mode through `open`: set it.
    f.set_permissions(fs::Permissions::from_mode(0o600))?;
    f.write_all(pem.as_bytes()).with_context(|| format!("cannot write {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use x509_parser::prelude::*;

    fn parsed(path: &Path) -> Vec<u8> {
        let text = fs::read(path).expect("read");
        let (_, pem) = x509_parser::pem::parse_x509_pem(&text).expect("PEM");
        pem.contents
    }

    #[test]
    fn a_ca_signs_each_name_and_is_reused_by_a_later_call() {
        let dir = tempfile::tempdir().expect("tmp");
        let names = ["robot1".to_string(), "coordinator".to_string()];
        let made = certs(dir.path(), &names, &["localhost".into(), "127.0.0.1".into()], false).expect("certs");
        assert!(made.ca_made && made.issued.iter().all(|i| i.made));
        let ca_der = parsed(&made.ca);
        let (_, ca) = X509Certificate::from_der(&ca_der).expect("the CA");
        assert!(ca.is_ca());
        assert_eq!(ca.subject().iter_common_name().next().and_then(|c| c.as_str().ok()), Some(CA_NAME));
        for i in &made.issued {
            let der = parsed(&i.cert);
            let (_, cert) = X509Certificate::from_der(&der).expect("a certificate");
            let cn = cert.subject().iter_common_name().next().and_then(|c| c.as_str().ok());
            assert_eq!(cn, Some(i.name.as_str()));
            assert!(!cert.is_ca());
            cert.verify_signature(Some(ca.public_key())).expect("signed by the CA");
            assert!(cert.validity().is_valid(), "valid now: {:?}", cert.validity());
            let sans = cert.subject_alternative_name().expect("parses").expect("has SANs");
            let general = &sans.value.general_names;
            assert!(general.iter().any(|g| matches!(g, GeneralName::DNSName(n) if *n == i.name)), "{general:?}");
            assert!(general.iter().any(|g| matches!(g, GeneralName::DNSName("localhost"))), "{general:?}");
            assert!(general.iter().any(|g| matches!(g, GeneralName::IPAddress([127, 0, 0, 1]))), "{general:?}");
            let mode = fs::metadata(&i.key).expect("key").permissions().mode() & 0o777;
            assert_eq!(mode, 0o600, "{}", i.key.display());
            // Its process's configuration: Zenoh reads it, and it connects with this certificate.
            zenoh::Config::from_file(&i.config).expect("zenoh reads the configuration");
            let (cert, cn) = baton_host::certificate_identity(&i.config).expect("it connects with a certificate");
            assert_eq!((cert, cn.as_str()), (i.cert.clone(), i.name.as_str()));
        }
        // Again, with one name more: the CA and robot1's certificate are kept, operator1's is signed by that CA.
        let before = (fs::read(&made.ca).expect("ca"), fs::read(dir.path().join("robot1.pem")).expect("robot1"));
        let names = ["robot1".to_string(), "operator1".to_string()];
        let again = certs(dir.path(), &names, &[], false).expect("certs again");
        assert!(!again.ca_made);
        assert_eq!(again.issued.iter().map(|i| i.made).collect::<Vec<_>>(), [false, true]);
        assert_eq!(fs::read(&made.ca).expect("ca"), before.0);
        assert_eq!(fs::read(dir.path().join("robot1.pem")).expect("robot1"), before.1);
        let der = parsed(&dir.path().join("operator1.pem"));
        let (_, op) = X509Certificate::from_der(&der).expect("operator1");
        op.verify_signature(Some(ca.public_key())).expect("signed by the same CA");
        // Renewed: a new certificate, the same CA.
        let renewed = certs(dir.path(), &["robot1".to_string()], &[], true).expect("renew");
        assert!(renewed.issued[0].made);
        assert_ne!(fs::read(dir.path().join("robot1.pem")).expect("robot1"), before.1);
    }

    #[test]
    fn bad_names_and_half_a_ca_are_refused() {
        let dir = tempfile::tempdir().expect("tmp");
        for bad in ["", "robot 1", "../etc", "ca"] {
            assert!(certs(dir.path(), &[bad.to_string()], &[], false).is_err(), "{bad:?}");
        }
        assert!(certs(dir.path(), &[], &[], false).is_err());
        fs::write(dir.path().join("ca.pem"), "x").expect("write");
        let err = certs(dir.path(), &["r1".to_string()], &[], false).expect_err("half a CA").to_string();
        assert!(err.contains("half a CA"), "{err}");
        fs::write(dir.path().join("ca.key"), "not a key").expect("write");
        let err = certs(dir.path(), &["r1".to_string()], &[], false).expect_err("garbage").to_string();
        assert!(err.contains("not a private key"), "{err}");
    }

    #[test]
    fn civil_dates_are_right_across_leap_years_and_centuries() {
        assert_eq!(civil_date(0), (1970, 1, 1));
        assert_eq!(civil_date(11_016), (2000, 2, 29));
        assert_eq!(civil_date(19_723), (2024, 1, 1));
        assert_eq!(civil_date(20_790), (2026, 12, 3));
        assert_eq!(civil_date(-1), (1969, 12, 31));
    }
}
