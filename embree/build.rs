//! Build script of the Embree cross-check: finds or provisions Intel Embree 4 (see the
//! `embree` section) and hands its library directory to the packages that link it.

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    let target = std::env::var("TARGET").unwrap_or_default();
    embree::configure(&target);
}

/// Finding Intel Embree 4 for the `embree` feature.
///
/// `embree4-sys` only emits `rustc-link-lib=embree4`, with no search path. This section finds a
/// directory holding `libembree4.so`, in this order:
///
/// 1. `EMBREE_DIR` (its `lib`, `lib64` or itself; an error if none holds the library),
/// 2. `pkg-config embree4`,
/// 3. the standard system library directories,
/// 4. on x86_64 Linux: the official Embree 4.4 release library (with oneTBB) bundled in the
///    PyPI wheel `embreex`, pinned by version and sha256, fetched with `pip download --no-deps`
///    into `OUT_DIR/embree4` (once per profile; `EMBREE_NO_DOWNLOAD` forbids it).
///
/// It then adds the directory to the link search path and, unless it is a system directory,
/// to the rpath of every target of this package (tests, benchmarks) and, through the `rpath`
/// metadata of `links = "tolray_embree"`, of the `tolray` command (cli/build.rs), so that
/// `cargo test`, `cargo run` and the built binary run with no environment variable; `$ORIGIN`
/// and `$ORIGIN/../lib` come first in that rpath, so a copy of the binary finds the libraries
/// that `scripts/bundle-embree.sh` puts beside it or in its `../lib`. When nothing
/// works, the build fails with one message listing the fixes.
mod embree {
    use std::env;
    use std::path::{Path, PathBuf};
    use std::process::Command;

    /// The pinned wheel: Intel's Embree 4.4.0 release binary and oneTBB 2021.12.
    const WHEEL_REQUIREMENT: &str = "embreex==4.4.0.post1 \
        --hash=sha256:2cd0f7d5c6342e6247e31f700761689cae7829454d8c6de0c41e62124a023e1f";

    const SYSTEM_DIRS: [&str; 6] = [
        "/usr/local/lib",
        "/usr/local/lib64",
        "/usr/lib/x86_64-linux-gnu",
        "/usr/lib64",
        "/usr/lib",
        "/opt/embree4/lib",
    ];

    pub fn configure(target: &str) {
        for v in [
            "EMBREE_DIR",
            "EMBREE_NO_DOWNLOAD",
            "PKG_CONFIG_PATH",
            "PYTHON",
        ] {
            println!("cargo:rerun-if-env-changed={v}");
        }
        let mut tried = Vec::new();
        let found = find(target, &mut tried);
        let (dir, via) = match found {
            Ok(x) => x,
            Err(why) => fail(&tried, &why),
        };
        if let Some(dir) = &dir {
            println!("cargo:rustc-link-search=native={}", dir.display());
            if !SYSTEM_DIRS.iter().any(|s| Path::new(s) == dir.as_path()) {
                // First the binary's own directory and ../lib, so that an installed copy is
                // relocatable (scripts/bundle-embree.sh copies the libraries there), then the
                // directory found, so that the build tree runs as it is.
                println!("cargo:rustc-link-arg=-Wl,-rpath,$ORIGIN:$ORIGIN/../lib");
                println!("cargo:rustc-link-arg=-Wl,-rpath,{}", dir.display());
                // For the packages that depend on this one (`DEP_TOLRAY_EMBREE_RPATH`): a
                // build script's link arguments reach only its own package's targets.
                println!("cargo:rpath=$ORIGIN:$ORIGIN/../lib:{}", dir.display());
            }
        }
        let shown = dir
            .as_ref()
            .map_or(String::new(), |d| d.display().to_string());
        println!("cargo:rustc-env=EMBREE4_LIB_DIR={shown}");
        println!("cargo:rustc-env=EMBREE4_FOUND_VIA={via}");
    }

    /// The library directory (None: the linker's default path) and how it was found.
    fn find(
        target: &str,
        tried: &mut Vec<String>,
    ) -> Result<(Option<PathBuf>, &'static str), String> {
        if let Some(root) = env::var_os("EMBREE_DIR") {
            let root = PathBuf::from(root);
            return [root.join("lib"), root.join("lib64"), root.clone()]
                .into_iter()
                .find(|d| d.join("libembree4.so").exists())
                .map(|d| (Some(d), "EMBREE_DIR"))
                .ok_or_else(|| {
                    format!(
                        "EMBREE_DIR={} holds no libembree4.so in lib/, lib64/ or itself",
                        root.display()
                    )
                });
        }
        tried.push("EMBREE_DIR: not set".into());
        match pkg_config_dir() {
            Ok(d) => return Ok((d, "pkg-config")),
            Err(e) => tried.push(format!("pkg-config embree4: {e}")),
        }
        if let Some(d) = SYSTEM_DIRS
            .iter()
            .map(PathBuf::from)
            .find(|d| d.join("libembree4.so").exists())
        {
            return Ok((Some(d), "system"));
        }
        tried.push(format!("no libembree4.so in {}", SYSTEM_DIRS.join(", ")));
        if !(target.starts_with("x86_64") && target.contains("linux")) {
            return Err(format!(
                "no bundled Embree for target {target} (the PyPI wheel is x86_64 Linux only)"
            ));
        }
        let out = PathBuf::from(env::var_os("OUT_DIR").ok_or("OUT_DIR is not set")?);
        provision(&out).map(|d| (Some(d), "pypi-embreex"))
    }

