//! The line `dynaserve serve` prints on stdout once both listeners are bound, and its parser
//! (for whoever starts a server as a child process: the load tester, the end-to-end tests):
//!
//! ```text
//! dynaserve listening: grpc=0.0.0.0:50051 http=0.0.0.0:8080 models=rigidformer-small
//! ```

use std::net::{Ipv6Addr, SocketAddr};

const PREFIX: &str = "dynaserve listening:";

/// The line for the bound addresses and the resident models' names.
pub fn listening_line(grpc: SocketAddr, http: SocketAddr, models: &[String]) -> String {
    format!(
        "{PREFIX} grpc={grpc} http={http} models={}",
        models.join(",")
    )
}

/// The gRPC and HTTP addresses of a listening line (anywhere in `line`), with unspecified
/// addresses (`0.0.0.0`, `::`) replaced by loopback so they can be connected to. `None` when
/// the line is not one or an address is missing or malformed.
pub fn parse_listening(line: &str) -> Option<(SocketAddr, SocketAddr)> {
    let rest = line.split(PREFIX).nth(1)?;
    let mut grpc = None;
    let mut http = None;
    for word in rest.split_whitespace() {
        if let Some(v) = word.strip_prefix("grpc=") {
            grpc = v.parse::<SocketAddr>().ok();
        } else if let Some(v) = word.strip_prefix("http=") {
            http = v.parse::<SocketAddr>().ok();
        }
    }
    let reachable = |mut a: SocketAddr| {
        if a.ip().is_unspecified() {
            a.set_ip(if a.is_ipv4() {
                [127, 0, 0, 1].into()
            } else {
                Ipv6Addr::LOCALHOST.into()
            });
        }
        a
    };
    Some((reachable(grpc?), reachable(http?)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_printed_line_parses_back() {
        let line = listening_line(
            "0.0.0.0:50051".parse().unwrap(),
            "127.0.0.1:38001".parse().unwrap(),
            &["a".into(), "b".into()],
        );
        assert_eq!(
            line,
            "dynaserve listening: grpc=0.0.0.0:50051 http=127.0.0.1:38001 models=a,b"
        );
        let (g, h) = parse_listening(&line).unwrap();
        assert_eq!(g, "127.0.0.1:50051".parse().unwrap());
        assert_eq!(h, "127.0.0.1:38001".parse().unwrap());
        assert!(parse_listening("something else").is_none());
        assert!(parse_listening("dynaserve listening: grpc=x http=1.2.3.4:5").is_none());
    }
}
