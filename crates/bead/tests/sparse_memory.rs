//! Nothing of size m x n or m x m on the sparse path (issue 8).
//!
//! Property checked: a chain of 10^4 links (n = 2 10^4 coordinates, m = 10^4 rows) builds
//! its simulation (formulation, J W J^T's pattern, the sparse factorization's symbolic
//! analysis, the integrator, the monitors) and takes steps with rk4, with rattle and with
//! rk4 + projection within a small multiple of its state size, measured as the peak of the
//! bytes this thread holds: below 100 times the state (n positions and n velocities, 320 KB),
//! 32 MB. A dense J alone would be m n 8 bytes = 1.6 GB. (Measured: about 55 times the state
//! for rk4, most of it the compiled constraint tape's scratch slots, twice: the formulation's
//! evaluation and the projections'.)
//!
//! A counting global allocator wraps the system allocator; it counts per thread (the harness
//! runs tests on several threads).

#![allow(unsafe_code)]

mod common;

use std::alloc::{GlobalAlloc, Layout, System as SystemAllocator};
use std::cell::Cell;
use std::sync::Arc;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::simulate::{Simulation, SimulationConfig};

thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static HELD: Cell<isize> = const { Cell::new(0) };
    static PEAK: Cell<isize> = const { Cell::new(0) };
}

fn note(bytes: isize) {
    let _ = COUNTING.try_with(|counting| {
        if counting.get() {
            let _ = HELD.try_with(|held| {
                let now = held.get() + bytes;
                held.set(now);
                let _ = PEAK.try_with(|peak| peak.set(peak.get().max(now)));
            });
        }
    });
}

/// Tracks the bytes held by the threads that have switched counting on, and their peak.
struct PeakAllocator;

// SAFETY: every method forwards to the system allocator with the caller's arguments unchanged;
// the bookkeeping touches only const-initialized thread-local `Cell`s, which neither allocate
// nor unwind.
unsafe impl GlobalAlloc for PeakAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note(layout.size() as isize);
        // SAFETY: forwarded contract of GlobalAlloc::alloc.
        unsafe { SystemAllocator.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note(layout.size() as isize);
        // SAFETY: forwarded contract of GlobalAlloc::alloc_zeroed.
        unsafe { SystemAllocator.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note(new_size as isize - layout.size() as isize);
        // SAFETY: forwarded contract of GlobalAlloc::realloc.
        unsafe { SystemAllocator.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        note(-(layout.size() as isize));
        // SAFETY: forwarded contract of GlobalAlloc::dealloc.
        unsafe { SystemAllocator.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: PeakAllocator = PeakAllocator;

/// The peak of the bytes this thread held above what it held before `f` ran.
fn peak_bytes<R>(f: impl FnOnce() -> R) -> (usize, R) {
    HELD.with(|h| h.set(0));
    PEAK.with(|p| p.set(0));
    COUNTING.with(|c| c.set(true));
    let result = f();
    COUNTING.with(|c| c.set(false));
    (PEAK.with(|p| p.get()).max(0) as usize, result)
}

#[test]
fn the_counter_sees_a_large_buffer() {
    let (peak, v) = peak_bytes(|| std::hint::black_box(vec![0u8; 1 << 20]));
    assert!(peak >= 1 << 20, "{peak}");
    drop(v);
}

#[test]
fn a_chain_of_ten_thousand_links_simulates_in_memory_linear_in_its_size() {
    let links = 10_000;
    let system = Arc::new(common::chain(links));
    let n = system.n_coords();
    let m = system.constraints().n_rows();
    let state_bytes = 2 * n * std::mem::size_of::<f64>();
    let dense_jacobian = m * n * std::mem::size_of::<f64>();
    for (integrator, project) in [
        (IntegratorKind::Rk4, false),
        (IntegratorKind::Rattle, false),
        (IntegratorKind::Rk4, true),
    ] {
        let config = SimulationConfig {
            method: Method::Implicit,
            integrator,
            dt: 1.0 / 120.0,
            project,
            ..Default::default()
        };
        let (peak, steps) = peak_bytes(|| {
            let mut simulation = Simulation::new(system.clone(), config).unwrap();
            for _ in 0..3 {
                simulation.step().unwrap();
            }
            simulation.steps()
        });
        assert_eq!(steps, 3);
        println!(
            "{} links, {}{}: peak {:.1} MB = {:.0} x the state ({} KB); a dense J would be {:.0} MB",
            links,
            integrator.name(),
            if project { " + projection" } else { "" },
            peak as f64 / 1e6,
            peak as f64 / state_bytes as f64,
            state_bytes / 1000,
            dense_jacobian as f64 / 1e6
        );
        assert!(
            peak < 100 * state_bytes,
            "peak {peak} bytes, state {state_bytes} bytes"
        );
    }
}
