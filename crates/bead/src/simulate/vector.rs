//! Which vector instructions the lanes' loop ([`super::lanes`]) and a run's batched checks
//! ([`super::express`]) run in: the same Rust compiled once per instruction set and chosen
//! at run time by what the CPU has. Every compilation performs the same operations in the
//! same order, so all give the same bits: AVX-512F enables FMA too, but nothing here calls
//! `mul_add` and Rust never contracts a multiply and an add, nor uses approximate
//! reciprocals; they differ in how many lanes one instruction takes.

/// An instruction set the lanes' code is compiled for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum VectorSet {
    /// The target's baseline (SSE2 on x86-64: 2 lanes an instruction)
    Baseline,
    /// AVX2 (4 lanes)
    #[cfg(target_arch = "x86_64")]
    Avx2,
    /// AVX-512F (8 lanes; AVX2 as well)
    #[cfg(target_arch = "x86_64")]
    Avx512,
}

impl VectorSet {
    /// The widest set this CPU runs (in tests, the one [`with_vector_set`] asks for).
    pub(crate) fn best() -> VectorSet {
        #[cfg(test)]
        if let Some(set) = ASKED.with(std::cell::Cell::get) {
            return set;
        }
        let wider: &[VectorSet] = &[
            #[cfg(target_arch = "x86_64")]
            VectorSet::Avx512,
            #[cfg(target_arch = "x86_64")]
            VectorSet::Avx2,
        ];
        (wider.iter().copied().find(|set| set.runs_here())).unwrap_or(VectorSet::Baseline)
    }

    /// This set, or AVX2 where it is wider: for code that runs in short bursts between
    /// scalar code (a run's batched checks), where AVX-512 measured slower than AVX2.
    pub(crate) fn at_most_avx2(self) -> VectorSet {
        match self {
            #[cfg(target_arch = "x86_64")]
            VectorSet::Avx512 => VectorSet::Avx2,
            set => set,
        }
    }

    /// Whether this CPU runs this set.
    pub(crate) fn runs_here(self) -> bool {
        match self {
            VectorSet::Baseline => true,
            #[cfg(target_arch = "x86_64")]
            VectorSet::Avx2 => std::arch::is_x86_feature_detected!("avx2"),
            #[cfg(target_arch = "x86_64")]
            VectorSet::Avx512 => std::arch::is_x86_feature_detected!("avx512f"),
        }
    }

    /// Every set this CPU runs, narrowest first (the tests run each).
    #[cfg(test)]
    pub(crate) fn available() -> Vec<VectorSet> {
        let all: &[VectorSet] = &[
            VectorSet::Baseline,
            #[cfg(target_arch = "x86_64")]
            VectorSet::Avx2,
            #[cfg(target_arch = "x86_64")]
            VectorSet::Avx512,
        ];
        all.iter().copied().filter(|set| set.runs_here()).collect()
    }
}

#[cfg(test)]
thread_local! {
    static ASKED: std::cell::Cell<Option<VectorSet>> = const { std::cell::Cell::new(None) };
}

/// `f()` with `set` taken for [`VectorSet::best`] on this thread (to test each set).
#[cfg(test)]
pub(crate) fn with_vector_set<R>(set: VectorSet, f: impl FnOnce() -> R) -> R {
    struct Restore(Option<VectorSet>);
    impl Drop for Restore {
        fn drop(&mut self) {
            ASKED.with(|a| a.set(self.0));
        }
    }
    let _restore = Restore(ASKED.with(|a| a.replace(Some(set))));
    f()
}

/// `fn $name(...) -> T` calling `$body(...)` compiled for the set asked (see
/// [`VectorSet`]): `$name(set, args...)`; a set the CPU lacks runs the baseline.
macro_rules! compiled_per_vector_set {
    ($(#[$doc:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) -> $ret:ty = $body:ident) => {
        $(#[$doc])*
        $vis fn $name(set: $crate::simulate::vector::VectorSet, $($arg: $ty),*) -> $ret {
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx2")]
            fn avx2($($arg: $ty),*) -> $ret {
                $body($($arg),*)
            }
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx512f")]
            fn avx512($($arg: $ty),*) -> $ret {
                $body($($arg),*)
            }
            use $crate::simulate::vector::VectorSet;
            // A set this CPU lacks falls back to the baseline (the same bits), so that the
            // unsafe calls below only ever run on a CPU with their instructions.
            match if set.runs_here() { set } else { VectorSet::Baseline } {
                VectorSet::Baseline => $body($($arg),*),
                // SAFETY: this CPU has AVX2 (`runs_here` above).
                #[cfg(target_arch = "x86_64")]
                #[allow(unsafe_code)]
                VectorSet::Avx2 => unsafe { avx2($($arg),*) },
                // SAFETY: this CPU has AVX-512F (`runs_here` above).
                #[cfg(target_arch = "x86_64")]
                #[allow(unsafe_code)]
                VectorSet::Avx512 => unsafe { avx512($($arg),*) },
            }
        }
    };
}
pub(crate) use compiled_per_vector_set;
