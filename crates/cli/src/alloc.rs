//! The binary's allocator: jemalloc, configured for training's allocation pattern, behind a
//! counter of bytes and calls (read by `prism bench iteration` to measure what an iteration
//! allocates).
//!
//! An allocation the system cannot hold ends the process with a clean error and exit status 1
//! instead of Rust's abort or the kernel's OOM kill: one the allocator refuses, and one of
//! [`LARGE`] bytes or more that exceeds the memory available (jemalloc maps with
//! `MAP_NORESERVE` where the kernel overcommits, so such a request would succeed and the process
//! be killed when it touches the pages). Every command estimates its peak memory first and
//! refuses above what is available, so this is reached when `--allow-memory` overrode that
//! estimate (or the estimate was low). Nothing in Prism relies on a failed allocation returning
//! (no `try_reserve`); a library that did would end the same way.

use std::alloc::{GlobalAlloc, Layout};
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};

/// jemalloc with two relaxed counters (a few nanoseconds per call; a training iteration makes
/// thousands of allocations of kilobytes to megabytes).
pub struct Counting;

static BYTES: AtomicU64 = AtomicU64::new(0);
static CALLS: AtomicU64 = AtomicU64::new(0);

/// Bytes and allocations (allocation, zeroed allocation or reallocation) since start-up.
#[derive(Clone, Copy, Debug, Default)]
pub struct Allocated {
    pub bytes: u64,
    pub calls: u64,
}

/// The counters now.
pub fn allocated() -> Allocated {
    Allocated {
        bytes: BYTES.load(Relaxed),
        calls: CALLS.load(Relaxed),
    }
}

#[inline]
fn count(size: usize) {
    BYTES.fetch_add(size as u64, Relaxed);
    CALLS.fetch_add(1, Relaxed);
}

/// A writer into a fixed stack buffer (formatting the refusal must not allocate).
struct StackText {
    buf: [u8; 320],
    len: usize,
}

impl std::fmt::Write for StackText {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        let n = s.len().min(self.buf.len() - self.len);
        self.buf[self.len..self.len + n].copy_from_slice(&s.as_bytes()[..n]);
        self.len += n;
        Ok(())
    }
}

/// Requests from this size on are compared with the memory available (reading
/// `/proc/meminfo`, a few microseconds, is nothing beside filling a gigabyte).
const LARGE: usize = 1 << 30;

/// End the process cleanly when `size` bytes cannot be held (see the module docs).
#[inline]
fn check(size: usize) {
    if size >= LARGE && prism_domain::memory::exceeds_available(size as u64).is_some() {
        refused(size);
    }
}

/// The system refused `size` bytes: say so on stderr and end the process with status 1.
#[cold]
fn refused(size: usize) -> ! {
    use std::fmt::Write as _;
    let mut text = StackText {
        buf: [0; 320],
        len: 0,
    };
    let gb = size as f64 / 1e9;
    let _ = writeln!(
        text,
        "error: out of memory: {size} bytes ({gb:.2} GB) asked at once, more than the system \
         can give; the work is larger than this machine can hold (without --allow-memory the \
         command's estimate refuses such runs before they start: see --dry-run)"
    );
    let _ = std::io::Write::write_all(&mut std::io::stderr(), &text.buf[..text.len]);
    std::process::exit(1)
}

// SAFETY: every call is forwarded unchanged to jemalloc, which upholds `GlobalAlloc`'s contract;
// a null result (refused) does not return.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count(layout.size());
        check(layout.size());
        let p = unsafe { tikv_jemallocator::Jemalloc.alloc(layout) };
        if p.is_null() {
            refused(layout.size());
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count(layout.size());
        check(layout.size());
        let p = unsafe { tikv_jemallocator::Jemalloc.alloc_zeroed(layout) };
        if p.is_null() {
            refused(layout.size());
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { tikv_jemallocator::Jemalloc.dealloc(ptr, layout) }
    }

    /// Counted as an allocation of the new size (a growing reallocation may copy).
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count(new_size);
        check(new_size);
        let p = unsafe { tikv_jemallocator::Jemalloc.realloc(ptr, layout, new_size) };
        if p.is_null() {
            refused(new_size);
        }
        p
    }
}
