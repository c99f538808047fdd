//! The listening front of `sonar-foxglove`: lets clients that speak only `foxglove.websocket.v1`
//! (Lichtblick, older Foxglove, the ws-protocol libraries) reach the `foxglove` crate's server.
//!
//! The crate (0.30, and every version since its import into foxglove-sdk) negotiates only
//! `foxglove.sdk.v1` and `foxglove.sdk.v1.1` and answers anything else with HTTP 400, and it has
//! no option to add a subprotocol. `foxglove.sdk.v1` is the ws-protocol v1 wire format under a
//! new name (the same JSON ops with inline schemas, the same binary frames: compared with
//! foxglove/ws-protocol's `docs/spec.md`); only `foxglove.sdk.v1.1` changes the advertisement
//! (schema tables). So the front, which owns the public port, reads each connection's HTTP
//! upgrade request, and when the client offers `foxglove.websocket.v1` and none of the SDK's
//! names, asks the inner server (on 127.0.0.1, any free port) for exactly `foxglove.sdk.v1` and
//! renames the agreed subprotocol in the reply back to `foxglove.websocket.v1`. Every other
//! request passes unchanged (so the crate still picks `v1.1` for current Foxglove, and still
//! refuses what it cannot serve). After the handshake it copies bytes both ways untouched: the
//! WebSocket accept key does not depend on the subprotocol and no extension is negotiated.
//!
//! Plain threads, two per connection (a viewer or two, never thousands): nothing async here.

use std::io::{self, Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::thread;
use std::time::Duration;

use tracing::{debug, info, warn};

/// The subprotocol of the ws-protocol specification, which the crate does not name.
pub const LEGACY_SUBPROTOCOL: &str = "foxglove.websocket.v1";
/// The crate's name for the same wire format, asked of it on a legacy client's behalf.
const SDK_V1: &str = "foxglove.sdk.v1";
/// Every subprotocol the crate negotiates itself.
const SDK_SUBPROTOCOLS: [&str; 2] = [SDK_V1, "foxglove.sdk.v1.1"];
const PROTOCOL_HEADER: &str = "sec-websocket-protocol";
/// An upgrade request or reply longer than this is not a WebSocket handshake.
const MAX_HEAD: usize = 16 * 1024;
/// A connection that has not finished its handshake by then is dropped.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// The public listener and the inner server's address.
#[derive(Debug)]
pub struct Front {
    listener: TcpListener,
    inner: SocketAddr,
}

impl Front {
    /// Listens on `host:port` for clients of the inner server at `inner`.
    pub fn bind(host: &str, port: u16, inner: SocketAddr) -> io::Result<Self> {
        let listener = TcpListener::bind((host, port))?;
        // Polled from the main loop, which wakes every few milliseconds anyway.
        listener.set_nonblocking(true)?;
        Ok(Self { listener, inner })
    }

    /// The port clients connect to (the one chosen when bound to port 0).
    pub fn port(&self) -> io::Result<u16> {
        Ok(self.listener.local_addr()?.port())
    }

    /// Hands each waiting connection to a thread of its own; returns when none is left.
    pub fn accept_waiting(&self) {
        loop {
            match self.listener.accept() {
                Ok((client, peer)) => {
                    let inner = self.inner;
                    thread::spawn(move || match serve(client, inner) {
                        Ok(()) => debug!(%peer, "client disconnected"),
                        Err(e) => info!(%peer, "client dropped: {e}"),
                    });
                }
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => return,
                Err(e) => {
                    warn!("accepting a connection failed: {e}");
                    return;
                }
            }
        }
    }
}

/// One client: the handshake through [`for_inner_server`] and [`for_legacy_client`], then the
/// bytes relayed until either side closes.
fn serve(client: TcpStream, inner: SocketAddr) -> io::Result<()> {
    client.set_nonblocking(false)?;
    client.set_read_timeout(Some(HANDSHAKE_TIMEOUT))?;
    let (request, early) = read_head(&client)?;
    let translated = std::str::from_utf8(&request)
        .ok()
        .and_then(for_inner_server);
    let server = TcpStream::connect(inner)?;
    server.set_read_timeout(Some(HANDSHAKE_TIMEOUT))?;
    (&server).write_all(translated.as_deref().map_or(&request, str::as_bytes))?;
    (&server).write_all(&early)?;
    let (reply, early) = read_head(&server)?;
    let reply = match (&translated, std::str::from_utf8(&reply)) {
        (Some(_), Ok(text)) => for_legacy_client(text).into_bytes(),
        _ => reply,
    };
    (&client).write_all(&reply)?;
    (&client).write_all(&early)?;
    if translated.is_some() {
        debug!("{LEGACY_SUBPROTOCOL} client served as {SDK_V1}");
    }
    client.set_read_timeout(None)?;
    server.set_read_timeout(None)?;
    relay(client, server)
}

/// Copies each direction until one side closes, then closes both, so neither copy outlives it.
fn relay(client: TcpStream, server: TcpStream) -> io::Result<()> {
    let (upstream_client, upstream_server) = (client.try_clone()?, server.try_clone()?);
    let upstream = thread::spawn(move || {
        let _ = io::copy(&mut &upstream_client, &mut &upstream_server);
        close(&upstream_client, &upstream_server);
    });
    let downstream = io::copy(&mut &server, &mut &client);
    close(&client, &server);
    let _ = upstream.join();
    downstream.map(drop)
}

fn close(a: &TcpStream, b: &TcpStream) {
    // Either may be closed already; nothing to report then.
    let _ = a.shutdown(Shutdown::Both);
    let _ = b.shutdown(Shutdown::Both);
}

/// An HTTP head (through the blank line) and whatever followed it in the same reads.
fn read_head(mut stream: &TcpStream) -> io::Result<(Vec<u8>, Vec<u8>)> {
    let mut head = Vec::new();
    let mut chunk = [0u8; 4096];
    loop {
        let n = stream.read(&mut chunk)?;
        if n == 0 {
            return Err(io::Error::new(
                io::ErrorKind::UnexpectedEof,
                "closed during the handshake",
            ));
        }
        head.extend_from_slice(&chunk[..n]);
        if let Some(end) = head.windows(4).position(|w| w == b"\r\n\r\n") {
            let rest = head.split_off(end + 4);
            return Ok((head, rest));
        }
        if head.len() > MAX_HEAD {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                "not a WebSocket handshake (head too long)",
            ));
        }
    }
}

