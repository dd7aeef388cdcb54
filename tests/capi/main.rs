//! The C ABI: the committed header matches the Rust exports, its version macros match
//! Cargo.toml, and C and C++ programs compiled against it (with the `cc` crate) and linked to
//! both the staticlib and the cdylib agree with the Rust API and survive every error path.

use std::path::{Path, PathBuf};
use std::process::Command;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

mod calls;
#[allow(unused_imports)]
use calls::*;

/// The header cbindgen generates from src/ffi with cbindgen.toml.
fn generated_header() -> String {
    let config =
        cbindgen::Config::from_file(Path::new(ROOT).join("cbindgen.toml")).expect("cbindgen.toml");
    let mut out = Vec::new();
    cbindgen::Builder::new()
        .with_config(config)
        .with_src(Path::new(ROOT).join("src/ffi/mod.rs"))
        .generate()
        .expect("cbindgen generates the header")
        .write(&mut out);
    String::from_utf8(out).expect("UTF-8 header")
}

#[test]
fn header_is_generated_from_the_rust_exports() {
    let path = Path::new(ROOT).join("include/tolray.h");
    let fresh = generated_header();
    if std::env::var_os("TOLRAY_BLESS").is_some() {
        std::fs::write(&path, &fresh).expect("write include/tolray.h");
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        committed == fresh,
        "include/tolray.h differs from what cbindgen generates from src/ffi; regenerate it with \
         TOLRAY_BLESS=1 cargo test --release --test capi header"
    );
}

#[test]
fn version_macros_match_cargo_toml() {
    let header = std::fs::read_to_string(Path::new(ROOT).join("include/tolray.h")).unwrap();
    let define = |name: &str| -> String {
        let line = header
            .lines()
            .find(|l| l.starts_with(&format!("#define {name} ")))
            .unwrap_or_else(|| panic!("tolray.h has no {name}"));
        line.split_whitespace()
            .nth(2)
            .unwrap()
            .trim_matches('"')
            .to_string()
    };
    assert_eq!(
        define("TOLRAY_VERSION_MAJOR"),
        env!("CARGO_PKG_VERSION_MAJOR")
    );
    assert_eq!(
        define("TOLRAY_VERSION_MINOR"),
        env!("CARGO_PKG_VERSION_MINOR")
    );
    assert_eq!(
        define("TOLRAY_VERSION_PATCH"),
        env!("CARGO_PKG_VERSION_PATCH")
    );
    assert_eq!(define("TOLRAY_VERSION_STRING"), env!("CARGO_PKG_VERSION"));
    let v = unsafe { std::ffi::CStr::from_ptr(tolray::ffi::tolray_version()) };
    assert_eq!(v.to_str().unwrap(), env!("CARGO_PKG_VERSION"));
}

/// Where cargo put libtolray.a and libtolray.so for this test run: next to the test binary
/// (target/<profile>/deps) or one level up.
fn lib_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let deps = exe.parent().unwrap().to_path_buf();
    for dir in [deps.clone(), deps.parent().unwrap().to_path_buf()] {
        if dir.join("libtolray.a").exists() && dir.join("libtolray.so").exists() {
            return dir;
        }
    }
    panic!(
        "libtolray.a / libtolray.so not found near {}",
        deps.display()
    );
}

/// A directory holding `libtolray.so.3` (the SONAME a program linked against the build's
/// library records, as an installed library is named) and `libtolray.so`, both links to the
/// build's library.
fn soname_dir() -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("solib");
    std::fs::create_dir_all(&dir).unwrap();
    let target = lib_dir().join("libtolray.so");
    let soname = format!("libtolray.so.{}", tolray::ffi::TOLRAY_ABI_VERSION);
    for name in ["libtolray.so", soname.as_str()] {
        let link = dir.join(name);
        if std::fs::read_link(&link).ok().as_deref() != Some(target.as_path()) {
            // Tests run in parallel: write the link under a private name, then rename it over.
            let tmp = dir.join(format!("{name}.{:?}", std::thread::current().id()));
            let _ = std::fs::remove_file(&tmp);
            std::os::unix::fs::symlink(&target, &tmp).unwrap();
            std::fs::rename(&tmp, &link).unwrap();
        }
    }
    dir
}

