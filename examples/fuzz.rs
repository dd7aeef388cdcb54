//! A seeded mutation fuzzer over every parser of tolray, running on each accepted input the work
//! a user's command would run next, on stable Rust.
//!
//! ```text
//! cargo run --release --example fuzz -- [--execs 100000] [--seed 1] [--threads 2]
//!     [--target NAME] [--hang-ms 20000] [--findings DIR] [--replay FILE]
//! ```
//!
//! Execution `i` mutates a seed input of one target with a random generator seeded from
//! (`--seed`, `i`) alone, so a run is the same whatever the thread count, and any execution can be
//! replayed from its number. A *finding* is a panic, an execution longer than `--hang-ms`, or a
//! result that reaches the caller non-finite (or otherwise impossible, such as a trace returning
//! fewer rows than it was given); each is written to `--findings` (default `target/fuzz-findings`)
//! as the input bytes, and the run exits 1. Errors are the expected answer to most mutated inputs
//! and are counted, not reported.
//!
//! Targets (the seed inputs are the repository's lens files, the built-in lenses, the Zemax corpus,
//! the test AGF catalog, and inputs written here):
//! - `lens-json`: DeepLens JSON lenses; then validation, paraxial data at the lens' wavelengths, a
//!   spot diagram at three fields, one PSF, and the JSON and .zmx round trips, each read back as
//!   the same lens (media, first-order data and a traced ray fan).
//! - `zmx`: Zemax files (bytes, so UTF-16 files too); then the same work as a lens.
//! - `agf`: AGF glass catalogs; then every glass' index in its range and a singlet made of it.
//! - `spec`, `pattern`: tolerance specs and patterns; then sampling, validation, applying the
//!   pattern to lens1 and its spot diagram; the pattern baked into a prescription traces as the
//!   perturbed lens and survives its JSON and .zmx round trips.
//! - `rays`: `tolray trace` input (CSV or JSON); then the raw trace through lens1.
//! - `flags`: the CLI's value parsers (fields, pupils, objects, materials, decoder kinds); then the
//!   work each value feeds.
//! - `decoder`: `decoder.bin` bytes; then decoding a crop.

#[path = "fuzz/roundtrip.rs"]
mod roundtrip;

use roundtrip::{round_trip, same_lens};
use std::collections::BTreeMap;
use std::panic::{self, AssertUnwindSafe};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tolray::analysis::{spot_diagram, SpotOptions};
use tolray::decoder::{Crop, Decoder, DecoderKind};
use tolray::lens::agf::AgfCatalog;
use tolray::lens::material::{GlassCatalogs, Material};
use tolray::lens::{json, zemax};
use tolray::psf::{psf_of, PsfOptions};
use tolray::tolerance::{Perturbation, ToleranceSpec};
use tolray::trace::{raw, Field, Pupil, PupilPattern, TraceOptions};
use tolray::{Lens, Object};

/// What one execution found: `Err` is a finding (a result that must not reach a caller).
type Verdict = Result<Outcome, String>;

/// How an input ended when nothing was wrong.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Outcome {
    /// A parser or a later step refused it with an error.
    Refused,
    /// Accepted; every result was checked.
    Accepted,
}

struct Target {
    name: &'static str,
    seeds: Vec<Vec<u8>>,
    run: fn(&[u8]) -> Verdict,
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match run(&args) {
        Ok(0) => {}
        Ok(_) => std::process::exit(1),
        Err(e) => {
            eprintln!("fuzz: {e}");
            std::process::exit(2);
        }
    }
}

struct Settings {
    execs: u64,
    seed: u64,
    threads: usize,
    target: Option<String>,
    hang: Duration,
    findings: PathBuf,
    replay: Option<PathBuf>,
}

fn parse_args(args: &[String]) -> Result<Settings, String> {
    let mut s = Settings {
        execs: 100_000,
        seed: 1,
        threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        target: None,
        hang: Duration::from_millis(20_000),
        findings: PathBuf::from("target/fuzz-findings"),
        replay: None,
    };
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut val = |what: &str| {
            it.next()
                .cloned()
                .ok_or_else(|| format!("{a} needs {what}"))
        };
        let num = |v: String| -> Result<u64, String> {
            let x: f64 = v.parse().map_err(|_| format!("{a}: not a number: {v}"))?;
            if !((0.0..=1e15).contains(&x) && x.fract() == 0.0) {
                return Err(format!("{a}: {v} is not a whole number from 0 to 1e15"));
            }
            Ok(x as u64)
        };
        match a.as_str() {
            "--execs" => s.execs = num(val("a count")?)?,
            "--seed" => s.seed = num(val("a seed")?)?,
            "--threads" => s.threads = (num(val("a count")?)? as usize).clamp(1, 256),
            "--target" => s.target = Some(val("a target name")?),
            "--hang-ms" => s.hang = Duration::from_millis(num(val("milliseconds")?)?.max(1)),
            "--findings" => s.findings = PathBuf::from(val("a directory")?),
            "--replay" => s.replay = Some(PathBuf::from(val("a file")?)),
            "-h" | "--help" => {
                return Err(
                    "usage: fuzz [--execs N] [--seed S] [--threads T] [--target NAME] \
                            [--hang-ms MS] [--findings DIR] [--replay FILE --target NAME]"
                        .into(),
                )
            }
            _ => return Err(format!("unknown argument {a}")),
        }
    }
    Ok(s)
}