/// The upgrade request rewritten to ask for `foxglove.sdk.v1`, when the client offers
/// `foxglove.websocket.v1` and none of the crate's own subprotocols; `None` to pass it unchanged.
fn for_inner_server(request: &str) -> Option<String> {
    let offered: Vec<&str> = request
        .split("\r\n")
        .filter_map(|line| header_value(line, PROTOCOL_HEADER))
        .flat_map(|value| value.split(','))
        .map(str::trim)
        .collect();
    let legacy_only = offered.contains(&LEGACY_SUBPROTOCOL)
        && !offered.iter().any(|name| SDK_SUBPROTOCOLS.contains(name));
    legacy_only.then(|| with_protocol(request, SDK_V1))
}

/// The inner server's reply with the agreed subprotocol named as the legacy client asked.
fn for_legacy_client(reply: &str) -> String {
    with_protocol(reply, LEGACY_SUBPROTOCOL)
}

/// `head` with its subprotocol header lines replaced by one naming `subprotocol`.
fn with_protocol(head: &str, subprotocol: &str) -> String {
    let mut out = String::with_capacity(head.len());
    let mut written = false;
    for line in head.split_inclusive("\r\n") {
        if header_value(line, PROTOCOL_HEADER).is_none() {
            out.push_str(line);
        } else if !written {
            out.push_str(&format!("Sec-WebSocket-Protocol: {subprotocol}\r\n"));
            written = true;
        }
    }
    out
}

