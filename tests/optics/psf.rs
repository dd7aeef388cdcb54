//! PSFs of real lenses: a near-perfect case lands in the centre pixel, every PSF sums to 1, the
//! similarity of a PSF with itself is 1 and drops for a perturbed lens.

use tolray::lens::material::LAMBDA_D_NM;
use tolray::psf::{psf_map, psf_of, psf_similarity, PsfOptions};
use tolray::tolerance::ToleranceSpec;
use tolray::trace::{Bundles, Field, TraceOptions};
use tolray::{Lens, Object};

#[test]
fn stopped_down_lens_focuses_into_the_centre_pixel() {
    // lens2 at infinity stopped down to a 0.2 mm stop (about F/110): the geometric spot is far
    // below a pixel ...
    let mut l = Lens::load("lens2").unwrap();
    l.object = Object::Infinite;
    l.surfaces[4].semi_aperture_mm = 0.1;
    // ... with the sensor at the paraxial focus.
    let bfd = l.paraxial(LAMBDA_D_NM).unwrap().bfd_mm.unwrap();
    l.surfaces.last_mut().unwrap().d_next_mm = bfd;
    let opts = PsfOptions::for_lens(&l);
    let rays = Bundles::pairs(&l, &[(Field::fraction(0.0), LAMBDA_D_NM)], &opts.pupil).unwrap();
    let (p, chief) = psf_of(&l.compile(), &rays, 0, &opts, TraceOptions::default());
    let c = p[25 * 51 + 25];
    assert!(chief.is_some());
    assert!(c > 0.99, "centre pixel holds {c}");
    assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-12);
}

#[test]
fn psf_map_sums_and_similarities() {
    let mut l = Lens::load("cooke-triplet").unwrap();
    l.object = Object::Infinite;
    let mut opts = PsfOptions::for_lens(&l);
    opts.pupil.pattern = tolray::trace::PupilPattern::Random { n: 2048, seed: 1 };
    let map = psf_map(&l, &l.compile(), 4, LAMBDA_D_NM, &opts).unwrap();
    assert_eq!(map.len(), 16);
    for p in &map {
        assert!(
            (p.iter().sum::<f64>() - 1.0).abs() < 1e-5,
            "f32 map sums to 1"
        );
        assert!((psf_similarity(p, p, 51) - 1.0).abs() < 1e-12);
    }
    // Symmetric fields (left/right mirror) have mirrored PSFs: similarity of one with the
    // mirror of the other is ~1 (same rays mirrored, up to f32 rounding).
    let mirror = |p: &Vec<f64>| -> Vec<f64> {
        (0..51 * 51)
            .map(|k| p[(k / 51) * 51 + 50 - k % 51])
            .collect()
    };
    assert!(psf_similarity(&map[5], &mirror(&map[6]), 51) > 0.999);
    // A perturbed lens has a less similar PSF than the nominal one.
    let rays = Bundles::pairs(&l, &[(Field::fraction(0.7), LAMBDA_D_NM)], &opts.pupil).unwrap();
    let nominal = psf_of(&l.compile(), &rays, 0, &opts, TraceOptions::default()).0;
    let mut spec = ToleranceSpec::default();
    for op in spec.operands.iter_mut() {
        op.max *= 10.0;
    }
    let (pl, adj) = spec.sample(&l, 1, 0).unwrap().apply(&l).unwrap();
    let perturbed = psf_of(
        &tolray::lens::System::<f64>::compile(&pl, &adj, &|_, v| v),
        &rays,
        0,
        &opts,
        TraceOptions::default(),
    )
    .0;
    let s = psf_similarity(&nominal, &perturbed, 51);
    assert!(s < 0.99 && s > 0.0, "{s}");
}

