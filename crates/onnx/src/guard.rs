//! Bounded memory while the engine plans or runs a user's ONNX file.
//!
//! A file of a few hundred bytes can declare a tensor of gigabytes (a `ConstantOfShape` of
//! 100,000 x 100,000 floats), or many tensors of tens of megabytes each (`Tile`s of small
//! initializers): the engine folds such constants while it plans the network and would allocate and
//! fill them before any check of ours could see a shape. Two guards bound it:
//!
//! - [`CappedAlloc`], the system allocator that, on a thread inside [`capped`], counts the
//!   bytes the thread holds and refuses (returns null for) an allocation that would take them
//!   past the file's memory bound ([`MemoryBound`]), or any single allocation larger than
//!   [`MAX_ALLOCATION_BYTES`]. A binary installs it with `#[global_allocator]` (the
//!   `fishprobe` CLI and the Python module do); without it only allocations the machine
//!   cannot satisfy fail.
//! - [`capped`] catches the engine's panic when an allocation fails (the engine asserts that
//!   its tensor allocations succeed) and returns it as an error naming the sizes, without
//!   printing the panic.
//!
//! Allocations under [`SMALL_ALLOCATION_BYTES`] are counted but refused only past twice the
//! bound: the engine's tensors (which it checks) are what grows with a hostile file, while a
//! small allocation refused inside the standard library ends the process instead of
//! failing. So the bytes a thread holds inside `capped` never exceed twice the bound, and a
//! file that reaches the bound through its tensors is refused with a message.

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

/// Allocations smaller than this are never refused below twice the bound (see the module).
pub const SMALL_ALLOCATION_BYTES: usize = 64 << 10;

/// The environment variable that sets the memory bound of every ONNX file, in MiB, for a
/// user with a big honest model (it replaces [`MemoryBound::for_file`]'s bound).
pub const MEMORY_ENV: &str = "FISHPROBE_ONNX_MAX_MEMORY_MB";

/// How much memory a thread may hold while the engine plans or runs one ONNX file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MemoryBound {
    /// The bound in bytes.
    pub bytes: usize,
    /// Whether it was set by [`MEMORY_ENV`] (else derived from the file's size).
    pub from_env: bool,
}

impl MemoryBound {
    /// Memory every file gets whatever its size: 256 MiB, room for the engine's planning of
    /// any network of fishprobe's contracts (the ConvNet fish plans in under 30 MB) and for
    /// running a batch of 4,096 rows of a policy with hidden layers of a thousand units.
    pub const BASE_BYTES: usize = 256 << 20;
    /// Memory per byte of the file on top of [`Self::BASE_BYTES`]: the engine keeps its own
    /// copy of every weight (packed for its kernels, perhaps in two layouts) next to the
    /// parsed file, so an honest network needs a few times its file; 16 leaves room.
    pub const PER_FILE_BYTE: usize = 16;
    /// Smallest and largest bound [`MEMORY_ENV`] may set, in MiB.
    pub const ENV_RANGE_MB: (usize, usize) = (16, 1 << 20);

    /// The bound of a file of `file_bytes` bytes: [`MEMORY_ENV`] if set, else
    /// [`Self::BASE_BYTES`] + [`Self::PER_FILE_BYTE`] x the file. A value of the variable that
    /// is not a whole number of MiB in [`Self::ENV_RANGE_MB`] is an error naming it.
    pub fn for_file(file_bytes: usize) -> Result<Self, crate::OnnxError> {
        match std::env::var(MEMORY_ENV) {
            Ok(v) => Self::from_setting(Some(&v), file_bytes),
            Err(std::env::VarError::NotUnicode(_)) => Err(crate::OnnxError::Setting(format!(
                "{MEMORY_ENV} is not valid Unicode"
            ))),
            Err(std::env::VarError::NotPresent) => Self::from_setting(None, file_bytes),
        }
    }

    /// [`Self::for_file`] with the variable's value given (`None`: not set).
    pub fn from_setting(
        setting: Option<&str>,
        file_bytes: usize,
    ) -> Result<Self, crate::OnnxError> {
        let Some(v) = setting else {
            return Ok(Self {
                bytes: Self::BASE_BYTES
                    .saturating_add(Self::PER_FILE_BYTE.saturating_mul(file_bytes)),
                from_env: false,
            });
        };
        let (lo, hi) = Self::ENV_RANGE_MB;
        match v.trim().parse::<usize>() {
            Ok(mb) if (lo..=hi).contains(&mb) => Ok(Self {
                bytes: mb << 20,
                from_env: true,
            }),
            _ => Err(crate::OnnxError::Setting(format!(
                "{MEMORY_ENV} = `{v}`: must be a whole number of MiB in [{lo}, {hi}]"
            ))),
        }
    }

