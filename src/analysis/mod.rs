//! Analyses built on the tracer: spot diagrams, their statistics and the spot moments every
//! spot size is computed from.

pub mod aberrations;
pub mod spot;

pub use spot::{
    afocal_spot_diagram_rows, spot_diagram, spot_diagram_rows, spot_stats, SpotFailure,
    SpotMoments, SpotOptions, SpotResult, SpotStats,
};
