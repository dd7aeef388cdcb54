//! The evaluation report as one self-contained HTML file: the paper's Table 2 layout, paired
//! differences with bootstrap intervals, PSNR histograms per design (the paper's Fig. A2), PSF
//! similarity per design, and for the best, median and worst unit of each design the sharp,
//! captured and reconstructed image, which a reader flips between. Pictures are inline (SVG and
//! base64 PNG): the file needs nothing else.

use super::eval::{DesignScores, Report};
use crate::image::Image;
use base64::Engine;

/// One design's example images: (label, trial index or None for nominal, PSNR, [sharp,
/// captured, reconstructed]).
pub type Examples = Vec<(String, Vec<(String, f64, [Image; 3])>)>;

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

const COLOURS: [&str; 4] = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd"];

/// Overlaid PSNR histograms of every design, as inline SVG.
fn histogram_svg(
    scores: &[DesignScores],
    value: fn(&super::eval::TrialScore) -> f64,
    label: &str,
) -> String {
    let all: Vec<f64> = scores
        .iter()
        .flat_map(|s| s.trials.iter().map(value))
        .collect();
    let (lo, hi) = all
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    if !(lo.is_finite() && hi.is_finite()) {
        return String::new();
    }
    let (lo, hi) = if hi - lo < 1e-9 {
        (lo - 0.5, hi + 0.5)
    } else {
        (lo, hi)
    };
    let bins = 20usize;
    let (w, h, ml, mb, mt) = (640.0, 300.0, 56.0, 44.0, 14.0);
    let pw = w - ml - 16.0;
    let ph = h - mb - mt;
    let counts: Vec<Vec<usize>> = scores
        .iter()
        .map(|s| {
            let mut c = vec![0usize; bins];
            for t in &s.trials {
                let k = (((value(t) - lo) / (hi - lo)) * bins as f64).floor() as isize;
                c[k.clamp(0, bins as isize - 1) as usize] += 1;
            }
            c
        })
        .collect();
    let cmax = counts.iter().flatten().copied().max().unwrap_or(1).max(1) as f64;
    let mut svg = format!(
        "<svg xmlns='http://www.w3.org/2000/svg' viewBox='0 0 {w} {h}' width='{w}' height='{h}' font-family='sans-serif' font-size='12'>"
    );
    svg.push_str(&format!(
        "<line x1='{ml}' y1='{}' x2='{}' y2='{}' stroke='#333'/><line x1='{ml}' y1='{mt}' x2='{ml}' y2='{}' stroke='#333'/>",
        mt + ph, ml + pw, mt + ph, mt + ph
    ));
    for k in 0..=4 {
        let v = lo + (hi - lo) * k as f64 / 4.0;
        let x = ml + pw * k as f64 / 4.0;
        svg.push_str(&format!(
            "<line x1='{x}' y1='{}' x2='{x}' y2='{}' stroke='#333'/><text x='{x}' y='{}' text-anchor='middle'>{v:.2}</text>",
            mt + ph, mt + ph + 5.0, mt + ph + 18.0
        ));
    }
    // Whole-number count ticks.
    let step = (cmax / 4.0).ceil().max(1.0);
    let mut c = 0.0;
    while c <= cmax {
        let y = mt + ph - ph * c / cmax;
        svg.push_str(&format!(
            "<line x1='{}' y1='{y}' x2='{ml}' y2='{y}' stroke='#333'/><text x='{}' y='{}' text-anchor='end'>{c:.0}</text>",
            ml - 5.0,
            ml - 8.0,
            y + 4.0
        ));
        c += step;
    }
    svg.push_str(&format!(
        "<text x='{}' y='{}' text-anchor='middle'>{}</text><text x='14' y='{}' text-anchor='middle' transform='rotate(-90 14 {})'>units</text>",
        ml + pw / 2.0,
        h - 6.0,
        esc(label),
        mt + ph / 2.0,
        mt + ph / 2.0
    ));
    let bw = pw / bins as f64;
    for (d, c) in counts.iter().enumerate() {
        let col = COLOURS[d % COLOURS.len()];
        for (k, &n) in c.iter().enumerate() {
            if n == 0 {
                continue;
            }
            let bh = ph * n as f64 / cmax;
            svg.push_str(&format!(
                "<rect x='{:.1}' y='{:.1}' width='{:.1}' height='{bh:.1}' fill='{col}' fill-opacity='0.35' stroke='{col}'/>",
                ml + k as f64 * bw,
                mt + ph - bh,
                bw
            ));
        }
        svg.push_str(&format!(
            "<rect x='{}' y='{}' width='12' height='12' fill='{col}' fill-opacity='0.5' stroke='{col}'/><text x='{}' y='{}'>{}</text>",
            ml + pw - 170.0,
            mt + 6.0 + 18.0 * d as f64,
            ml + pw - 152.0,
            mt + 16.0 + 18.0 * d as f64,
            esc(&scores[d].name)
        ));
    }
    svg.push_str("</svg>");
    svg
}

fn png_data_uri(img: &Image) -> String {
    let bytes = img.encode_png().unwrap_or_default();
    format!(
        "data:image/png;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes)
    )
}

