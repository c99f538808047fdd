//! The bridge's one wait. zenoh delivers on its own threads; iceoryx2's ports live on the main
//! thread. Every zenoh handler here is zenoh's default FIFO channel whose callback also writes a
//! byte to a socket ([`Wake`]), and the main thread's waitset watches that socket beside the
//! local services' wake-up events and its next deadline: the bridge sleeps until something
//! arrives on either side instead of looking every few milliseconds.

use std::io::{ErrorKind, Read, Write};
use std::os::unix::net::UnixStream;
use std::sync::Arc;

use sonar_common::ipc::WatchedFd;
use zenoh::handlers::{Callback, FifoChannel, FifoChannelHandler, IntoHandler};

/// The reading end, which the main thread watches and drains.
#[derive(Debug)]
pub struct Wake {
    woken: UnixStream,
    poke: Poke,
}

/// The writing end, shared by zenoh's callbacks.
#[derive(Debug, Clone)]
pub struct Poke(Arc<UnixStream>);

impl Wake {
    pub fn new() -> std::io::Result<Self> {
        let (woken, poke) = UnixStream::pair()?;
        // Neither end blocks: a full socket already wakes the reader, so a poke can be dropped.
        woken.set_nonblocking(true)?;
        poke.set_nonblocking(true)?;
        Ok(Self {
            woken,
            poke: Poke(Arc::new(poke)),
        })
    }

    pub fn poke(&self) -> Poke {
        self.poke.clone()
    }

    /// What a waitset attaches; `None` if the socket has no descriptor (it always has).
    pub fn watched(&self) -> Option<WatchedFd> {
        WatchedFd::new(&self.woken)
    }

    /// Forgets the pokes so far: the caller then takes everything the handlers hold.
    pub fn drain(&self) {
        let mut bytes = [0u8; 256];
        loop {
            match (&self.woken).read(&mut bytes) {
                Ok(n) if n > 0 => continue,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                _ => break,
            }
        }
    }
}

impl Poke {
    pub fn poke(&self) {
        // WouldBlock: the socket is full, the reader will wake anyway.
        let _ = (&*self.0).write(&[1]);
    }
}

/// zenoh's default handler (a FIFO channel read with `try_recv`), whose every delivery pokes.
pub fn waking_fifo<T: Send + 'static>(poke: &Poke) -> (Callback<T>, FifoChannelHandler<T>) {
    let (deliver, handler) = FifoChannel::default().into_handler();
    let poke = poke.clone();
    let callback = Callback::from(move |item: T| {
        deliver.call(item);
        poke.poke();
    });
    (callback, handler)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A delivery lands in the handler and leaves a byte on the socket; draining takes it.
    #[test]
    fn a_delivery_is_kept_and_pokes() {
        let wake = Wake::new().unwrap();
        let (callback, handler) = waking_fifo::<u32>(&wake.poke());
        callback.call(7);
        let mut byte = [0u8; 1];
        assert_eq!((&wake.woken).read(&mut byte).unwrap(), 1);
        callback.call(8);
        wake.drain();
        assert_eq!(
            (&wake.woken).read(&mut byte).unwrap_err().kind(),
            ErrorKind::WouldBlock
        );
        assert_eq!(handler.try_recv().unwrap(), Some(7));
        assert_eq!(handler.try_recv().unwrap(), Some(8));
    }
}
