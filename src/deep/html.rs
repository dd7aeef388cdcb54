//! The evaluation report as one self-contained HTML file: the paper's Table 2 layout, paired
//! differences with bootstrap intervals, the distribution of PSNR over the fabricated units of
//! every design as yield curves (the paper's Fig. A2 as cumulative curves), PSF similarity
//! likewise, and for the best, median and worst unit of each design the sharp,
//! captured and reconstructed image, which a reader flips between. Pictures are inline (SVG and
//! base64 PNG): the file needs nothing else.

use super::eval::{DesignScores, Report};
use crate::figures::{self, CurveSpec};
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

/// The distribution of a score over the fabricated units of every design, as inline SVG drawn
/// by the figures module: for each design the fraction of units that reach at least x (the
/// yield curve, read off directly: where it crosses 0.9 is the value 90 % of units reach), with
/// the 90 % line dashed.
fn distribution_svg(
    scores: &[DesignScores],
    value: fn(&super::eval::TrialScore) -> f64,
    x_desc: &str,
    title: &str,
) -> String {
    let mut series: Vec<CurveSpec> = Vec::new();
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (d, sc) in scores.iter().enumerate() {
        let mut v: Vec<f64> = sc
            .trials
            .iter()
            .map(value)
            .filter(|x| x.is_finite())
            .collect();
        if v.is_empty() {
            continue;
        }
        v.sort_by(f64::total_cmp);
        lo = lo.min(v[0]);
        hi = hi.max(v[v.len() - 1]);
        series.push((sc.name.clone(), d, false, survival_steps(&v)));
    }
    if series.is_empty() {
        return String::new();
    }
    let pad = if hi - lo < 1e-9 {
        0.5
    } else {
        0.02 * (hi - lo)
    };
    series.push((
        "90 % of units".to_string(),
        6,
        true,
        vec![(lo - pad, 0.9), (hi + pad, 0.9)],
    ));
    let fig = figures::curves_figure(
        title,
        x_desc,
        "fraction of units at least x",
        Some(0.0..1.02),
        &series,
    );
    fig.to_svg().unwrap_or_default()
}

/// The step curve of the fraction of `sorted` values (ascending) that are at least x.
fn survival_steps(sorted: &[f64]) -> Vec<(f64, f64)> {
    let n = sorted.len() as f64;
    let mut pts = vec![(sorted[0], 1.0)];
    for (i, &x) in sorted.iter().enumerate() {
        let above = (sorted.len() - i - 1) as f64 / n;
        pts.push((x, pts[pts.len() - 1].1));
        pts.push((x, above));
    }
    pts
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
    let (header, rows) = report.design_table();
    h.push_str("<h2>Table 2 layout</h2><table id='designs'><tr>");
    for c in header {
        h.push_str(&format!("<th>{}</th>", esc(c)));
    }
    h.push_str("</tr>");
    for row in &rows {
        h.push_str("<tr>");
        for c in row {
            h.push_str(&format!("<td>{}</td>", esc(c)));
        }
        h.push_str("</tr>");
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
    h.push_str(&distribution_svg(
        &report.scores,
        |t| t.psnr,
        "PSNR (dB)",
        "PSNR yield: fraction of units reaching at least x",
    ));
    h.push_str("<h2>PSF similarity to the nominal design</h2>");
    h.push_str(&distribution_svg(
        &report.scores,
        |t| t.psf_similarity,
        "PSF similarity",
        "PSF similarity: fraction of units reaching at least x",
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