/// Returns the number of findings.
fn run(args: &[String]) -> Result<usize, String> {
    let s = parse_args(args)?;
    // The fuzz threads are the parallelism; the library's own parallel loops run inline.
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build_global()
        .map_err(|e| e.to_string())?;
    let mut targets = targets()?;
    if let Some(t) = &s.target {
        targets.retain(|x| x.name == t);
        if targets.is_empty() {
            return Err(format!("no target {t}"));
        }
    }
    // Panics are findings, reported with their message once per execution, not printed by the
    // default hook from every thread.
    // A replay also prints the default report (with RUST_BACKTRACE=1, where it panicked from).
    let default_hook = s.replay.is_some().then(panic::take_hook);
    panic::set_hook(Box::new(move |info| {
        LAST_PANIC.with(|p| *p.borrow_mut() = Some(info.to_string()));
        if let Some(h) = &default_hook {
            h(info);
        }
    }));
    if let Some(file) = &s.replay {
        let bytes = std::fs::read(file).map_err(|e| format!("{}: {e}", file.display()))?;
        let t = &targets[0];
        let v = execute(t, &bytes);
        println!("{} on {}: {v:?}", t.name, file.display());
        return Ok(usize::from(v.is_err()));
    }
    let targets = Arc::new(targets);
    let next = Arc::new(AtomicU64::new(0));
    let stop = Arc::new(AtomicBool::new(false));
    let t0 = Instant::now();
    // Per thread: the execution running and when it started (ms since t0 + 1; 0 = idle).
    let running: Arc<Vec<(AtomicU64, AtomicU64)>> = Arc::new(
        (0..s.threads)
            .map(|_| (AtomicU64::new(0), AtomicU64::new(0)))
            .collect(),
    );
    let stats = Arc::new(Mutex::new(Counts::new()));
    let findings = Arc::new(Mutex::new(
        Vec::<(u64, &'static str, Vec<u8>, String)>::new(),
    ));
    let mut handles = Vec::new();
    for w in 0..s.threads {
        let (targets, next, stop, running, stats, findings) = (
            targets.clone(),
            next.clone(),
            stop.clone(),
            running.clone(),
            stats.clone(),
            findings.clone(),
        );
        let (execs, seed) = (s.execs, s.seed);
        handles.push(std::thread::spawn(move || {
            let mut local = Counts::new();
            while !stop.load(Ordering::Relaxed) {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= execs {
                    break;
                }
                let (t, input) = input_of(&targets, seed, i);
                running[w].0.store(i, Ordering::Relaxed);
                running[w]
                    .1
                    .store(t0.elapsed().as_millis() as u64 + 1, Ordering::Relaxed);
                let v = execute(t, &input);
                running[w].1.store(0, Ordering::Relaxed);
                match v {
                    Ok(o) => *local.entry((t.name, o)).or_default() += 1,
                    Err(m) => {
                        findings.lock().unwrap().push((i, t.name, input, m));
                    }
                }
                if i % 256 == 0 {
                    merge(&stats, &mut local);
                }
            }
            merge(&stats, &mut local);
        }));
    }
    // Watchdog and progress.
    let mut last_report = Instant::now();
    let mut hung = None;
    while handles.iter().any(|h| !h.is_finished()) {
        std::thread::sleep(Duration::from_millis(100));
        let now = t0.elapsed().as_millis() as u64 + 1;
        for (i, started) in running.iter() {
            let st = started.load(Ordering::Relaxed);
            if st != 0 && now.saturating_sub(st) > s.hang.as_millis() as u64 {
                hung = Some(i.load(Ordering::Relaxed));
            }
        }
        if hung.is_some() {
            stop.store(true, Ordering::Relaxed);
            break;
        }
        if last_report.elapsed() > Duration::from_secs(30) {
            last_report = Instant::now();
            let done = next.load(Ordering::Relaxed).min(s.execs);
            eprintln!(
                "fuzz: {done} of {} executions, {:.0} s",
                s.execs,
                t0.elapsed().as_secs_f64()
            );
        }
    }
    let mut found = findings.lock().unwrap().clone();
    if let Some(i) = hung {
        let (t, input) = input_of(&targets, s.seed, i);
        found.push((
            i,
            t.name,
            input,
            format!("still running after {} ms (a hang)", s.hang.as_millis()),
        ));
    } else {
        for h in handles {
            h.join().map_err(|_| "a fuzz thread died".to_string())?;
        }
    }
    let secs = t0.elapsed().as_secs_f64();
    let stats = stats.lock().unwrap().clone();
    let total: u64 = stats.values().sum();
    println!(
        "fuzz: seed {}, {total} executions in {secs:.1} s ({:.0}/s, {} threads), {} findings",
        s.seed,
        total as f64 / secs.max(1e-9),
        s.threads,
        found.len()
    );
    println!("{:<10} {:>12} {:>12}", "target", "accepted", "refused");
    for t in targets.iter() {
        let get = |o| stats.get(&(t.name, o)).copied().unwrap_or(0);
        println!(
            "{:<10} {:>12} {:>12}",
            t.name,
            get(Outcome::Accepted),
            get(Outcome::Refused)
        );
    }
    // A target whose inputs are all refused tests only its parser's first lines (broken seed
    // inputs, or a parser that changed): a failure of the harness, reported as a finding.
    if total >= 10_000 {
        for t in targets.iter() {
            if stats
                .get(&(t.name, Outcome::Accepted))
                .copied()
                .unwrap_or(0)
                == 0
            {
                found.push((
                    u64::MAX,
                    t.name,
                    Vec::new(),
                    "no input was accepted: the downstream work never ran".into(),
                ));
            }
        }
    }
    if !found.is_empty() {
        std::fs::create_dir_all(&s.findings)
            .map_err(|e| format!("{}: {e}", s.findings.display()))?;
        found.sort_by_key(|f| f.0);
        for (i, name, input, msg) in &found {
            let path = s.findings.join(format!("{name}-seed{}-exec{i}", s.seed));
            std::fs::write(&path, input).map_err(|e| format!("{}: {e}", path.display()))?;
            println!(
                "FINDING exec {i} ({name}): {msg}\n  input: {} (replay: --target {name} --replay {})",
                path.display(),
                path.display()
            );
        }
    }
    Ok(found.len())
}

type Counts = BTreeMap<(&'static str, Outcome), u64>;

fn merge(shared: &Mutex<Counts>, local: &mut Counts) {
    let mut g = shared.lock().unwrap();
    for (k, v) in std::mem::take(local) {
        *g.entry(k).or_default() += v;
    }
}

thread_local! {
    static LAST_PANIC: std::cell::RefCell<Option<String>> = const { std::cell::RefCell::new(None) };
}

fn execute(t: &Target, input: &[u8]) -> Verdict {
    match panic::catch_unwind(AssertUnwindSafe(|| (t.run)(input))) {
        Ok(v) => v,
        Err(_) => Err(format!(
            "panic: {}",
            LAST_PANIC
                .with(|p| p.borrow_mut().take())
                .unwrap_or_default()
        )),
    }
}

/// The target and input of execution `i`: a function of (`seed`, `i`) only.
fn input_of(targets: &[Target], seed: u64, i: u64) -> (&Target, Vec<u8>) {
    let mut rng = ChaCha8Rng::seed_from_u64(splitmix(seed ^ splitmix(i)));
    let t = &targets[rng.random_range(0..targets.len())];
    let mut data = t.seeds[rng.random_range(0..t.seeds.len())].clone();
    // One execution in 16 runs a seed unchanged (the accepted paths stay covered).
    if rng.random_range(0..16) != 0 {
        let n = 1 + rng.random_range(0..6usize);
        for _ in 0..n {
            mutate(&mut rng, &mut data, &t.seeds);
        }
    }
    (t, data)
}

fn splitmix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

const INTERESTING_NUMBERS: &[&str] = &[
    "0",
    "-0",
    "1",
    "-1",
    "2",
    "0.5",
    "-0.5",
    "3",
    "7",
    "64",
    "65",
    "1025",
    "100000",
    "1e9",
    "-100",
    "1e-4",
    "1e-12",
    "1e300",
    "-1e300",
    "1e308",
    "-1e308",
    "1e-308",
    "5e-324",
    "1e999",
    "NaN",
    "nan",
    "inf",
    "-inf",
    "4294967296",
    "18446744073709551616",
    "9e18",
    "-9e18",
    "0.999999",
    "1.0000001",
    "89.9",
    "90",
    "180",
    "380",
    "780",
    "8500",
];

const INTERESTING_BYTES: &[u8] = b"0-.e9 \n\r\t\",:{}[]/\\+Ee";

/// One random edit of `data`.
fn mutate(rng: &mut ChaCha8Rng, data: &mut Vec<u8>, seeds: &[Vec<u8>]) {
    const MAX_LEN: usize = 1 << 20;
    let len = data.len();
    let pos = |rng: &mut ChaCha8Rng, n: usize| if n == 0 { 0 } else { rng.random_range(0..n) };
    match rng.random_range(0..11) {
        0 if len > 0 => {
            let p = pos(rng, len);
            data[p] ^= 1 << rng.random_range(0..8);
        }
        1 if len > 0 => {
            let p = pos(rng, len);
            data[p] = INTERESTING_BYTES[pos(rng, INTERESTING_BYTES.len())];
        }
        2 if len > 0 => {
            let a = pos(rng, len);
            let b = (a + 1 + pos(rng, 32)).min(len);
            data.drain(a..b);
        }
        3 if len > 0 && len < MAX_LEN => {
            let a = pos(rng, len);
            let b = (a + 1 + pos(rng, 64)).min(len);
            let chunk = data[a..b].to_vec();
            let at = pos(rng, len + 1);
            data.splice(at..at, chunk);
        }
        4..=6 => {
            // Replace a number with an interesting one (the most productive edit for text).
            let nums = number_spans(data);
            if !nums.is_empty() {
                let (a, b) = nums[pos(rng, nums.len())];
                let v = INTERESTING_NUMBERS[pos(rng, INTERESTING_NUMBERS.len())];
                data.splice(a..b, v.bytes());
            }
        }
        7 => {
            // Delete, duplicate or swap lines.
            let lines = line_spans(data);
            if lines.len() > 1 {
                let (a, b) = lines[pos(rng, lines.len())];
                match rng.random_range(0..3) {
                    0 => {
                        data.drain(a..b);
                    }
                    1 if len < MAX_LEN => {
                        let l = data[a..b].to_vec();
                        data.splice(b..b, l);
                    }
                    _ => {
                        let (c, d) = lines[pos(rng, lines.len())];
                        if b <= c {
                            let (l1, l2) = (data[a..b].to_vec(), data[c..d].to_vec());
                            data.splice(c..d, l1);
                            data.splice(a..b, l2);
                        }
                    }
                }
            }
        }
        8 if len < MAX_LEN => {
            // Splice in a piece of another seed.
            let other = &seeds[pos(rng, seeds.len())];
            if !other.is_empty() {
                let a = pos(rng, other.len());
                let b = (a + 1 + pos(rng, 256)).min(other.len());
                let at = pos(rng, len + 1);
                let end = (at + pos(rng, 64)).min(len);
                data.splice(at..end, other[a..b].iter().copied());
            }
        }
        9 if len < MAX_LEN => {
            let at = pos(rng, len + 1);
            let n = 1 + pos(rng, 8);
            let bytes: Vec<u8> = (0..n).map(|_| rng.random_range(0x20..0x7f)).collect();
            data.splice(at..at, bytes);
        }
        _ if len > 0 => {
            let at = pos(rng, len);
            data.truncate(at);
        }
        _ => data.push(rng.random()),
    }
}

/// Byte ranges of decimal numbers (sign, digits, fraction, exponent).
fn number_spans(d: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < d.len() {
        let start = i;
        if d[i] == b'-' || d[i] == b'+' {
            i += 1;
        }
        let digits = i;
        while i < d.len() && (d[i].is_ascii_digit() || d[i] == b'.') {
            i += 1;
        }
        if i > digits && d[digits..i].iter().any(u8::is_ascii_digit) {
            if i < d.len() && (d[i] == b'e' || d[i] == b'E') {
                let mut j = i + 1;
                if j < d.len() && (d[j] == b'-' || d[j] == b'+') {
                    j += 1;
                }
                if j < d.len() && d[j].is_ascii_digit() {
                    while j < d.len() && d[j].is_ascii_digit() {
                        j += 1;
                    }
                    i = j;
                }
            }
            out.push((start, i));
        } else {
            i = start + 1;
        }
    }
    out
}

fn line_spans(d: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut a = 0;
    for (i, &c) in d.iter().enumerate() {
        if c == b'\n' {
            out.push((a, i + 1));
            a = i + 1;
        }
    }
    if a < d.len() {
        out.push((a, d.len()));
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Targets

fn read_dir_files(dir: &str, ext: &[&str], out: &mut Vec<Vec<u8>>) -> Result<(), String> {
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/");
    let mut stack = vec![PathBuf::from(root).join(dir)];
    while let Some(d) = stack.pop() {
        let mut entries: Vec<_> = std::fs::read_dir(&d)
            .map_err(|e| format!("{}: {e}", d.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .collect();
        entries.sort();
        for p in entries {
            if p.is_dir() {
                stack.push(p);
            } else if p
                .extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| ext.iter().any(|x| e.eq_ignore_ascii_case(x)))
            {
                out.push(std::fs::read(&p).map_err(|e| format!("{}: {e}", p.display()))?);
            }
        }
    }
    Ok(())
}

fn lens1() -> &'static Lens {
    static L: OnceLock<Lens> = OnceLock::new();
    L.get_or_init(|| Lens::load("lens1").expect("built-in lens1"))
}

fn targets() -> Result<Vec<Target>, String> {
    let builtin = ["lens1", "lens2", "cooke-triplet"];
    let mut lens_json = Vec::new();
    for name in builtin {
        let l = Lens::load(name).map_err(|e| e.to_string())?;
        lens_json.push(json::to_string(&l).into_bytes());
    }
    read_dir_files("tests/data", &["json"], &mut lens_json)?;
    lens_json.retain(|b| json::from_str(&String::from_utf8_lossy(b)).is_ok());
    let mut zmx = Vec::new();
    read_dir_files("tests/data/zemax", &["zmx"], &mut zmx)?;
    let mut agf = Vec::new();
    read_dir_files("tests/data/zemax", &["agf"], &mut agf)?;
    let spec = ToleranceSpec::default();
    let specs = vec![spec.to_json().into_bytes()];
    let mut patterns = Vec::new();
    for (k, name) in builtin.iter().enumerate() {
        let l = Lens::load(name).map_err(|e| e.to_string())?;
        let p = spec.sample(&l, 7, k as u64).map_err(|e| e.to_string())?;
        patterns.push(p.to_json().into_bytes());
    }
    let rays = vec![
        b"ox,oy,oz,dx,dy,dz,wavelength_nm\n0,0,-10,0,0,1,587.5618\n0,1,-10,0,0,1,486.1327\n\
          0,0,-10,0,0.1,0.99498743710662,656.2725\n0,0,-10,0,0,-1,587.5618\n"
            .to_vec(),
        br#"[{"ox":0,"oy":0.5,"oz":-5,"dx":0,"dy":0,"dz":1,"wavelength_nm":587.5618},
{"ox":1,"oy":0,"oz":-5,"dx":0,"dy":0,"dz":1,"wavelength_nm":0}]"#
            .to_vec(),
    ];
    let flags: Vec<Vec<u8>> = [
        "field:0.7",
        "field:12deg",
        "field:-1",
        "field:0:2mm@image",
        "field:1.5mm@real-image",
        "field:-1mm@real-image:2mm@real-image",
        "pupil:grid:16",
        "pupil:hex:6",
        "pupil:random:500",
        "object:inf",
        "object:1000",
        "object:-500",
        "material:N-BK7",
        "material:SF5",
        "material:1.6/40",
        "material:AIR",
        "decoder:wiener+unet",
        "decoder:wiener",
    ]
    .iter()
    .map(|s| s.as_bytes().to_vec())
    .collect();
    let mut decoders = Vec::new();
    for (kind, grid, ks, width) in [
        (DecoderKind::Wiener, 2, 3, 1),
        (DecoderKind::WienerUnet, 1, 3, 1),
        (DecoderKind::Unet, 1, 5, 2),
    ] {
        let psfs: Vec<f32> = (0..grid * grid * 3 * ks * ks)
            .map(|i| {
                if i % (ks * ks) == ks * ks / 2 {
                    1.0
                } else {
                    0.0
                }
            })
            .collect();
        let d = Decoder::new(kind, grid, ks, &psfs, 0.01, width, 3).map_err(|e| e.to_string())?;
        decoders.push(tolray::deep::study::decoder_to_bytes(&d));
    }
    for (name, seeds) in [("lens-json", &lens_json), ("zmx", &zmx), ("agf", &agf)] {
        if seeds.is_empty() {
            return Err(format!("no seed inputs for {name}"));
        }
    }
    Ok(vec![
        Target {
            name: "lens-json",
            seeds: lens_json,
            run: run_lens_json,
        },
        Target {
            name: "zmx",
            seeds: zmx,
            run: run_zmx,
        },
        Target {
            name: "agf",
            seeds: agf,
            run: run_agf,
        },
        Target {
            name: "spec",
            seeds: specs,
            run: run_spec,
        },
        Target {
            name: "pattern",
            seeds: patterns,
            run: run_pattern,
        },
        Target {
            name: "rays",
            seeds: rays,
            run: run_rays,
        },
        Target {
            name: "flags",
            seeds: flags,
            run: run_flags,
        },
        Target {
            name: "decoder",
            seeds: decoders,
            run: run_decoder,
        },
    ])
}

macro_rules! finite {
    ($what:expr, $($v:expr),+ $(,)?) => {
        $(
            if !$v.is_finite() {
                return Err(format!("{}: {} = {} reached the caller", $what, stringify!($v), $v));
            }
        )+
    };
}

fn text(b: &[u8]) -> Option<&str> {
    std::str::from_utf8(b).ok()
}

fn run_lens_json(b: &[u8]) -> Verdict {
    let Some(t) = text(b) else {
        return Ok(Outcome::Refused);
    };
    match json::from_str(t) {
        Ok(l) => lens_work(&l, true),
        Err(_) => Ok(Outcome::Refused),
    }
}

fn run_zmx(b: &[u8]) -> Verdict {
    match zemax::from_bytes(b, &GlassCatalogs::builtin()) {
        Ok(z) => lens_work(&z.lens, true),
        Err(_) => Ok(Outcome::Refused),
    }
}

/// What a user's next commands do with a lens they loaded: `info`, `spot`, `psf`, `convert`.
fn lens_work(l: &Lens, round_trips: bool) -> Verdict {
    if l.validate().is_err() {
        return Ok(Outcome::Refused);
    }
    let mut wavelengths = vec![l.primary_wavelength_nm];
    wavelengths.extend(l.rgb_wavelengths_nm);
    let mut any_paraxial = false;
    for &wl in &wavelengths {
        let Ok(p) = l.paraxial(wl) else { continue };
        any_paraxial = true;
        // (None: an afocal lens' focal numbers, an image at infinity.)
        let (efl, bfd, image, fnum, working_fnum, half_fov, angular) = (
            p.efl_mm.unwrap_or(0.0),
            p.bfd_mm.unwrap_or(0.0),
            p.image_distance_mm.unwrap_or(0.0),
            p.fnum.unwrap_or(0.0),
            p.working_fnum.unwrap_or(0.0),
            p.half_fov_deg.unwrap_or(0.0),
            p.angular_magnification.unwrap_or(0.0),
        );
        finite!(
            "paraxial",
            efl,
            bfd,
            image,
            p.power_per_mm,
            p.entrance_pupil_z_mm,
            p.entrance_pupil_diameter_mm,
            p.exit_pupil_z_mm,
            p.exit_pupil_diameter_mm,
            fnum,
            working_fnum,
            p.magnification,
            half_fov,
            angular,
            p.total_track_mm
        );
    }
    if !any_paraxial {
        return Ok(Outcome::Refused);
    }
    let sys = l.compile();
    let opts = SpotOptions {
        fields: vec![
            Field::fraction(0.0),
            Field::fraction(0.7),
            Field::fraction(1.0),
        ],
        wavelengths_nm: vec![l.primary_wavelength_nm],
        pupil: Pupil::grid(8),
        trace: TraceOptions { apertures: true },
    };
    if let Ok(spots) = spot_diagram(l, &sys, &opts) {
        for r in &spots {
            let s = &r.stats;
            finite!(
                "spot",
                s.rms_um,
                s.geo_radius_um,
                s.centroid_mm[0],
                s.centroid_mm[1],
                s.vignetted_fraction
            );
            if let Some(c) = s.rms_chief_um {
                finite!("spot", c);
            }
            if s.n_valid == 0 || s.n_valid > s.n_launched {
                return Err(format!(
                    "spot: {} valid rays of {} reported as a result",
                    s.n_valid, s.n_launched
                ));
            }
        }
    }
    let mut po = PsfOptions::for_lens(l);
    po.ks = 15;
    po.pupil = Pupil {
        pattern: PupilPattern::Random { n: 200, seed: 1 },
        scale: 1.0,
        aim: false,
    };
    if let Ok(rays) = tolray::trace::Bundles::pairs(
        l,
        &[(Field::fraction(0.5), l.primary_wavelength_nm)],
        &po.pupil,
    ) {
        if tolray::psf::check_options(&po).is_ok() {
            let (psf, _) = psf_of(&sys, &rays, 0, &po, TraceOptions { apertures: true });
            let sum: f64 = psf.iter().sum();
            if psf.iter().any(|v| !v.is_finite()) {
                return Err("psf: a non-finite pixel".into());
            }
            if sum != 0.0 && (sum - 1.0).abs() > 1e-9 {
                return Err(format!("psf: sums to {sum}, not 1"));
            }
        }
    }
    wave_work(l, &sys)?;
    if round_trips {
        round_trip(l, &sys)?;
    }
    Ok(Outcome::Accepted)
}

/// `tolray wavefront`, `mtf` and `psf --method fft|huygens` on a loaded lens: every number a
/// result carries is finite, and a result is never empty.
fn wave_work(l: &Lens, sys: &tolray::lens::System<f64>) -> Result<(), String> {
    use tolray::wave::{mtf, psf, wavefront, Sampling, WaveOptions};
    let wl = l.primary_wavelength_nm;
    let q = WaveOptions {
        sampling: Sampling::Quadrature {
            rings: 4,
            spokes: 8,
        },
        ..WaveOptions::default()
    };
    let Ok(w) = wavefront(l, sys, Field::fraction(0.7), wl, &q) else {
        return Ok(());
    };
    if w.opd_waves.is_empty() || w.opd_waves.len() != w.weight.len() {
        return Err("wavefront: an empty or ragged result".into());
    }
    if let Ok(s) = w.stats(15) {
        finite!(
            "wavefront",
            s.rms_to_chief_waves,
            s.rms_to_centroid_waves,
            s.pv_to_chief_waves,
            s.strehl_marechal
        );
        if s.zernike_standard
            .coefficients
            .iter()
            .any(|v| !v.is_finite())
        {
            return Err("wavefront: a non-finite Zernike coefficient".into());
        }
    }
    let g = WaveOptions {
        sampling: Sampling::Grid(8),
        ..WaveOptions::default()
    };
    let Ok(w) = wavefront(l, sys, Field::fraction(0.7), wl, &g) else {
        return Ok(());
    };
    let fft = psf::FftOptions {
        pupil_samples: 8,
        grid: 16,
    };
    if let Ok(p) = psf::fft_psf(&w, &fft) {
        if p.values.iter().any(|v| !v.is_finite()) || !p.strehl.is_finite() {
            return Err("fft psf: a non-finite value".into());
        }
    }
    if let Ok(p) = psf::huygens_psf(
        &w,
        &psf::HuygensOptions {
            image_samples: 4,
            pitch_um: 1.0,
        },
    ) {
        if p.values.iter().any(|v| !v.is_finite()) || !p.strehl.is_finite() {
            return Err("huygens psf: a non-finite value".into());
        }
    }
    if let Ok(m) = mtf::fft_mtf(&w, &fft, &[1.0, 10.0]) {
        if m.tangential
            .iter()
            .chain(&m.sagittal)
            .any(|v| !v.is_finite())
        {
            return Err("mtf: a non-finite value".into());
        }
    }
    if !psf::strehl(&w).is_finite() {
        return Err("strehl: not finite".into());
    }
    if let Ok(m) = mtf::direct_mtf(l, sys, Field::fraction(0.7), wl, &g, &[1.0, 10.0]) {
        if m.tangential
            .iter()
            .chain(&m.sagittal)
            .any(|v| !v.is_finite())
        {
            return Err("direct mtf: a non-finite value".into());
        }
    }
    aberration_work(l, sys)
}

/// The aberration curves but relative illumination: any error is a refusal, any number finite.
fn aberration_work(l: &Lens, sys: &tolray::lens::System<f64>) -> Result<(), String> {
    use tolray::analysis::aberrations as ab;
    let wl = l.primary_wavelength_nm;
    let f = [Field::fraction(0.0), Field::fraction(0.7)];
    if let Ok([t, s]) = ab::field_curvature(l, sys, f[1], wl, false) {
        finite!("field curvature", t, s);
    }
    if let Ok(d) = ab::distortion(l, sys, &f, wl, ab::DistortionKind::FTan, false) {
        finite!("distortion", d[0], d[1]);
    }
    if let Ok(g) = ab::grid_distortion(l, sys, 3, wl, ab::DistortionKind::FTan, false) {
        let all = g.real_mm.iter().chain(&g.ideal_mm).flatten();
        if g.real_mm.len() != 9 || all.chain(&g.distortion_pct).any(|v| !v.is_finite()) {
            return Err("grid distortion: a ragged or non-finite result".into());
        }
    }
    // Relative illumination traces 64² rays per field: left to its tests, to keep the pass short.
    if let Ok(c) = ab::lateral_colour(l, sys, &f, &[wl, wl * 1.1], false) {
        finite!("lateral colour", c[1][0], c[1][1]);
    }
    if let Ok(fan) = ab::fans(l, sys, f[1], wl, 5, &Default::default()) {
        if fan.pupil.len() != 5 || fan.opd_tangential_waves.iter().any(|v| v.is_infinite()) {
            return Err("fans: a ragged or infinite result".into());
        }
    }
    Ok(())
}

fn run_agf(b: &[u8]) -> Verdict {
    let Ok((cat, _)) = AgfCatalog::from_bytes(b, "fuzz.agf") else {
        return Ok(Outcome::Refused);
    };
    let names: Vec<String> = cat.glasses.iter().take(8).map(|g| g.name.clone()).collect();
    for g in cat.glasses.iter() {
        // The reader skips (with a warning) a glass whose formula fails inside its range.
        if let Some((um, n)) = tolray::lens::agf::broken_in_range(g) {
            return Err(format!("agf: {} kept with index {n} at {um} µm", g.name));
        }
    }
    let catalogs = GlassCatalogs {
        user: vec![cat],
        ..GlassCatalogs::builtin()
    };
    let mut accepted = false;
    for name in names.iter().take(2) {
        let t = format!(
            r#"{{"info":"fuzz singlet","foclen":50,"fnum":4,"hfov":0.1,"r_sensor":3,
"surfaces":[{{"type":"Spheric","r":6,"c":0.02,"d":0,"mat2":"{name}"}},
{{"type":"Spheric","r":6,"c":-0.01,"d":4,"mat2":"air"}},
{{"type":"Aperture","r":5,"d":6,"mat2":"air"}}],"d_sensor":75,"mat1":"air"}}"#
        );
        if let Ok(l) = json::from_str_with(&t, &catalogs) {
            accepted |= lens_work(&l, false)? == Outcome::Accepted;
        }
    }
    Ok(if accepted {
        Outcome::Accepted
    } else {
        Outcome::Refused
    })
}

fn run_spec(b: &[u8]) -> Verdict {
    let Ok(spec) = serde_json::from_slice::<ToleranceSpec>(b) else {
        return Ok(Outcome::Refused);
    };
    let l = lens1();
    if spec.validate(l).is_err() {
        return Ok(Outcome::Refused);
    }
    let mut accepted = false;
    for k in 0..2 {
        let Ok(p) = spec.sample(l, 11, k) else {
            return Ok(Outcome::Refused);
        };
        accepted |= pattern_work(&p)? == Outcome::Accepted;
    }
    Ok(if accepted {
        Outcome::Accepted
    } else {
        Outcome::Refused
    })
}

fn run_pattern(b: &[u8]) -> Verdict {
    match serde_json::from_slice::<Perturbation>(b) {
        Ok(p) => pattern_work(&p),
        Err(_) => Ok(Outcome::Refused),
    }
}

fn pattern_work(p: &Perturbation) -> Verdict {
    let l = lens1();
    if p.validate(l).is_err() {
        return Ok(Outcome::Refused);
    }
    match p.apply(l) {
        Ok((perturbed, adj)) => {
            let v = lens_work(&perturbed, false)?;
            // `tolray convert --perturb`: the pattern baked into a prescription traces as the
            // perturbed system and survives its own JSON and .zmx files.
            if let Ok(baked) = perturbed.with_adjustments(&adj) {
                let sys = tolray::lens::System::compile(&perturbed, &adj, &|_, v| v);
                // (Not its first-order data: the perturbed lens' is the nominal geometry's.)
                same_lens(&perturbed, &sys, &baked, "baked pattern", false, true)?;
                round_trip(&baked, &baked.compile())?;
            }
            Ok(v)
        }
        Err(_) => Ok(Outcome::Refused),
    }
}

fn run_rays(b: &[u8]) -> Verdict {
    let Some(t) = text(b) else {
        return Ok(Outcome::Refused);
    };
    let parsed = if t.trim_start().starts_with('[') {
        raw::parse_json(t)
    } else {
        raw::parse_csv(t)
    };
    let Ok(rays) = parsed else {
        return Ok(Outcome::Refused);
    };
    let Ok(hits) = raw::trace_raw(&lens1().compile(), &rays, TraceOptions { apertures: true })
    else {
        return Ok(Outcome::Refused);
    };
    if hits.len() != rays.len() {
        return Err(format!(
            "trace: {} rays in, {} rows out",
            rays.len(),
            hits.len()
        ));
    }
    for h in &hits {
        if h.status == "alive" {
            finite!("trace", h.x, h.y, h.z, h.dx, h.dy, h.dz, h.opl_mm);
            if h.opl_mm.is_nan() || h.opl_mm < 0.0 {
                return Err(format!(
                    "trace: an alive ray with optical path {}",
                    h.opl_mm
                ));
            }
        }
    }
    Ok(Outcome::Accepted)
}

fn run_flags(b: &[u8]) -> Verdict {
    let Some(t) = text(b) else {
        return Ok(Outcome::Refused);
    };
    let Some((kind, value)) = t.split_once(':') else {
        return Ok(Outcome::Refused);
    };
    let l = lens1();
    match kind {
        "field" => {
            let Ok(f) = Field::parse(value) else {
                return Ok(Outcome::Refused);
            };
            let opts = SpotOptions {
                fields: vec![f],
                wavelengths_nm: vec![l.primary_wavelength_nm],
                pupil: Pupil::grid(8),
                trace: TraceOptions { apertures: true },
            };
            if let Ok(spots) = spot_diagram(l, &l.compile(), &opts) {
                for r in &spots {
                    finite!("spot", r.stats.rms_um, r.stats.centroid_mm[1]);
                }
            }
            Ok(Outcome::Accepted)
        }
        "pupil" => {
            let Ok(p) = Pupil::parse(value, 5) else {
                return Ok(Outcome::Refused);
            };
            if p.pattern.check().is_err() {
                return Ok(Outcome::Refused);
            }
            let pts = p.points();
            if pts.is_empty() {
                return Err(format!("pupil {value}: no points, accepted"));
            }
            for q in &pts {
                finite!("pupil", q[0], q[1]);
            }
            Ok(Outcome::Accepted)
        }
        "object" => {
            let Ok(o) = Object::parse(value) else {
                return Ok(Outcome::Refused);
            };
            let mut l2 = l.clone();
            l2.object = o;
            lens_work(&l2, false)
        }
        "material" => {
            let Ok(m) = Material::parse(value) else {
                return Ok(Outcome::Refused);
            };
            let mut l2 = l.clone();
            l2.surfaces[0].material = m;
            lens_work(&l2, false)
        }
        "decoder" => Ok(match DecoderKind::parse(value) {
            Ok(_) => Outcome::Accepted,
            Err(_) => Outcome::Refused,
        }),
        _ => Ok(Outcome::Refused),
    }
}

fn run_decoder(b: &[u8]) -> Verdict {
    let Ok(d) = tolray::deep::study::decoder_from_bytes(b, "decoder.bin") else {
        return Ok(Outcome::Refused);
    };
    if d.grid * d.grid * d.ks * d.ks > 1 << 16 || d.unet_width > 8 {
        // Large but valid: decoding it is legitimate work, not a finding; keep executions short.
        return Ok(Outcome::Accepted);
    }
    let (w, h) = (16, 16);
    let x: Vec<f32> = (0..3 * w * h).map(|i| (i % 7) as f32 / 7.0).collect();
    let crop = Crop {
        tile: 0,
        y: x.clone(),
        x,
        w,
        h,
    };
    match d.decode_batch(&[crop]) {
        Ok(out) => {
            if out.iter().flatten().any(|v| !v.is_finite()) {
                return Err("decoder: a non-finite output pixel".into());
            }
            Ok(Outcome::Accepted)
        }
        Err(_) => Ok(Outcome::Refused),
    }
}
