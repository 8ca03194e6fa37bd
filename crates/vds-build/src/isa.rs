//! The instruction set the build's hot kernels run in, chosen at run time.
//!
//! Release binaries target the x86-64 baseline (SSE2), which every x86-64 CPU runs. The
//! build's arithmetic kernels (a leaf's attributes, a node's merge of its children, an octree
//! split) are also compiled a second time for AVX2 with BMI1/2, LZCNT and POPCNT (x86-64-v3
//! without FMA), and [`Isa::detect`] picks that copy when the CPU has those extensions. The
//! copy's gain is the three-operand VEX encoding: the kernels are scalar `f64` arithmetic, in
//! which two-operand SSE2 spends many instructions copying registers. (Compiling the whole
//! workspace for x86-64-v3 made a 10 M-triangle build 10 % faster, but binaries built so
//! refuse older CPUs; this keeps them portable.)
//!
//! Both copies compute bit-identical results, so `.vdt` files do not depend on the CPU: Rust
//! never fuses a multiply and an add unless asked (`mul_add`), the wide copy is compiled
//! without the `fma` extension besides, so no instruction can round differently, and Rust does
//! not let LLVM reorder floating-point operations. A unit test builds trees both ways.

/// Which compilation of the kernels to run: the baseline, or the wide one, which only
/// [`Isa::detect`] can choose (the field is private to this module), after checking that this
/// CPU runs it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Isa {
    wide: bool,
}

impl Isa {
    /// The x86-64 baseline (and every other architecture).
    #[cfg_attr(not(test), allow(dead_code))]
    pub(crate) const BASELINE: Isa = Isa { wide: false };

    /// The widest instruction set this CPU runs.
    pub(crate) fn detect() -> Isa {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("bmi1")
                && std::arch::is_x86_feature_detected!("bmi2")
                && std::arch::is_x86_feature_detected!("lzcnt")
                && std::arch::is_x86_feature_detected!("popcnt")
            {
                return Isa { wide: true };
            }
        }
        Isa::BASELINE
    }

    /// True when the wide kernels run: this CPU has every extension they are compiled for.
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    pub(crate) fn is_wide(self) -> bool {
        self.wide
    }
}

/// `fn $dispatch(args…) -> R = $kernel;` defines `$dispatch(isa, args…)`, which runs the kernel
/// function `$kernel(args…)` compiled
/// for `isa`. The kernel must be `#[inline(always)]`: its wide copy is made by inlining it
/// into a function with the wide target features (code inlined into a function is compiled
/// with that function's features), and anything it leaves as a call runs as baseline code,
/// which is slower but computes the same.
macro_rules! dispatched {
    ($(#[$doc:meta])* $vis:vis fn $dispatch:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)? = $kernel:path;) => {
        $(#[$doc])*
        #[inline]
        $vis fn $dispatch(isa: $crate::isa::Isa, $($arg: $ty),*) $(-> $ret)? {
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx2,bmi1,bmi2,lzcnt,popcnt")]
            fn wide($($arg: $ty),*) $(-> $ret)? {
                $kernel($($arg),*)
            }
            #[cfg(target_arch = "x86_64")]
            if isa.is_wide() {
                #[allow(unsafe_code)]
                // SAFETY: `is_wide` holds only when `Isa::detect` found every extension
                // `wide` is compiled for on this CPU, so the CPU executes its instructions:
                // the one requirement of calling a `target_feature` function.
                return unsafe { wide($($arg),*) };
            }
            let _ = isa;
            $kernel($($arg),*)
        }
    };
}
pub(crate) use dispatched;
