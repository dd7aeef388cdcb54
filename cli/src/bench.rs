//! `tolray bench`: the kernel's and the commands' speed on this machine, with the instruction set
//! in use, so that users and bug reports carry comparable figures. The criterion benchmarks in
//! `benches/` are the project's measurements; this is their quick counterpart for any machine.

use crate::report::emit;
use clap::{Args, ValueEnum};
use std::time::{Duration, Instant};
use tolray::analysis::{spot_diagram_rows, SpotOptions};
use tolray::deep::{step, DeepConfig, DeepState, Phase};
use tolray::lens::material::LAMBDA_D_NM;
use tolray::lens::{Adjustments, Param, System};
use tolray::psf::{psf_map, psf_streamed, PsfModel, PsfOptions};
use tolray::real::{Dual, GRAD_WIDTH};
use tolray::trace::simd::{self, Isa};
use tolray::trace::{trace, Field, Pupil, PupilPattern, RayBatch, RaySet, TraceOptions, Traceable};
use tolray::Lens;

/// The size of the deep-optics iteration measured.
#[derive(Clone, Copy, ValueEnum)]
pub enum DeepSize {
    /// The demo's batch: 32 crops of 32², through the rays' PSFs.
    Demo,
    /// The paper's batch: 64 crops of 256² (about 6 s a run on two cores).
    Paper,
    /// No deep-optics iteration.
    None,
}

