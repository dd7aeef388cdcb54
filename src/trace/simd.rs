//! The instruction sets the kernel is compiled for, and the one it runs on.
//!
//! The lane loops of the kernels (`f32`, `f64` and the dual numbers the library differentiates
//! with) and of the ray launch are compiled once per [`Isa`], and the build is chosen when they
//! run: the best the CPU has, or the one the environment variable `TOLRAY_SIMD` (`avx512`, `avx2`
//! or `baseline`) or [`set_active`] forces, so that each path can be tested and measured on one
//! machine. Every build computes the same numbers bit for bit: the
//! kernel uses no fused multiply-add and no approximate instruction, and a lane's arithmetic is
//! the same whatever the vector width.
//!
//! ```
//! use tolray::trace::simd::{self, Isa};
//! let best = Isa::detected();
//! assert!(best.supported());
//! assert!(Isa::Baseline.supported()); // every CPU runs the baseline build
//! assert_eq!(Isa::parse("avx2").unwrap(), Isa::Avx2);
//! println!("tracing with {}", simd::active().name());
//! ```

use crate::{Error, Result};
use std::sync::atomic::{AtomicU8, Ordering};

/// An instruction set the kernel is compiled for, from the widest down.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Isa {
    /// x86-64 AVX-512 (F, VL, BW, DQ, CD) with FMA: 512-bit vectors, a block's 16 `f32` lanes in
    /// one register.
    Avx512,
    /// x86-64 AVX2 with FMA: 256-bit vectors.
    Avx2,
    /// The target's baseline (SSE2 on x86-64), on any CPU. (An SSE 4.2 build was 10-20 % faster
    /// than this one and is not kept: one path fewer to test, and CPUs without AVX2 are over ten
    /// years old.)
    Baseline,
}

impl Isa {
    /// Every build, widest first.
    pub const ALL: [Isa; 3] = [Isa::Avx512, Isa::Avx2, Isa::Baseline];

    /// The name `TOLRAY_SIMD` and [`Isa::parse`] take, and reports print.
    pub fn name(self) -> &'static str {
        match self {
            Isa::Avx512 => "avx512",
            Isa::Avx2 => "avx2",
            Isa::Baseline => "baseline",
        }
    }

    /// The instruction set named `s` (as [`Isa::name`] prints it, any case).
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] for another name.
    pub fn parse(s: &str) -> Result<Isa> {
        let t = s.trim().to_ascii_lowercase();
        Isa::ALL.into_iter().find(|i| i.name() == t).ok_or_else(|| {
            Error::argument(format!(
                "instruction set \"{s}\": expected one of avx512, avx2, baseline"
            ))
        })
    }

    /// Whether this CPU runs the build.
    pub fn supported(self) -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            match self {
                Isa::Avx512 => {
                    has!("avx512f")
                        && has!("avx512vl")
                        && has!("avx512bw")
                        && has!("avx512dq")
                        && has!("avx512cd")
                        && has!("avx2")
                        && has!("fma")
                }
                Isa::Avx2 => has!("avx2") && has!("fma"),
                Isa::Baseline => true,
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            self == Isa::Baseline
        }
    }

    /// The widest build this CPU runs.
    pub fn detected() -> Isa {
        Isa::ALL
            .into_iter()
            .find(|i| i.supported())
            .unwrap_or(Isa::Baseline)
    }

    /// Every build this CPU runs, widest first.
    pub fn available() -> Vec<Isa> {
        Isa::ALL.into_iter().filter(|i| i.supported()).collect()
    }

    fn code(self) -> u8 {
        match self {
            Isa::Avx512 => ISA_AVX512,
            Isa::Avx2 => ISA_AVX2,
            Isa::Baseline => ISA_BASELINE,
        }
    }
}

/// The build in use, 0 until the first trace chooses it.
static ACTIVE: AtomicU8 = AtomicU8::new(0);

/// The instruction set forced by `TOLRAY_SIMD`, if it is set.
///
/// # Errors
/// [`crate::ErrorKind::Argument`] when the variable names no build, or one this CPU does not
/// run (the message names the variable, the value and what the CPU runs).
pub fn from_env() -> Result<Option<Isa>> {
    let Some(v) = std::env::var_os("TOLRAY_SIMD") else {
        return Ok(None);
    };
    let v = v.to_string_lossy();
    let isa =
        Isa::parse(&v).map_err(|e| Error::argument(format!("TOLRAY_SIMD: {}", e.message())))?;
    if !isa.supported() {
        return Err(Error::argument(format!(
            "TOLRAY_SIMD={v}: this CPU does not run the {} build (it runs {})",
            isa.name(),
            names(&Isa::available())
        )));
    }
    Ok(Some(isa))
}

