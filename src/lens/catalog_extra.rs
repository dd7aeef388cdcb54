//! The hand-kept part of the built-in glass catalog: glasses the refractiveindex.info database
//! (from which `catalog_data.rs` is generated) does not have, each with its source. Edited by
//! hand; `scripts/glass/generate_catalog.py` leaves out of the generated table any name kept
//! here. `material::catalog()` is the two together, sorted by vendor then name.
//!
//! - **Misc**: plastics and crystals from the Zemax `MISC.AGF` catalog as committed in the
//!   DeepLens repository: PMMA, POLYCARB, POLYSTYR (Handbook of Optics Vol. II), COC (Hoechst
//!   Celanese), F_SILICA and SILICA (fused silica, both Malitson 1965, as Zemax's MISC catalog
//!   has both names), CAF2 (Handbook of Optics Vol. II).
use super::material::{CatalogGlass, Dispersion};

/// Hand-kept catalog glasses.
pub(crate) const EXTRA: &[CatalogGlass] = &[
    CatalogGlass {
        name: "CAF2",
        vendor: "Misc",
        dispersion: Dispersion::Sellmeier3 {
            b: [0.5675888, 0.4710914, 3.8484723],
            c: [0.00252643, 0.010078333, 1200.556],
        },
        nd: 1.433849,
        vd: 94.995854,
        range_um: (0.23, 9.7),
    },
    CatalogGlass {
        name: "COC",
        vendor: "Misc",
        dispersion: Dispersion::Schott {
            a: [
                2.28448546,
                0.0102952211,
                0.0373493703,
                -0.00928409653,
                0.00173289808,
                -0.000115203047,
            ],
        },
        nd: 1.533732,
        vd: 56.227932,
        range_um: (0.334, 2.325),
    },
    CatalogGlass {
        name: "F_SILICA",
        vendor: "Misc",
        dispersion: Dispersion::Sellmeier3 {
            b: [0.6961663, 0.4079426, 0.8974794],
            c: [0.004679148, 0.013512063, 97.9340025],
        },
        nd: 1.458464,
        vd: 67.821433,
        range_um: (0.21, 3.71),
    },
    CatalogGlass {
        name: "PMMA",
        vendor: "Misc",
        dispersion: Dispersion::Schott {
            a: [
                2.1864582,
                -0.00024475348,
                0.014155787,
                -0.00044329781,
                7.7664259e-05,
                -2.9936382e-06,
            ],
        },
        nd: 1.491756,
        vd: 57.440791,
        range_um: (0.365, 1.06),
    },
    CatalogGlass {
        name: "POLYCARB",
        vendor: "Misc",
        dispersion: Dispersion::Schott {
            a: [
                2.42838566,
                -3.86116645e-05,
                0.0287574474,
                -0.000197897366,
                0.000148358968,
                1.38651935e-06,
            ],
        },
        nd: 1.58547,
        vd: 29.909185,
        range_um: (0.365, 1.014),
    },
    CatalogGlass {
        name: "POLYSTYR",
        vendor: "Misc",
        dispersion: Dispersion::Schott {
            a: [
                2.44598368,
                2.21428933e-05,
                0.0272988569,
                0.000301210852,
                8.88934888e-05,
                -1.75707929e-06,
            ],
        },
        nd: 1.590481,
        vd: 30.866877,
        range_um: (0.365, 1.014),
    },
    CatalogGlass {
        name: "SILICA",
        vendor: "Misc",
        dispersion: Dispersion::Sellmeier3 {
            b: [0.6961663, 0.4079426, 0.8974794],
            c: [0.004679148, 0.013512063, 97.9340025],
        },
        nd: 1.458464,
        vd: 67.821433,
        range_um: (0.21, 3.71),
    },
];