/// The report as HTML.
pub fn render(report: &Report, examples: &Examples) -> String {
    let mut h = String::from(
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>tolray deep-optics evaluation</title><style>\
         body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}\
         table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:4px 10px;text-align:right}\
         th{background:#eee}td:first-child{text-align:left}figure{display:inline-block;margin:8px}\
         .flip img{width:384px;image-rendering:pixelated;border:1px solid #999}\
         button{margin:2px}</style></head><body>",
    );
    let c = &report.config;
    h.push_str(&format!(
        "<h1>Deep-optics evaluation</h1><p>{} random fabricated units per design (tolerance patterns of seed {}, the same for every design), \
         RGB PSF maps of {}x{} kernels of {} px ({} rays each), Gaussian noise σ = {}{}, {}; images: {}. \
         PSNR and SSIM on sRGB-encoded images; yield: the PSNR that 90/70/50/10 % of units exceed.</p>",
        c.trials,
        c.seed,
        c.grid,
        c.grid,
        c.ks,
        c.spp,
        c.noise_sigma,
        c.full_well_electrons
            .map_or(String::new(), |f| format!(" and photon shot noise of a {f}-electron full well")),
        if c.compensate_focus { "each unit refocused (focus compensator)" } else { "no refocus" },
        esc(&report.images.join(", "))
    ));
    h.push_str("<h2>Table 2 layout</h2><table id='designs'><tr><th>design</th><th>RMS spot (µm)</th><th>PSNR (dB)</th><th>SSIM</th><th>PSF similarity</th><th>PSNR @90 %</th><th>@70 %</th><th>@50 %</th><th>@10 %</th><th>nominal PSNR</th></tr>");
    for d in &report.designs {
        let y = &d.psnr.yield_table;
        h.push_str(&format!(
            "<tr><td>{}</td><td>{:.2}</td><td>{:.2} ± {:.2}</td><td>{:.4}</td><td>{:.3}</td><td>{:.2}</td><td>{:.2}</td><td>{:.2}</td><td>{:.2}</td><td>{:.2}</td></tr>",
            esc(&d.name),
            d.rms_spot_um.mean,
            d.psnr.mean,
            d.psnr.std,
            d.ssim.mean,
            d.psf_similarity.mean,
            y.y90,
            y.y70,
            y.y50,
            y.y10,
            d.nominal_psnr
        ));
    }
    h.push_str("</table>");
    if !report.pairs.is_empty() {
        h.push_str("<h2>Paired differences (a − b)</h2><table id='pairs'><tr><th>a</th><th>b</th><th>mean PSNR (dB)</th><th>95 % interval</th><th>PSNR @90 % (dB)</th><th>95 % interval</th></tr>");
        for p in &report.pairs {
            h.push_str(&format!(
                "<tr><td>{}</td><td style='text-align:left'>{}</td><td>{:+.3}</td><td>[{:+.3}, {:+.3}]</td><td>{:+.3}</td><td>[{:+.3}, {:+.3}]</td></tr>",
                esc(&p.a),
                esc(&p.b),
                p.psnr_mean_diff,
                p.psnr_mean_diff_ci95[0],
                p.psnr_mean_diff_ci95[1],
                p.psnr_yield90_diff,
                p.psnr_yield90_diff_ci95[0],
                p.psnr_yield90_diff_ci95[1]
            ));
        }
        h.push_str("</table>");
    }
    h.push_str("<h2>PSNR over fabricated units</h2>");
    h.push_str(&histogram_svg(&report.scores, |t| t.psnr, "PSNR (dB)"));
    h.push_str("<h2>PSF similarity to the nominal design</h2>");
    h.push_str(&histogram_svg(
        &report.scores,
        |t| t.psf_similarity,
        "PSF similarity",
    ));
    h.push_str("<h2>Examples</h2><p>The first evaluation image of the best, median and worst unit of each design; the buttons flip between the sharp, captured and reconstructed image.</p>");
    let mut id = 0;
    for (design, list) in examples {
        h.push_str(&format!("<h3>{}</h3>", esc(design)));
        for (label, psnr, imgs) in list {
            let uris: Vec<String> = imgs.iter().map(png_data_uri).collect();
            h.push_str(&format!(
                "<figure class='flip'><img id='ex{id}' src='{}' alt='{} {} reconstructed'><figcaption>{} ({psnr:.2} dB): \
                 <button onclick=\"document.getElementById('ex{id}').src=this.dataset.u\" data-u='{}'>sharp</button>\
                 <button onclick=\"document.getElementById('ex{id}').src=this.dataset.u\" data-u='{}'>captured</button>\
                 <button onclick=\"document.getElementById('ex{id}').src=this.dataset.u\" data-u='{}'>reconstructed</button></figcaption></figure>",
                uris[2],
                esc(design),
                esc(label),
                esc(label),
                uris[0],
                uris[1],
                uris[2]
            ));
            id += 1;
        }
    }
    // For headless checks (and curious readers): how many images decoded once the page loaded.
    h.push_str(
        "<script>window.addEventListener('load',()=>{const im=[...document.images];\
         const ok=im.filter(i=>i.complete&&i.naturalWidth>0).length;\
         document.body.setAttribute('data-images',ok+'/'+im.length);});</script>",
    );
    h.push_str("</body></html>\n");
    h
}