/// The dynamic-section entries of an ELF file of `tag` (`SONAME`, `NEEDED`), by `readelf -d`.
fn elf_dynamic(path: &Path, tag: &str) -> Vec<String> {
    let out = Command::new("readelf")
        .arg("-d")
        .arg(path)
        .output()
        .expect("readelf (binutils, which the C compiler needs) runs");
    assert!(out.status.success(), "readelf -d {}", path.display());
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter(|l| l.contains(&format!("({tag})")))
        .filter_map(|l| Some(l.split('[').nth(1)?.trim_end_matches(']').to_string()))
        .collect()
}

/// The shared library's SONAME is `libtolray.so.<ABI version>` (issue 15): programs record it,
/// and the installed library carries that name with `libtolray.so` linking to it.
#[test]
fn the_shared_library_is_named_by_its_abi_version() {
    let soname = format!("libtolray.so.{}", tolray::ffi::TOLRAY_ABI_VERSION);
    assert_eq!(
        elf_dynamic(&lib_dir().join("libtolray.so"), "SONAME"),
        std::slice::from_ref(&soname)
    );
    let exe = build("capi_test.c", Link::Dynamic, "-soname");
    assert!(
        elf_dynamic(&exe, "NEEDED").contains(&soname),
        "{:?}",
        elf_dynamic(&exe, "NEEDED")
    );
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Link {
    Static,
    Dynamic,
}

/// Compiles `source` (C or C++) against include/tolray.h, links it to the library and returns
/// the executable's path.
fn build(source: &str, link: Link, tag: &str) -> PathBuf {
    let cpp = source.ends_with(".cpp");
    let target = env!("TOLRAY_TARGET");
    let mut cmd = cc::Build::new()
        .cpp(cpp)
        .target(target)
        .host(target)
        .opt_level(1)
        .cargo_metadata(false)
        .warnings(true)
        .extra_warnings(true)
        .get_compiler()
        .to_command();
    let name = format!(
        "{}-{}{tag}",
        Path::new(source).file_stem().unwrap().to_string_lossy(),
        if link == Link::Static {
            "static"
        } else {
            "dynamic"
        }
    );
    let exe = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let lib = lib_dir();
    cmd.arg(if cpp { "-std=c++17" } else { "-std=c11" })
        .args(["-Werror", "-pedantic"])
        .arg("-I")
        .arg(Path::new(ROOT).join("include"))
        .arg(Path::new(ROOT).join("tests/c").join(source))
        .arg("-o")
        .arg(&exe);
    match link {
        Link::Static => {
            cmd.arg(lib.join("libtolray.a"));
            cmd.args([
                "-lgcc_s",
                "-lutil",
                "-lrt",
                "-lpthread",
                "-lm",
                "-ldl",
                "-lc",
            ]);
        }
        Link::Dynamic => {
            let lib = soname_dir();
            cmd.arg(format!("-L{}", lib.display()))
                .arg("-ltolray")
                .arg(format!("-Wl,-rpath,{}", lib.display()))
                .arg("-lm");
        }
    }
    let out = cmd.output().expect("run the C compiler");
    assert!(
        out.status.success(),
        "compiling {source} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    exe
}

/// Runs a built program and returns its RESULT lines as key -> numbers.
fn run(exe: &Path) -> std::collections::HashMap<String, Vec<f64>> {
    // A program just written may still be open for writing in a child that another test
    // thread forked meanwhile (ETXTBSY = 26 on Linux, "Text file busy"): try again shortly.
    let mut tries = 0;
    let out = loop {
        match Command::new(exe).env_remove("LD_LIBRARY_PATH").output() {
            Err(e) if e.raw_os_error() == Some(26) && tries < 50 => {
                tries += 1;
                std::thread::sleep(std::time::Duration::from_millis(100));
            }
            r => break r.unwrap(),
        }
    };
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{} failed:\n{stdout}\n{}",
        exe.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
        .lines()
        .filter_map(|l| l.strip_prefix("RESULT "))
        .map(|l| {
            let mut it = l.split_whitespace();
            let key = it.next().unwrap().to_string();
            (key, it.filter_map(|v| v.parse().ok()).collect())
        })
        .collect()
}

mod rust_side {
    //! The same numbers from the Rust API.
    use tolray::analysis::spot::{spot_diagram, SpotOptions};
    use tolray::lens::{Lens, Param, System};
    use tolray::math::Vec3;
    use tolray::optim::{gradient, PsfLoss, SpotLoss, SpotMeasure};
    use tolray::psf::PsfOptions;
    use tolray::tolerance::ToleranceSpec;
    use tolray::trace::{trace, Bundles, Field, Pupil, PupilPattern, RayBatch, TraceOptions};

    pub const D: f64 = 587.5618;
    pub const RGB: [f64; 3] = [486.1327, 587.5618, 656.2725];

    pub fn triplet() -> Lens {
        Lens::load("cooke-triplet").unwrap()
    }

    pub fn spot_rms(fraction: f64, wavelengths: &[f64]) -> f64 {
        let lens = triplet();
        let opts = SpotOptions {
            fields: vec![Field::fraction(fraction)],
            wavelengths_nm: wavelengths.to_vec(),
            pupil: Pupil::grid(32),
            trace: TraceOptions::default(),
        };
        let r = spot_diagram(&lens, &lens.compile(), &opts).unwrap();
        r.last().unwrap().stats.rms_um
    }

    /// The perturbed lens of the C program (default spec, seed 7, pattern 3).
    pub fn perturbed() -> (Lens, tolray::lens::Adjustments, System<f64>) {
        let lens = triplet();
        let p = ToleranceSpec::default().sample(&lens, 7, 3).unwrap();
        let (pl, adj) = p.apply(&lens).unwrap();
        let sys = System::compile(&pl, &adj, &|_, v| v);
        (pl, adj, sys)
    }

    /// The C program's fan, traced through the perturbed lens: per ray x y z dx dy dz opl status.
    pub fn fan() -> Vec<[f64; 8]> {
        let (_, _, sys) = perturbed();
        let mut b = RayBatch::<f64>::new();
        for i in 0..9 {
            b.push(
                Vec3::new(0.3, -16.0 + 4.0 * i as f64, -5.0),
                Vec3::new(0.0, 0.02, 1.0),
            );
        }
        trace(&sys, D, &mut b, TraceOptions::default());
        b.iter()
            .map(|r| {
                [
                    r.o.x,
                    r.o.y,
                    r.o.z,
                    r.d.x,
                    r.d.y,
                    r.d.z,
                    r.opl,
                    r.status.code() as f64,
                ]
            })
            .collect()
    }

    pub fn vars() -> [Param; 3] {
        [Param::Curvature(0), Param::Curvature(3), Param::Gap(2)]
    }

    /// Spot loss and gradient (mean measure, fields 0 and 0.7, d line, 8x8 grid).
    pub fn spot_loss(perturbed_lens: bool) -> (f64, Vec<f64>) {
        let lens = triplet();
        let fields = [Field::fraction(0.0), Field::fraction(0.7)];
        let bundles = Bundles::new(&lens, &fields, &[D], &Pupil::grid(8)).unwrap();
        let obj = SpotLoss {
            bundles,
            measure: SpotMeasure::Mean,
            trace: TraceOptions::default(),
        };
        let (l, adj) = if perturbed_lens {
            let (l, adj, _) = perturbed();
            (l, adj)
        } else {
            let n = lens.surfaces.len();
            (lens.clone(), tolray::lens::Adjustments::none(n))
        };
        gradient::<_, 8>(&obj, &l, &adj, &vars()).unwrap()
    }

    /// PSF loss and its derivative by the first curvature (15 px, 2048 random rays, seed 0).
    pub fn psf_loss() -> (f64, Vec<f64>) {
        let lens = triplet();
        let mut opts = PsfOptions::for_lens(&lens);
        opts.ks = 15;
        opts.pupil.pattern = PupilPattern::Random { n: 2048, seed: 0 };
        let loss = PsfLoss {
            rays: Bundles::pairs(&lens, &[(Field::fraction(0.7), D)], &opts.pupil).unwrap(),
            opts,
            trace: TraceOptions::default(),
        };
        let (l, adj, _) = perturbed();
        gradient::<_, 8>(&loss, &l, &adj, &vars()[..1]).unwrap()
    }
}

fn assert_close(what: &str, c: &[f64], rust: &[f64]) {
    assert_eq!(c.len(), rust.len(), "{what}: lengths differ");
    for (i, (a, b)) in c.iter().zip(rust).enumerate() {
        let tol = 1e-12 * b.abs().max(1e-9);
        assert!(
            (a - b).abs() <= tol,
            "{what}[{i}]: C gives {a:e}, Rust gives {b:e}"
        );
    }
}

fn check_c_program(link: Link) {
    let got = run(&build("capi_test.c", link, ""));
    let lens = rust_side::triplet();
    let para = lens.paraxial(rust_side::D).unwrap();
    assert_close("efl_mm", &got["efl_mm"], &[para.efl_mm.unwrap()]);
    assert_close(
        "num_surfaces",
        &got["num_surfaces"],
        &[lens.surfaces.len() as f64],
    );
    assert_close(
        "spot field 0",
        &got["spot_rms_um_field0"],
        &[rust_side::spot_rms(0.0, &[rust_side::D])],
    );
    assert_close(
        "spot field 0.7",
        &got["spot_rms_um_field1"],
        &[rust_side::spot_rms(0.7, &[rust_side::D])],
    );
    assert_close(
        "polychromatic spot",
        &got["spot_rms_um_poly"],
        &[rust_side::spot_rms(0.7, &rust_side::RGB)],
    );
    let fan = rust_side::fan();
    assert!(fan.iter().any(|r| r[7] == 0.0) && fan.iter().any(|r| r[7] != 0.0));
    for (i, r) in fan.iter().enumerate() {
        assert_close(&format!("trace{i}"), &got[&format!("trace{i}")], r);
    }
    let (loss, grad) = rust_side::spot_loss(true);
    assert_close("spot_loss", &got["spot_loss"], &[loss]);
    assert_close("spot_grad", &got["spot_grad"], &grad);
    assert!((got["psf_sum"][0] - 1.0).abs() < 1e-12, "PSF sums to 1");
    assert!(got["psf_peak"][0] > 0.0 && got["psf_peak"][0] < 1.0);
    let (ploss, pgrad) = rust_side::psf_loss();
    assert_close("psf_loss", &got["psf_loss"], &[ploss, pgrad[0]]);
}

#[test]
fn c_program_with_the_staticlib_matches_the_rust_api() {
    check_c_program(Link::Static);
}

#[test]
fn c_program_with_the_cdylib_matches_the_rust_api() {
    check_c_program(Link::Dynamic);
}

fn check_cpp_program(link: Link) {
    let got = run(&build("capi_test.cpp", link, ""));
    assert_close(
        "spot field 0",
        &got["spot_rms_um_field0"],
        &[rust_side::spot_rms(0.0, &[rust_side::D])],
    );
    assert_close(
        "spot field 0.7",
        &got["spot_rms_um_field1"],
        &[rust_side::spot_rms(0.7, &[rust_side::D])],
    );
    let (loss, grad) = rust_side::spot_loss(false);
    assert_close("nominal_spot_loss", &got["nominal_spot_loss"], &[loss]);
    assert_close("nominal_spot_grad", &got["nominal_spot_grad"], &grad);
}

#[test]
fn cpp_program_with_the_staticlib_matches_the_rust_api() {
    check_cpp_program(Link::Static);
}

#[test]
fn cpp_program_with_the_cdylib_matches_the_rust_api() {
    check_cpp_program(Link::Dynamic);
}

/// The C program, error paths included, under valgrind's memcheck: no invalid read or write,
/// no use of uninitialized memory, no definite leak. Skipped (with a note) when valgrind is not
/// installed, unless TOLRAY_REQUIRE_VALGRIND is set (as CI does).
#[test]
fn c_program_runs_clean_under_valgrind() {
    let have = Command::new("valgrind").arg("--version").output().is_ok();
    if !have {
        assert!(
            std::env::var_os("TOLRAY_REQUIRE_VALGRIND").is_none(),
            "valgrind is required (TOLRAY_REQUIRE_VALGRIND is set) but not installed"
        );
        eprintln!("valgrind not installed: skipping the memcheck run");
        return;
    }
    let exe = build("capi_test.c", Link::Dynamic, "-valgrind");
    let out = Command::new("valgrind")
        .args([
            "--error-exitcode=99",
            "--leak-check=full",
            "--errors-for-leak-kinds=definite",
            "--show-leak-kinds=definite",
            "--quiet",
        ])
        .arg(&exe)
        .env_remove("LD_LIBRARY_PATH")
        .env("RAYON_NUM_THREADS", "2")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "valgrind found errors (exit {:?}):\n{}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// scripts/install-c.sh installs the header, both libraries, the pkg-config files and the CMake
/// package; examples/c builds with pkg-config (shared and static) and examples/cpp with CMake's
/// find_package. CMake is optional unless TOLRAY_REQUIRE_CMAKE is set (as CI does). The prefix
/// has a space in its name (issue 15: the pkg-config output broke there).
#[test]
fn install_script_serves_pkg_config_and_cmake_users() {
    let tmp = Path::new(env!("CARGO_TARGET_TMPDIR")).join("c-install");
    let _ = std::fs::remove_dir_all(&tmp);
    let prefix = tmp.join("my prefix");
    let ok = |cmd: &mut Command, what: &str| {
        let out = cmd.env_remove("LD_LIBRARY_PATH").output().unwrap();
        assert!(
            out.status.success(),
            "{what} failed:\n{}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    ok(
        Command::new("bash")
            .arg(Path::new(ROOT).join("scripts/install-c.sh"))
            .arg(&prefix)
            .arg(lib_dir())
            .env_remove("TOLRAY_KEEP_DEBUG"),
        "install-c.sh",
    );
    // The shared library is installed under its SONAME, with the linker's name linking to it.
    let soname = format!("libtolray.so.{}", tolray::ffi::TOLRAY_ABI_VERSION);
    assert_eq!(
        std::fs::read_link(prefix.join("lib/libtolray.so")).unwrap(),
        Path::new(&soname)
    );
    assert_eq!(
        elf_dynamic(&prefix.join("lib").join(&soname), "SONAME"),
        std::slice::from_ref(&soname)
    );
    // The installed libraries are stripped of debug information (the build's carry it: the
    // release profile keeps line tables), so they are much smaller than the build's.
    if Command::new("strip").arg("--version").output().is_ok() {
        for f in ["libtolray.so", "libtolray.a"] {
            let built = std::fs::metadata(lib_dir().join(f)).unwrap().len();
            let installed = std::fs::metadata(prefix.join("lib").join(f)).unwrap().len();
            assert!(
                installed < built / 2,
                "{f}: installed {installed} bytes, built {built}"
            );
        }
    }
    let pc = prefix.join("lib/pkgconfig");
    let ex = tmp.join("c");
    std::fs::create_dir_all(&ex).unwrap();
    for f in ["spot.c", "Makefile"] {
        std::fs::copy(Path::new(ROOT).join("examples/c").join(f), ex.join(f)).unwrap();
    }
    for static_link in [false, true] {
        let mut make = Command::new("make");
        make.arg("-B").current_dir(&ex).env("PKG_CONFIG_PATH", &pc);
        if static_link {
            make.arg("STATIC=1");
        }
        ok(&mut make, "make examples/c");
        if !static_link {
            assert!(elf_dynamic(&ex.join("spot"), "NEEDED").contains(&soname));
        }
        let out = ok(&mut Command::new(ex.join("spot")), "examples/c/spot");
        assert!(
            out.contains("cooke-triplet") && out.lines().count() == 7,
            "{out}"
        );
    }
    if Command::new("cmake").arg("--version").output().is_err() {
        assert!(
            std::env::var_os("TOLRAY_REQUIRE_CMAKE").is_none(),
            "cmake is required (TOLRAY_REQUIRE_CMAKE is set) but not installed"
        );
        eprintln!("cmake not installed: skipping the CMake example");
        return;
    }
    let build = tmp.join("cpp-build");
    ok(
        Command::new("cmake")
            .arg("-S")
            .arg(Path::new(ROOT).join("examples/cpp"))
            .arg("-B")
            .arg(&build)
            .arg(format!("-DCMAKE_PREFIX_PATH={}", prefix.display())),
        "cmake configure",
    );
    ok(
        Command::new("cmake").arg("--build").arg(&build),
        "cmake build",
    );
    let out = ok(&mut Command::new(build.join("spot")), "examples/cpp/spot");
    assert!(out.starts_with("RMS spot"), "{out}");
}

/// The nominal system of `lens` (a live handle), asserting success; free it with
/// `tolray_system_free`.
///
/// # Safety
/// `lens` is a live lens handle.
unsafe fn nominal_system(lens: *const tolray::ffi::tolray_lens) -> *mut tolray::ffi::tolray_system {
    let mut sys = std::ptr::null_mut();
    assert_eq!(
        tolray::ffi::tolray_system_new(lens, std::ptr::null(), &mut sys),
        tolray::ffi::tolray_status::TOLRAY_OK
    );
    sys
}