    /// How the bound was set, for messages.
    pub fn describe(&self, file_bytes: usize) -> String {
        if self.from_env {
            format!("{} (set by {MEMORY_ENV})", mib(self.bytes))
        } else {
            format!(
                "{}: {} MiB + {} x the file's {} bytes; set {MEMORY_ENV} to raise it",
                mib(self.bytes),
                Self::BASE_BYTES >> 20,
                Self::PER_FILE_BYTE,
                file_bytes
            )
        }
    }
}

/// `bytes` as MiB with one decimal.
pub(crate) fn mib(bytes: usize) -> String {
    format!("{:.1} MiB", bytes as f64 / f64::from(1u32 << 20))
}

/// What the allocator refused inside [`capped`]: the size asked for and the bytes held then.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Refusal {
    pub asked: usize,
    pub held: isize,
}

thread_local! {
    /// This thread's bound on the bytes it holds inside `capped` (`usize::MAX`: none).
    static BUDGET: Cell<usize> = const { Cell::new(usize::MAX) };
    /// Bytes allocated minus bytes freed by this thread since `capped` began.
    static HELD: Cell<isize> = const { Cell::new(0) };
    /// The first allocation refused inside `capped`.
    static REFUSED: Cell<Option<Refusal>> = const { Cell::new(None) };
    /// Inside [`capped`]: a panic's message is kept here instead of printed.
    static CAUGHT: RefCell<Option<String>> = const { RefCell::new(None) };
}

/// The system allocator, counting and bounding a thread's allocations inside `capped`;
/// everywhere else exactly [`System`].
pub struct CappedAlloc;

/// Whether an allocation of `size` more bytes (`grow`: net growth of a reallocation) may be
/// made; refusals are recorded. Never allocates.
fn admit(size: usize, grow: usize) -> bool {
    // `try_with`: during a thread's teardown the state is gone, and nothing is bounded.
    let budget = BUDGET.try_with(Cell::get).unwrap_or(usize::MAX);
    if budget == usize::MAX {
        return true;
    }
    let held = HELD.try_with(Cell::get).unwrap_or(0);
    let after = held.saturating_add(isize::try_from(grow).unwrap_or(isize::MAX));
    let limit = if size < SMALL_ALLOCATION_BYTES {
        budget.saturating_mul(2)
    } else {
        budget
    };
    let ok = size <= MAX_ALLOCATION_BYTES && after <= isize::try_from(limit).unwrap_or(isize::MAX);
    if !ok {
        let _ = REFUSED.try_with(|r| {
            if r.get().is_none() {
                r.set(Some(Refusal { asked: size, held }));
            }
        });
    }
    ok
}

/// Counts `delta` bytes more (or fewer) held by this thread, inside `capped`.
fn count(delta: isize) {
    if BUDGET.try_with(Cell::get).unwrap_or(usize::MAX) != usize::MAX {
        let _ = HELD.try_with(|h| h.set(h.get().saturating_add(delta)));
    }
}

fn signed(n: usize) -> isize {
    isize::try_from(n).unwrap_or(isize::MAX)
}

// SAFETY: every call is forwarded to `System` unchanged, or answered with null, which the
// `GlobalAlloc` contract allows for any request. The bookkeeping touches only `Cell`s of
// constant-initialised thread-locals, which never allocate.
unsafe impl GlobalAlloc for CappedAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if !admit(layout.size(), layout.size()) {
            return std::ptr::null_mut();
        }
        // SAFETY: the caller's contract, forwarded.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            count(signed(layout.size()));
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if !admit(layout.size(), layout.size()) {
            return std::ptr::null_mut();
        }
        // SAFETY: the caller's contract, forwarded.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            count(signed(layout.size()));
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: the caller's contract, forwarded.
        unsafe { System.dealloc(ptr, layout) };
        count(-signed(layout.size()));
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if !admit(new_size, new_size.saturating_sub(layout.size())) {
            return std::ptr::null_mut();
        }
        // SAFETY: the caller's contract, forwarded.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            count(signed(new_size) - signed(layout.size()));
        }
        p
    }
}

/// Why [`capped`]'s work stopped.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Stopped {
    /// An allocation was refused (the bound or the single-allocation cap), and the engine
    /// stopped on it.
    Memory(Refusal),
    /// The engine panicked for another reason, with this message.
    Panic(String),
}