/// The value of a header line named `name` (case-insensitive, as HTTP says).
fn header_value<'a>(line: &'a str, name: &str) -> Option<&'a str> {
    let (key, value) = line.split_once(':')?;
    key.trim().eq_ignore_ascii_case(name).then(|| value.trim())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request(protocols: &[&str]) -> String {
        let mut head = String::from(
            "GET / HTTP/1.1\r\nHost: 127.0.0.1:8765\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
             Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n",
        );
        for p in protocols {
            head.push_str(&format!("Sec-WebSocket-Protocol: {p}\r\n"));
        }
        head + "\r\n"
    }

    #[test]
    fn a_legacy_only_client_is_asked_for_as_sdk_v1() {
        let rewritten = for_inner_server(&request(&["foxglove.websocket.v1"])).unwrap();
        assert_eq!(
            rewritten,
            request(&["foxglove.sdk.v1"]),
            "only the subprotocol line changes"
        );
        // Among unknown names, in either header form and letter case.
        let rewritten = for_inner_server(
            &request(&["x.y, foxglove.websocket.v1"])
                .replace("Sec-WebSocket-Protocol", "sec-websocket-protocol"),
        )
        .unwrap();
        assert!(rewritten.contains("\r\nSec-WebSocket-Protocol: foxglove.sdk.v1\r\n"));
        let two_lines = for_inner_server(&request(&["x.y", "foxglove.websocket.v1"])).unwrap();
        assert_eq!(two_lines.matches("foxglove.sdk.v1").count(), 1);
        assert!(!two_lines.contains("x.y"));
    }

    #[test]
    fn clients_the_crate_serves_itself_or_refuses_pass_unchanged() {
        for protocols in [
            &["foxglove.sdk.v1.1, foxglove.websocket.v1"][..],
            &["foxglove.websocket.v1", "foxglove.sdk.v1"],
            &["foxglove.sdk.v1"],
            &["foxglove.websocket.v2"],
            &["foxglove.websocket.v1.1"],
            &[],
        ] {
            assert_eq!(for_inner_server(&request(protocols)), None, "{protocols:?}");
        }
    }

    #[test]
    fn the_reply_names_the_legacy_subprotocol() {
        let reply = "HTTP/1.1 101 Switching Protocols\r\nconnection: Upgrade\r\nupgrade: websocket\r\n\
                     sec-websocket-accept: s3pPLMBiTxaQ9kYGzzhZRbK+xOo=\r\n\
                     sec-websocket-protocol: foxglove.sdk.v1\r\n\r\n";
        assert_eq!(
            for_legacy_client(reply),
            reply.replace(
                "sec-websocket-protocol: foxglove.sdk.v1",
                "Sec-WebSocket-Protocol: foxglove.websocket.v1"
            )
        );
    }

    /// A stand-in inner server that replies to one handshake with the subprotocol it was asked
    /// for, then echoes: the front must hand the legacy client its own name and relay the bytes.
    #[test]
    fn the_front_relays_a_legacy_handshake_and_the_bytes_after_it() {
        let inner = TcpListener::bind("127.0.0.1:0").unwrap();
        let inner_addr = inner.local_addr().unwrap();
        let echo = thread::spawn(move || {
            let (stream, _) = inner.accept().unwrap();
            let (head, _) = read_head(&stream).unwrap();
            let head = String::from_utf8(head).unwrap();
            let asked = head
                .split("\r\n")
                .find_map(|l| header_value(l, PROTOCOL_HEADER))
                .unwrap()
                .to_owned();
            (&stream)
                .write_all(
                    format!("HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: {asked}\r\n\r\nhello")
                        .as_bytes(),
                )
                .unwrap();
            // Ends when the front closes the connection after the client left.
            let _ = io::copy(&mut &stream, &mut &stream);
            asked
        });
        let front = Front::bind("127.0.0.1", 0, inner_addr).unwrap();
        let client = TcpStream::connect(("127.0.0.1", front.port().unwrap())).unwrap();
        (&client)
            .write_all(request(&["foxglove.websocket.v1"]).as_bytes())
            .unwrap();
        // The connection waits in the listener's queue until the loop polls.
        client
            .set_read_timeout(Some(Duration::from_millis(20)))
            .unwrap();
        let mut reply = Vec::new();
        let mut chunk = [0u8; 256];
        while !reply.ends_with(b"hello") {
            front.accept_waiting();
            match (&client).read(&mut chunk) {
                Ok(0) => panic!("closed: {}", String::from_utf8_lossy(&reply)),
                Ok(n) => reply.extend_from_slice(&chunk[..n]),
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {}
                Err(e) => panic!("{e}"),
            }
        }
        assert_eq!(
            String::from_utf8(reply).unwrap(),
            "HTTP/1.1 101 Switching Protocols\r\nSec-WebSocket-Protocol: foxglove.websocket.v1\r\n\r\nhello"
        );
        (&client).write_all(b"frame bytes").unwrap();
        let mut echoed = [0u8; 11];
        client.set_read_timeout(None).unwrap();
        (&client).read_exact(&mut echoed).unwrap();
        assert_eq!(&echoed, b"frame bytes");
        client.shutdown(Shutdown::Both).unwrap();
        assert_eq!(echo.join().unwrap(), "foxglove.sdk.v1");
    }
}
