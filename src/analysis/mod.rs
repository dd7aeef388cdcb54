//! Analyses built on the tracer: spot diagrams and their statistics.

pub mod spot;

pub use spot::{
    spot_diagram, spot_diagram_rows, spot_stats, SpotFailure, SpotOptions, SpotResult, SpotStats,
};
