//! Finding Neons on the local network: the Companion app announces its
//! Real-time API over mDNS / DNS-SD as an `_http._tcp.local.` service whose
//! instance name starts with `PI monitor:` (then the device name and id),
//! port 8080 by default. [`discover_neons`] browses for a while and returns
//! every such instance with the `neon://` URI to use.

use std::net::IpAddr;
use std::time::{Duration, Instant};

use mdns_sd::{ServiceDaemon, ServiceEvent};

/// The DNS-SD service type the Companion app announces.
pub const SERVICE_TYPE: &str = "_http._tcp.local.";
/// The instance-name prefix that marks a Neon (Pupil Invisible's too).
pub const INSTANCE_PREFIX: &str = "PI monitor:";

/// A Neon found by mDNS.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FoundNeon {
    /// The instance name, e.g. `PI monitor:Neon Companion:1a2b3c`.
    pub name: String,
    /// The announced host name, e.g. `neon.local.`.
    pub host: String,
    /// Its addresses (IPv4 first).
    pub addresses: Vec<IpAddr>,
    /// The HTTP port of the Real-time API.
    pub port: u16,
}

impl FoundNeon {
    /// `neon://ADDRESS:PORT` (the first IPv4 address, else the first one,
    /// else the host name).
    pub fn uri(&self) -> String {
        match self.addresses.first() {
            Some(IpAddr::V6(a)) => format!("neon://[{a}]:{}", self.port),
            Some(a) => format!("neon://{a}:{}", self.port),
            None => format!("neon://{}:{}", self.host.trim_end_matches('.'), self.port),
        }
    }
}

/// Why browsing could not run.
#[derive(Debug, thiserror::Error)]
pub enum DiscoverError {
    #[error("mDNS: cannot browse {SERVICE_TYPE}: {0}")]
    Browse(String),
}

/// The instance name of a DNS-SD full name (`NAME._http._tcp.local.`).
fn instance_name(fullname: &str) -> &str {
    fullname
        .strip_suffix(SERVICE_TYPE)
        .map_or(fullname, |n| n.trim_end_matches('.'))
}

/// Whether a DNS-SD full name is a Neon's.
pub fn is_neon(fullname: &str) -> bool {
    instance_name(fullname).starts_with(INSTANCE_PREFIX)
}

/// Browses mDNS for `wait` and returns the Neons that answered (each once,
/// sorted by name). Nothing found is an empty list, not an error.
pub fn discover_neons(wait: Duration) -> Result<Vec<FoundNeon>, DiscoverError> {
    let daemon = ServiceDaemon::new().map_err(|e| DiscoverError::Browse(e.to_string()))?;
    let events = daemon
        .browse(SERVICE_TYPE)
        .map_err(|e| DiscoverError::Browse(e.to_string()))?;
    let end = Instant::now() + wait;
    let mut found: Vec<FoundNeon> = Vec::new();
    while let Some(left) = end.checked_duration_since(Instant::now()) {
        let Ok(event) = events.recv_timeout(left) else {
            break;
        };
        if let ServiceEvent::ServiceResolved(s) = event {
            if !is_neon(&s.fullname) || found.iter().any(|f| f.name == instance_name(&s.fullname)) {
                continue;
            }
            let mut addresses: Vec<IpAddr> = s.addresses.iter().map(|a| a.to_ip_addr()).collect();
            addresses.sort_by_key(|a| (a.is_ipv6(), *a));
            found.push(FoundNeon {
                name: instance_name(&s.fullname).to_owned(),
                host: s.host.clone(),
                addresses,
                port: s.port,
            });
        }
    }
    // Best effort: the daemon thread ends with the process anyway.
    let _ = daemon.shutdown();
    found.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(found)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_uris() {
        assert!(is_neon("PI monitor:Neon Companion:1a2b._http._tcp.local."));
        assert!(!is_neon("printer._http._tcp.local."));
        assert_eq!(
            instance_name("PI monitor:Neon:1._http._tcp.local."),
            "PI monitor:Neon:1"
        );
        let mut n = FoundNeon {
            name: "PI monitor:Neon:1".into(),
            host: "neon.local.".into(),
            addresses: vec!["192.168.1.20".parse().unwrap_or(IpAddr::from([0, 0, 0, 0]))],
            port: 8080,
        };
        assert_eq!(n.uri(), "neon://192.168.1.20:8080");
        n.addresses.clear();
        assert_eq!(n.uri(), "neon://neon.local:8080");
    }
}