/// Runs `f` with this thread's memory bounded by `budget` bytes and single allocations capped
/// at [`MAX_ALLOCATION_BYTES`] (when [`CappedAlloc`] is installed); a panic inside `f` (the
/// engine's, when an allocation fails) becomes `Err` and is not printed.
pub(crate) fn capped<T>(budget: usize, f: impl FnOnce() -> T) -> Result<T, Stopped> {
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
    // Nested calls keep the outer bound and count.
    let budget_before = BUDGET.with(|c| c.replace(budget.min(c.get()).min(usize::MAX - 1)));
    let held_before = HELD.with(|h| h.replace(0));
    let refused_before = REFUSED.with(|r| r.replace(None));
    // `Some("")` marks this thread as catching; nested calls keep the outer mark.
    let outer = CAUGHT.with(|c| c.borrow_mut().replace(String::new()));
    let result = std::panic::catch_unwind(AssertUnwindSafe(f));
    let message = CAUGHT.with(|c| std::mem::replace(&mut *c.borrow_mut(), outer));
    let refused = REFUSED.with(|r| r.replace(refused_before));
    let held = HELD.with(|h| h.replace(held_before));
    BUDGET.with(|c| c.set(budget_before));
    if budget_before != usize::MAX {
        count(held);
    }
    result.map_err(|payload| match refused {
        Some(r) => Stopped::Memory(r),
        None => Stopped::Panic(match message {
            Some(m) if !m.is_empty() => m,
            _ => panic_text(&*payload),
        }),
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
            !capped(usize::MAX, try_big).unwrap(),
            "an allocation over the cap was granted inside `capped`"
        );
        // Inside, allocations up to the cap work; outside, nothing is capped (1 GiB + 1 of
        // address space is reserved, not touched).
        assert_eq!(
            capped(2 << 20, || vec![0u8; 1 << 20].len()).unwrap(),
            1 << 20
        );
        assert!(try_big(), "an allocation was capped outside `capped`");
    }

    #[test]
    fn a_panic_inside_becomes_an_error_with_its_message() {
        let e = capped(1 << 30, || -> u32 {
            panic!("failed to allocate 80000000000 bytes")
        })
        .unwrap_err();
        assert_eq!(
            e,
            Stopped::Panic("failed to allocate 80000000000 bytes".into())
        );
        // The thread is usable afterwards, with no bound left behind.
        assert_eq!(BUDGET.with(Cell::get), usize::MAX);
    }

    #[test]
    fn the_bytes_held_inside_are_bounded_in_sum_not_only_one_by_one() {
        // Ten allocations of 4 MiB each, every one far under the single cap, against a bound
        // of 16 MiB: the fifth is refused, and the refusal says what was asked and held.
        let grab = || {
            let mut kept: Vec<Vec<u8>> = Vec::new();
            for _ in 0..10 {
                let mut v: Vec<u8> = Vec::new();
                if v.try_reserve_exact(std::hint::black_box(4 << 20)).is_err() {
                    return (kept.len(), false);
                }
                kept.push(v);
            }
            (kept.len(), true)
        };
        let (n, all) = capped(16 << 20, grab).unwrap();
        assert_eq!(
            (n, all),
            (3, false),
            "held {n} blocks of 4 MiB under 16 MiB"
        );
        // Freed memory is given back: the same work, one block at a time, is never refused.
        let churn = || {
            (0..10).all(|_| {
                let mut v: Vec<u8> = Vec::new();
                let ok = v.try_reserve_exact(std::hint::black_box(4 << 20)).is_ok();
                std::hint::black_box(&v);
                ok
            })
        };
        assert!(capped(16 << 20, churn).unwrap());
        // A refusal that stops the work (the engine's assert) is reported as memory.
        let stop = capped(16 << 20, || {
            let mut v: Vec<u8> = Vec::new();
            assert!(
                v.try_reserve_exact(std::hint::black_box(32 << 20)).is_ok(),
                "failed to allocate"
            );
        })
        .unwrap_err();
        assert!(
            matches!(stop, Stopped::Memory(Refusal { asked, .. }) if asked == 32 << 20),
            "{stop:?}"
        );
    }

    #[test]
    fn the_bound_is_derived_from_the_file_unless_the_variable_sets_it() {
        let b = MemoryBound::from_setting(None, 1000).unwrap();
        assert_eq!(b.bytes, MemoryBound::BASE_BYTES + 16_000);
        assert!(!b.from_env && b.describe(1000).contains(MEMORY_ENV));
        let b = MemoryBound::from_setting(Some(" 4096 "), 1000).unwrap();
        assert_eq!((b.bytes, b.from_env), (4 << 30, true));
        for bad in ["", "1e3", "-1", "15", "1048577", "lots"] {
            let e = MemoryBound::from_setting(Some(bad), 1000)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(MEMORY_ENV) && e.contains("[16, 1048576]"),
                "{bad}: {e}"
            );
        }
    }
}