fn names(isas: &[Isa]) -> String {
    isas.iter().map(|i| i.name()).collect::<Vec<_>>().join(", ")
}

/// The build the kernel runs: the one [`set_active`] chose, else `TOLRAY_SIMD`'s when the CPU
/// runs it (a value it cannot use is ignored here; the command line refuses it through
/// [`from_env`]), else [`Isa::detected`].
pub fn active() -> Isa {
    match ACTIVE.load(Ordering::Relaxed) {
        1 => Isa::Avx512,
        2 => Isa::Avx2,
        3 => Isa::Baseline,
        _ => {
            let isa = from_env().ok().flatten().unwrap_or_else(Isa::detected);
            // Another thread may have chosen first; either choice is a supported build.
            let _ = ACTIVE.compare_exchange(0, isa.code(), Ordering::Relaxed, Ordering::Relaxed);
            active()
        }
    }
}

/// Makes every later trace, in every thread, run the `isa` build (results do not change: see the
/// module's documentation).
///
/// ```
/// use tolray::trace::simd::{self, Isa};
/// simd::set_active(Isa::Baseline).unwrap();
/// assert_eq!(simd::active(), Isa::Baseline);
/// simd::set_active(Isa::detected()).unwrap();
/// ```
///
/// # Errors
/// [`crate::ErrorKind::Argument`] when this CPU does not run `isa`.
pub fn set_active(isa: Isa) -> Result<()> {
    if !isa.supported() {
        return Err(Error::argument(format!(
            "instruction set {}: this CPU does not run it (it runs {})",
            isa.name(),
            names(&Isa::available())
        )));
    }
    ACTIVE.store(isa.code(), Ordering::Relaxed);
    Ok(())
}

/// `$item` (a function) with the AVX-512 build's target features.
macro_rules! with_avx512 {
    ($item:item) => {
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx512f,avx512vl,avx512bw,avx512dq,avx512cd,avx2,fma")]
        $item
    };
}
pub(crate) use with_avx512;

/// `$item` (a function) with the AVX2 build's target features.
macro_rules! with_avx2 {
    ($item:item) => {
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,fma")]
        $item
    };
}
pub(crate) use with_avx2;

/// The code of the build a function of [`isa_dispatch`] runs in, its constant `ISA` (see
/// `trace::kernel::lanes_in`): the AVX-512 build.
pub(crate) const ISA_AVX512: u8 = 1;
/// The AVX2 build's code.
pub(crate) const ISA_AVX2: u8 = 2;
/// The baseline build's code.
pub(crate) const ISA_BASELINE: u8 = 3;

/// Defines `$name`, running `$body` (a call of `#[inline(always)]` generic code) compiled for the
/// active [`Isa`]: a function per build with the build's target features, and a dispatcher.
/// Inside `$body`, the constant `ISA` is the build's code ([`ISA_AVX512`], [`ISA_AVX2`],
/// [`ISA_BASELINE`]), for code that calls functions compiled out of line in the same build.
macro_rules! isa_dispatch {
    ($(#[$m:meta])* $vis:vis fn $name:ident $(<$($lt:lifetime),*>)?
        ($($arg:ident : $ty:ty),* $(,)?) $body:block) => {
        $(#[$m])*
        $vis fn $name $(<$($lt),*>)? ($($arg: $ty),*) {
            $crate::trace::simd::with_avx512! {
                fn avx512 $(<$($lt),*>)? ($($arg: $ty),*) {
                    #[allow(dead_code)]
                    const ISA: u8 = $crate::trace::simd::ISA_AVX512;
                    $body
                }
            }
            $crate::trace::simd::with_avx2! {
                fn avx2 $(<$($lt),*>)? ($($arg: $ty),*) {
                    #[allow(dead_code)]
                    const ISA: u8 = $crate::trace::simd::ISA_AVX2;
                    $body
                }
            }
            #[inline(never)]
            fn baseline $(<$($lt),*>)? ($($arg: $ty),*) {
                #[allow(dead_code)]
                const ISA: u8 = $crate::trace::simd::ISA_BASELINE;
                $body
            }
            match $crate::trace::simd::active() {
                // SAFETY: `active` returns only builds the CPU runs (`Isa::supported`).
                #[cfg(target_arch = "x86_64")]
                $crate::trace::simd::Isa::Avx512 => unsafe { avx512($($arg),*) },
                #[cfg(target_arch = "x86_64")]
                $crate::trace::simd::Isa::Avx2 => unsafe { avx2($($arg),*) },
                _ => baseline($($arg),*),
            }
        }
    };
}
pub(crate) use isa_dispatch;
