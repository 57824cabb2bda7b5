//! Decoded windows of a repository's surface shared between cold tiles: the tiles of one
//! group (the 4 × 4 mesh tiles of a level under one key) read one window decoded over all
//! their blocks, decoded once however many requests ask for it at the same time (single
//! flight: the others wait for it), and kept within a memory bound, the oldest first out.
//! Inside a window the samples are those of the whole decode, so a tile read from a larger
//! window is the same bytes.

use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

use crate::bounded::Bounded;
use crate::surface::Surface;

/// Bytes of decoded windows a tiler keeps by default (`cbdam serve --tile-cache`).
pub const WINDOW_CACHE_BYTES: usize = 256 << 20;

/// A group's window: level, group x, group y, and the first level index decoded.
pub type WindowKey = (u8, u32, u32, usize);

/// A window being decoded: every request for it waits on the one decode.
type InFlight<V> = Arc<OnceLock<Result<Arc<V>, String>>>;

/// The windows (by default [`Surface`]s) decoded for a tiler's cold tiles.
#[derive(Debug)]
pub struct SharedWindows<V = Surface> {
    held: Bounded<WindowKey, V>,
    making: Mutex<HashMap<WindowKey, InFlight<V>>>,
    decodes: AtomicUsize,
}

impl<V> SharedWindows<V> {
    /// Holding at most `limit` bytes of decoded samples (0: none kept, each decode still
    /// shared by the requests waiting on it).
    pub fn new(limit: usize) -> SharedWindows<V> {
        SharedWindows {
            held: Bounded::new(limit),
            making: Mutex::new(HashMap::new()),
            decodes: AtomicUsize::new(0),
        }
    }

    /// The window of `key`: the one held, the one another request is decoding (waited for),
    /// or decoded by `decode` now (the window and its bytes).
    pub fn get_or_decode(
        &self,
        key: WindowKey,
        decode: impl FnOnce() -> Result<(V, usize), String>,
    ) -> Result<Arc<V>, String> {
        if let Some(held) = self.held.get(&key) {
            return Ok(held);
        }
        let flight = {
            let mut making = self.making.lock().unwrap_or_else(|e| e.into_inner());
            // Decoded and held since the look above: no second decode.
            if let Some(held) = self.held.get(&key) {
                return Ok(held);
            }
            Arc::clone(making.entry(key).or_default())
        };
        let result = flight
            .get_or_init(|| {
                self.decodes.fetch_add(1, Ordering::Relaxed);
                let (window, bytes) = decode()?;
                Ok(self.held.insert(key, Arc::new(window), bytes))
            })
            .clone();
        let mut making = self.making.lock().unwrap_or_else(|e| e.into_inner());
        if making.get(&key).is_some_and(|f| Arc::ptr_eq(f, &flight)) {
            making.remove(&key);
        }
        result
    }

    /// How many windows were decoded (each decode counted once, however many waited on it).
    pub fn decodes(&self) -> usize {
        self.decodes.load(Ordering::Relaxed)
    }

    /// Bytes of windows held.
    pub fn bytes(&self) -> usize {
        self.held.bytes()
    }

    /// Drops every window held.
    pub fn clear(&self) {
        self.held.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Barrier;
    use std::time::Duration;

    #[test]
    fn requests_at_once_for_one_window_decode_it_once() {
        let windows: SharedWindows<u32> = SharedWindows::new(1 << 10);
        let start = Barrier::new(8);
        std::thread::scope(|s| {
            for _ in 0..8 {
                s.spawn(|| {
                    start.wait();
                    let got = windows.get_or_decode((3, 1, 2, 0), || {
                        // Long enough for every thread to ask while it is being decoded.
                        std::thread::sleep(Duration::from_millis(200));
                        Ok((7, 4))
                    });
                    assert_eq!(got.as_deref(), Ok(&7));
                });
            }
        });
        assert_eq!(windows.decodes(), 1);
        assert_eq!(windows.bytes(), 4);
        // Held: asked again, not decoded again.
        let again = windows.get_or_decode((3, 1, 2, 0), || Ok((8, 4)));
        assert_eq!((again.as_deref(), windows.decodes()), (Ok(&7), 1));
    }

    #[test]
    fn a_failed_decode_is_told_and_tried_again_and_the_bound_holds() {
        let windows: SharedWindows<u32> = SharedWindows::new(10);
        let failed = windows.get_or_decode((1, 0, 0, 0), || Err("damaged".to_string()));
        assert_eq!(failed, Err("damaged".to_string()));
        let retried = windows.get_or_decode((1, 0, 0, 0), || Ok((5, 6)));
        assert_eq!((retried.as_deref(), windows.decodes()), (Ok(&5), 2));
        // 6 + 6 bytes pass the bound of 10: the oldest goes.
        windows.get_or_decode((1, 1, 0, 0), || Ok((6, 6))).unwrap();
        assert_eq!(windows.bytes(), 6);
        let third = windows.get_or_decode((1, 0, 0, 0), || Ok((9, 6)));
        assert_eq!((third.as_deref(), windows.decodes()), (Ok(&9), 4));
        windows.clear();
        assert_eq!(windows.bytes(), 0);
    }
}