    /// `pkg-config --libs-only-L embree4`: its `-L` directory, or None for the default path.
    fn pkg_config_dir() -> Result<Option<PathBuf>, String> {
        let out = Command::new("pkg-config")
            .args(["--libs-only-L", "embree4"])
            .output()
            .map_err(|e| format!("cannot run pkg-config ({e})"))?;
        if !out.status.success() {
            return Err("not found".into());
        }
        let text = String::from_utf8_lossy(&out.stdout);
        Ok(text
            .split_whitespace()
            .find_map(|w| w.strip_prefix("-L"))
            .map(PathBuf::from))
    }

    /// Fetches the pinned `embreex` wheel and unpacks its bundled libraries (`embreex.libs/*`)
    /// into `out/embree4`, with a `libembree4.so` link to the versioned library. Reuses an
    /// earlier result.
    fn provision(out: &Path) -> Result<PathBuf, String> {
        let dest = out.join("embree4");
        if dest.join("libembree4.so").exists() {
            return Ok(dest);
        }
        if env::var_os("EMBREE_NO_DOWNLOAD").is_some() {
            return Err("EMBREE_NO_DOWNLOAD is set, so the PyPI wheel was not fetched".into());
        }
        let python = env::var("PYTHON").unwrap_or_else(|_| "python3".into());
        let wheel_dir = out.join("wheel");
        let req = out.join("embree-requirements.txt");
        std::fs::write(&req, format!("{WHEEL_REQUIREMENT}\n"))
            .map_err(|e| format!("cannot write {}: {e}", req.display()))?;
        let status = Command::new(&python)
            .args(["-m", "pip", "download", "--no-deps", "--only-binary=:all:"])
            .args(["--require-hashes", "--platform", "manylinux_2_28_x86_64"])
            .args(["--python-version", "3.11", "--implementation", "cp"])
            .args(["--abi", "cp311", "-q", "-d"])
            .arg(&wheel_dir)
            .arg("-r")
            .arg(&req)
            .status()
            .map_err(|e| format!("cannot run `{python} -m pip` ({e})"))?;
        if !status.success() {
            return Err(format!(
                "`{python} -m pip download embreex==4.4.0.post1` failed ({status})"
            ));
        }
        let wheel = std::fs::read_dir(&wheel_dir)
            .map_err(|e| format!("{}: {e}", wheel_dir.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .find(|p| p.extension().is_some_and(|x| x == "whl"))
            .ok_or("pip reported success but left no wheel")?;
        let tmp = out.join("embree4.tmp");
        let _ = std::fs::remove_dir_all(&tmp);
        // Python's zipfile unpacks the wheel: no unzip tool or zip crate needed.
        let script = "import sys, zipfile, os\n\
            z = zipfile.ZipFile(sys.argv[1]); d = sys.argv[2]; os.makedirs(d)\n\
            for n in z.namelist():\n\
            \x20   b = os.path.basename(n)\n\
            \x20   if b and (n.startswith('embreex.libs/') or b.startswith('LICENSE')):\n\
            \x20       open(os.path.join(d, b), 'wb').write(z.read(n))\n";
        let status = Command::new(&python)
            .args(["-c", script])
            .arg(&wheel)
            .arg(&tmp)
            .status()
            .map_err(|e| format!("cannot run {python} to unpack the wheel ({e})"))?;
        if !status.success() {
            return Err(format!("unpacking {} failed", wheel.display()));
        }
        let lib = std::fs::read_dir(&tmp)
            .map_err(|e| format!("{}: {e}", tmp.display()))?
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .find(|n| n.starts_with("libembree4") && n.contains(".so"))
            .ok_or("the wheel holds no libembree4 library")?;
        std::os::unix::fs::symlink(&lib, tmp.join("libembree4.so"))
            .map_err(|e| format!("cannot link libembree4.so -> {lib}: {e}"))?;
        let _ = std::fs::remove_dir_all(&dest);
        std::fs::rename(&tmp, &dest).map_err(|e| format!("{}: {e}", dest.display()))?;
        let _ = std::fs::remove_dir_all(&wheel_dir);
        Ok(dest)
    }

    fn fail(tried: &[String], why: &str) -> ! {
        let mut msg = String::from(
            "\nlibembree4 (Intel Embree 4) not found, and the `embree` feature needs it.\n",
        );
        for t in tried {
            msg += &format!("  tried: {t}\n");
        }
        msg += &format!("  failed: {why}\n");
        msg += "Fix one of:\n\
            \x20 1. set EMBREE_DIR to an Embree 4 install (holding lib/libembree4.so), or make\n\
            \x20    `pkg-config embree4` find it;\n\
            \x20 2. let the build fetch it: needs python3 with pip and access to PyPI (unset\n\
            \x20    EMBREE_NO_DOWNLOAD; PYTHON selects the interpreter);\n\
            \x20 3. build without the feature: `cargo build` (the default) needs only Rust.\n\
            (The embree4-sys build also needs libclang: apt-get install libclang1-14\n\
            libclang-common-14-dev.)\n";
        panic!("{msg}");
    }
}
