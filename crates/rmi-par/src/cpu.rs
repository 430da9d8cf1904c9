//! Runtime CPU-feature dispatch for the solver's hot loops.
//!
//! The crate is built for baseline x86-64 so that the Python wheel runs on any x86-64 CPU.
//! The loops that dominate a step (neighbour lists, pressure passes, densities, viscosity,
//! the implicit solve's operator rows and set-up, the skeleton's rotations and stresses) run
//! through [`hot`], which on CPUs with AVX2 and FMA (x86-64-v3: Intel Haswell and AMD
//! Excavator/Zen onwards) executes a copy compiled for those features: wider registers and
//! three-operand instructions (measured in docs/benchmark-history.md, "CPU dispatch,
//! fluid-pair densities, empty-cell skip for walls"). A closure reaches that copy
//! only when every closure between it and [`hot`] is inlined: a non-inlined adapter leaves
//! the loop body compiled for the baseline CPU without any error or warning.
//!
//! Results are bit-identical either way: Rust never contracts `a * b + c` into a fused
//! multiply-add nor reorders floating-point sums on its own, so only the instruction
//! encoding changes, not the arithmetic. The engine's test `crates/rmi-sph/tests/dispatch.rs` checks
//! this on a sponge with pore water and on a water column with explicit viscosity.

use std::sync::atomic::{AtomicU8, Ordering};

/// 0: not yet detected, 1: baseline, 2: AVX2 + FMA.
static LEVEL: AtomicU8 = AtomicU8::new(0);

/// Whether [`hot`] runs the AVX2 + FMA copy on this CPU (detected once per process).
#[inline]
pub fn avx2_enabled() -> bool {
    match LEVEL.load(Ordering::Relaxed) {
        0 => {
            let on = detect();
            LEVEL.store(if on { 2 } else { 1 }, Ordering::Relaxed);
            on
        }
        l => l == 2,
    }
}

/// Forces the baseline path (`false`) or re-enables detection (`true`); for tests and for
/// measuring what the dispatch gains (so does the environment variable [`DISABLE_ENV`]).
/// Results do not depend on it.
pub fn set_avx2(allowed: bool) {
    LEVEL.store(if allowed && detect() { 2 } else { 1 }, Ordering::Relaxed);
}

/// Set to a non-empty value to run the baseline copy on any CPU, e.g. to measure the dispatch.
pub const DISABLE_ENV: &str = "RMI_NO_AVX2";

fn detect() -> bool {
    if std::env::var_os(DISABLE_ENV).is_some_and(|v| !v.is_empty()) {
        return false;
    }
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Runs `f`, compiled for AVX2 + FMA when the CPU has them.
///
/// `f` must be inlined into the dispatched copy to benefit: pass closures marked
/// `#[inline(always)]` and keep the per-element functions they call `#[inline]`. Call it
/// once per parallel chunk, not per element.
#[inline(always)]
pub fn hot<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    {
        if avx2_enabled() {
            // SAFETY: the CPU supports the features the copy is compiled for (detected above).
            return unsafe { with_avx2(f) };
        }
    }
    f()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx,avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
unsafe fn with_avx2<R>(f: impl FnOnce() -> R) -> R {
    f()
}
