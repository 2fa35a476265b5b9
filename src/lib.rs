//! twistopt: design optimisation of soft twisting pneumatic actuators.
//!
//! * [`geometry`]: the parametric actuator geometry (GEOMETRY.md), closed forms and volumes;
//! * [`meshing`]: structured hexahedral meshes of the wall (Hex8/Hex20/Hex27, full or 120° sector)
//!   with named node/face sets, quality report and shape derivatives;
//! * [`export`]: VTU/PVD, STL and INP writers; [`calculix`]: CalculiX decks of the scenes, runs, results;
//! * [`problem`]: TOML problem files; [`evaluate`]: run a problem's scenes and write its outputs;
//! * [`plot`]: PNG/SVG line plots with an embedded font;
//! * [`sweep`]: resumable, shardable grid sweeps (the letter's Table I), Fig.-5 maps, optimiser check;
//! * [`cli`]: the command-line interface.
pub use twistopt_solver as solver;

pub mod calculix;
pub mod cli;
pub mod evaluate;
pub mod export;
pub mod geometry;
pub mod gradient;
pub mod meshing;
pub mod optimise;
pub mod plot;
pub mod problem;
pub mod rom;
pub mod scene;
pub mod sweep;