/// Arguments of `tolray bench`.
#[derive(Args)]
pub struct BenchArgs {
    /// Seconds spent on each figure: runs repeat until then (at least 3) and the median is
    /// printed.
    #[arg(long, value_name = "S", default_value_t = 1.0)]
    pub seconds: f64,
    /// Measure the kernel with every instruction-set build this CPU runs, not only the one in
    /// use (TOLRAY_SIMD=avx512|avx2|baseline forces the one in use).
    #[arg(long)]
    pub all_isas: bool,
    /// The deep-optics iteration measured (lens1, tolerance phase, Wiener + U-Net).
    #[arg(long, value_enum, default_value = "demo")]
    pub deep: DeepSize,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// One measured figure.
struct Figure {
    what: String,
    isa: Option<Isa>,
    threads: usize,
    value: f64,
    unit: &'static str,
    /// A comparison printed beside the value.
    note: String,
}

/// The median seconds of `f` over runs repeated for `budget` (at least 3), each run after
/// `prepare` (not timed).
fn median_s<T, P>(
    budget: Duration,
    mut prepare: impl FnMut() -> P,
    mut f: impl FnMut(P) -> T,
) -> f64 {
    let start = Instant::now();
    let mut times = Vec::new();
    while times.len() < 3 || (start.elapsed() < budget && times.len() < 10_000) {
        let p = prepare();
        let t = Instant::now();
        std::hint::black_box(f(p));
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    times[times.len() / 2]
}

fn pool(threads: usize) -> anyhow::Result<rayon::ThreadPool> {
    Ok(rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?)
}

/// Runs `tolray bench`.
pub fn run(a: BenchArgs) -> anyhow::Result<()> {
    if !(a.seconds > 0.0 && a.seconds <= 600.0) {
        return Err(crate::app::Usage(format!(
            "--seconds {}: give a time per figure above 0 and at most 600 s",
            a.seconds
        ))
        .into());
    }
    let budget = Duration::from_secs_f64(a.seconds);
    let all = std::thread::available_parallelism().map_or(1, |n| n.get());
    let counts: Vec<usize> = if all > 1 { vec![1, all] } else { vec![1] };
    let active = simd::active();
    let isas = if a.all_isas {
        Isa::available()
    } else {
        vec![active]
    };
    let lens = Lens::load("lens2")?;
    let surfaces = (lens.surfaces.len() + 1) as f64;
    let para = lens.paraxial(LAMBDA_D_NM)?;
    let random = |n: usize| Pupil {
        pattern: PupilPattern::Random { n, seed: 1 },
        scale: 1.0,
        aim: false,
    };
    let set = RaySet::generate(
        &lens,
        &para,
        Field::fraction(0.7),
        &random(1 << 18),
        LAMBDA_D_NM,
    )?;
    let n_rays = set.origins.len() as f64;
    let mut figs = Vec::new();

    // The kernel: value traces of 262,144 rays.
    fn kernel<S: Traceable>(set: &RaySet, lens: &Lens, budget: Duration) -> f64 {
        let sys: System<S> = lens.compile().convert();
        let fresh: RayBatch<S> = set.batch();
        median_s(
            budget,
            || fresh.clone(),
            |mut b| trace(&sys, LAMBDA_D_NM, &mut b, TraceOptions::default()),
        )
    }
    let mut f64_rate = std::collections::HashMap::new();
    for &isa in &isas {
        simd::set_active(isa)?;
        for &t in &counts {
            let p = pool(t)?;
            for (ty, s) in [
                ("f32", p.install(|| kernel::<f32>(&set, &lens, budget))),
                ("f64", p.install(|| kernel::<f64>(&set, &lens, budget))),
            ] {
                let rate = n_rays * surfaces / s / 1e6;
                if ty == "f64" && isa == active {
                    f64_rate.insert(t, rate);
                }
                figs.push(Figure {
                    what: format!("kernel {ty}, lens2"),
                    isa: Some(isa),
                    threads: t,
                    value: rate,
                    unit: "M ray-surfaces/s",
                    note: String::new(),
                });
            }
        }
    }
    simd::set_active(active)?;

    // Gradients: 4,096 rays carrying GRAD_WIDTH derivatives against the f64 value trace.
    let small = RaySet::generate(
        &lens,
        &para,
        Field::fraction(0.7),
        &random(4096),
        LAMBDA_D_NM,
    )?;
    let p1 = pool(1)?;
    let value = p1.install(|| kernel::<f64>(&small, &lens, budget));
    let seed = |p: Param, v: Dual<f64, GRAD_WIDTH>| match p {
        Param::Curvature(i) => Dual::var(v.re, i % GRAD_WIDTH),
        _ => v,
    };
    let sys: System<Dual<f64, GRAD_WIDTH>> =
        System::compile(&lens, &Adjustments::none(lens.surfaces.len()), &seed);
    let fresh: RayBatch<Dual<f64, GRAD_WIDTH>> = small.batch();
    let dual = p1.install(|| {
        median_s(
            budget,
            || fresh.clone(),
            |mut b| trace(&sys, LAMBDA_D_NM, &mut b, TraceOptions::default()),
        )
    });
    figs.push(Figure {
        what: format!("kernel dual ({GRAD_WIDTH} derivatives), lens2"),
        isa: Some(active),
        threads: 1,
        value: small.origins.len() as f64 * surfaces / dual / 1e6,
        unit: "M ray-surfaces/s",
        note: format!("{:.1}x the f64 value trace's time per ray", dual / value),
    });

    // The spot analysis end to end: a 1024 x 1024 pupil grid generated, traced and reduced.
    let opts = SpotOptions {
        fields: vec![Field::fraction(0.7)],
        wavelengths_nm: vec![LAMBDA_D_NM],
        pupil: Pupil::grid(1024),
        trace: TraceOptions::default(),
    };
    let sys = lens.compile();
    let (rows, failed) = spot_diagram_rows(&lens, &sys, &opts)?;
    let Some(row) = rows.first() else {
        anyhow::bail!("the spot analysis of lens2 at 0.7 field traced no ray: {failed:?}");
    };
    let launched = row.stats.n_launched as f64;
    for &t in &counts {
        let s = pool(t)?
            .install(|| median_s(budget, || (), |()| spot_diagram_rows(&lens, &sys, &opts)));
        let rate = launched * surfaces / s / 1e6;
        figs.push(Figure {
            what: "spot, lens2, grid:1024".into(),
            isa: Some(active),
            threads: t,
            value: rate,
            unit: "M ray-surfaces/s",
            note: f64_rate
                .get(&t)
                .map(|k| format!("{:.0} % of the f64 kernel", 100.0 * rate / k))
                .unwrap_or_default(),
        });
    }

    // One PSF end to end (`tolray psf`): 262,144 random pupil rays generated, traced and
    // splatted a chunk at a time.
    let mut popts = PsfOptions::for_lens(&lens);
    popts.pupil = random(1 << 18);
    for &t in &counts {
        let s = pool(t)?.install(|| {
            median_s(
                budget,
                || (),
                |()| psf_streamed(&lens, &sys, Field::fraction(0.7), LAMBDA_D_NM, &popts),
            )
        });
        let rate = (1 << 18) as f64 * surfaces / s / 1e6;
        figs.push(Figure {
            what: "PSF, lens2, 262,144 rays".into(),
            isa: Some(active),
            threads: t,
            value: rate,
            unit: "M ray-surfaces/s",
            note: f64_rate
                .get(&t)
                .map(|k| format!("{:.0} % of the f64 kernel", 100.0 * rate / k))
                .unwrap_or_default(),
        });
    }

    // A PSF map: 8 x 8 fields of 51² pixels, 8,192 rays each.
    let popts = PsfOptions::for_lens(&lens);
    let s = pool(all)?.install(|| {
        median_s(
            budget,
            || (),
            |()| psf_map(&lens, &sys, 8, LAMBDA_D_NM, &popts),
        )
    });
    figs.push(Figure {
        what: "PSF map 8x8 x 51² x 8192 rays, lens2".into(),
        isa: Some(active),
        threads: all,
        value: s * 1e3,
        unit: "ms",
        note: String::new(),
    });

    // One deep-optics iteration: crops, patterns, rays, rendering, decoding, both backward
    // passes and the Adam steps.
    if let Some((name, samples, crop)) = match a.deep {
        DeepSize::Demo => Some(("demo batch, 32 crops of 32²", 32, 32)),
        DeepSize::Paper => Some(("paper batch, 64 crops of 256²", 64, 256)),
        DeepSize::None => None,
    } {
        let mut l1 = Lens::load("lens1")?;
        let p = l1.paraxial(l1.primary_wavelength_nm)?;
        let last = l1.surfaces.len() - 1;
        if let Some(d) = p.image_distance_mm {
            l1.surfaces[last].d_next_mm = d;
        }
        let mut cfg = DeepConfig::for_lens(&l1);
        cfg.optics.samples = samples;
        cfg.crop_px = crop;
        cfg.psf = PsfModel::Geometric;
        let st = DeepState::new(cfg, l1, None, Phase::Tolerance, 1, 0)?;
        let s = pool(all)?.install(|| median_s(budget, || st.clone(), |mut s| step(&mut s)));
        figs.push(Figure {
            what: format!("deep-optics iteration, lens1, {name}"),
            isa: Some(active),
            threads: all,
            value: s,
            unit: "s",
            note: String::new(),
        });
    }

    let cpu = cpu_name();
    if a.json {
        let v = serde_json::json!({
            "tolray_version": env!("CARGO_PKG_VERSION"),
            "cpu": cpu,
            "threads": all,
            "isa": active.name(),
            "isas_available": Isa::available().iter().map(|i| i.name()).collect::<Vec<_>>(),
            "seconds_per_figure": a.seconds,
            "figures": figs.iter().map(|f| serde_json::json!({
                "what": f.what,
                "isa": f.isa.map(Isa::name),
                "threads": f.threads,
                "value": f.value,
                "unit": f.unit,
                "note": f.note,
            })).collect::<Vec<_>>(),
        });
        crate::report::emit_line(&serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    let mut out = format!(
        "tolray {} on {cpu}, {all} threads; instruction set in use: {} (this CPU runs {})\n\
         median of runs over {} s per figure\n\n",
        env!("CARGO_PKG_VERSION"),
        active.name(),
        Isa::available()
            .iter()
            .map(|i| i.name())
            .collect::<Vec<_>>()
            .join(", "),
        a.seconds
    );
    out += &format!(
        "{:<58} {:>8} {:>7} {:>10}  {}\n",
        "figure", "isa", "threads", "value", "unit"
    );
    for f in &figs {
        out += &format!(
            "{:<58} {:>8} {:>7} {:>10.*}  {}{}\n",
            f.what,
            f.isa.map_or("", Isa::name),
            f.threads,
            if f.unit == "s" { 3 } else { 1 },
            f.value,
            f.unit,
            if f.note.is_empty() {
                String::new()
            } else {
                format!(" ({})", f.note)
            }
        );
    }
    emit(&out);
    Ok(())
}

/// The CPU's model name (Linux), else "an unknown CPU".
fn cpu_name() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, v)| v.trim().to_string())
        })
        .unwrap_or_else(|| "an unknown CPU".into())
}
