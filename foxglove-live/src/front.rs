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
//! Plain threads, two per connection, and at most [`Front::max_clients`] connections at once (a
//! viewer or two, never thousands): nothing async here. A connection over the limit, or one for
//! which no thread can be started (the process's thread limit), is closed at once and counted;
//! such refusals are logged at most once per 10 s with the number left out.

use std::io::{self, Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::thread;
use std::time::{Duration, Instant};

use sonar_common::throttle::Throttle;
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

/// Starts a connection's thread; a test can make it fail as a thread limit would.
type Spawn = fn(Box<dyn FnOnce() + Send>) -> io::Result<()>;

fn spawn_thread(work: Box<dyn FnOnce() + Send>) -> io::Result<()> {
    thread::Builder::new()
        .name("foxglove-client".into())
        .spawn(work)
        .map(drop)
}

/// The public listener and the inner server's address.
#[derive(Debug)]
pub struct Front {
    listener: TcpListener,
    inner: SocketAddr,
    max_clients: usize,
    /// Connections being served now.
    active: Arc<AtomicUsize>,
    /// Connections closed at once: over the limit, or no thread for them.
    refused: u64,
    refused_log: Throttle,
    spawn: Spawn,
}

/// Counts a connection as active until dropped (also when its thread ends by a panic).
struct Active(Arc<AtomicUsize>);

impl Drop for Active {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

impl Front {
    /// Listens on `host:port` for at most `max_clients` clients at once of the inner server at
    /// `inner`.
    pub fn bind(host: &str, port: u16, inner: SocketAddr, max_clients: usize) -> io::Result<Self> {
        let listener = TcpListener::bind((host, port))?;
        // Polled from the main loop, which wakes every few milliseconds anyway.
        listener.set_nonblocking(true)?;
        Ok(Self {
            listener,
            inner,
            max_clients,
            active: Arc::new(AtomicUsize::new(0)),
            refused: 0,
            refused_log: Throttle::new(Duration::from_secs(10)),
            spawn: spawn_thread,
        })
    }

    /// Connections closed at once since the start (over the limit, or no thread for them).
    pub fn refused(&self) -> u64 {
        self.refused
    }

    /// The port clients connect to (the one chosen when bound to port 0).
    pub fn port(&self) -> io::Result<u16> {
        Ok(self.listener.local_addr()?.port())
    }

    /// Hands each waiting connection to a thread of its own, or closes it when the limit is
    /// reached or no thread can be started; returns when none is left.
    pub fn accept_waiting(&mut self) {
        loop {
            match self.listener.accept() {
                Ok((client, peer)) => {
                    if let Err(why) = self.start(client, peer) {
                        self.refused += 1;
                        if let Some(left_out) = self.refused_log.allow(Instant::now()) {
                            warn!(
                                %peer,
                                refused = self.refused,
                                left_out,
                                "connection closed: {why}"
                            );
                        }
                    }
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

impl Front {
    /// Serves `client` on a thread of its own, within the limit.
    fn start(&self, client: TcpStream, peer: SocketAddr) -> Result<(), String> {
        // Only this thread adds to the count, so checking then adding cannot overshoot.
        if self.active.load(Ordering::Acquire) >= self.max_clients {
            return Err(format!(
                "{} clients already (--max-clients)",
                self.max_clients
            ));
        }
        self.active.fetch_add(1, Ordering::AcqRel);
        let active = Active(self.active.clone());
        let inner = self.inner;
        (self.spawn)(Box::new(move || {
            let _active = active;
            match serve(client, inner) {
                Ok(()) => debug!(%peer, "client disconnected"),
                Err(e) => info!(%peer, "client dropped: {e}"),
            }
        }))
        // The closure (with the connection and its count) was dropped with the error.
        .map_err(|e| format!("no thread for it: {e}"))
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
    // No thread (the process's limit): an error for this client, not a panic.
    let upstream = thread::Builder::new()
        .name("foxglove-upstream".into())
        .spawn(move || {
            let _ = io::copy(&mut &upstream_client, &mut &upstream_server);
            close(&upstream_client, &upstream_server);
        })
        .inspect_err(|_| close(&client, &server))?;
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
        let mut front = Front::bind("127.0.0.1", 0, inner_addr, 4).unwrap();
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

    /// Reads until the server closes the connection (true) or `patience` passes (false).
    fn closed_by_server(client: &TcpStream, front: &mut Front, patience: Duration) -> bool {
        client
            .set_read_timeout(Some(Duration::from_millis(20)))
            .unwrap();
        let deadline = Instant::now() + patience;
        let mut chunk = [0u8; 64];
        while Instant::now() < deadline {
            front.accept_waiting();
            match (&*client).read(&mut chunk) {
                Ok(0) => return true,
                Ok(_) => {}
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {}
                Err(e) if e.kind() == io::ErrorKind::TimedOut => {}
                Err(_) => return true,
            }
        }
        false
    }

    #[test]
    fn connections_over_the_limit_are_closed_and_counted() {
        // An inner address nobody serves: clients wait in their handshake, which is enough.
        let inner = TcpListener::bind("127.0.0.1:0").unwrap();
        let mut front = Front::bind("127.0.0.1", 0, inner.local_addr().unwrap(), 2).unwrap();
        let port = front.port().unwrap();
        let connect = || TcpStream::connect(("127.0.0.1", port)).unwrap();
        let (first, second) = (connect(), connect());
        while front.active.load(Ordering::Acquire) < 2 {
            front.accept_waiting();
            thread::sleep(Duration::from_millis(5));
        }
        let third = connect();
        assert!(closed_by_server(
            &third,
            &mut front,
            Duration::from_secs(60)
        ));
        assert_eq!(front.refused(), 1);
        // The first two are still being served (each waits for its handshake).
        for client in [&first, &second] {
            assert!(!closed_by_server(
                client,
                &mut front,
                Duration::from_millis(100)
            ));
        }
        // A client that leaves frees its place.
        drop(first);
        while front.active.load(Ordering::Acquire) > 1 {
            front.accept_waiting();
            thread::sleep(Duration::from_millis(5));
        }
        let fourth = connect();
        assert!(!closed_by_server(
            &fourth,
            &mut front,
            Duration::from_millis(100)
        ));
        assert_eq!(front.refused(), 1);
    }

    #[test]
    fn no_thread_for_a_connection_closes_it_instead_of_panicking() {
        let inner = TcpListener::bind("127.0.0.1:0").unwrap();
        let mut front = Front::bind("127.0.0.1", 0, inner.local_addr().unwrap(), 8).unwrap();
        front.spawn = |_| Err(io::Error::from(io::ErrorKind::WouldBlock));
        let client = TcpStream::connect(("127.0.0.1", front.port().unwrap())).unwrap();
        assert!(closed_by_server(
            &client,
            &mut front,
            Duration::from_secs(60)
        ));
        assert_eq!(front.refused(), 1);
        assert_eq!(
            front.active.load(Ordering::Acquire),
            0,
            "its place is free again"
        );
    }
}
