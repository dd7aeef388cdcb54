//! The optimizer keeps the manufacturability constraints users set: centre thicknesses and air
//! gaps by projection (exactly), edge thickness, total track and a target EFL by penalties (to a
//! stated tolerance). Each case makes its constraint active: the unconstrained stage-1 design
//! would break it.

use tolray::lens::material::LAMBDA_D_NM;
use tolray::optim::train::{step, Constraints, TrainConfig, TrainState};
use tolray::Lens;

/// Runs `iters` stage-1 iterations on `lens` with `constraints` and returns the design.
fn pretrain(lens: &Lens, iters: usize, constraints: Constraints) -> Lens {
    let mut cfg = TrainConfig::for_lens(lens);
    cfg.pretrain_iters = iters;
    cfg.tolerance_iters = 0;
    cfg.constraints = constraints;
    let mut state = TrainState::new(lens, cfg);
    while state.next_iter < state.total_iters() {
        step(&mut state).unwrap();
    }
    state.lens
}

/// (centre thickness or air gap, edge thickness or gap, is glass) of each pair of neighbouring
/// surfaces, the edge taken at the smaller clear aperture.
fn gaps(lens: &Lens) -> Vec<(f64, f64, bool)> {
    lens.surfaces
        .windows(2)
        .map(|w| {
            let r = w[0].semi_aperture_mm.min(w[1].semi_aperture_mm);
            let edge = w[0].d_next_mm + w[1].sag(r).unwrap() - w[0].sag(r).unwrap();
            (w[0].d_next_mm, edge, !w[0].material.is_air())
        })
        .collect()
}

fn efl(lens: &Lens) -> f64 {
    lens.paraxial(LAMBDA_D_NM).unwrap().efl_mm.unwrap()
}

fn track(lens: &Lens) -> f64 {
    lens.paraxial(LAMBDA_D_NM).unwrap().total_track_mm
}

/// lens1's free stage-1 design (150 iterations, default constraints) thins the air gap after
/// surface 3 from 1.0 to 0.88 mm and the glass after surface 5 to 2.75 mm centre and 0.79 mm edge,
/// shortens the EFL from 48.5 to 47.6 mm and keeps the track near 60.4 mm. Each test sets a
/// constraint the free design breaks.
const ITERS: usize = 150;

#[test]
fn centre_thickness_and_air_gaps_hold_exactly() {
    let lens = Lens::load("lens1").unwrap();
    let c = Constraints {
        min_center_thickness_mm: 1.2, // the glass after surface 2 is 1.0 mm
        min_air_gap_mm: 1.1,          // the air gap after surface 3 is 1.0 mm
        ..Constraints::default()
    };
    let nominal = gaps(&lens);
    assert!(nominal[2].0 < 1.2 && nominal[2].2 && nominal[3].0 < 1.1 && !nominal[3].2);
    let out = pretrain(&lens, ITERS, c.clone());
    for (i, &(centre, _, glass)) in gaps(&out).iter().enumerate() {
        let min = if glass {
            c.min_center_thickness_mm
        } else {
            c.min_air_gap_mm
        };
        assert!(centre >= min, "gap after surface {i}: {centre} < {min}");
    }
}

#[test]
fn edge_thickness_holds() {
    let lens = Lens::load("lens1").unwrap();
    let c = Constraints {
        min_edge_thickness_mm: 0.9, // the free design takes surface 5's glass edge to 0.79
        ..Constraints::default()
    };
    let out = pretrain(&lens, ITERS, c.clone());
    for (i, &(_, edge, glass)) in gaps(&out).iter().enumerate() {
        if glass {
            println!("edge thickness after surface {i}: {edge:.4} mm");
            assert!(edge >= 0.9 - 0.01, "edge after surface {i}: {edge}");
        }
    }
}

#[test]
fn maximum_total_track_holds() {
    let lens = Lens::load("lens1").unwrap();
    let c = Constraints {
        max_total_track_mm: Some(60.0),
        ..Constraints::default()
    };
    let out = pretrain(&lens, ITERS, c);
    println!("track {:.4} mm", track(&out));
    assert!(track(&out) <= 60.0 + 0.01, "track {}", track(&out));
}

#[test]
fn target_efl_is_reached() {
    let lens = Lens::load("lens1").unwrap();
    let c = Constraints {
        target_efl_mm: Some(50.0),
        ..Constraints::default()
    };
    let out = pretrain(&lens, ITERS, c);
    println!("efl {:.4} mm", efl(&out));
    assert!((efl(&out) - 50.0).abs() < 0.05, "EFL {}", efl(&out));
}

/// A mirror system trains: the gap after the primary mirror (negative, light travelling toward
/// −z) keeps its sign through the projection, with at least the minimum air gap along the path,
/// and a gap squeezed below the minimum is pushed back to it on the light's side. (The projection
/// used to clamp every gap to +0.1 mm, which flipped the Cassegrain's −150 mm gap and failed the
/// first iteration.)
#[test]
fn mirror_systems_keep_their_negative_gaps() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/cassegrain.json");
    let lens = Lens::load(path).unwrap();
    assert!(lens.surfaces[0].d_next_mm < -100.0);
    let out = pretrain(&lens, 12, Constraints::default());
    let dirs = out.travel_directions();
    for (i, s) in out.surfaces.iter().enumerate() {
        assert!(
            s.d_next_mm * dirs[i + 1] >= 0.1,
            "gap {i}: {} mm against travel {}",
            s.d_next_mm,
            dirs[i + 1]
        );
    }
    assert!((out.surfaces[0].d_next_mm + 150.0).abs() < 1.0);
    // A squeezed gap on the reversed path is pushed to −min, not to +min.
    let mut squeezed = lens.clone();
    squeezed.surfaces[0].d_next_mm = -0.01;
    let mut cfg = TrainConfig::for_lens(&squeezed);
    cfg.pretrain_iters = 1;
    cfg.tolerance_iters = 0;
    let mut state = TrainState::new(&squeezed, cfg);
    step(&mut state).unwrap();
    let d = state.lens.surfaces[0].d_next_mm;
    assert!((-0.2..=-0.1).contains(&d), "{d}");
}

/// A lens with a virtual image (its image plane in front of the last surface) trains with the
/// image plane kept on that side: the projection bounds the image gap by 1 mm on its own side
/// instead of flipping it to +1 mm (which would turn the virtual image into a real plane 1 mm
/// behind the lens).
#[test]
fn a_virtual_image_stays_virtual() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/zemax/virtual-image.zmx"
    );
    let lens = tolray::lens::zemax::read_file(
        std::path::Path::new(path),
        &tolray::lens::GlassCatalogs::builtin(),
    )
    .unwrap()
    .lens;
    let out = pretrain(&lens, 10, Constraints::default());
    let gap = out.surfaces.last().unwrap().d_next_mm;
    assert!((-45.0..-30.0).contains(&gap), "{gap}");
    // Squeezed toward the lens, it stops at -1 mm.
    let mut near = lens.clone();
    near.surfaces.last_mut().unwrap().d_next_mm = -0.2;
    let out = pretrain(&near, 1, Constraints::default());
    let gap = out.surfaces.last().unwrap().d_next_mm;
    assert!((-1.1..=-1.0).contains(&gap), "{gap}");
}
