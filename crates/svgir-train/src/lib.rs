//! svgir-train: the optimisation layer. Depends on the maths crates (raster, metrics) and the
//! shared types; knows nothing about files except checkpoints.

#![warn(missing_docs)]

pub mod adam;
pub mod checkpoint;
pub mod colour_model;
pub mod composite;
pub mod config;
pub mod coverage;
pub mod densify;
pub mod driver;
pub mod exposure;
pub mod foreground;
pub mod grid_cut;
pub mod gt_materials;
pub mod init;
pub mod losses;
pub mod mask_check;
pub mod mask_refine;
pub mod orient;
pub mod relight;
pub mod stage1;
pub mod stage2;
pub mod surroundings;

pub use config::{BackgroundMode, NamedWeights, Profile, Stage1Config, ViewOrder};
pub use stage1::{Stage1, StepStats};
pub use stage2::{Kernels, Stage2, Stage2Config, Stage2Profile};
