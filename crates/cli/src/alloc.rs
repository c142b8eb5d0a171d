//! The binary's allocator: jemalloc, configured for training's allocation pattern, behind a
//! counter of bytes and calls (read by `prism bench iteration` to measure what an iteration
//! allocates).

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

// SAFETY: every call is forwarded unchanged to jemalloc, which upholds `GlobalAlloc`'s contract.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count(layout.size());
        unsafe { tikv_jemallocator::Jemalloc.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count(layout.size());
        unsafe { tikv_jemallocator::Jemalloc.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { tikv_jemallocator::Jemalloc.dealloc(ptr, layout) }
    }

    /// Counted as an allocation of the new size (a growing reallocation may copy).
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count(new_size);
        unsafe { tikv_jemallocator::Jemalloc.realloc(ptr, layout, new_size) }
    }
}
