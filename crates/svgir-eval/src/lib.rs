//! svgir-eval: SPEC 8's evaluation of svgir runs, kept out of the command line so that the CLI,
//! the tests, the benchmarks and the exporters call the same code.
//!
//! - [`spec8::evaluate`]: a stage-2 model on the dataset's test views: novel views, albedo after
//!   the median scale, roughness, normals, and relighting under every map (SPEC 7 and 8); it
//!   writes the images it scores into the run folder.
//! - [`run`]: a run folder's JSON files and the dataset it was trained on.
//! - [`lpips_weights`]: finding and loading the LPIPS weights.
//! - [`turntable`]: turntable cameras about the object.
//! - [`table`]: result tables (markdown per scene, per metric for the terminal).
//! - [`plot`]: line plots as SVG text (report curves, convergence curves).

#![warn(missing_docs)]

pub mod lpips_weights;
pub mod plot;
pub mod run;
pub mod spec8;
pub mod table;
pub mod turntable;

pub use lpips_weights::load_lpips;
pub use run::{load_run_dataset, read_json};
pub use spec8::{evaluate, EvalSink, EvalWriter, MetricsOnly};
pub use turntable::turntable_cameras;
