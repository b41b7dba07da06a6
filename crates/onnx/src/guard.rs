//! Bounded memory while the engine plans or runs a user's ONNX file.
//!
//! A file of a few hundred bytes can declare a tensor of gigabytes (a `ConstantOfShape` of
//! 100,000 x 100,000 floats): the engine folds such constants while it plans the network and
//! would allocate and fill 40 GB before any check of ours could see the shape. Two guards
//! bound it:
//!
//! - [`CappedAlloc`], the system allocator refusing, on a thread inside [`capped`], any single
//!   allocation larger than [`MAX_ALLOCATION_BYTES`]. A binary installs it with
//!   `#[global_allocator]` (the `fishprobe` CLI and the Python module do); without it only
//!   allocations the machine cannot satisfy fail.
//! - [`capped`] catches the engine's panic when an allocation fails (the engine asserts that
//!   its tensor allocations succeed) and returns it as an error, without printing the panic.

// An allocator is unsafe by its trait; every method forwards to `System` or returns null.
#![allow(unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::{Cell, RefCell};
use std::panic::AssertUnwindSafe;

/// Largest single allocation while an ONNX file is planned or run: 1 GiB, twice the largest
/// file accepted ([`crate::MAX_FILE_BYTES`]), so a network's weights always fit, and far
/// beyond any tensor of fishprobe's contracts (a batch of 4,096 views of the ConvNet fish is
/// 26 MB).
pub const MAX_ALLOCATION_BYTES: usize = 1 << 30;

thread_local! {
    /// This thread's cap on a single allocation (`usize::MAX`: none).
    static CAP: Cell<usize> = const { Cell::new(usize::MAX) };
    /// Inside [`capped`]: a panic's message is kept here instead of printed.
    static CAUGHT: RefCell<Option<String>> = const { RefCell::new(None) };
}

/// The system allocator, refusing (returning null) any single allocation larger than the
/// cap of the thread asking, inside `capped`; everywhere else exactly [`System`].
pub struct CappedAlloc;

fn over_cap(size: usize) -> bool {
    // `try_with`: during a thread's teardown the cap is gone, and nothing is capped.
    CAP.try_with(|c| size > c.get()).unwrap_or(false)
}

// SAFETY: every call is forwarded to `System` unchanged, or answered with null, which the
// `GlobalAlloc` contract allows for any request.
unsafe impl GlobalAlloc for CappedAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if over_cap(layout.size()) {
            return std::ptr::null_mut();
        }
        // SAFETY: the caller's contract, forwarded.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if over_cap(layout.size()) {
            return std::ptr::null_mut();
        }
        // SAFETY: the caller's contract, forwarded.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: the caller's contract, forwarded.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if over_cap(new_size) {
            return std::ptr::null_mut();
        }
        // SAFETY: the caller's contract, forwarded.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// Runs `f` with this thread's single allocations capped at [`MAX_ALLOCATION_BYTES`] (when
/// [`CappedAlloc`] is installed); a panic inside `f` (the engine's, when an allocation fails)
/// becomes `Err` with its message and is not printed.
pub(crate) fn capped<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        let earlier = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let kept = CAUGHT
                .try_with(|c| match c.try_borrow_mut() {
                    Ok(mut slot) if slot.is_some() => {
                        *slot = Some(panic_text(info.payload()));
                        true
                    }
                    _ => false,
                })
                .unwrap_or(false);
            if !kept {
                earlier(info);
            }
        }));
    });
    let cap_before = CAP.with(|c| c.replace(MAX_ALLOCATION_BYTES));
    // `Some("")` marks this thread as catching; nested calls keep the outer mark.
    let outer = CAUGHT.with(|c| c.borrow_mut().replace(String::new()));
    let result = std::panic::catch_unwind(AssertUnwindSafe(f));
    let message = CAUGHT.with(|c| std::mem::replace(&mut *c.borrow_mut(), outer));
    CAP.with(|c| c.set(cap_before));
    result.map_err(|payload| match message {
        Some(m) if !m.is_empty() => m,
        _ => panic_text(&*payload),
    })
}

fn panic_text(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| (*s).to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "the engine stopped (a panic without a message)".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_allocation_over_the_cap_fails_inside_and_succeeds_outside() {
        // The lib's test binary installs CappedAlloc (lib.rs).
        let big = MAX_ALLOCATION_BYTES + 1;
        // black_box: the optimiser may otherwise elide an allocation that is never used.
        let try_big = || {
            let mut v: Vec<u8> = Vec::new();
            let granted = v.try_reserve_exact(std::hint::black_box(big)).is_ok();
            std::hint::black_box(&v);
            granted
        };
        assert!(
            !capped(try_big).unwrap(),
            "an allocation over the cap was granted inside `capped`"
        );
        // Inside, allocations up to the cap work; outside, nothing is capped (1 GiB + 1 of
        // address space is reserved, not touched).
        assert_eq!(capped(|| vec![0u8; 1 << 20].len()).unwrap(), 1 << 20);
        assert!(try_big(), "an allocation was capped outside `capped`");
    }

    #[test]
    fn a_panic_inside_becomes_an_error_with_its_message() {
        let e = capped(|| -> u32 { panic!("failed to allocate 80000000000 bytes") }).unwrap_err();
        assert_eq!(e, "failed to allocate 80000000000 bytes");
        // The thread is usable afterwards, with no cap left behind.
        assert_eq!(CAP.with(Cell::get), usize::MAX);
    }
}
