//! Built-in glass catalog: dispersion data transcribed from the public manufacturer catalogs.
//!
//! Every coefficient below is copied verbatim (no refitting, no reordering of terms) from a
//! publicly distributed catalog, using the dispersion formula the catalog itself uses:
//!
//! - **Schott**: SCHOTT Zemax catalog 2017-01-20b (public download from schott.com), as mirrored
//!   in the refractiveindex.info database (`database/data-nk/glass/schott/*.yml`, CC0). LAFN7 is
//!   taken from the SCHOTT Zemax catalog of December 2024 (`SCHOTT.AGF`, "preferred, inquiry,
//!   AR glasses (revC)") as committed in the DeepLens repository. All Schott glasses use the
//!   Sellmeier formula.
//! - **CDGM**: CDGM Zemax catalog 2022-06 (`CDGM-ZEMAX202206new.AGF`, public download from
//!   cdgmgd.com) via refractiveindex.info (`glass/cdgm/*.yml`). Most CDGM glasses use the
//!   Sellmeier formula; H-ZK9A, H-ZLAF52 and ZF6 use the Schott formula in that catalog.
//!   CDGM's Sellmeier terms are kept in the catalog's own order (not sorted by resonance).
//! - **Ohara**: OHARA Zemax catalog 2017-11-30 (public download from ohara-inc.co.jp) via
//!   refractiveindex.info (`glass/ohara/*.yml`). Sellmeier formula.
//! - **Hikari**: Nikon/Hikari Zemax catalog 2017-11 via refractiveindex.info
//!   (`glass/hikari/*.yml`), in the catalog's extended 9-term formula.
//! - **Misc**: plastics and crystals from the Zemax `MISC.AGF` catalog (as committed in the
//!   DeepLens repository): PMMA, POLYCARB, POLYSTYR (Handbook of Optics Vol. II), COC
//!   (Hoechst Celanese spec sheet), F_SILICA (Malitson 1965 fused silica), CAF2 (Handbook of
//!   Optics Vol. II). Names are the catalog names.
//!
//! `nd`/`vd` are the catalog's nominal values (n_d at 587.56 nm, V_d) and `range_um` is the
//! catalog's stated valid wavelength range of the formula. All data came from public catalogs.
//! Generated and checked by a transcription script: each entry reproduces its catalog n_d to
//! 2e-5 and V_d to 0.05 when evaluated at the d, F and C lines.
use super::material::{CatalogGlass, Dispersion};