/// The PSF map's fast path (rays generated straight into f32 blocks, a block at a time) gives the
/// PSFs of the general path (`Bundles::pairs` in f64, then `psf_of` on the f32 system), for a finite and
/// an infinite object.
#[test]
fn psf_map_fast_path_matches_psf_of() {
    for (name, object) in [("lens2", None), ("cooke-triplet", Some(Object::Infinite))] {
        let mut l = Lens::load(name).unwrap();
        if let Some(o) = object {
            l.object = o;
        }
        let mut opts = PsfOptions::for_lens(&l);
        opts.pupil.pattern = tolray::trace::PupilPattern::Random { n: 1000, seed: 3 };
        let sys = l.compile();
        let map = psf_map(&l, &sys, 3, LAMBDA_D_NM, &opts).unwrap();
        let pairs: Vec<(Field, f64)> = tolray::psf::grid_fields(&l, 3)
            .into_iter()
            .map(|f| (f, LAMBDA_D_NM))
            .collect();
        let rays = Bundles::pairs(&l, &pairs, &opts.pupil).unwrap();
        let sys32: tolray::lens::System<f32> = sys.convert();
        for (k, tile) in map.iter().enumerate() {
            let p = psf_of(&sys32, &rays, k, &opts, TraceOptions::default()).0;
            let worst = tile
                .iter()
                .zip(&p)
                .map(|(a, b)| (a - f64::from(*b)).abs())
                .fold(0.0, f64::max);
            assert!(worst < 1e-7, "{name} field {k}: differs by {worst}");
            assert!(tile.iter().sum::<f64>() > 0.5, "{name} field {k} is empty");
        }
    }
}

/// The streamed PSF (`psf_streamed`: rays generated, traced and splatted a chunk at a time) is
/// the PSF of all rays at once to rounding, centred on the chief ray or on the centroid, over
/// random, grid and aimed pupils, a perturbed lens and a pixel window too large for 16 partial
/// sums; and it is the same bits at 1 and 3 threads.
#[test]
fn streamed_psf_is_the_psf_of_all_rays() {
    use tolray::psf::{psf_streamed, PsfCentre};
    use tolray::trace::{Pupil, PupilPattern};
    let lens = Lens::load("lens2").unwrap();
    let spec = ToleranceSpec::default();
    let (pl, adj) = spec.sample(&lens, 3, 0).unwrap().apply(&lens).unwrap();
    let perturbed = tolray::lens::System::<f64>::compile(&pl, &adj, &|_, v| v);
    let nominal = lens.compile();
    let random = Pupil {
        pattern: PupilPattern::Random { n: 50_000, seed: 4 },
        scale: 1.0,
        aim: false,
    };
    let aimed = Pupil {
        aim: true,
        ..Pupil::grid(150)
    };
    let base = PsfOptions::for_lens(&lens);
    let cases = [
        (random, PsfCentre::Chief, 51, &perturbed),
        (random, PsfCentre::Centroid, 51, &perturbed),
        (Pupil::grid(200), PsfCentre::Chief, 51, &nominal),
        (aimed, PsfCentre::Centroid, 31, &nominal),
        (Pupil::grid(120), PsfCentre::Chief, 1025, &nominal),
    ];
    let pools: Vec<_> = [1, 3]
        .map(|n| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build();
            pool.unwrap()
        })
        .into();
    for (k, (pupil, centre, ks, sys)) in cases.into_iter().enumerate() {
        let opts = PsfOptions {
            pupil,
            centre,
            ks,
            pitch_mm: if ks > 1000 { 0.0007 } else { base.pitch_mm },
        };
        let field = Field::fraction(0.8);
        let wl = 486.1327;
        let streamed: Vec<_> = pools
            .iter()
            .map(|p| p.install(|| psf_streamed(&lens, sys, field, wl, &opts).unwrap()))
            .collect();
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&streamed[0].0), bits(&streamed[1].0), "case {k}");
        let rays = Bundles::pairs(&lens, &[(field, wl)], &opts.pupil).unwrap();
        let (whole, chief) = psf_of(sys, &rays, 0, &opts, TraceOptions::default());
        assert_eq!(streamed[0].1, chief, "case {k}");
        let (psf, _) = &streamed[0];
        assert!((psf.iter().sum::<f64>() - 1.0).abs() < 1e-12, "case {k}");
        assert!(
            psf.iter().filter(|&&x| x > 0.0).count() > 20,
            "case {k}: a real spread"
        );
        let worst = psf
            .iter()
            .zip(&whole)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        // A centroid summed chunk by chunk moves by its rounding (~1e-14 mm here), which moves
        // every ray's bilinear weights the same way: pixels differ by up to ~1e-14 then.
        let bound = match centre {
            PsfCentre::Chief => 1e-15,
            PsfCentre::Centroid => 1e-13,
        };
        assert!(worst < bound, "case {k}: {worst:e}");
    }
}