/// Built-in catalog glasses, sorted by vendor then name.
pub(crate) const CATALOG: &[CatalogGlass] = &[
    CatalogGlass {
        name: "H-BAK7",
        vendor: "CDGM",
        dispersion: Dispersion::Sellmeier3 {
            b: [0.659469741, 0.7621967, 1.19935835],
            c: [0.000766009635, 0.0177403402, 129.975103],
        },
        nd: 1.56883,
        vd: 56.041308,
        range_um: (0.365, 2.325),
    },
    CatalogGlass {
        name: "H-F4",
        vendor: "CDGM",
        dispersion: Dispersion::Sellmeier3 {
            b: [0.131898794, 1.42441827, 1.21746316],
            c: [0.05793195, 0.0106270032, 117.376535],
        },
        nd: 1.62005,
        vd: 36.345886,
        range_um: (0.365, 2.325),
    },
    CatalogGlass {
        name: "H-K51",
        vendor: "CDGM",
        dispersion: Dispersion::Sellmeier3 {
            b: [0.960161808, 1.18368963, 0.102338243],
            c: [116.24248, 0.0118029997, -0.0189575777],
        },
        nd: 1.52307,
        vd: 58.639792,
        range_um: (0.365, 2.325),
    },
    CatalogGlass {
        name: "H-K9L",
        vendor: "CDGM",
        dispersion: Dispersion::Sellmeier3 {
            b: [0.614555251, 0.656775017, 1.02699346],
            c: [0.0145987884, 0.00287769588, 107.653051],
        },
        nd: 1.5168,
        vd: 64.198732,
        range_um: (0.302, 2.325),
    },
    CatalogGlass {
        name: "H-LAK51A",
        vendor: "CDGM",
        dispersion: Dispersion::Sellmeier3 {
            b: [0.639398694, 1.18748481, 1.26545352],
            c: [5.67124825e-05, 0.0158001968, 91.097053],
        },
        nd: 1.6968,
        vd: 55.526357,
        range_um: (0.302, 2.325),
    },
    CatalogGlass {
        name: "H-QK3L",
        vendor: "CDGM",
        dispersion: Dispersion::Sellmeier3 {
            b: [0.601737491, 0.858737004, 0.586761501],
            c: [0.012574974, 92.3325663, 0.002687509],
        },
        nd: 1.48749,
        vd: 70.440487,
        range_um: (0.302, 2.325),
    },
    CatalogGlass {
        name: "H-ZF1",
        vendor: "CDGM",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.06294164, 0.146910876, 1.48922543],
            c: [108.400406, 0.0591797128, 0.0115933111],
        },
        nd: 1.64769,
        vd: 33.840317,
        range_um: (0.365, 2.325),
    },
    CatalogGlass {
        name: "H-ZF2",
        vendor: "CDGM",
        dispersion: Dispersion::Sellmeier3 {
            b: [0.16764338, 1.54335076, 1.17313123],
            c: [0.0605177711, 0.0118524273, 113.6711],
        },
        nd: 1.6727,
        vd: 32.171186,
        range_um: (0.365, 2.325),
    },
    CatalogGlass {
        name: "H-ZF52",
        vendor: "CDGM",
        dispersion: Dispersion::Sellmeier3 {
            b: [0.409982615, 2.37517176, 1.83913582],
            c: [0.0621421199, 185.055134, 0.0136093459],
        },
        nd: 1.84666,
        vd: 23.784497,
        range_um: (0.4047, 2.325),
    },
    CatalogGlass {
        name: "H-ZK9A",
        vendor: "CDGM",
        dispersion: Dispersion::Schott {
            a: [
                2.58407802,
                -0.0111281379,
                0.0154281597,
                2.64033929e-05,
                2.77466467e-05,
                -1.24493904e-06,
            ],
        },
        nd: 1.620412,
        vd: 60.368242,
        range_um: (0.365, 1.014),
    },
    CatalogGlass {
        name: "H-ZK9B",
        vendor: "CDGM",
        dispersion: Dispersion::Sellmeier3 {
            b: [0.874918734, 0.7096273, 1.09453882],
            c: [0.00373965378, 0.0163972089, 100.204324],
        },
        nd: 1.62041,
        vd: 60.339343,
        range_um: (0.302, 2.325),
    },
    CatalogGlass {
        name: "H-ZLAF52",
        vendor: "CDGM",
        dispersion: Dispersion::Schott {
            a: [
                3.16943454,
                -0.0124379117,
                0.0322101116,
                0.000181456299,
                8.90652926e-05,
                -1.91933145e-06,
            ],
        },
        nd: 1.806099,
        vd: 40.945389,
        range_um: (0.365, 1.014),
    },
    CatalogGlass {
        name: "H-ZLAF52A",
        vendor: "CDGM",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.85313688, 0.317938591, 1.16396318],
            c: [0.00985534639, 0.0392611678, 93.1032763],
        },
        nd: 1.8061,
        vd: 41.016887,
        range_um: (0.365, 2.325),
    },
    CatalogGlass {
        name: "ZF6",
        vendor: "CDGM",
        dispersion: Dispersion::Schott {
            a: [
                2.96285995,
                -0.0104077823,
                0.0356441238,
                0.00245699205,
                -0.000149615893,
                1.77827751e-05,
            ],
        },
        nd: 1.755205,
        vd: 27.546239,
        range_um: (0.365, 1.014),
    },
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
        name: "S-BAH11",
        vendor: "Ohara",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.5713886, 0.147869313, 1.28092846],
            c: [0.00910807936, 0.0402401684, 130.399367],
        },
        nd: 1.666718,
        vd: 48.325247,
        range_um: (0.34, 2.4),
    },
    CatalogGlass {
        name: "S-BAL14",
        vendor: "Ohara",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.27553696, 0.146083393, 1.16754699],
            c: [0.00749692359, 0.031042153, 128.947092],
        },
        nd: 1.568832,
        vd: 56.363897,
        range_um: (0.33, 2.4),
    },
    CatalogGlass {
        name: "S-BAL42",
        vendor: "Ohara",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.39570615, 0.071850507, 1.27129267],
            c: [0.0112218843, -0.0252117422, 134.49786],
        },
        nd: 1.583126,
        vd: 59.374673,
        range_um: (0.29, 2.4),
    },
    CatalogGlass {
        name: "S-BSL7",
        vendor: "Ohara",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.1515019, 0.118583612, 1.26301359],
            c: [0.010598413, -0.011822519, 129.617662],
        },
        nd: 1.51633,
        vd: 64.142022,
        range_um: (0.29, 2.4),
    },
    CatalogGlass {
        name: "S-FSL5",
        vendor: "Ohara",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.17447043, 0.0140056154, 1.19272435],
            c: [0.00841855181, -0.0581790767, 129.599726],
        },
        nd: 1.48749,
        vd: 70.236252,
        range_um: (0.28, 2.4),
    },
    CatalogGlass {
        name: "S-LAH55VS",
        vendor: "Ohara",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.92591095, 0.34895346, 1.42230744],
            c: [0.0096115249, 0.036513298, 103.36409],
        },
        nd: 1.834809,
        vd: 42.74368,
        range_um: (0.365015, 2.32542),
    },
    CatalogGlass {
        name: "S-LAH58",
        vendor: "Ohara",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.78764964, 0.6526356, 1.79914564],
            c: [0.00847378536, 0.0313126408, 132.788001],
        },
        nd: 1.882997,
        vd: 40.765107,
        range_um: (0.32, 2.4),
    },
    CatalogGlass {
        name: "S-LAL14",
        vendor: "Ohara",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.2372097, 0.589722623, 1.3192188],
            c: [0.015355132, -0.00030789625, 93.7202947],
        },
        nd: 1.696797,
        vd: 55.532241,
        range_um: (0.28, 2.4),
    },
    CatalogGlass {
        name: "S-NPH1",
        vendor: "Ohara",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.75156623, 0.364006304, 2.47874141],
            c: [0.0135004681, 0.0668245147, 170.756006],
        },
        nd: 1.808095,
        vd: 22.760817,
        range_um: (0.38, 2.4),
    },
    CatalogGlass {
        name: "S-TIH11",
        vendor: "Ohara",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.72677471, 0.324568628, 2.65816809],
            c: [0.0129369958, 0.0618255245, 221.904637],
        },
        nd: 1.784723,
        vd: 25.683446,
        range_um: (0.37, 2.4),
    },
    CatalogGlass {
        name: "S-TIH53",
        vendor: "Ohara",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.87904886, 0.369719775, 2.33730863],
            c: [0.014412177, 0.063881799, 182.66818],
        },
        nd: 1.84666,
        vd: 23.77794,
        range_um: (0.37, 2.4),
    },
    CatalogGlass {
        name: "S-TIL6",
        vendor: "Ohara",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.17701777, 0.12795803, 1.34740124],
            c: [0.00771087686, 0.0411325328, 154.531692],
        },
        nd: 1.531717,
        vd: 48.840718,
        range_um: (0.34, 2.4),
    },
    CatalogGlass {
        name: "S-TIM35",
        vendor: "Ohara",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.55849775, 0.230767007, 1.84436099],
            c: [0.0115367235, 0.0586095947, 162.981888],
        },
        nd: 1.698947,
        vd: 30.127865,
        range_um: (0.37, 2.4),
    },
    CatalogGlass {
        name: "F2",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.34533359, 0.209073176, 0.937357162],
            c: [0.00997743871, 0.0470450767, 111.886764],
        },
        nd: 1.62004,
        vd: 36.37,
        range_um: (0.32, 2.5),
    },
    CatalogGlass {
        name: "F5",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.3104463, 0.19603426, 0.96612977],
            c: [0.00958633048, 0.0457627627, 115.011883],
        },
        nd: 1.60342,
        vd: 38.03,
        range_um: (0.32, 2.5),
    },
    CatalogGlass {
        name: "LAFN7",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.66842615, 0.298512803, 1.0774376],
            c: [0.0103159999, 0.0469216348, 82.5078509],
        },
        nd: 1.7495,
        vd: 34.95,
        range_um: (0.35, 2.5),
    },
    CatalogGlass {
        name: "N-BAF10",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.5851495, 0.143559385, 1.08521269],
            c: [0.00926681282, 0.0424489805, 105.613573],
        },
        nd: 1.67003,
        vd: 47.11,
        range_um: (0.35, 2.5),
    },
    CatalogGlass {
        name: "N-BAK1",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.12365662, 0.309276848, 0.881511957],
            c: [0.00644742752, 0.0222284402, 107.297751],
        },
        nd: 1.5725,
        vd: 57.55,
        range_um: (0.3, 2.5),
    },
    CatalogGlass {
        name: "N-BAK4",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.28834642, 0.132817724, 0.945395373],
            c: [0.00779980626, 0.0315631177, 105.965875],
        },
        nd: 1.56883,
        vd: 55.98,
        range_um: (0.334, 2.5),
    },
    CatalogGlass {
        name: "N-BALF4",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.31004128, 0.142038259, 0.964929351],
            c: [0.0079659645, 0.0330672072, 109.19732],
        },
        nd: 1.57956,
        vd: 53.87,
        range_um: (0.35, 2.5),
    },
    CatalogGlass {
        name: "N-BK10",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [0.888308131, 0.328964475, 0.984610769],
            c: [0.00516900822, 0.0161190045, 99.7575331],
        },
        nd: 1.49782,
        vd: 66.95,
        range_um: (0.29, 2.5),
    },
    CatalogGlass {
        name: "N-BK7",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.03961212, 0.231792344, 1.01046945],
            c: [0.00600069867, 0.0200179144, 103.560653],
        },
        nd: 1.5168,
        vd: 64.17,
        range_um: (0.3, 2.5),
    },
    CatalogGlass {
        name: "N-F2",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.39757037, 0.159201403, 1.2686543],
            c: [0.00995906143, 0.0546931752, 119.248346],
        },
        nd: 1.62005,
        vd: 36.43,
        range_um: (0.365, 2.5),
    },
    CatalogGlass {
        name: "N-FK5",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [0.844309338, 0.344147824, 0.910790213],
            c: [0.00475111955, 0.0149814849, 97.8600293],
        },
        nd: 1.48749,
        vd: 70.41,
        range_um: (0.26, 2.5),
    },
    CatalogGlass {
        name: "N-K5",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.08511833, 0.199562005, 0.930511663],
            c: [0.00661099503, 0.024110866, 111.982777],
        },
        nd: 1.52249,
        vd: 59.48,
        range_um: (0.31, 2.5),
    },
    CatalogGlass {
        name: "N-KZFS4",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.35055424, 0.197575506, 1.09962992],
            c: [0.0087628207, 0.0371767201, 90.3866994],
        },
        nd: 1.61336,
        vd: 44.49,
        range_um: (0.334, 2.5),
    },
    CatalogGlass {
        name: "N-LAF2",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.80984227, 0.15729555, 1.0930037],
            c: [0.0101711622, 0.0442431765, 100.687748],
        },
        nd: 1.74397,
        vd: 44.85,
        range_um: (0.35, 2.5),
    },
    CatalogGlass {
        name: "N-LAK22",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.14229781, 0.535138441, 1.04088385],
            c: [0.00585778594, 0.0198546147, 100.834017],
        },
        nd: 1.65113,
        vd: 55.89,
        range_um: (0.31, 2.5),
    },
    CatalogGlass {
        name: "N-LAK34",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.26661442, 0.665919318, 1.1249612],
            c: [0.00589278062, 0.0197509041, 78.8894174],
        },
        nd: 1.72916,
        vd: 54.5,
        range_um: (0.29, 2.5),
    },
    CatalogGlass {
        name: "N-LAK9",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.46231905, 0.344399589, 1.15508372],
            c: [0.00724270156, 0.0243353131, 85.4686868],
        },
        nd: 1.691,
        vd: 54.71,
        range_um: (0.3, 2.5),
    },
    CatalogGlass {
        name: "N-LASF44",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.78897105, 0.38675867, 1.30506243],
            c: [0.00872506277, 0.0308085023, 92.7743824],
        },
        nd: 1.8042,
        vd: 46.5,
        range_um: (0.334, 2.5),
    },
    CatalogGlass {
        name: "N-LASF9",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [2.00029547, 0.298926886, 1.80691843],
            c: [0.0121426017, 0.0538736236, 156.530829],
        },
        nd: 1.85025,
        vd: 32.17,
        range_um: (0.365, 2.5),
    },
    CatalogGlass {
        name: "N-PK51",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.15610775, 0.153229344, 0.785618966],
            c: [0.00585597402, 0.0194072416, 140.537046],
        },
        nd: 1.52855,
        vd: 76.98,
        range_um: (0.3, 2.5),
    },
    CatalogGlass {
        name: "N-PK52A",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.029607, 0.1880506, 0.736488165],
            c: [0.00516800155, 0.0166658798, 138.964129],
        },
        nd: 1.497,
        vd: 81.61,
        range_um: (0.29, 2.5),
    },
    CatalogGlass {
        name: "N-SF10",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.62153902, 0.256287842, 1.64447552],
            c: [0.0122241457, 0.0595736775, 147.468793],
        },
        nd: 1.72828,
        vd: 28.53,
        range_um: (0.38, 2.5),
    },
    CatalogGlass {
        name: "N-SF11",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.73759695, 0.313747346, 1.89878101],
            c: [0.013188707, 0.0623068142, 155.23629],
        },
        nd: 1.78472,
        vd: 25.68,
        range_um: (0.37, 2.5),
    },
    CatalogGlass {
        name: "N-SF5",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.52481889, 0.187085527, 1.42729015],
            c: [0.011254756, 0.0588995392, 129.141675],
        },
        nd: 1.67271,
        vd: 32.25,
        range_um: (0.37, 2.5),
    },
    CatalogGlass {
        name: "N-SF57",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.87543831, 0.37375749, 2.30001797],
            c: [0.0141749518, 0.0640509927, 177.389795],
        },
        nd: 1.84666,
        vd: 23.78,
        range_um: (0.37, 2.5),
    },
    CatalogGlass {
        name: "N-SF6",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.77931763, 0.338149866, 2.08734474],
            c: [0.0133714182, 0.0617533621, 174.01759],
        },
        nd: 1.80518,
        vd: 25.36,
        range_um: (0.37, 2.5),
    },
    CatalogGlass {
        name: "N-SK14",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [0.936155374, 0.594052018, 1.04374583],
            c: [0.00461716525, 0.016885927, 103.736265],
        },
        nd: 1.60311,
        vd: 60.6,
        range_um: (0.31, 2.5),
    },
    CatalogGlass {
        name: "N-SK16",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.34317774, 0.241144399, 0.994317969],
            c: [0.00704687339, 0.0229005, 92.7508526],
        },
        nd: 1.62041,
        vd: 60.32,
        range_um: (0.31, 2.5),
    },
    CatalogGlass {
        name: "N-SK2",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.28189012, 0.257738258, 0.96818604],
            c: [0.0072719164, 0.0242823527, 110.377773],
        },
        nd: 1.60738,
        vd: 56.65,
        range_um: (0.31, 2.5),
    },
    CatalogGlass {
        name: "N-SK4",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.32993741, 0.228542996, 0.988465211],
            c: [0.00716874107, 0.0246455892, 100.886364],
        },
        nd: 1.61272,
        vd: 58.63,
        range_um: (0.334, 2.5),
    },
    CatalogGlass {
        name: "N-SSK2",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.4306027, 0.153150554, 1.01390904],
            c: [0.00823982975, 0.0333736841, 106.870822],
        },
        nd: 1.62229,
        vd: 53.27,
        range_um: (0.35, 2.5),
    },
    CatalogGlass {
        name: "N-SSK8",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.44857867, 0.117965926, 1.06937528],
            c: [0.00869310149, 0.0421566593, 111.300666],
        },
        nd: 1.61773,
        vd: 49.83,
        range_um: (0.35, 2.5),
    },
    CatalogGlass {
        name: "N-ZK7",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.07715032, 0.168079109, 0.851889892],
            c: [0.00676601657, 0.0230642817, 89.0498778],
        },
        nd: 1.50847,
        vd: 61.19,
        range_um: (0.3, 2.5),
    },
    CatalogGlass {
        name: "SF10",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.61625977, 0.259229334, 1.07762317],
            c: [0.0127534559, 0.0581983954, 116.60768],
        },
        nd: 1.72825,
        vd: 28.41,
        range_um: (0.38, 2.5),
    },
    CatalogGlass {
        name: "SF11",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.73848403, 0.311168974, 1.17490871],
            c: [0.0136068604, 0.0615960463, 121.922711],
        },
        nd: 1.78472,
        vd: 25.76,
        range_um: (0.39, 2.5),
    },
    CatalogGlass {
        name: "SF2",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.40301821, 0.231767504, 0.939056586],
            c: [0.0105795466, 0.0493226978, 112.405955],
        },
        nd: 1.64769,
        vd: 33.85,
        range_um: (0.35, 2.5),
    },
    CatalogGlass {
        name: "SF5",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.46141885, 0.247713019, 0.949995832],
            c: [0.0111826126, 0.0508594669, 112.041888],
        },
        nd: 1.6727,
        vd: 32.21,
        range_um: (0.35, 2.5),
    },
    CatalogGlass {
        name: "SF6",
        vendor: "Schott",
        dispersion: Dispersion::Sellmeier3 {
            b: [1.72448482, 0.390104889, 1.04572858],
            c: [0.0134871947, 0.0569318095, 118.557185],
        },
        nd: 1.80518,
        vd: 25.43,
        range_um: (0.365, 2.5),
    },
    CatalogGlass {
        name: "J-BK7A",
        vendor: "Hikari",
        dispersion: Dispersion::Extended {
            a: [
                2.27110883,
                -0.00938988354,
                -0.000100277081,
                0.0109572221,
                0.000120210067,
                3.31079774e-06,
                -1.48235581e-08,
                0.0,
                0.0,
            ],
        },
        nd: 1.5168,
        vd: 64.12995,
        range_um: (0.365015, 2.05809),
    },
    CatalogGlass {
        name: "J-SF10",
        vendor: "Hikari",
        dispersion: Dispersion::Extended {
            a: [
                2.87916509,
                -0.0119049122,
                0.0,
                0.0328054585,
                0.00270047713,
                -0.000476826023,
                0.000107927203,
                -1.07672748e-05,
                5.00986227e-07,
            ],
        },
        nd: 1.72825,
        vd: 28.378835,
        range_um: (0.388865, 2.05809),
    },
    CatalogGlass {
        name: "J-LASF016",
        vendor: "Hikari",
        dispersion: Dispersion::Extended {
            a: [
                3.07219058,
                -0.0142144846,
                -0.000167817254,
                0.0244174902,
                0.000425680243,
                6.77243763e-06,
                4.02219194e-07,
                0.0,
                0.0,
            ],
        },
        nd: 1.7725,
        vd: 49.620185,
        range_um: (0.365015, 2.05809),
    },
];
